"""The budget's clock in the observation (agents/time_feature.py): the training wrapper and the agent's side."""

from __future__ import annotations

import doctest

import gymnasium as gym
import numpy as np
import pytest
from policy_entry_checks import assert_acts_as_trained  # tests/ is on sys.path under pytest

import agents.time_feature
import seif_gym  # noqa: F401  (registers the envs)
from agents.evaluate import SB3Agent, run_episode
from agents.networks import BeliefPolicy
from agents.time_feature import TIME_LEFT, TimeLeftClock, TimeLeftObservation, episode_limit, uses_time_left
from seif_gym.envs.explore import SeifExploreEnv


def test_module_doctests_pass():
    results = doctest.testmod(agents.time_feature)
    assert results.attempted > 0 and results.failed == 0


def test_wrapper_adds_the_fraction_left_and_ends_the_task_at_the_limit():
    limit = 7
    plain = gym.make("SeifExploreBudget-v2", max_episode_steps=limit)
    wrapped = TimeLeftObservation(gym.make("SeifExploreBudget-v2", max_episode_steps=limit))
    assert uses_time_left(wrapped.observation_space) and not uses_time_left(plain.observation_space)
    expected_observation, _ = plain.reset(seed=4)
    observation, _ = wrapped.reset(seed=4)
    assert wrapped.observation_space.contains(observation)
    rng = np.random.default_rng(1)
    for step in range(1, limit + 1):
        # the env's own entries are untouched
        for key, value in expected_observation.items():
            np.testing.assert_array_equal(observation[key], value)
        assert observation[TIME_LEFT].dtype == np.float32 and observation[TIME_LEFT].shape == (1,)
        assert observation[TIME_LEFT][0] == pytest.approx((limit - step + 1) / limit)
        action = rng.uniform(-1.0, 1.0, 2).astype(np.float32)
        expected_observation, expected_reward, _, expected_truncated, _ = plain.step(action)
        observation, reward, terminated, truncated, _ = wrapped.step(action)
        assert reward == expected_reward
        # the limit ends the task: a terminal state, never a truncation to bootstrap across
        assert expected_truncated == (step == limit)
        assert (terminated, truncated) == (step == limit, False)
    assert observation[TIME_LEFT][0] == 0.0
    # a reset restarts the clock
    observation, _ = wrapped.reset(seed=5)
    assert observation[TIME_LEFT][0] == 1.0


def test_clock_gives_the_wrappers_entry_single_and_batched():
    limit = 5
    wrapped = TimeLeftObservation(gym.make("SeifExploreBudget-v2", max_episode_steps=limit))
    plain = gym.make("SeifExploreBudget-v2", max_episode_steps=limit)
    clock = TimeLeftClock(episode_limit(plain))
    observation, _ = wrapped.reset(seed=0)
    plain_observation, _ = plain.reset(seed=0)
    start = True
    for _ in range(limit):
        seen = clock.observe(plain_observation, np.array([start]))
        start = False
        np.testing.assert_array_equal(seen[TIME_LEFT], observation[TIME_LEFT])
        assert TIME_LEFT not in plain_observation  # the caller's dict is not changed
        action = np.array([0.5, 0.1], dtype=np.float32)
        observation, *_ = wrapped.step(action)
        plain_observation, *_ = plain.step(action)
    # batched: each env counts on its own; episode_start restarts one
    batch = {"pose": np.zeros((3, 7), dtype=np.float32)}
    clock = TimeLeftClock(4)
    first = clock.observe(batch, np.array([True, True, True]))
    np.testing.assert_array_equal(first[TIME_LEFT], np.ones((3, 1), dtype=np.float32))
    clock.observe(batch, np.array([False, False, False]))
    third = clock.observe(batch, np.array([False, True, False]))
    np.testing.assert_allclose(third[TIME_LEFT][:, 0], [0.5, 1.0, 0.5])
    clock.reset(2)
    fourth = clock.observe(batch)
    np.testing.assert_allclose(fourth[TIME_LEFT][:, 0], [0.25, 0.75, 1.0])
    # an observation that has the entry already keeps it
    given = {"pose": np.zeros(7, dtype=np.float32), TIME_LEFT: np.array([0.3], dtype=np.float32)}
    assert TimeLeftClock(4).observe(given)[TIME_LEFT][0] == np.float32(0.3)


def test_bad_input_is_refused_clearly():
    with pytest.raises(TypeError, match="env"):
        TimeLeftObservation(gym.make("CartPole-v1"))
    with pytest.raises(ValueError, match="max_episode_steps"):
        TimeLeftObservation(SeifExploreEnv())
    wrapped = TimeLeftObservation(gym.make("SeifExploreBudget-v2"))
    with pytest.raises(ValueError, match="already"):
        TimeLeftObservation(wrapped)
    for limit, error in ((0, ValueError), (-3, ValueError), (2.5, TypeError), (True, TypeError), (None, TypeError)):
        with pytest.raises(error, match="limit"):
            TimeLeftClock(limit)  # type: ignore[arg-type]
    clock = TimeLeftClock(3)
    single = {"pose": np.zeros(7, dtype=np.float32)}
    clock.observe(single, np.array([True]))
    with pytest.raises(ValueError, match="episode_start"):
        clock.observe({"pose": np.zeros((2, 7), dtype=np.float32)}, np.array([True, False, True]))
    # the refused call changed nothing: the single env's count goes on
    assert clock.observe(single)[TIME_LEFT][0] == pytest.approx(2 / 3)


def test_a_policy_with_the_clock_runs_on_the_plain_env(tmp_path):
    """A model trained on the wrapped env is evaluated on the plain one: SB3Agent adds the entry itself."""
    from stable_baselines3 import PPO

    limit = 6
    training_env = TimeLeftObservation(gym.make("SeifExploreBudget-v2", max_episode_steps=limit))
    model = PPO(BeliefPolicy, training_env, n_steps=8, batch_size=8, seed=0, device="cpu")
    path = tmp_path / "model.zip"
    model.save(path)

    env = gym.make("SeifExploreBudget-v2", max_episode_steps=limit)
    agent = SB3Agent(path, env=env)
    assert agent.memories is not None
    (clock,) = agent.memories.memories
    assert isinstance(clock, TimeLeftClock) and clock.limit == limit
    seen: list[float] = []
    predict = agent.model.predict

    def recording_predict(observation, **kwargs):
        seen.append(float(observation[TIME_LEFT][0]))
        return predict(observation, **kwargs)

    agent.model.predict = recording_predict  # type: ignore[method-assign]
    for seed in (0, 1):
        seen.clear()
        row, _ = run_episode(agent, env, seed)
        assert row["length"] == limit
        np.testing.assert_allclose(seen, [(limit - step) / limit for step in range(limit)])
    # same actions as the model given the wrapper's observations
    assert_acts_as_trained(agent, predict, training_env, env, seeds=(2,), steps=limit)


def test_the_benchmark_takes_a_policy_with_the_clock(tmp_path):
    from stable_baselines3 import PPO

    from agents.benchmark import ShippedPolicy, policy_fits

    env = TimeLeftObservation(gym.make("SeifExploreBudget-v2"))
    path = tmp_path / "model.zip"
    PPO(BeliefPolicy, env, n_steps=8, batch_size=8, seed=0, device="cpu").save(path)
    assert policy_fits(ShippedPolicy(path, "SeifExploreBudget-v2", "here"), "SeifExploreBudget-v2")
    # the plain policy of the same task does not take the wrapped observation
    assert not policy_fits(ShippedPolicy(path, "SeifExploreBudget-v2", "here"), "CartPole-v1")
