"""SeifExploreVectorEnv: N envs in compiled calls equal a SyncVectorEnv of N single envs, bit for bit."""

from __future__ import annotations

import os
import subprocess
import sys

import gymnasium as gym
import numba
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv

import seif_gym  # noqa: F401  (registers the envs)
from seif_gym.envs.explore import Measurements
from seif_gym.envs.vector import SeifExploreVectorEnv
from seif_gym.threads import numba_threads

#: What ``SeifExploreVectorEnv()``'s defaults compute: the newest uniform id.
LATEST_ID = f"SeifExplore-v{seif_gym.LATEST_VERSION}"


def _assert_equal(a, b, where: str) -> None:
    if isinstance(a, dict):
        assert isinstance(b, dict) and set(a) == set(b), f"{where}: keys {sorted(a)} vs {sorted(b)}"
        for key in a:
            _assert_equal(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, np.ndarray) and a.dtype == object:
        assert isinstance(b, np.ndarray) and b.dtype == object and a.shape == b.shape, where
        for k, (x, y) in enumerate(zip(a, b)):
            _assert_equal(x, y, f"{where}[{k}]")
    elif isinstance(a, Measurements):
        assert isinstance(b, Measurements), where
        for field in Measurements._fields:
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=f"{where}.{field}")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape, (
            f"{where}: {a.dtype}{a.shape} vs {getattr(b, 'dtype', type(b))}{getattr(b, 'shape', '')}"
        )
        np.testing.assert_array_equal(a, b, err_msg=where)
    else:
        assert a == b, f"{where}: {a!r} vs {b!r}"


@pytest.mark.parametrize(
    "mode, threads, num_envs, filter_kwargs",
    [
        (AutoresetMode.NEXT_STEP, 1, 3, {}),
        (AutoresetMode.SAME_STEP, 1, 3, {}),
        # the parallel loop (slow: starts numba's thread pool and compiles the parallel kernels)
        pytest.param(AutoresetMode.NEXT_STEP, numba.config.NUMBA_NUM_THREADS, 3, {}, marks=pytest.mark.slow),
        # envs shared out over the threads
        pytest.param(AutoresetMode.SAME_STEP, numba.config.NUMBA_NUM_THREADS, 40, {}, marks=pytest.mark.slow),
        # the batched ESEIF, relocalizing often (a bound of 3), on one thread and on the parallel loop
        (AutoresetMode.NEXT_STEP, 1, 3, {"filter": "eseif", "max_active": 3}),
        pytest.param(
            AutoresetMode.SAME_STEP,
            numba.config.NUMBA_NUM_THREADS,
            4,
            {"filter": "eseif", "max_active": 3},
            marks=pytest.mark.slow,
        ),
    ],
    ids=["next", "same", "next-threads", "same-threads-40", "eseif-next", "eseif-same-threads"],
)
def test_vector_env_equals_sync_vector_env(mode, threads, num_envs, filter_kwargs):
    steps, limit = 120, 30
    # some episodes end by divergence, the others by the time limit
    kwargs = {"divergence_threshold": 0.06, **filter_kwargs}
    native = SeifExploreVectorEnv(num_envs, max_episode_steps=limit, autoreset_mode=mode, num_threads=threads, **kwargs)
    assert native.backend == "compiled" and native.metadata["autoreset_mode"] == mode
    assert native.num_threads == threads
    reference = SyncVectorEnv([lambda: gym.make(LATEST_ID, max_episode_steps=limit, **kwargs)
                               for _ in range(num_envs)], autoreset_mode=mode)  # fmt: skip
    observations, infos = native.reset(seed=11)
    expected_observations, expected_infos = reference.reset(seed=11)
    _assert_equal(observations, expected_observations, "reset obs")
    _assert_equal(infos, expected_infos, "reset info")
    rng = np.random.default_rng(3)
    ended = {"terminated": 0, "truncated": 0}
    relocalized = 0
    for t in range(steps):
        actions = rng.uniform(-1.0, 1.0, size=(num_envs, 2))
        got = native.step(actions)
        expected = reference.step(actions)
        for name, a, b in zip(("obs", "reward", "terminated", "truncated", "info"), got, expected):
            _assert_equal(a, b, f"step {t} {name}")
        ended["terminated"] += int(got[2].sum())
        ended["truncated"] += int(got[3].sum())
        if filter_kwargs:
            relocalized = max(relocalized, int(native._filters.eseif_counters[:, 0].sum()))
    assert ended["terminated"] > 0 and ended["truncated"] > 0  # both ways of ending (and their resets) exercised
    if filter_kwargs:
        assert relocalized > 0  # the ESEIF's relocalizations exercised
    native.close()
    reference.close()


