"""Env versions: ``-v0`` reproduces seif_gym 0.1 bit for bit, ``-v1`` is the newest behaviour.

The digests below were computed with seif_gym 0.1 (commit 0da2cee), by the
same functions as here: a SHA-256 over every observation array, reward and
pose estimate of a seeded episode. They are regression fixtures of the old
version's output, not expected values of a computation.

"Bit for bit" holds for one set of BLAS/LAPACK kernels: OpenBLAS picks its
kernels by CPU at run time, and kernels of different families round the
small matrix products and factorizations of the filter differently (seif_gym
0.1's own output differs between them). So 0.1's digests are recorded per
OpenBLAS kernel family, for every x86-64 family OpenBLAS has. To record a
family (for example an ARM machine's), run 0.1 on it::

    git worktree add /tmp/seif_gym_0_1 0da2cee
    PYTHONPATH=/tmp/seif_gym_0_1 python tests/env/test_versions.py

which prints the kernel architecture and the five digests of 0.1
(``OPENBLAS_CORETYPE=<name>`` forces a family on a CPU that can run it; that
is how the x86-64 rows were made, on one AMD EPYC).
"""

from __future__ import annotations

import hashlib
import inspect
import warnings

import gymnasium as gym
import numpy as np
import pytest
import scipy.linalg  # noqa: F401  (loads scipy's OpenBLAS, which the compiled kernels' LAPACK calls use)
import threadpoolctl

import seif_gym
from seif_gym.envs.explore import SeifExploreEnv

#: OpenBLAS kernel architecture (as threadpoolctl reports it) -> the family whose results it shares.
KERNEL_FAMILIES: dict[str, str] = {
    **dict.fromkeys(("Prescott", "Core2"), "sse3"),
    **dict.fromkeys(("Nehalem", "Barcelona"), "sse4"),
    **dict.fromkeys(("SandyBridge", "Bulldozer", "Piledriver", "Steamroller", "Excavator"), "avx"),
    **dict.fromkeys(("Haswell", "Zen"), "avx2"),
    **dict.fromkeys(("SkylakeX", "Cooperlake", "SapphireRapids"), "avx512"),
}

#: (env id, kwargs, policy, {kernel family: digest of seif_gym 0.1}).
V0_DIGESTS = [
    ("SeifExplore-v0", {}, "random", {"sse3": "5a65f4fd75926bdd", "sse4": "612c24ef0e296eb7",
     "avx": "46a95c7b028eea91", "avx2": "de88b8089b2ede59", "avx512": "610dcfbba32abb1d"}),
    ("SeifExploreLoop-v0", {}, "random", {"sse3": "0db0c6ea81cb4563", "sse4": "1a01476c5750e1cc",
     "avx": "44cf63ad99e7a1aa", "avx2": "419731381d931bfd", "avx512": "8f45a998679e44f2"}),
    ("SeifExplore-v0", {"filter": "eseif"}, "random", {"sse3": "259feade699cc027", "sse4": "259feade699cc027",
     "avx": "9d397bbbd92ff8d0", "avx2": "f363626823e00e07", "avx512": "04e7a366421de062"}),
    ("SeifExploreLoop-v0", {"data_association": "ml"}, "weave", {"sse3": "9b9f1166d5c24e25",
     "sse4": "251da6885e94fa25", "avx": "e147e2c599f7ba28", "avx2": "2303aac46d94fd41",
     "avx512": "a55ffe2d4e07499b"}),
    ("SeifExplore-v0", {"data_association": "ml"}, "weave", {"sse3": "4b1624752744f1e6",
     "sse4": "9e8883244f507920", "avx": "f4dbf5e3193bbef5", "avx2": "16df03d3d773ea53",
     "avx512": "a86c7a93aecc7d86"}),
]  # fmt: skip


def blas_architecture() -> str:
    """The kernel architecture of the loaded OpenBLAS libraries (numpy's and scipy's must agree)."""
    found = {info.get("architecture") for info in threadpoolctl.threadpool_info() if info["internal_api"] == "openblas"}
    if len(found) != 1:
        raise RuntimeError(
            f"expected one OpenBLAS kernel architecture in numpy and scipy, found {sorted(map(str, found))}"
        )
    return str(found.pop())


