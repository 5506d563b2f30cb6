"""info_gain's planner: every plan equals the reference planner's (the chosen action and every score, bit for bit).

:meth:`InfoGainAgent.plan` rolls all candidates out together in compiled code and computes their swept
areas together; :meth:`InfoGainAgent._plan_reference` is the planner as first written (a deep copy of the
filter per candidate, stepped by the filter's own methods, one raster per candidate). Along episodes of the
leaderboard's seeds the two must choose the same action with the same score arrays at every plan, and
neither may change the env's filter.
"""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest

import seif_gym  # noqa: F401  (registers the envs)
from agents import make_agent
from agents.protocol import HELD_OUT_SEED

SCORES = ("gain", "explore", "walls", "score")


def _compare_plans(env_id: str, seed: int, steps: int, **env_kwargs) -> int:
    """Run ``steps`` steps of info_gain; at every plan compare the two planners. Returns the plans compared."""
    env = gym.make(env_id, **env_kwargs)
    agent = make_agent("info_gain", env)
    obs, _ = env.reset(seed=seed)
    base = env.unwrapped
    plans = 0
    for step in range(steps):
        if agent._state(0).repeat <= 0:  # this step plans
            where = f"{env_id} seed {seed} step {step}"
            before = pickle.dumps(base.filter)
            expected_action = agent._plan_reference(obs)
            expected = agent.last_plan
            assert pickle.dumps(base.filter) == before, f"{where}: the reference planner changed the filter"
            action = agent.plan(obs)
            assert pickle.dumps(base.filter) == before, f"{where}: the planner changed the filter"
            np.testing.assert_array_equal(action, expected_action, err_msg=where)
            for name in SCORES:
                np.testing.assert_array_equal(agent.last_plan[name], expected[name], err_msg=f"{where}: {name}")
            plans += 1
        action, _ = agent.predict(obs)
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            break
    env.close()
    return plans


@pytest.mark.parametrize("env_id", ["SeifExplore-v2", "SeifExploreLoop-v2", "SeifExploreLarge-v2"])
def test_plans_equal_the_reference_planner(env_id):
    for seed in (HELD_OUT_SEED, HELD_OUT_SEED + 1):
        assert _compare_plans(env_id, seed, 80) >= 20


def test_plans_equal_the_reference_planner_with_an_eseif_and_a_fallback_filter():
    assert _compare_plans("SeifExplore-v2", HELD_OUT_SEED + 1, 24, filter="eseif", max_active=4) >= 6
    assert _compare_plans("SeifExplore-v2", HELD_OUT_SEED + 1, 12, filter="ekf") >= 3  # deep copies on both sides


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ["SeifExplore-v2", "SeifExploreLoop-v2", "SeifExploreLarge-v2"])
def test_plans_equal_the_reference_planner_along_long_episodes(env_id):
    for seed in range(HELD_OUT_SEED, HELD_OUT_SEED + 4):
        assert _compare_plans(env_id, seed, 240) >= 50


@pytest.mark.slow
def test_plans_equal_the_reference_planner_over_a_whole_large_episode():
    """1000 steps: the map fills up to its 120 landmarks and the recovery queue holds most of them."""
    assert _compare_plans("SeifExploreLarge-v2", HELD_OUT_SEED + 3, 1000) >= 200
