"""Env versions: ``-v0`` reproduces seif_gym 0.1 bit for bit, ``-v1`` is the newest behaviour.

The digests below were computed with seif_gym 0.1 (commit 0da2cee), by the
same functions as here: a SHA-256 over every observation array, reward and
pose estimate of a seeded episode. They are regression fixtures of the old
version's output, not expected values of a computation.
"""

from __future__ import annotations

import hashlib
import inspect
import warnings

import gymnasium as gym
import numpy as np
import pytest

import seif_gym
from seif_gym.envs.explore import SeifExploreEnv

#: (env id, kwargs, seed, policy) -> digest of seif_gym 0.1.
V0_DIGESTS = [
    ("SeifExplore-v0", {}, "random", "de88b8089b2ede59"),
    ("SeifExploreLoop-v0", {}, "random", "419731381d931bfd"),
    ("SeifExplore-v0", {"filter": "eseif"}, "random", "f363626823e00e07"),
    ("SeifExploreLoop-v0", {"data_association": "ml"}, "weave", "2303aac46d94fd41"),
    ("SeifExplore-v0", {"data_association": "ml"}, "weave", "16df03d3d773ea53"),
]


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


@pytest.mark.parametrize(
    "env_id, kwargs, policy, expected", V0_DIGESTS, ids=[f"{d[0]}-{d[2]}-{d[1]}" for d in V0_DIGESTS]
)
def test_v0_reproduces_seif_gym_0_1(env_id, kwargs, policy, expected):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # gymnasium: "-v0 is out of date"
        env = gym.make(env_id, **kwargs)
    steps = 300 if policy == "random" else 400
    assert episode_digest(env, policy, steps) == expected


def test_every_layout_has_every_version():
    for name in seif_gym.VERSIONED_VARIANTS:
        for version in seif_gym.VERSIONS:
            kwargs, _ = seif_gym.VARIANTS[f"{name}-v{version}"]
            assert kwargs.items() >= seif_gym.VERSIONS[version].items()
    # the variants outside the versioned family run the latest version's settings
    for env_id, (kwargs, _) in seif_gym.VARIANTS.items():
        if env_id.rsplit("-v", 1)[0] not in seif_gym.VERSIONED_VARIANTS:
            assert kwargs.items() >= seif_gym.VERSIONS[seif_gym.LATEST_VERSION].items(), env_id


def test_latest_version_is_the_env_default():
    defaults = {name: p.default for name, p in inspect.signature(SeifExploreEnv.__init__).parameters.items()}
    for name, value in seif_gym.VERSIONS[seif_gym.LATEST_VERSION].items():
        assert defaults[name] == value, name


def test_v1_recovery_differs_from_v0():
    """The versions compute different beliefs from the same data (the mean recovery changed)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        old = gym.make("SeifExploreLoop-v0")
    new = gym.make("SeifExploreLoop-v1")
    assert episode_digest(old, "weave", 200) != episode_digest(new, "weave", 200)
    assert new.unwrapped.filter.mean_recovery == "wavefront" and old.unwrapped.filter.mean_recovery == "amortized"
