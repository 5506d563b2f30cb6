"""Training and the shipped policies: a PPO smoke run, and the shipped model against random."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import seif_gym  # noqa: F401
from agents import make_agent
from agents.evaluate import SB3Agent
from agents.showcase import SHIPPED_POLICY
from agents.train import build_parser, resolve_config, train

POLICIES = Path(SHIPPED_POLICY).parent


def test_training_smoke_run_writes_a_loadable_model(tmp_path):
    args = build_parser().parse_args(
        [
            "--algo", "ppo", "--env", "SeifExplore-v0", "--timesteps", "1024", "--out", str(tmp_path),
            "--n-envs", "2", "--no-progress-bar", "--eval-freq", "512", "--eval-episodes", "1",
            "--checkpoint-freq", "1024", "--env-kwargs", json.dumps({"num_landmarks": 10}),
            "--hyperparams", "n_steps=256", "batch_size=128", "n_epochs=1",
        ]
    )  # fmt: skip
    config = resolve_config(args)
    assert config.n_envs == 2 and config.algo_kwargs["n_steps"] == 256 and config.algo_kwargs["n_epochs"] == 1
    train(config)
    for name in ("model.zip", "vecnormalize.pkl", "config.json", "best/best_model.zip"):
        assert (tmp_path / name).exists(), name
    assert any((tmp_path / "tb").rglob("events.out.tfevents*")), "no TensorBoard log"
    env = gym.make("SeifExplore-v0", num_landmarks=10, max_episode_steps=5)
    agent = SB3Agent(tmp_path / "model.zip", env=env)
    observation, _ = env.reset(seed=0)
    action, _ = agent.predict(observation, deterministic=True)
    assert action.shape == (2,) and np.all(np.abs(action) <= 1.0 + 1e-6)


def final_map_errors(agent, seeds) -> list[float]:
    env = gym.make("SeifExplore-v0")
    errors = []
    for seed in seeds:
        observation, info = env.reset(seed=seed)
        done = False
        while not done:
            action, _ = agent.predict(observation, deterministic=True)
            observation, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        errors.append(info["map_error"])
    env.close()
    return errors


def test_shipped_policy_loads_and_beats_random_on_ten_seeds():
    assert SHIPPED_POLICY.exists(), f"the shipped policy {SHIPPED_POLICY} is missing"
    env = gym.make("SeifExplore-v0")
    policy = SB3Agent(SHIPPED_POLICY, env=env)
    seeds = range(2000, 2010)
    ppo = final_map_errors(policy, seeds)
    random = final_map_errors(make_agent("random", env, seed=0), seeds)
    assert np.mean(ppo) < np.mean(random)
    # and not by a hair: every episode of the policy ends below random's mean
    assert max(ppo) < np.mean(random), (ppo, random)


@pytest.mark.parametrize("name", ["ppo_seif_explore.zip", "ppo_adversary.zip"])
def test_shipped_models_match_the_env_spaces(name):
    env = gym.make("SeifExplore-v0")
    agent = SB3Agent(POLICIES / name, env=env)
    assert agent.model.observation_space == env.observation_space
    assert agent.model.action_space == env.action_space
