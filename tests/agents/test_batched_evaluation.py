"""The batched evaluation: an agent's episodes as the sub-envs of one native vector env, the same rows as serial."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("stable_baselines3", reason="stable-baselines3 is in the train extra")

import torch  # noqa: E402

import seif_gym  # noqa: E402, F401  (registers the environments)
from agents.evaluate import (  # noqa: E402
    batch_env,
    batch_refusal,
    evaluate_agents,
    limited_threads,
    make_evaluation_env,
    run_batched_episodes,
    run_episode,
)
from agents.evaluate.batched import batch_sizes  # noqa: E402
from agents.evaluate.cli import main as evaluate_main  # noqa: E402
from agents.loading import SHIPPED_POLICIES, load_agent  # noqa: E402
from agents.parallel import Executor  # noqa: E402
from agents.protocol import HELD_OUT_SEED  # noqa: E402
from agents.sb3_agent import InexactBatchError, SB3Agent  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
TIMED = "decision_time_ms"
# each shipped policy on its task; ppo's (SeifExplore-v0) is not batched, so on the showcase's task
POLICY_TASKS = {name: ("SeifExplore-v2" if policy.task.endswith("-v0") else policy.task)
                for name, policy in SHIPPED_POLICIES.items()}  # fmt: skip


def untimed(rows):
    return [{key: value for key, value in row.items() if key != TIMED} for row in rows]


def test_every_shipped_policy_is_batched_on_its_task():
    assert set(POLICY_TASKS) == set(SHIPPED_POLICIES)
    for name, env_id in POLICY_TASKS.items():
        env = make_evaluation_env(env_id, {})
        try:
            agent = load_agent(name, env)
            assert batch_refusal(agent) is None, name
            assert agent.unbatchable_layers() == []
        finally:
            env.close()
        vector, why = batch_env(env_id, {"exact_pose_nees": False}, 2)
        assert vector is not None and why == "", (env_id, why)
        vector.close()


@pytest.mark.parametrize("name", sorted(SHIPPED_POLICIES))
def test_batched_rows_equal_serial_rows_for_each_shipped_policy(name):
    """Short episodes on three held-out seeds of the policy's task (the full episodes: the slow test below)."""
    kwargs = {"max_episode_steps": 30}
    serial, _ = evaluate_agents([name], 3, HELD_OUT_SEED, POLICY_TASKS[name], kwargs, batch=False)
    batched, _ = evaluate_agents([name], 3, HELD_OUT_SEED, POLICY_TASKS[name], kwargs)
    assert untimed(batched) == untimed(serial)
    assert all(row[TIMED] > 0 for row in batched)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SHIPPED_POLICIES))
def test_batched_rows_equal_serial_rows_on_full_episodes_for_each_shipped_policy(name):
    """Four held-out seeds, in two batches (2 + 2), full episodes: every column but the time, bit for bit."""
    serial, _ = evaluate_agents([name], 4, HELD_OUT_SEED, POLICY_TASKS[name], batch=False)
    batched, _ = evaluate_agents([name], 4, HELD_OUT_SEED, POLICY_TASKS[name], batch_size=2)
    assert untimed(batched) == untimed(serial)


@pytest.mark.slow
def test_batched_evaluation_reproduces_the_published_leaderboard():
    """100 held-out episodes of SeifExplore-v2, every baseline and two policies batched: the leaderboard's means, to the last bit."""
    published = json.loads((ROOT / "docs" / "leaderboard.json").read_text())
    rows = {row["agent"]: row for row in published["rows"] if row["env_id"] == "SeifExplore-v2"}
    episodes = published["episodes"]["SeifExplore-v2"]
    agents = ["random", "frontier", "revisit", "info_gain", "ppo", "ppo_lstm_seif_explore_v2"]
    _, summary = evaluate_agents(agents, episodes, HELD_OUT_SEED, "SeifExplore-v2")
    for label, entry in summary["agents"].items():
        assert entry["final_map_error"]["mean"] == rows[label]["final_map_error"], label
        assert entry["pose_rmse"]["mean"] == rows[label]["pose_rmse"], label


def test_batched_rows_equal_serial_rows_for_the_baselines_in_uneven_batches(capsys):
    specs = ["random", "frontier", "revisit", "info_gain"]
    kwargs = {"max_episode_steps": 15}
    serial, serial_summary = evaluate_agents(specs, 5, 40, "SeifExplore-v2", kwargs, batch=False)
    batched, summary = evaluate_agents(specs, 5, 40, "SeifExplore-v2", kwargs, batch_size=2, verbose=True)
    assert untimed(batched) == untimed(serial)
    assert summary["paired"] == serial_summary["paired"]
    err = capsys.readouterr().err
    assert "one episode at a time" not in err  # every baseline is batched
    # info_gain's plans are counted per episode, batched as serially
    assert "ms per plan" in err


