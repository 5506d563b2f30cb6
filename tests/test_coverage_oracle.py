"""benchmarks/coverage_oracle.py: the cheating explorer used as the tasks' coverage yardstick."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "coverage_oracle.py"


@pytest.fixture(scope="module")
def oracle():
    spec = importlib.util.spec_from_file_location("coverage_oracle", PATH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_oracle_action_steers_to_the_cheapest_unmapped_landmark(oracle):
    landmarks = np.array([[4.0, 0.0], [0.0, 3.0], [-2.0, 0.0]])
    pose = np.array([0.0, 0.0, 0.0])
    # ahead at 4 m costs 4; left at 3 m costs 3 + pi/2; behind at 2 m costs 2 + pi: the one ahead
    np.testing.assert_allclose(oracle.oracle_action(pose, landmarks, set()), [1.0, 0.0])
    # without it, the left one (4.57) before the one behind (5.14): slow while turning, full left turn
    np.testing.assert_allclose(oracle.oracle_action(pose, landmarks, {0}), [0.3, 1.0])
    # facing the other way, the one behind is now ahead
    np.testing.assert_allclose(oracle.oracle_action(np.array([0.0, 0.0, math.pi]), landmarks, {0, 1}), [1.0, 0.0],
                               atol=1e-6)  # fmt: skip
    np.testing.assert_array_equal(oracle.oracle_action(pose, landmarks, {0, 1, 2}), [0.0, 0.0])


def test_oracle_maps_more_than_random_and_repeats(oracle):
    from agents.evaluate import evaluate_agents

    seeds = [500000, 500001, 500002]
    result = oracle.run_oracle("SeifExploreClusteredBudget-v2", seeds)
    assert result == oracle.run_oracle("SeifExploreClusteredBudget-v2", seeds)  # same seeds, same episodes
    rows, _ = evaluate_agents(["random"], episodes=3, seed=seeds[0], env_id="SeifExploreClusteredBudget-v2")
    random_mapped = np.mean([row["landmarks_mapped"] for row in rows])
    assert result["landmarks_mapped"] >= 28 > random_mapped + 5
    assert result["final_map_error"]["mean"] < 0.5 < np.mean([row["final_map_error"] for row in rows])


def test_main_prints_a_row_per_task_and_checks_episodes(oracle, capsys):
    assert oracle.main(["--env", "SeifExploreClusteredBudget-v2", "--episodes", "2", "--seed", "500000"]) == 0
    out = capsys.readouterr().out
    assert "| `SeifExploreClusteredBudget-v2` |" in out and "seeds 500000..500001" in out
    with pytest.raises(SystemExit):
        oracle.main(["--episodes", "1"])
    assert "--episodes" in capsys.readouterr().err


def test_run_oracle_refuses_what_it_cannot_measure(oracle):
    with pytest.raises(ValueError, match="seeds"):
        oracle.run_oracle("SeifExploreClusteredBudget-v2", [])
    import gymnasium as gym

    gym.register("OracleMlProbe-v0", entry_point="seif_gym.envs.explore:SeifExploreEnv",
                 kwargs={"data_association": "ml"}, max_episode_steps=5)  # fmt: skip
    try:
        with pytest.raises(ValueError, match="env_id.*maximum likelihood"):
            oracle.run_oracle("OracleMlProbe-v0", [0])
    finally:
        del gym.registry["OracleMlProbe-v0"]
