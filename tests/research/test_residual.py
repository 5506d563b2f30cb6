"""The residual on the info_gain planner (agents/residual.py) and its agent side (agents/memories.py)."""

from __future__ import annotations

import doctest

import gymnasium as gym
import numpy as np
import pytest

import research.residual
import seif_gym  # noqa: F401  (registers the envs)
from agents.baselines import make_agent
from agents.evaluate import SB3Agent, run_episode
from agents.memories import policy_memories
from agents.networks import BeliefPolicy
from research.coverage_memory import CoverageMemoryObservation
from research.residual import PLANNER_ACTION, PlannerResidual, PlannerResidualAction, uses_planner_action

LARGE = "SeifExploreLarge-v2"


def test_module_doctest_passes():
    results = doctest.testmod(research.residual)
    assert results.attempted > 0 and results.failed == 0


def test_a_zero_residual_is_the_planner_bit_for_bit():
    """Ten plans on the large world: the wrapper with a zero residual is info_gain's episode, step for step."""
    env = PlannerResidualAction(gym.make(LARGE))
    plain = gym.make(LARGE)
    planner = make_agent("info_gain", plain)
    observation, _ = env.reset(seed=7)
    expected, _ = plain.reset(seed=7)
    for _ in range(40):
        action, _ = planner.predict(expected)
        np.testing.assert_array_equal(observation[PLANNER_ACTION], action)
        observation, reward, terminated, truncated, _ = env.step(np.zeros(2, dtype=np.float32))
        expected, expected_reward, *_ = plain.step(action)
        assert reward == expected_reward and not (terminated or truncated)
        for key in ("pose", "belief_map"):
            np.testing.assert_array_equal(observation[key], expected[key])


def test_the_env_executes_the_clipped_sum():
    env = PlannerResidualAction(gym.make(LARGE))
    twin = gym.make(LARGE)
    observation, _ = env.reset(seed=1)
    twin.reset(seed=1)
    residual = np.array([1.5, -0.4], dtype=np.float32)  # the speed's sum lies beyond 1
    executed = np.clip(observation[PLANNER_ACTION] + residual, -1.0, 1.0)
    assert executed[0] == 1.0
    observation, *_ = env.step(residual)
    expected, *_ = twin.step(executed)
    np.testing.assert_array_equal(observation["pose"], expected["pose"])
    assert env.observation_space.contains(observation) and uses_planner_action(env.observation_space)


def test_acting_needs_the_steps_observation_and_the_actions_shape():
    env = gym.make(LARGE)
    residual = PlannerResidual(env)
    observation, _ = env.reset(seed=0)
    with pytest.raises(RuntimeError, match="observe"):
        residual.act(np.zeros(2))
    plan = residual.observe(observation, episode_start=True)[PLANNER_ACTION]
    with pytest.raises(ValueError, match="residual"):
        residual.act(np.zeros(3))
    # the refused residual changed nothing: the step's plan still stands, and is used once
    np.testing.assert_array_equal(residual.act(np.zeros(2)), plan)
    with pytest.raises(RuntimeError, match="observe"):
        residual.act(np.zeros(2))


def _next_action(tell: bool) -> tuple[np.ndarray, np.ndarray]:
    """info_gain's first action, and its next after the robot was held still (told so, or not)."""
    env = gym.make(LARGE)
    agent = make_agent("info_gain", env)
    observation, _ = env.reset(seed=0)
    planned, _ = agent.predict(observation)
    still = np.zeros(2, dtype=np.float32)
    if tell:
        agent.executed(still)
    observation, *_ = env.step(still)
    return planned, agent.predict(observation)[0]


def test_a_planner_told_the_executed_action_does_not_take_it_for_a_bump():
    planned, untold = _next_action(tell=False)
    assert planned[0] > 0.3  # a speed the bump check looks at
    # not told, the planner reads the robot standing still as a bump and turns away
    np.testing.assert_array_equal(untold, [0.0, 1.0])
    # told that the robot was held, it goes on with its plan (repeated for replan_every steps)
    _, told = _next_action(tell=True)
    np.testing.assert_array_equal(told, planned)


def test_a_residual_policy_runs_on_the_plain_env(tmp_path):
    """A model trained on the wrapped env is evaluated on the plain one: the agent adds the plan and the sum."""
    from stable_baselines3 import PPO

    from agents.benchmark import ShippedPolicy, policy_fits
    from agents.callbacks import _NormalizedPolicy

    limit = 6
    training_env = PlannerResidualAction(CoverageMemoryObservation(gym.make(LARGE, max_episode_steps=limit)))
    path = tmp_path / "model.zip"
    model = PPO(BeliefPolicy, training_env, n_steps=8, batch_size=8, seed=0, device="cpu")
    model.save(path)
    assert policy_fits(ShippedPolicy(path, LARGE, "here"), LARGE)
    assert [
        type(memory).__name__ for memory in policy_memories(training_env.observation_space, training_env).memories
    ] == [
        "CoverageMemory",
        "PlannerResidual",
    ]

    env = gym.make(LARGE, max_episode_steps=limit)
    agent = SB3Agent(path, env=env)
    validation_env = gym.make(LARGE, max_episode_steps=limit)
    validation = _NormalizedPolicy(model, deterministic=True, env=validation_env)
    row, _ = run_episode(agent, env, 0)
    assert row["length"] == limit
    for seed in (2, 3):
        observation, _ = training_env.reset(seed=seed)
        plain, _ = env.reset(seed=seed)
        validation_observation, _ = validation_env.reset(seed=seed)
        agent.reset()
        validation.reset()
        for step in range(limit):
            residual, _ = agent.model.predict(observation, deterministic=True)
            start = np.array([step == 0])
            action, _ = agent.predict(plain, episode_start=start, deterministic=True)
            np.testing.assert_array_equal(action, np.clip(observation[PLANNER_ACTION] + residual, -1.0, 1.0))
            # the validation callback's policy acts the same way
            np.testing.assert_array_equal(validation.predict(validation_observation, episode_start=start)[0], action)
            observation, *_ = training_env.step(residual)
            plain, *_ = env.step(action)
            validation_observation, *_ = validation_env.step(action)
            np.testing.assert_array_equal(plain["pose"], observation["pose"])
    with pytest.raises(ValueError, match="env: .*residual"):
        SB3Agent(path)
