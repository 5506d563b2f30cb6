"""The leaderboard command (agents.benchmark): paired statistics, outputs, verdicts."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

import seif_gym
from agents import benchmark, loading, protocol
from agents.cli import resolve_tasks


def test_default_variants_are_every_layout_of_a_version():
    import seif_gym

    assert benchmark.default_variants() == [i for i in seif_gym.VARIANTS if i.endswith(f"-v{seif_gym.LATEST_VERSION}")]
    assert all(i.endswith("-v0") for i in benchmark.default_variants(0))
    with pytest.raises(ValueError, match="version"):
        benchmark.default_variants(99)
    assert resolve_tasks(["SeifExploreLoop", "SeifExplore-v0"], None) == [
        f"SeifExploreLoop-v{seif_gym.LATEST_VERSION}", "SeifExplore-v0"]  # fmt: skip
    with pytest.raises(ValueError, match="unknown env 'NoSuchLayout'"):
        resolve_tasks(["NoSuchLayout"], None)


@pytest.mark.slow
def test_shipped_policy_fits_the_default_variant():
    assert benchmark.policy_fits(benchmark.SHIPPED_POLICIES["ppo"], "SeifExplore-v1")
    for policy in benchmark.SHIPPED_POLICIES.values():  # and each fits the variant it was trained on and its task
        assert benchmark.policy_fits(policy, policy.trained_on) and benchmark.policy_fits(policy, policy.task)
    ring = benchmark.SHIPPED_POLICIES["ppo_lstm_clustered_budget_v2"]
    assert ring.task == ring.chosen_for == "SeifExploreClusteredBudget-v2" != ring.trained_on
    assert benchmark.SHIPPED_POLICIES["ppo"].task == "SeifExplore-v0"  # no chosen_for: its training task
    for policy in benchmark.SHIPPED_POLICIES.values():  # research.ship's record of the choice names the same task
        record = policy.path.with_suffix("") / "selection.json"
        if record.is_file():
            assert json.loads(record.read_text())["env_id"] == policy.task, policy.path.name
    assert (loading.POLICY_DIR / "ppo_lstm_loop_v2" / "selection.json").is_file()


def test_policy_fits_reads_a_recurrent_policy(tmp_path):
    """A RecurrentPPO ``.zip`` (the leaderboard ships one) loads, with its own algorithm, and fits its task."""
    import gymnasium as gym
    from sb3_contrib import RecurrentPPO

    from agents.evaluate import sb3_algorithm
    from agents.networks import BeliefRecurrentPolicy

    env = gym.make("SeifExploreLoopBudget-v2")
    model = RecurrentPPO(BeliefRecurrentPolicy, env, n_steps=16, batch_size=16, device="cpu",
                         policy_kwargs={"lstm_hidden_size": 8})  # fmt: skip
    env.close()
    path = tmp_path / "lstm.zip"
    model.save(path)
    assert sb3_algorithm(path) is RecurrentPPO
    assert benchmark.policy_fits(benchmark.ShippedPolicy(path, "SeifExploreLoopBudget-v2", "a test"), "SeifExplore-v2")


@pytest.mark.slow
def test_run_benchmark_writes_the_leaderboard(tmp_path, monkeypatch):
    # a policy whose spaces do not fit is left out, and the leaderboard says so
    monkeypatch.setattr(benchmark, "policy_fits", lambda policy, env_id: False)
    rows = benchmark.run_benchmark(["SeifExplore-v1"], ["frontier", "random", "ppo"], episodes=2, seed=7,
                                   out=tmp_path)  # fmt: skip
    by_agent = {row["agent"]: row for row in rows}
    assert set(by_agent) == {"frontier", "random", "ppo"}
    assert by_agent["ppo"]["episodes"] == 0 and by_agent["ppo"]["verdict"].startswith("left out")
    best = by_agent["frontier"]["best_baseline"]
    assert best in ("frontier", "random")
    other = "random" if best == "frontier" else "frontier"
    assert by_agent[best]["verdict"] == "best baseline"
    # the paired difference is the mean of the per-seed differences in the variant's results.csv
    with (tmp_path / "SeifExplore-v1" / "results.csv").open() as handle:
        results = list(csv.DictReader(handle))
    errors = {(r["agent"], int(r["seed"])): float(r["final_map_error"]) for r in results}
    assert sorted({seed for _, seed in errors}) == [7, 8]
    expected = np.mean([errors[(other, s)] - errors[(best, s)] for s in (7, 8)])
    assert by_agent[other]["difference"] == pytest.approx(expected)
    assert by_agent[other]["verdict"] in ("beats", "worse", "tie (interval holds 0)")
    saved = json.loads((tmp_path / "leaderboard.json").read_text())
    assert saved["seeds"] == {"SeifExplore-v1": [7, 8]} and saved["episodes"] == {"SeifExplore-v1": 2}
    assert len(saved["rows"]) == 3
    with (tmp_path / "leaderboard.csv").open() as handle:
        assert tuple(csv.DictReader(handle).fieldnames) == benchmark.LEADERBOARD_COLUMNS
    text = (tmp_path / "leaderboard.md").read_text()
    assert "## SeifExplore-v1" in text and "ppo: left out" in text and "Seeds 7…8, 2 episodes per agent." in text
    assert (tmp_path / "SeifExplore-v1" / "map_error.png").stat().st_size > 0
    assert math.isfinite(by_agent["random"]["final_map_error"])


@pytest.mark.slow
def test_a_shipped_policy_goes_by_its_leaderboard_name_in_the_variants_own_files(tmp_path):
    # the file is ppo.zip; the leaderboard, results.csv and summary.md all call it ppo
    rows = benchmark.run_benchmark(["SeifExplore-v0"], ["frontier", "ppo"], episodes=1, seed=7, out=tmp_path)
    assert [row["agent"] for row in rows] == ["frontier", "ppo"]
    assert rows[1]["kind"] == "policy" and rows[1]["episodes"] == 1
    with (tmp_path / "SeifExplore-v0" / "results.csv").open() as handle:
        assert {row["agent"] for row in csv.DictReader(handle)} == {"frontier", "ppo"}
    summary = (tmp_path / "SeifExplore-v0" / "summary.md").read_text()
    assert "| ppo |" in summary and "ppo_seif_explore" not in summary


def test_held_out_episodes_are_400_on_the_short_tasks_and_100_on_the_others():
    assert protocol.held_out_episodes("SeifExploreClusteredBudget-v2") == 400  # 100 steps
    assert protocol.held_out_episodes("SeifExploreLoopBudget-v2") == 400  # 150 steps
    assert protocol.held_out_episodes("SeifExplore-v2") == 100  # 400 steps
    assert protocol.held_out_episodes("SeifExploreLarge-v2") == 100
    longest = max(protocol.held_out_episodes(env_id) for env_id in seif_gym.VARIANTS)
    assert longest < protocol.DECLARED_HELD_OUT_EPISODES == 1600  # a declared experiment's count reaches further
    first = protocol.HELD_OUT_SEED
    assert protocol.HELD_OUT_SEEDS == range(first, first + protocol.DECLARED_HELD_OUT_EPISODES)
    with pytest.raises(ValueError, match="env_id: unknown env 'Nope-v0'"):
        protocol.held_out_episodes("Nope-v0")
    with pytest.raises(TypeError, match="env_id must be a str"):
        protocol.held_out_episodes(5)


def test_a_declared_count_is_1600_on_the_short_tasks_and_400_on_the_others_within_the_held_out_seeds():
    assert protocol.declared_held_out_episodes("SeifExploreClusteredBudget-v2") == 1600
    assert protocol.declared_held_out_episodes("SeifExploreBudget-v2") == 1600
    assert protocol.declared_held_out_episodes("SeifExploreLoop-v2") == 400  # 400 steps
    assert protocol.declared_held_out_episodes("SeifExploreLarge-v2") == 400
    for env_id in seif_gym.VARIANTS:
        declared = protocol.declared_held_out_episodes(env_id)
        assert declared > protocol.held_out_episodes(env_id)  # reaches beyond the leaderboard's seeds
        assert protocol.HELD_OUT_SEED + declared - 1 in protocol.HELD_OUT_SEEDS  # so research.select refuses them all
    with pytest.raises(ValueError, match="env_id: unknown env 'Nope-v0'"):
        protocol.declared_held_out_episodes("Nope-v0")
    with pytest.raises(TypeError, match="env_id must be a str"):
        protocol.declared_held_out_episodes(None)


def test_run_benchmark_runs_each_variant_on_its_protocol_count(tmp_path, monkeypatch):
    counts = {}

    def fake_variant(env_id, agents, episodes, seed, out, verbose=False, *settings, resume=False):  # executor, batch...
        counts[env_id] = (episodes, seed)
        return []

    monkeypatch.setattr(benchmark, "benchmark_variant", fake_variant)
    variants = ["SeifExplore-v2", "SeifExploreClusteredBudget-v2"]
    benchmark.run_benchmark(variants, ["random"], episodes=None, seed=1_000_000, out=tmp_path)
    assert counts == {"SeifExplore-v2": (100, 1_000_000), "SeifExploreClusteredBudget-v2": (400, 1_000_000)}
    saved = json.loads((tmp_path / "leaderboard.json").read_text())
    assert saved["seeds"]["SeifExploreClusteredBudget-v2"] == [1_000_000, 1_000_399]


@pytest.mark.parametrize("episodes", [None, 2])
def test_run_benchmark_refuses_an_unknown_variant_before_writing_anything(tmp_path, episodes):
    out = tmp_path / "board"
    with pytest.raises(ValueError, match="env_id: unknown env 'Nope-v0'"):
        benchmark.run_benchmark(["SeifExplore-v2", "Nope-v0"], ["random"], episodes=episodes, seed=0, out=out)
    assert not out.exists()


def test_run_benchmark_rejects_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="agents"):
        benchmark.run_benchmark(["SeifExplore-v1"], ["nobody"], episodes=1, seed=0, out=tmp_path)
    with pytest.raises(ValueError, match="episodes"):
        benchmark.run_benchmark(["SeifExplore-v1"], ["random"], episodes=0, seed=0, out=tmp_path)


@pytest.mark.slow
def test_run_benchmark_on_local_processes_equals_the_serial_run(tmp_path):
    """``--jobs`` runs the variants through agents.parallel.Executor: the same rows as one process."""
    arguments = (["SeifExplore-v1", "SeifExploreLoop-v1"], ["frontier", "random"])
    serial = benchmark.run_benchmark(*arguments, episodes=2, seed=11, out=tmp_path / "serial")
    parallel = benchmark.run_benchmark(*arguments, episodes=2, seed=11, out=tmp_path / "jobs", jobs=2)
    assert parallel == serial and len(serial) == 4
    assert (tmp_path / "jobs" / "leaderboard.md").read_text() == (tmp_path / "serial" / "leaderboard.md").read_text()


@pytest.mark.slow
def test_run_benchmark_with_episodes_on_local_processes_equals_the_serial_run(tmp_path):
    """``--workers``: each variant's episodes spread over the executor's processes; the rows of one process."""
    from agents.parallel import Executor

    arguments = (["SeifExplore-v1", "SeifExploreLoop-v1"], ["frontier", "random"])
    serial = benchmark.run_benchmark(*arguments, episodes=3, seed=11, out=tmp_path / "serial")
    executor = Executor(workers=2)
    spread = benchmark.run_benchmark(*arguments, episodes=3, seed=11, out=tmp_path / "spread", executor=executor)
    assert spread == serial and len(serial) == 4
    assert len(executor.placements) > 2  # the episodes ran as several tasks, not one per variant
    for env_id in arguments[0]:  # every episode the same, all but the wall-clock column
        episodes = [_episodes(tmp_path / run / env_id / "results.csv") for run in ("serial", "spread")]
        assert episodes[0] == episodes[1] and len(episodes[0]) == 6
    with pytest.raises(ValueError, match="jobs"):
        benchmark.run_benchmark(*arguments, episodes=1, seed=11, out=tmp_path / "x", jobs=2, executor=executor)
    with pytest.raises(TypeError, match="executor"):
        benchmark.run_benchmark(*arguments, episodes=1, seed=11, out=tmp_path / "x", executor=2)
    assert not (tmp_path / "x").exists()


def test_benchmark_command_refuses_jobs_with_workers(tmp_path, capsys):
    with pytest.raises(SystemExit):
        benchmark.main(["--tasks", "SeifExplore-v1", "--jobs", "2", "--workers", "2", "--out", str(tmp_path / "b")])
    assert "exclude each other" in capsys.readouterr().err
    assert not (tmp_path / "b").exists()


def _episodes(path):
    import csv

    with open(path) as handle:
        return [{k: v for k, v in row.items() if k != "decision_time_ms"} for row in csv.DictReader(handle)]