def episode_digest(env: gym.Env, policy: str, steps: int) -> str:
    """SHA-256 (16 hex digits) of a seeded episode's observations, rewards and pose estimates."""
    seed = 11 if policy == "random" else 5
    observation, _ = env.reset(seed=seed)
    env.action_space.seed(seed)
    digest = hashlib.sha256()
    for t in range(steps):
        if policy == "random":
            action = env.action_space.sample()
        else:  # a weaving drive that closes loops (association decisions at revisits)
            action = np.array([0.8, 0.25 * np.sin(t / 40.0) + 0.15])
        observation, reward, terminated, truncated, info = env.step(action)
        for key in sorted(observation):
            digest.update(np.ascontiguousarray(observation[key]).tobytes())
        digest.update(np.float64(reward).tobytes())
        digest.update(np.asarray(info["pose_estimate"]).tobytes())
        if terminated or truncated:
            break
    return digest.hexdigest()[:16]


def case_digest(env_id: str, kwargs: dict, policy: str) -> str:
    """:func:`episode_digest` of one case of :data:`V0_DIGESTS` (300 random steps, or 400 of the weave)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # gymnasium: "-v0 is out of date"
        env = gym.make(env_id, **kwargs)
    return episode_digest(env, policy, 300 if policy == "random" else 400)


@pytest.mark.parametrize(
    "env_id, kwargs, policy, expected", V0_DIGESTS, ids=[f"{d[0]}-{d[2]}-{d[1]}" for d in V0_DIGESTS]
)
def test_v0_reproduces_seif_gym_0_1(env_id, kwargs, policy, expected):
    architecture = blas_architecture()
    if architecture not in KERNEL_FAMILIES:
        pytest.fail(
            f"no seif_gym 0.1 digests recorded for OpenBLAS kernels {architecture!r}: record them (module docstring)"
        )
    assert case_digest(env_id, kwargs, policy) == expected[KERNEL_FAMILIES[architecture]]


def test_every_case_has_a_digest_for_every_family():
    for env_id, _, _, digests in V0_DIGESTS:
        assert set(digests) == set(KERNEL_FAMILIES.values()), env_id


def test_every_layout_has_every_version():
    for name in seif_gym.VERSIONED_VARIANTS:
        for version in seif_gym.VERSIONS:
            kwargs, _ = seif_gym.VARIANTS[f"{name}-v{version}"]
            assert kwargs.items() >= seif_gym.VERSIONS[version].items()
    # the MRCLAM world, outside the versioned family: its newest id runs the latest version's settings, its
    # -v0 those of the 0.2 family (kept reproducible when -v2 added the sensor's blind zone)
    assert [i for i in seif_gym.VARIANTS if i.startswith("SeifExploreMRCLAM")] == [
        "SeifExploreMRCLAM-v0",
        seif_gym.MRCLAM_ID,
    ]
    assert seif_gym.VARIANTS[seif_gym.MRCLAM_ID][0].items() >= seif_gym.VERSIONS[seif_gym.LATEST_VERSION].items()
    assert seif_gym.VARIANTS["SeifExploreMRCLAM-v0"][0].items() >= seif_gym.VERSIONS[1].items()


def test_latest_version_is_the_env_default():
    defaults = {name: p.default for name, p in inspect.signature(SeifExploreEnv.__init__).parameters.items()}
    for name, value in seif_gym.VERSIONS[seif_gym.LATEST_VERSION].items():
        assert defaults[name] == value, name


def test_latest_id_is_the_newest_version_and_current():
    # the tools' default task: gymnasium warns about every id older than its newest version, never about this one
    assert seif_gym.LATEST_ID == f"SeifExplore-v{seif_gym.LATEST_VERSION}"
    assert seif_gym.VARIANTS[seif_gym.LATEST_ID][0].items() >= seif_gym.VERSIONS[seif_gym.LATEST_VERSION].items()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym.make(seif_gym.LATEST_ID).close()
        gym.make(f"SeifExplore-v{seif_gym.LATEST_VERSION - 1}").close()
    out_of_date = [str(w.message) for w in caught if "out of date" in str(w.message)]
    assert len(out_of_date) == 1 and f"SeifExplore-v{seif_gym.LATEST_VERSION - 1}" in out_of_date[0], out_of_date


def test_v1_recovery_differs_from_v0():
    """The versions compute different beliefs from the same data (the mean recovery changed)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        old = gym.make("SeifExploreLoop-v0")
    new = gym.make("SeifExploreLoop-v1")
    assert episode_digest(old, "weave", 200) != episode_digest(new, "weave", 200)
    assert new.unwrapped.filter.mean_recovery == "wavefront" and old.unwrapped.filter.mean_recovery == "amortized"


if __name__ == "__main__":  # print this machine's kernel architecture and the digests of the seif_gym on PYTHONPATH
    print(f"OpenBLAS kernels: {blas_architecture()} ({seif_gym.__file__})")
    for env_id, kwargs, policy, _ in V0_DIGESTS:
        print(env_id, kwargs, policy, case_digest(env_id, kwargs, policy))
