"""The coverage oracle (research.oracle): the cheating explorer, as the tasks' yardstick
(research/coverage_oracle.py) and as a privileged teacher for kickstarting."""

from __future__ import annotations

import importlib.util
import math

import gymnasium as gym
import numpy as np
import pytest

import seif_gym  # noqa: F401
from research.imitation import collect_demonstrations, make_teacher
from research.oracle import CoverageOracle, oracle_action


@pytest.fixture(scope="module")
def oracle():
    return importlib.import_module("research.coverage_oracle")


def test_oracle_action_steers_to_the_cheapest_unmapped_landmark():
    landmarks = np.array([[4.0, 0.0], [0.0, 3.0], [-2.0, 0.0]])
    pose = np.array([0.0, 0.0, 0.0])
    # ahead at 4 m costs 4; left at 3 m costs 3 + pi/2; behind at 2 m costs 2 + pi: the one ahead
    np.testing.assert_allclose(oracle_action(pose, landmarks, set()), [1.0, 0.0])
    # without it, the left one (4.57) before the one behind (5.14): slow while turning, full left turn
    np.testing.assert_allclose(oracle_action(pose, landmarks, {0}), [0.3, 1.0])
    # facing the other way, the one behind is now ahead
    np.testing.assert_allclose(oracle_action(np.array([0.0, 0.0, math.pi]), landmarks, {0, 1}), [1.0, 0.0],
                               atol=1e-6)  # fmt: skip
    np.testing.assert_array_equal(oracle_action(pose, landmarks, {0, 1, 2}), [0.0, 0.0])
    with pytest.raises(ValueError, match=r"pose must have shape \(3,\)"):
        oracle_action(np.zeros(2), landmarks, set())
    with pytest.raises(ValueError, match=r"landmarks must have shape \(n, 2\)"):
        oracle_action(pose, landmarks.ravel(), set())


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


def test_env_kwargs_make_the_variant_measured(oracle, capsys):
    # a step budget passed through: the oracle's episodes end where an env made with it ends them
    env = gym.make("SeifExploreClusteredBudget-v2", max_episode_steps=20)
    agent, errors, mapped = CoverageOracle(env), [], []
    for seed in (500000, 500001):
        observation, _ = env.reset(seed=seed)
        steps, terminated, truncated = 0, False, False
        while not (terminated or truncated):
            observation, _, terminated, truncated, info = env.step(agent.predict(observation)[0])
            steps += 1
        assert steps == 20 and truncated
        errors.append(info["map_error"])
        mapped.append(info["landmarks_mapped"])
    env.close()
    result = oracle.run_oracle("SeifExploreClusteredBudget-v2", [500000, 500001], {"max_episode_steps": 20})
    assert result["final_map_error"]["mean"] == float(np.mean(errors))  # the same episodes, to the bit
    assert result["landmarks_mapped"] == np.mean(mapped)
    assert result["landmarks_mapped"] < oracle.run_oracle("SeifExploreClusteredBudget-v2", [500000, 500001])[
        "landmarks_mapped"]  # fmt: skip
    assert oracle.main(["--episodes", "2", "--seed", "500000", "--env-kwargs", '{"max_episode_steps": 20}']) == 0
    out = capsys.readouterr().out
    assert "max_episode_steps" in out and f"| {result['landmarks_mapped']:.1f} |" in out
    with pytest.raises(TypeError, match="env_kwargs must be a mapping"):
        oracle.run_oracle("SeifExploreClusteredBudget-v2", [500000], [("max_episode_steps", 20)])
    with pytest.raises(SystemExit):
        oracle.main(["--env-kwargs", "[1]"])
    assert "--env-kwargs" in capsys.readouterr().err


def test_run_oracle_refuses_what_it_cannot_measure(oracle):
    with pytest.raises(ValueError, match="seeds"):
        oracle.run_oracle("SeifExploreClusteredBudget-v2", [])
    gym.register("OracleMlProbe-v0", entry_point="seif_gym.envs.explore:SeifExploreEnv",
                 kwargs={"data_association": "ml"}, max_episode_steps=5)  # fmt: skip
    try:
        with pytest.raises(ValueError, match="env_id.*maximum likelihood"):
            oracle.run_oracle("OracleMlProbe-v0", [0])
    finally:
        del gym.registry["OracleMlProbe-v0"]


def _true_action(env: gym.Env) -> np.ndarray:
    base = env.unwrapped
    return oracle_action(base.world.pose, base.world.landmarks, {int(i) for i in base.filter.landmark_ids})


def test_the_agent_acts_on_the_true_state_of_its_env():
    env = gym.make("SeifExploreClusteredBudget-v2")
    agent = CoverageOracle(env)  # before reset: the world is built by reset
    observation, _ = env.reset(seed=7)
    for _ in range(5):
        action, _ = agent.predict(observation)
        np.testing.assert_array_equal(action, _true_action(env))
        observation, *_ = env.step(np.array([0.5, 0.3], dtype=np.float32))  # it labels states it does not drive
    batch = {key: np.stack([value, value]) for key, value in observation.items()}
    with pytest.raises(ValueError, match="batch row 1"):
        agent.predict(batch)
    env.close()


def test_the_agent_refuses_what_it_cannot_read():
    with pytest.raises(TypeError, match="env"):
        CoverageOracle(gym.make("CartPole-v1"))
    ml = gym.make("SeifExplore-v2", data_association="ml")
    with pytest.raises(ValueError, match="env.*maximum likelihood"):
        CoverageOracle(ml)


def test_as_a_teacher_it_labels_every_state_the_learner_drives_into():
    assert isinstance(make_teacher("coverage_oracle", gym.make("SeifExploreClusteredBudget-v2"), seed=0),
                      CoverageOracle)  # fmt: skip
    with pytest.raises(ValueError, match="teacher: unknown 'oracle'"):
        make_teacher("oracle", gym.make("SeifExploreClusteredBudget-v2"), seed=0)

    def make_env() -> gym.Env:
        return gym.make("SeifExploreClusteredBudget-v2", max_episode_steps=30)

    def straight_then_left(observation) -> np.ndarray:
        return np.array([1.0, 0.0 if observation["pose"][0] < 0.2 else 0.8], dtype=np.float32)

    demos = collect_demonstrations(make_env, "coverage_oracle", [11], learner=straight_then_left)
    # replay the learner's episode: each label is the oracle's action on the true state of that step
    env = make_env()
    observation, _ = env.reset(seed=11)
    expected = []
    while True:
        expected.append(_true_action(env))
        observation, _, terminated, truncated, _ = env.step(straight_then_left(observation))
        if terminated or truncated:
            break
    np.testing.assert_array_equal(demos.actions, np.stack(expected))
    assert len(demos) == 30 and len({tuple(a) for a in demos.actions}) > 1


def test_module_doctests_pass():
    import doctest

    import research.oracle

    results = doctest.testmod(research.oracle)
    assert results.attempted > 0 and results.failed == 0