def test_vector_env_rejects_bad_actions_before_any_env_moves():
    env = SeifExploreVectorEnv(2, max_episode_steps=10)
    env.reset(seed=0)
    poses = env._world.poses.copy()
    with pytest.raises(ValueError, match="actions"):
        env.step(np.array([[0.5, 0.0], [np.nan, 0.0]]))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(2))
    np.testing.assert_array_equal(env._world.poses, poses)
    with pytest.raises(ValueError, match="num_envs"):
        SeifExploreVectorEnv(0)
    with pytest.raises(ValueError, match="autoreset_mode"):
        SeifExploreVectorEnv(1, autoreset_mode="Disabled")
    for threads in (0, numba.config.NUMBA_NUM_THREADS + 1):
        with pytest.raises(ValueError, match="num_threads"):
            SeifExploreVectorEnv(1, num_threads=threads)
    for threads in (1.5, True, None):
        with pytest.raises(TypeError, match="num_threads"):
            SeifExploreVectorEnv(1, num_threads=threads)
    # the context manager checks its count before it starts or changes anything
    for count, error in ((0, ValueError), (numba.config.NUMBA_NUM_THREADS + 1, ValueError), ("2", TypeError)):
        with pytest.raises(error, match="count"), numba_threads(count):
            pass


_THREADED_STEP = """
import multiprocessing
import sys
import torch
import numba, numpy as np
import seif_gym.envs.vector as vector
assert torch.get_num_threads() == 1
env = vector.SeifExploreVectorEnv(4, max_episode_steps=5, num_threads=2)
env.reset(seed=0)
env.step(np.zeros((4, 2)))
print(torch.get_num_threads(), numba.get_num_threads() == numba.config.NUMBA_NUM_THREADS)
if sys.argv[1] == "fork":
    child = multiprocessing.get_context("fork").Process(target=env.step, args=(np.zeros((4, 2)),))
    child.start()
    child.join(120)
    print(child.exitcode)
"""


