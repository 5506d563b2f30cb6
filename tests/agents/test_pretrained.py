"""The front door to the shipped policies: agents.pretrained, agents.list_pretrained, agents.load_agent."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("stable_baselines3", reason="stable-baselines3 is in the train extra")

import agents  # noqa: E402
from agents.loading import POLICY_DIR, SHIPPED_POLICIES  # noqa: E402
from agents.sb3_agent import SB3Agent  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
LEADERBOARD = json.loads((ROOT / "docs" / "leaderboard.json").read_text())
TASKS = sorted({row["env_id"] for row in LEADERBOARD["rows"]})


def test_list_pretrained_names_every_shipped_policy_with_its_recipe_and_results():
    infos = {info.name: info for info in agents.list_pretrained()}
    assert set(infos) == set(SHIPPED_POLICIES) and "ppo" in infos and "ppo_adversary_v1" in infos
    for name, info in infos.items():
        assert info.algorithm in ("PPO", "RecurrentPPO")
        assert info.command.startswith("python -m agents.train ")
        assert info.task in gym.registry
        # the held-out results are the leaderboard's own rows, to the digit
        expected = {row["env_id"]: row for row in LEADERBOARD["rows"] if row["agent"] == name}
        assert {env_id: dict(row) for env_id, row in info.held_out.items()} == expected
        assert bool(expected) == SHIPPED_POLICIES[name].explorer  # the adversary is on no leaderboard
    assert infos["ppo_lstm_loop_v2"].algorithm == "RecurrentPPO" and infos["ppo"].algorithm == "PPO"


@pytest.mark.parametrize("task", TASKS)
def test_pretrained_task_is_the_leaderboards_best_shipped_policy_and_acts_through_predict_alone(task):
    shipped = [r for r in LEADERBOARD["rows"] if r["env_id"] == task and r["agent"] in SHIPPED_POLICIES]
    best = min(shipped, key=lambda row: row["final_map_error"])["agent"]
    agent = agents.pretrained(task)
    assert isinstance(agent, SB3Agent) and agent.path == SHIPPED_POLICIES[best].path
    # predict alone (the recurrent state kept inside) acts as the evaluation's loop, which carries the state
    reference = agents.load_agent(best, gym.make(task))
    env = gym.make(task)
    observation, _ = env.reset(seed=1000000)
    state, start = None, True
    for _ in range(12):
        action, _ = agent.predict(observation, deterministic=True)
        expected, state = reference.predict(
            observation, state=state, episode_start=np.array([start]), deterministic=True
        )
        start = False
        np.testing.assert_array_equal(action, expected)
        assert action.shape == (2,) and env.action_space.contains(action)
        observation, _, terminated, truncated, _ = env.step(action)
        assert not (terminated or truncated)
    agent.reset()  # a new episode: the first action is again the fresh policy's
    observation, _ = env.reset(seed=1000000)
    first, _ = agents.load_agent(best, env).predict(observation, episode_start=np.array([True]), deterministic=True)
    np.testing.assert_array_equal(agent.predict(observation, deterministic=True)[0], first)


def test_pretrained_by_name_and_refusals():
    assert agents.pretrained("ppo_adversary_v1").path == SHIPPED_POLICIES["ppo_adversary_v1"].path
    assert agents.pretrained("seif_gym:SeifExplore-v2").path == agents.pretrained("SeifExplore-v2").path
    with pytest.raises(ValueError, match="task_or_name.*SeifExplore-v2"):
        agents.pretrained("SeifExploreMRCLAM-v1")  # no shipped policy was measured there
    with pytest.raises(ValueError, match="task_or_name"):
        agents.pretrained("no_such_policy")
    with pytest.raises(TypeError, match="task_or_name"):
        agents.pretrained(3)  # type: ignore[arg-type]


def test_load_agent_builds_every_kind_of_spec():
    env = gym.make("SeifExplore-v2")
    assert type(agents.load_agent("frontier", env)).__name__ == "FrontierAgent"
    assert agents.load_agent("random", env, seed=3).seed == 3
    assert agents.load_agent("ppo", env).path == POLICY_DIR / "ppo.zip"
    assert agents.load_agent(str(POLICY_DIR / "ppo.zip"), env).path == POLICY_DIR / "ppo.zip"
    with pytest.raises(ValueError, match="unknown agent 'nope'.*shipped policy"):
        agents.load_agent("nope", env)
    with pytest.raises(FileNotFoundError):
        agents.load_agent("missing.zip", env)


@pytest.mark.parametrize("name", sorted(SHIPPED_POLICIES))
def test_shipped_files_hold_what_acting_needs_only(name):
    import torch

    with zipfile.ZipFile(SHIPPED_POLICIES[name].path) as archive:
        optimizer = torch.load(io.BytesIO(archive.read("policy.optimizer.pth")), weights_only=True)
        weights = torch.load(io.BytesIO(archive.read("policy.pth")), weights_only=True)
    assert optimizer["state"] == {}  # Adam's moments: only for going on training
    critic = [key for key in weights if key.startswith(("mlp_extractor.value_net.", "value_net.", "lstm_critic."))]
    assert critic and all(not weights[key].any() for key in critic)  # the value function, zeroed
    actor = [
        key for key in weights if key.startswith(("pi_features_extractor.", "action_net.", "mlp_extractor.policy"))
    ]
    assert actor and all(weights[key].any() for key in actor)


def test_a_bare_sb3_load_of_a_policy_with_its_own_entries_says_what_to_use():
    from stable_baselines3 import PPO

    path = ROOT / "research" / "policies" / "ppo_budget_v2.zip"  # trained with the budget's clock
    env = gym.make("SeifExploreBudget-v2")
    observation, _ = env.reset(seed=0)
    with pytest.raises(ValueError, match=r"lacks \['time_left'\].*agents.load_agent"):
        PPO.load(path, device="cpu").predict(observation)
    action, _ = agents.load_agent(str(path), env).predict(observation, deterministic=True)  # the clock inside
    assert env.action_space.contains(action)
