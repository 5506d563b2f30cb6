"""The native vector env with ``filter="cseif"``: the batched ConservativeSEIF equals N single envs, bit for bit."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import SyncVectorEnv

import seif_gym  # noqa: F401  (registers the envs)
from seif_gym.envs.vector import SeifExploreVectorEnv
from seif_gym.slam import ConservativeSEIF
from seif_gym.slam.batched import BatchedConservativeSEIF


def _assert_equal(a, b, where: str) -> None:
    if isinstance(a, tuple) and not hasattr(a, "_fields"):
        assert isinstance(b, tuple) and len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b)):
            _assert_equal(x, y, f"{where}[{k}]")
    elif isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), f"{where}: keys {sorted(a)} vs {sorted(b)}"
        for key in a:
            _assert_equal(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, np.ndarray) and a.dtype == object:
        assert isinstance(b, np.ndarray) and b.dtype == object and a.shape == b.shape, where
        for k, (x, y) in enumerate(zip(a, b)):
            _assert_equal(x, y, f"{where}[{k}]")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape, where
        np.testing.assert_array_equal(a, b, err_msg=where)
    elif hasattr(a, "_fields"):  # Measurements
        for field in a._fields:
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=f"{where}.{field}")
    else:
        assert a == b, f"{where}: {a!r} vs {b!r}"


@pytest.mark.parametrize(
    "options, limit, steps",
    [
        # short episodes that end by divergence or the time limit, many cuts
        ({"max_active": 3, "divergence_threshold": 0.06}, 40, 90),
        # the env's defaults (a bound of 8), two whole episodes
        ({}, 400, 800),
    ],
)
def test_make_vec_cseif_equals_three_single_envs(options, limit, steps):
    """``gym.make_vec(..., filter="cseif")`` runs compiled and returns what three single envs return."""
    num_envs = 3
    kwargs = {"filter": "cseif", **options}
    native = gym.make_vec("SeifExplore-v2", num_envs=num_envs, max_episode_steps=limit, **kwargs)
    assert isinstance(native.unwrapped, SeifExploreVectorEnv)
    assert native.unwrapped.backend == "compiled"
    filters = native.unwrapped._filters
    assert isinstance(filters, BatchedConservativeSEIF)
    reference = SyncVectorEnv([lambda: gym.make("SeifExplore-v2", max_episode_steps=limit, **kwargs)
                               for _ in range(num_envs)])  # fmt: skip
    _assert_equal(native.reset(seed=5), reference.reset(seed=5), "reset")
    rng = np.random.default_rng(2)
    ended = cuts = 0
    for t in range(steps):
        actions = rng.uniform(-1.0, 1.0, size=(num_envs, 2))
        got, expected = native.step(actions), reference.step(actions)
        for name, a, b in zip(("obs", "reward", "terminated", "truncated", "info"), got, expected):
            _assert_equal(a, b, f"step {t} {name}")
        ended += int(got[2].sum() + got[3].sum())
        cuts = max(cuts, int(filters.cseif_counters[:, 0].sum()))
    assert ended > 0  # an episode ended and its sub-env was reset and loaded again
    assert cuts > 0  # certified cuts happened in the batch
    # the batch's filter, rebuilt, is the single env's
    for e in range(num_envs):
        rebuilt = filters.to_filter(e)
        single = reference.envs[e].unwrapped.filter
        assert isinstance(rebuilt, ConservativeSEIF) and isinstance(single, ConservativeSEIF)
        np.testing.assert_array_equal(rebuilt.mean, single.mean)
        np.testing.assert_array_equal(rebuilt._map_info, single._map_info)
        assert (rebuilt.cuts, rebuilt.deferred_cuts, rebuilt.discarded_measurements) == (
            single.cuts,
            single.deferred_cuts,
            single.discarded_measurements,
        )
    native.close()
    reference.close()


@pytest.mark.parametrize("threads, backend", [(1, "compiled"), (2, "sync")])
def test_cseif_backend(threads, backend):
    """The ConservativeSEIF's batched update runs on one thread; with more the vector env steps single envs."""
    if threads > 1:
        import numba

        if numba.config.NUMBA_NUM_THREADS < threads:
            pytest.skip("needs two numba threads")
    env = SeifExploreVectorEnv(2, filter="cseif", num_threads=threads)
    assert env.backend == backend
    env.close()
