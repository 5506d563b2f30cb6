"""The potential-based coverage shaping used to train the shipped policy (agents/shaping.py)."""

from __future__ import annotations

import doctest

import gymnasium as gym
import numpy as np
import pytest

import agents.shaping
import seif_gym  # noqa: F401  (registers the envs)
from agents.shaping import CoverageShaping


def test_module_doctests_pass():
    results = doctest.testmod(agents.shaping)
    assert results.attempted > 0 and results.failed == 0


@pytest.mark.parametrize("coef, gamma", [(1.0, 0.995), (0.3, 1.0), (0.0, 0.9)])
def test_reward_is_the_env_reward_plus_the_potential_difference(coef, gamma):
    plain = gym.make("SeifExplore-v0", max_episode_steps=60)
    shaped = CoverageShaping(gym.make("SeifExplore-v0", max_episode_steps=60), coef=coef, gamma=gamma)
    plain.reset(seed=3)
    _, info = shaped.reset(seed=3)
    previous = info["swept_fraction"]
    assert 0.0 < previous < 1.0
    rng = np.random.default_rng(0)
    grew = False
    for _ in range(60):
        action = rng.uniform(-1.0, 1.0, 2).astype(np.float32)
        _, reward, terminated, truncated, _ = plain.step(action)
        _, shaped_reward, shaped_terminated, shaped_truncated, info = shaped.step(action)
        # same episode: the wrapper changes the reward only
        assert (terminated, truncated) == (shaped_terminated, shaped_truncated)
        potential = info["swept_fraction"]
        expected = reward + coef * (gamma * (0.0 if terminated else potential) - previous)
        assert shaped_reward == pytest.approx(expected, abs=1e-12)
        grew = grew or potential > previous
        previous = potential
        if terminated or truncated:
            break
    assert grew, "driving around should sweep new area"


def test_bad_arguments_are_named():
    env = gym.make("SeifExplore-v0")
    with pytest.raises(ValueError, match="coef"):
        CoverageShaping(env, coef=-1.0)
    with pytest.raises(TypeError, match="gamma"):
        CoverageShaping(env, gamma="0.99")
    with pytest.raises(ValueError, match="gamma"):
        CoverageShaping(env, gamma=1.5)
    with pytest.raises(TypeError, match="SeifExploreEnv"):
        CoverageShaping(gym.make("CartPole-v1"))