def _threaded_step(then: str, **variables: str) -> list[str]:
    """Run ``_THREADED_STEP`` in a fresh process (numba's pool starts once per process)."""
    pytest.importorskip("torch", reason="torch is in the train extra")
    # as in the test session and most launchers: OpenMP limited to one thread before torch loads
    env = {**os.environ, "OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "2", **variables}
    command = [sys.executable, "-c", _THREADED_STEP, then]
    result = subprocess.run(command, capture_output=True, text=True, timeout=600, env=env)
    assert result.returncode == 0, result.stderr[-2000:]
    return result.stdout.split()


@pytest.mark.slow
def test_threads_leave_torchs_thread_count_alone():
    """Starting numba's pool on GNU OpenMP (its default where torch is loaded) set torch's threads to 2."""
    assert _threaded_step("stay") == ["1", "True"]


@pytest.mark.slow
def test_threads_on_the_forksafe_layer_survive_a_fork():
    """The documented way to fork after threads: on GNU OpenMP the child is killed (exit code -15)."""
    assert _threaded_step("fork", NUMBA_THREADING_LAYER="forksafe") == ["1", "True", "0"]


def test_sync_backend_renders_sub_env_0_too():
    env = gym.make_vec("SeifExplore-v1", num_envs=2, max_episode_steps=8, render_mode="rgb_array", filter="ekf")
    single = gym.make("SeifExplore-v1", max_episode_steps=8, render_mode="rgb_array", filter="ekf")
    assert env.backend == "sync"
    env.reset(seed=3)
    single.reset(seed=3)
    np.testing.assert_array_equal(env.render(), single.render())  # one frame, as the compiled backend gives
    env.close()
    single.close()


def test_vector_env_renders_sub_env_0_as_the_single_env_would():
    env = gym.make_vec("SeifExplore-v1", num_envs=2, max_episode_steps=8, render_mode="rgb_array")
    assert isinstance(env, SeifExploreVectorEnv) and env.backend == "compiled"
    single = gym.make("SeifExplore-v1", max_episode_steps=8, render_mode="rgb_array")
    observations, _ = env.reset(seed=3)
    expected, _ = single.reset(seed=3)
    np.testing.assert_array_equal(env.render(), single.render())
    rng = np.random.default_rng(0)
    for t in range(12):  # through the time limit and the next episode's start
        actions = rng.uniform(-1, 1, size=(2, 2))
        observations, _, _, truncated, _ = env.step(actions)
        if t == 8:  # NextStep: this step reset sub-env 0
            expected, _ = single.reset()
        else:
            expected, _, _, _, _ = single.step(actions[0])
        for key in expected:
            np.testing.assert_array_equal(observations[key][0], expected[key], err_msg=f"step {t} {key}")
        np.testing.assert_array_equal(env.render(), single.render(), err_msg=f"step {t}")
    env.close()
    single.close()


@pytest.mark.parametrize(
    "env_id", ["SeifExploreLoop-v1", "SeifExploreClustered-v1", "SeifExploreLarge-v1", "SeifExplore-v0"]
)
def test_every_variant_vectorises_equal_to_single_envs(env_id):
    """gym.make_vec(id) is the native env (compiled for -v1, a SyncVectorEnv inside for -v0's amortized recovery)."""
    limit, steps = 15, 35
    native = gym.make_vec(env_id, num_envs=2, max_episode_steps=limit)
    assert isinstance(native, SeifExploreVectorEnv)
    assert native.backend == ("sync" if env_id.endswith("-v0") else "compiled")
    reference = SyncVectorEnv([lambda: gym.make(env_id, max_episode_steps=limit) for _ in range(2)])
    for name, a, b in zip(("obs", "info"), native.reset(seed=2), reference.reset(seed=2)):
        _assert_equal(a, b, f"{env_id} reset {name}")
    rng = np.random.default_rng(1)
    for t in range(steps):
        actions = rng.uniform(-1, 1, size=(2, 2))
        for name, a, b in zip(("obs", "reward", "terminated", "truncated", "info"), native.step(actions),
                              reference.step(actions)):  # fmt: skip
            _assert_equal(a, b, f"{env_id} step {t} {name}")
    native.close()
    reference.close()


def test_vector_env_passes_checker_style_checks():
    """What gymnasium's env checker asks of an env, asked of the vector env: spaces, dtypes, seeding, metadata."""
    env = gym.make_vec("SeifExplore-v1", num_envs=3)
    assert isinstance(env.metadata["autoreset_mode"], AutoresetMode)
    assert env.observation_space == gym.vector.utils.batch_space(env.single_observation_space, 3)
    assert env.action_space == gym.vector.utils.batch_space(env.single_action_space, 3)
    first, _ = env.reset(seed=5)
    assert env.observation_space.contains(first)
    again, _ = env.reset(seed=5)
    _assert_equal(first, again, "reset(seed) is reproducible")
    different, _ = env.reset(seed=6)
    assert not np.array_equal(first["pose"], different["pose"])
    env.action_space.seed(0)
    for _ in range(5):
        obs, rewards, terminated, truncated, infos = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs)
        assert rewards.dtype == np.float64 and rewards.shape == (3,)
        assert terminated.dtype == truncated.dtype == np.bool_ and terminated.shape == (3,)
        for key, value in infos.items():
            if not key.startswith("_"):
                assert infos[f"_{key}"].dtype == np.bool_ and len(value) == 3, key
    # per-sub-env seeds, None among them: that sub-env draws its own seed
    obs, _ = env.reset(seed=[1, None, 3])
    single, _ = gym.make("SeifExplore-v1").reset(seed=3)
    np.testing.assert_array_equal(obs["belief_map"][2], single["belief_map"])
    with pytest.raises(ValueError, match="seed"):
        env.reset(seed=[1, 2])
    env.close()