class _EpisodesCutShort:
    """Ends the episodes of some seeds early (``terminated``, as a diverged filter ends one), single and vector envs alike."""

    def __init__(self, monkeypatch, stop_after):
        from seif_gym.envs.explore import SeifExploreEnv
        from seif_gym.envs.vector import SeifExploreVectorEnv

        self.stop_after = stop_after  # seed -> steps after which its episode ends
        single_reset, single_step = SeifExploreEnv.reset, SeifExploreEnv.step
        vector_reset, vector_step = SeifExploreVectorEnv.reset, SeifExploreVectorEnv.step
        cut = self

        def reset(env, *, seed=None, options=None):
            env.cut_seed, env.cut_steps = seed, 0
            return single_reset(env, seed=seed, options=options)

        def step(env, action):
            observation, reward, terminated, truncated, info = single_step(env, action)
            env.cut_steps += 1
            return observation, reward, terminated or cut.ends(env.cut_seed, env.cut_steps), truncated, info

        def reset_vector(env, *, seed=None, options=None):
            out = vector_reset(env, seed=seed, options=options)
            env.cut_steps = np.zeros(env.num_envs, dtype=int)
            return out

        def step_vector(env, actions):
            observation, reward, terminated, truncated, info = vector_step(env, actions)
            env.cut_steps += 1
            terminated = terminated | np.array([cut.ends(sub.cut_seed, k) for sub, k in zip(env.envs, env.cut_steps)])
            return observation, reward, terminated, truncated, info

        monkeypatch.setattr(SeifExploreEnv, "reset", reset)
        monkeypatch.setattr(SeifExploreEnv, "step", step)
        monkeypatch.setattr(SeifExploreVectorEnv, "reset", reset_vector)
        monkeypatch.setattr(SeifExploreVectorEnv, "step", step_vector)

    def ends(self, seed, steps):
        return seed in self.stop_after and steps >= self.stop_after[seed]


@pytest.mark.parametrize("spec", ["random", "info_gain"])
def test_batched_rows_equal_serial_rows_when_episodes_end_early(monkeypatch, spec):
    """random's draws are made ahead for episodes of the time limit; an episode cut short moves the later ones."""
    _EpisodesCutShort(monkeypatch, {41: 7, 43: 3, 44: 11})
    kwargs = {"max_episode_steps": 12}
    serial, _ = evaluate_agents([spec], 6, 40, "SeifExplore-v2", kwargs, batch=False)
    assert [row["length"] for row in serial] == [12, 7, 12, 3, 11, 12]
    for size in (6, 4):
        batched, _ = evaluate_agents([spec], 6, 40, "SeifExplore-v2", kwargs, batch_size=size)
        assert untimed(batched) == untimed(serial), size


def test_random_leaves_its_generator_where_a_serial_run_does():
    kwargs = {"max_episode_steps": 9}
    single = gym.make("SeifExplore-v2", **kwargs)
    serial_agent, batched_agent = load_agent("random", single, seed=5), load_agent("random", single, seed=5)
    expected = [run_episode(serial_agent, single, seed) for seed in (1, 2, 3)]
    vector, _ = batch_env("SeifExplore-v2", kwargs, 3)
    got = run_batched_episodes(batched_agent, vector, [1, 2, 3])
    assert untimed([row for row, *_ in got]) == untimed([row for row, _ in expected])
    assert batched_agent.rng.bit_generator.state == serial_agent.rng.bit_generator.state
    vector.close()
    single.close()


def test_a_configuration_the_vector_env_runs_as_single_envs_runs_serially(capsys):
    kwargs = {"max_episode_steps": 10}
    serial, _ = evaluate_agents(["frontier"], 2, 3, "SeifExplore-v0", kwargs, batch=False)
    batched, _ = evaluate_agents(["frontier"], 2, 3, "SeifExplore-v0", kwargs, verbose=True)
    assert untimed(batched) == untimed(serial)
    err = capsys.readouterr().err
    assert err.count("SeifExplore-v0: every agent runs one episode at a time") == 1 and "backend 'sync'" in err
    env, why = batch_env("SeifExplore-v2", {"filter": "ekf"}, 2)
    assert env is None and "backend 'sync'" in why


def test_run_batched_episodes_equals_run_episode_row_by_row():
    env_id, kwargs, seeds = "SeifExploreBudget-v2", {"max_episode_steps": 20, "exact_pose_nees": False}, [5, 9, 2]
    single = gym.make(env_id, **kwargs)
    agent = load_agent("revisit", single)
    expected = [run_episode(agent, single, seed) for seed in seeds]
    vector, _ = batch_env(env_id, kwargs, len(seeds))
    assert vector is not None
    got = run_batched_episodes(agent, vector, seeds)
    for (row, trace, _, _), (expected_row, expected_trace) in zip(got, expected):
        assert untimed([row]) == untimed([expected_row]) and trace == expected_trace
    with pytest.raises(ValueError, match="one seed per sub-env"):
        run_batched_episodes(agent, vector, seeds[:2])
    vector.close()
    single.close()


