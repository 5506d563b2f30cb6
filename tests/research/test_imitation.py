"""Kickstarting (research.imitation): demonstrations, behaviour cloning, DAgger, and agents.train --kickstart."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import torch

import seif_gym  # noqa: F401
from agents import make_agent
from research.imitation import (
    Demonstrations,
    behaviour_clone,
    collect_demonstrations,
    discounted_returns,
    running_returns,
)

pytest.importorskip("rl_zoo3", reason="rl_zoo3 is in the train extra")

from research.kickstart import build_parser, kickstart_seeds, prepare  # noqa: E402

ENV_KWARGS = {"num_landmarks": 10, "max_episode_steps": 25}
#: a tiny PPO run: 2 envs of 10 landmarks, 25-step episodes
SMALL = [
    "--env",
    "SeifExplore-v2",
    "--n-envs",
    "2",
    "--seed",
    "3",
    "--env-kwargs",
    json.dumps(ENV_KWARGS),
    "--hyperparams",
    "n_steps=64",
    "batch_size=64",
    "n_epochs=1",
]


def small_env() -> gym.Env:
    return gym.make("SeifExplore-v2", **ENV_KWARGS)


def test_module_doctests_pass():
    import doctest

    import research.imitation

    results = doctest.testmod(research.imitation)
    assert results.attempted > 0 and results.failed == 0


def test_discounted_returns_restart_at_each_episode_end():
    rewards = [1.0, 2.0, 3.0, 4.0, 5.0]
    dones = [False, True, False, False, True]
    expected = [1.0 + 0.9 * 2.0, 2.0, 3.0 + 0.9 * 4.0 + 0.81 * 5.0, 4.0 + 0.9 * 5.0, 5.0]
    np.testing.assert_allclose(discounted_returns(rewards, dones, 0.9), expected)
    with pytest.raises(ValueError, match="rewards and dones"):
        discounted_returns([1.0, 2.0], [True], 0.9)


def test_running_returns_give_the_statistics_vecnormalize_would_gather():
    from stable_baselines3.common.running_mean_std import RunningMeanStd

    rng = np.random.default_rng(0)
    rewards = rng.normal(size=30)
    dones = np.zeros(30, dtype=bool)
    dones[[9, 29]] = True
    demos = Demonstrations({"x": np.zeros((30, 1))}, np.zeros((30, 2)), rewards, dones)
    reference, running = RunningMeanStd(shape=()), 0.0
    for reward, done in zip(rewards, dones, strict=True):
        running = running * 0.99 + reward
        reference.update(np.array([running]))
        running = 0.0 if done else running
    # one batch of the running returns gives the statistics of their step-by-step updates
    gathered = RunningMeanStd(shape=())
    gathered.update(running_returns(demos, 0.99))
    assert gathered.count == pytest.approx(reference.count)
    np.testing.assert_allclose([gathered.mean, gathered.var], [reference.mean, reference.var], rtol=1e-3)


def test_teacher_episodes_are_labelled_with_the_teachers_own_actions():
    demos = collect_demonstrations(small_env, "frontier", [11, 12])
    assert len(demos) == 50 and demos.actions.shape == (50, 2) and demos.dones.sum() == 2
    assert set(demos.observations) == set(small_env().observation_space.spaces)
    # replaying the first episode with the teacher gives the same actions and observations
    env = small_env()
    teacher = make_agent("frontier", env)
    observation, _ = env.reset(seed=11)
    for t in range(25):
        np.testing.assert_array_equal(observation["belief_map"], demos.observations["belief_map"][t])
        action = teacher.predict(observation, deterministic=True)[0]
        np.testing.assert_array_equal(action, demos.actions[t])
        observation, *_ = env.step(action)


def test_dagger_episodes_are_driven_by_the_learner_and_labelled_by_the_teacher():
    still = np.zeros(2, dtype=np.float32)
    demos = collect_demonstrations(small_env, "frontier", [11], learner=lambda observation: still)
    # the robot never moves, so the pose in the observation stays where it started ...
    assert np.ptp(demos.observations["pose"][:, :2], axis=0).max() < 1e-6
    # ... while the teacher asks it to move (to drive, then, thinking it bumped, to turn)
    assert np.all(np.abs(demos.actions).max(axis=1) > 0.0)


@pytest.mark.slow
def test_behaviour_cloning_fits_the_actions_and_the_values(tmp_path):
    _, model = prepare(build_parser().parse_args([*SMALL, "--out", str(tmp_path)]))
    demos = collect_demonstrations(small_env, "random", [21, 22])
    target = np.array([0.6, -0.4], dtype=np.float32)
    demos.actions[:] = target
    values = np.linspace(-1.0, 1.0, len(demos))
    losses = behaviour_clone(model.policy, demos, value_targets=values, epochs=60, learning_rate=3e-3, seed=0)
    assert losses[-1] < losses[0]
    observation = {key: value[:10] for key, value in demos.observations.items()}
    actions, _ = model.predict(observation, deterministic=True)
    np.testing.assert_allclose(actions, np.tile(target, (10, 1)), atol=0.05)
    predicted = model.policy.predict_values(model.policy.obs_to_tensor(demos.observations)[0]).detach().numpy()
    assert np.corrcoef(predicted.ravel(), values)[0, 1] > 0.9


def test_behaviour_cloning_refuses_bad_input(tmp_path):
    _, model = prepare(build_parser().parse_args([*SMALL, "--out", str(tmp_path)]))
    demos = collect_demonstrations(small_env, "random", [21])
    with pytest.raises(ValueError, match="value_targets"):
        behaviour_clone(model.policy, demos, value_targets=np.zeros(3))
    before = {k: v.clone() for k, v in model.policy.state_dict().items()}
    with pytest.raises(ValueError, match="epochs and batch_size"):
        behaviour_clone(model.policy, demos, epochs=0)
    assert all(torch.equal(before[k], v) for k, v in model.policy.state_dict().items())


def test_train_kickstart_clones_the_baseline_before_learning(tmp_path):
    argv = [*SMALL, "--out", str(tmp_path), "--quiet", "--kickstart", "frontier"]
    argv += ["--kickstart-episodes", "8", "--dagger-rounds", "1"]
    _, model = prepare(build_parser().parse_args(argv))
    _, untouched = prepare(build_parser().parse_args([*SMALL, "--out", str(tmp_path / "plain"), "--quiet"]))
    # the reward statistics come from the baseline's episodes, not the untrained defaults
    assert model.get_vec_normalize_env().ret_rms.count == pytest.approx(4 * 25, abs=1e-3)  # + its prior 1e-4
    assert untouched.get_vec_normalize_env().ret_rms.count < 2
    # the clone acts closer to the baseline than the untrained policy on fresh episodes
    demos = collect_demonstrations(small_env, "frontier", [31, 32])
    cloned = model.predict(demos.observations, deterministic=True)[0]
    plain = untouched.predict(demos.observations, deterministic=True)[0]
    assert np.mean((cloned - demos.actions) ** 2) < 0.5 * np.mean((plain - demos.actions) ** 2)


def test_kickstart_seeds_are_training_seeds_of_the_run():
    seeds = kickstart_seeds(3, 48)
    assert len(set(seeds)) == 48 and max(seeds) < 500_000 and seeds == kickstart_seeds(3, 48)
    assert seeds != kickstart_seeds(4, 48)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--kickstart", "oracle"], "--kickstart: unknown teacher"),
        (["--kickstart", "frontier", "--kickstart-episodes", "0"], "--kickstart-episodes"),
        (["--kickstart", "frontier", "--kickstart-episodes", "2", "--dagger-rounds", "3"], "seeds"),
        (["--kickstart", "frontier", "--dagger-rounds", "-1"], "non-negative"),
        (["--kickstart", "frontier", "--init-from", "agents/policies/ppo_budget_v2.zip"], "pass one of them"),
    ],
)
def test_bad_kickstart_arguments_are_refused(tmp_path, extra, message):
    run = tmp_path / "run"
    with pytest.raises(ValueError, match=message):
        prepare(build_parser().parse_args([*SMALL, "--out", str(run), "--quiet", *extra]))
    assert not run.exists()  # refused before anything was built