def test_large_maps_take_the_sparse_pose_marginal_like_the_single_env(monkeypatch):
    """Above the dense threshold both envs factorise Omega sparsely, and info['pose_nees'] still agrees bit for bit."""
    from seif_gym.envs import vector
    from seif_gym.slam import SEIF

    monkeypatch.setattr(vector, "DENSE_MARGINALS_UP_TO", 1)
    monkeypatch.setattr(SEIF, "DENSE_MARGINALS_UP_TO", 1)
    native = SeifExploreVectorEnv(2, max_episode_steps=30)
    reference = SyncVectorEnv([lambda: gym.make("SeifExplore-v1", max_episode_steps=30) for _ in range(2)])
    native.reset(seed=8)
    reference.reset(seed=8)
    rng = np.random.default_rng(2)
    sparse_steps = 0
    for t in range(25):
        actions = rng.uniform(-1, 1, size=(2, 2))
        got, expected = native.step(actions), reference.step(actions)
        _assert_equal(got[4], expected[4], f"step {t} info")
        sparse_steps += int((got[4]["landmarks_mapped"] > 1).sum())
    assert sparse_steps > 10  # the sparse path was taken


def test_exact_pose_nees_off_vectorises_like_the_single_env():
    """``exact_pose_nees=False`` in the compiled backend: NaN NEES on small and large maps, all else as before.

    Equal to a SyncVectorEnv of single envs with the same argument, and, but for the NEES, to the
    native env that computes it; 80 landmarks seen all round to 12 m pass the dense threshold (60).
    """
    kwargs = {"num_landmarks": 80, "sensor_range": 12.0, "fov": 2 * np.pi}
    cheap = SeifExploreVectorEnv(2, max_episode_steps=40, exact_pose_nees=False, **kwargs)
    exact = SeifExploreVectorEnv(2, max_episode_steps=40, **kwargs)
    reference = SyncVectorEnv(
        [lambda: gym.make(LATEST_ID, max_episode_steps=40, exact_pose_nees=False, **kwargs) for _ in range(2)]
    )
    assert cheap.backend == "compiled"
    for env in (cheap, exact, reference):
        env.reset(seed=3)
    rng = np.random.default_rng(3)
    large = 0
    for t in range(30):
        actions = rng.uniform(-1, 1, size=(2, 2))
        got, with_nees, expected = cheap.step(actions), exact.step(actions), reference.step(actions)
        for k in range(5):
            _assert_equal(got[k], expected[k], f"step {t} [{k}]")
        assert np.isnan(got[4]["pose_nees"]).all() and np.isfinite(with_nees[4]["pose_nees"]).all()
        got[4]["pose_nees"] = with_nees[4]["pose_nees"]
        for k in range(5):
            _assert_equal(got[k], with_nees[k], f"step {t} [{k}] (exact NEES)")
        large += int((got[4]["landmarks_mapped"] > 60).sum())
    assert large > 10  # the sparse factorisation's side was reached
    for env in (cheap, exact, reference):
        env.close()


def test_bench_vector_stages_split_the_native_step():
    """``benchmarks/bench_vector.py --stages``: every compiled call of the step is timed, and only once."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_vector.py"
    spec = importlib.util.spec_from_file_location("bench_vector", path)
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    stages = bench.stage_times("SeifExplore-v2", 2, {}, 0.3)
    compiled = [name for name in stages if not name.startswith("Python")]
    assert len(compiled) == 6 and all(stages[name] > 0.0 for name in compiled)
    assert stages["Python around them (infos, checks, autoresets)"] > 0.0
    # the module's kernels are restored: a new env steps with the originals
    from seif_gym.envs import vector

    assert vector.encode_many.__module__ == "seif_gym.observation" and hasattr(vector._score_many, "py_func")
    with pytest.raises(SystemExit, match="compiled native env"):
        bench.stage_times("SeifExplore-v2", 2, {"filter": "ekf"}, 0.1)