def test_a_policy_whose_batch_rounds_otherwise_falls_back_to_the_serial_rows(monkeypatch, capsys):
    def differs(self, *args):
        raise InexactBatchError("row 0 differs")

    monkeypatch.setattr(SB3Agent, "_check_rows", differs)
    kwargs = {"max_episode_steps": 10}
    serial, _ = evaluate_agents(["ppo"], 2, 11, "SeifExplore-v2", kwargs, batch=False)
    batched, _ = evaluate_agents(["ppo"], 2, 11, "SeifExplore-v2", kwargs, verbose=True)
    assert untimed(batched) == untimed(serial)
    assert "ppo: one episode at a time (row 0 differs)" in capsys.readouterr().err


def test_exact_batches_give_each_row_its_bits_alone():
    env = make_evaluation_env("SeifExplore-v2", {})
    agent = load_agent("ppo_lstm_seif_explore_v2", env)
    observations = []
    for seed in range(3):
        observation, _ = env.reset(seed=seed)
        for _ in range(4):
            observations.append(observation)
            observation, *_ = env.step(env.action_space.sample())
    alone = []
    for observation in observations:
        agent.reset()
        alone.append(agent.predict(observation, episode_start=np.array([True]), deterministic=True)[0])
    batch = {key: np.stack([o[key] for o in observations]) for key in observations[0]}
    agent.reset()
    with agent.exact_batches():
        actions, _ = agent.predict(batch, episode_start=np.ones(len(observations), bool), deterministic=True)
    assert np.array_equal(actions, np.array(alone))
    linear = agent.model.policy.action_net
    assert "forward" not in vars(linear)  # the layers are the class's again after the block
    env.close()


def test_sb3_agent_runs_its_forward_passes_on_its_threads(monkeypatch):
    env = make_evaluation_env("SeifExplore-v2", {"max_episode_steps": 5})
    agent = load_agent("ppo", env)
    assert isinstance(agent, SB3Agent) and agent.threads == 1
    seen = []
    predict = agent.model.predict
    monkeypatch.setattr(
        agent.model, "predict", lambda *a, **k: (seen.append(torch.get_num_threads()), predict(*a, **k))[1]
    )
    observation, _ = env.reset(seed=0)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        agent.predict(observation, deterministic=True)
        agent.threads = None
        agent.predict(observation, deterministic=True)
        assert seen == [1, 2] and torch.get_num_threads() == 2  # restored after the call
    finally:
        torch.set_num_threads(before)
    for bad, error in ((0, ValueError), (1.5, TypeError), (True, TypeError)):
        with pytest.raises(error, match="threads must be a positive int or None"):
            SB3Agent(SHIPPED_POLICIES["ppo"].path, env, threads=bad)
    env.close()


def test_limited_threads_sets_blas_and_torch_threads_and_restores_them():
    from threadpoolctl import threadpool_info

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with limited_threads(1):
            assert torch.get_num_threads() == 1
            assert all(info["num_threads"] == 1 for info in threadpool_info() if info["user_api"] == "blas")
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
    with pytest.raises(ValueError, match="threads must be a positive int"):
        evaluate_agents(["frontier"], 1, 0, threads=0)
    with pytest.raises(ValueError, match="batch_size must be a positive int"):
        evaluate_agents(["frontier"], 1, 0, batch_size=0)


def test_batch_sizes_cut_evenly():
    assert batch_sizes(250, 100) == [84, 83, 83]
    assert batch_sizes(3, 100) == [3] and batch_sizes(4, 2) == [2, 2] and batch_sizes(5, 2) == [2, 2, 1]
    assert sum(batch_sizes(401, 100)) == 401 and max(batch_sizes(401, 100)) <= 100


@pytest.mark.slow
def test_batched_rows_equal_on_local_processes():
    kwargs = {"max_episode_steps": 12}
    serial, _ = evaluate_agents(["frontier", "ppo"], 4, 30, "SeifExplore-v2", kwargs, batch=False)
    executor = Executor(workers=2)
    batched, _ = evaluate_agents(["frontier", "ppo"], 4, 30, "SeifExplore-v2", kwargs, executor=executor)
    assert untimed(batched) == untimed(serial)
    assert len(set(executor.placements)) == 2  # each worker batched its runs of seeds


def test_evaluate_command_takes_the_batch_options(tmp_path, capsys):
    common = ["--agents", "frontier", "--episodes", "2", "--env-kwargs", '{"max_episode_steps": 5}', "--quiet"]
    assert evaluate_main([*common, "--out", str(tmp_path / "a"), "--no-batch"]) == 0
    assert evaluate_main([*common, "--out", str(tmp_path / "b"), "--batch-size", "1", "--threads", "1"]) == 0
    first = (tmp_path / "a" / "results.csv").read_text().splitlines()
    second = (tmp_path / "b" / "results.csv").read_text().splitlines()
    column = first[0].split(",").index(TIMED)
    assert [line.split(",")[:column] for line in first] == [line.split(",")[:column] for line in second]
    for option, value in (("--batch-size", "0"), ("--threads", "0")):
        with pytest.raises(SystemExit):
            evaluate_main([*common, option, value])
        err = capsys.readouterr().err
        assert option in err and "positive" in err
