"""The agent's memory of the swept arena (agents/coverage_memory.py) and the policy-side entries (agents/memories.py)."""

from __future__ import annotations

import doctest
import math

import gymnasium as gym
import numpy as np
import pytest
from policy_entry_checks import assert_acts_as_trained  # tests/ is on sys.path under pytest

import agents.entries
import agents.memories
import research.coverage_memory
import seif_gym  # noqa: F401  (registers the envs)
from agents.baselines import Geometry
from agents.evaluate import SB3Agent, run_episode
from agents.memories import PolicyMemories, has_policy_entries, policy_memories, policy_view
from agents.networks import BeliefPolicy
from agents.time_feature import TIME_LEFT, TimeLeftClock, TimeLeftObservation
from research.coverage_memory import UNSWEPT, CoverageMemory, CoverageMemoryObservation, uses_coverage_memory


@pytest.mark.parametrize("module", [research.coverage_memory, agents.entries, agents.memories])
def test_module_doctests_pass(module):
    results = doctest.testmod(module)
    assert results.attempted > 0 and results.failed == 0


def reference_fractions(geometry: Geometry, poses: list[np.ndarray], cell: float, sectors: int, near: float):
    """The entry after ``poses`` (x, y, θ in metres and radians), cell by cell with plain loops."""
    n = math.ceil(geometry.arena_size / cell)
    size = geometry.arena_size / n
    swept = set()
    for x, y, theta in poses:
        for i in range(n):
            for j in range(n):
                cx, cy = (i + 0.5) * size - geometry.half, (j + 0.5) * size - geometry.half
                bearing = math.atan2(cy - y, cx - x) - theta
                bearing = (bearing + math.pi) % (2 * math.pi) - math.pi
                if math.hypot(cx - x, cy - y) <= geometry.sensor_range and abs(bearing) <= geometry.fov / 2:
                    swept.add((i, j))
    x, y, theta = poses[-1]
    total, unswept = np.zeros(2 * sectors), np.zeros(2 * sectors)
    for i in range(n):
        for j in range(n):
            cx, cy = (i + 0.5) * size - geometry.half, (j + 0.5) * size - geometry.half
            bearing = (math.atan2(cy - y, cx - x) - theta + math.pi) % (2 * math.pi) - math.pi
            sector = min(int((bearing + math.pi) / (2 * math.pi / sectors)), sectors - 1)
            b = sector + (sectors if math.hypot(cx - x, cy - y) >= near else 0)
            total[b] += 1
            unswept[b] += (i, j) not in swept
    return np.where(total > 0, unswept / np.maximum(total, 1), 0.0)


def pose_entry(geometry: Geometry, x: float, y: float, theta: float) -> np.ndarray:
    h = geometry.half
    return np.array([x / h, y / h, math.cos(theta), math.sin(theta), 0.1, 0.1, 0.01], dtype=np.float32)


def test_the_entry_matches_a_cell_by_cell_reference():
    geometry = Geometry.from_env(gym.make("SeifExploreLarge-v2"))
    memory = CoverageMemory(geometry, cell=3.0, sectors=6, near=7.0)
    rng = np.random.default_rng(0)
    poses: list[np.ndarray] = []
    for step in range(12):
        x, y = rng.uniform(-geometry.half, geometry.half, 2)
        theta = rng.uniform(-math.pi, math.pi)
        observation = {"pose": pose_entry(geometry, x, y, theta)}
        entry = memory.observe(observation, episode_start=np.array([step == 0]))[UNSWEPT]
        # the pose as the observation carries it (float32), decoded as the memory decodes it
        decoded = observation["pose"].astype(np.float64)
        poses.append(np.array([decoded[0] * geometry.half, decoded[1] * geometry.half,
                               math.atan2(decoded[3], decoded[2])]))  # fmt: skip
        assert entry.dtype == np.float32 and entry.shape == (12,)
        np.testing.assert_allclose(entry, reference_fractions(geometry, poses, 3.0, 6, 7.0), atol=1e-6)


def test_sweeping_follows_the_field_of_view():
    geometry = Geometry.from_env(gym.make("SeifExploreLarge-v2"))  # 5 m range, a half circle ahead
    memory = CoverageMemory(geometry)
    entry = memory.observe({"pose": pose_entry(geometry, 0.0, 0.0, 0.0)})[UNSWEPT]
    near_ring = entry[: memory.sectors]
    # the sectors behind (the first two and the last two of eight) keep every cell; those ahead lose the
    # part within the sensor's 5 m of the ring's 10 m (a quarter of the area)
    np.testing.assert_array_equal(near_ring[[0, 1, 6, 7]], 1.0)
    assert ((near_ring[2:6] > 0.6) & (near_ring[2:6] < 0.9)).all()
    assert (entry[memory.sectors :] == 1.0).all()  # nothing beyond 10 m is swept
    # turning round sweeps the other half: the near sectors behind the new heading are the swept ones
    entry = memory.observe({"pose": pose_entry(geometry, 0.0, 0.0, math.pi)})[UNSWEPT]
    assert entry[: memory.sectors][0] < 1.0 and entry[: memory.sectors][-1] < 1.0


def test_batched_envs_keep_their_own_memories_and_restart_alone():
    geometry = Geometry.from_env(gym.make("SeifExploreLarge-v2"))
    batched, singles = CoverageMemory(geometry), [CoverageMemory(geometry) for _ in range(3)]
    rng = np.random.default_rng(1)
    for step in range(6):
        poses = np.stack([pose_entry(geometry, *rng.uniform(-15, 15, 2), rng.uniform(-3, 3)) for _ in range(3)])
        starts = np.array([step == 0, step == 3, False])
        entry = batched.observe({"pose": poses}, starts)[UNSWEPT]
        for k, single in enumerate(singles):
            expected = single.observe({"pose": poses[k]}, np.array([starts[k]]))[UNSWEPT]
            np.testing.assert_array_equal(entry[k], expected)
    batched.reset(1)
    singles[1].reset()
    poses = np.stack([pose_entry(geometry, 0.0, 0.0, 0.0)] * 3)
    entry = batched.observe({"pose": poses})[UNSWEPT]
    for k, single in enumerate(singles):
        np.testing.assert_array_equal(entry[k], single.observe({"pose": poses[k]})[UNSWEPT])


def test_the_wrapper_adds_the_entry_and_leaves_the_env_as_it_is():
    plain = gym.make("SeifExploreLarge-v2", max_episode_steps=5)
    wrapped = CoverageMemoryObservation(gym.make("SeifExploreLarge-v2", max_episode_steps=5))
    assert uses_coverage_memory(wrapped.observation_space) and not uses_coverage_memory(plain.observation_space)
    expected, _ = plain.reset(seed=7)
    observation, _ = wrapped.reset(seed=7)
    memory = CoverageMemory(Geometry.from_env(plain))
    rng = np.random.default_rng(2)
    for _ in range(5):
        assert wrapped.observation_space.contains(observation)
        for key, value in expected.items():
            np.testing.assert_array_equal(observation[key], value)
        np.testing.assert_array_equal(observation[UNSWEPT], memory.observe(expected)[UNSWEPT])
        action = rng.uniform(-1.0, 1.0, 2).astype(np.float32)
        expected, expected_reward, expected_terminated, expected_truncated, _ = plain.step(action)
        observation, reward, terminated, truncated, _ = wrapped.step(action)
        assert (reward, terminated, truncated) == (expected_reward, expected_terminated, expected_truncated)
    # a reset forgets the sweep
    observation, _ = wrapped.reset(seed=8)
    fresh = CoverageMemory(Geometry.from_env(plain)).observe(plain.reset(seed=8)[0])
    np.testing.assert_array_equal(observation[UNSWEPT], fresh[UNSWEPT])


def test_bad_input_is_refused_clearly():
    geometry = Geometry.from_env(gym.make("SeifExploreLarge-v2"))
    with pytest.raises(TypeError, match="geometry"):
        CoverageMemory(None)  # type: ignore[arg-type]
    for name, kwargs in (("cell", {"cell": 0.0}), ("cell", {"cell": math.inf}), ("near", {"near": -1.0}),
                         ("sectors", {"sectors": 0})):  # fmt: skip
        with pytest.raises(ValueError, match=name):
            CoverageMemory(geometry, **kwargs)
    for name, kwargs in (("cell", {"cell": "2"}), ("sectors", {"sectors": 2.5})):
        with pytest.raises(TypeError, match=name):
            CoverageMemory(geometry, **kwargs)
    with pytest.raises(TypeError, match="env"):
        CoverageMemoryObservation(gym.make("CartPole-v1"))
    with pytest.raises(ValueError, match="already"):
        CoverageMemoryObservation(CoverageMemoryObservation(gym.make("SeifExploreLarge-v2")))
    memory = CoverageMemory(geometry)
    single = {"pose": pose_entry(geometry, 0.0, 0.0, 0.0)}
    before = memory.observe(single, np.array([True]))[UNSWEPT]
    with pytest.raises(ValueError, match="episode_start"):
        memory.observe({"pose": np.stack([single["pose"]] * 2)}, np.array([True, False, True]))
    with pytest.raises(ValueError, match="pose"):
        memory.observe({"pose": np.zeros(3, dtype=np.float32)})
    # the refused calls changed nothing: the single env's memory goes on
    np.testing.assert_array_equal(memory.observe(single)[UNSWEPT], before)


def test_policy_memories_follow_the_policys_space():
    env = gym.make("SeifExploreLarge-v2")
    assert policy_memories(env.observation_space, env) is None and not has_policy_entries(env.observation_space)
    both = CoverageMemoryObservation(TimeLeftObservation(gym.make("SeifExploreLarge-v2")))
    memories = policy_memories(both.observation_space, env)
    assert isinstance(memories, PolicyMemories) and has_policy_entries(both.observation_space)
    assert [type(memory) for memory in memories.memories] == [CoverageMemory, TimeLeftClock]
    assert policy_view(gym.make("SeifExploreLarge-v2"), both.observation_space).observation_space == (
        both.observation_space
    )
    expected, _ = both.reset(seed=3)
    observation, _ = env.reset(seed=3)
    given = memories.observe(observation, episode_start=True)
    assert set(given) == set(expected)
    for key in (TIME_LEFT, UNSWEPT):
        np.testing.assert_array_equal(given[key], expected[key])


def test_a_policy_with_the_memory_runs_on_the_plain_env(tmp_path):
    """A model trained on the wrapped env is evaluated on the plain one: SB3Agent adds the entry itself."""
    from stable_baselines3 import PPO

    from agents.benchmark import ShippedPolicy, policy_fits

    limit = 6
    training_env = CoverageMemoryObservation(gym.make("SeifExploreLarge-v2", max_episode_steps=limit))
    path = tmp_path / "model.zip"
    PPO(BeliefPolicy, training_env, n_steps=8, batch_size=8, seed=0, device="cpu").save(path)
    assert policy_fits(ShippedPolicy(path, "SeifExploreLarge-v2", "here"), "SeifExploreLarge-v2")

    env = gym.make("SeifExploreLarge-v2", max_episode_steps=limit)
    agent = SB3Agent(path, env=env)
    assert agent.memories is not None
    predict = agent.model.predict
    row, _ = run_episode(agent, env, 0)
    assert row["length"] == limit
    # the same actions as the model given the wrapper's observations, episode after episode
    assert_acts_as_trained(agent, predict, training_env, env, seeds=(2, 3), steps=limit)


def test_a_refused_observation_changes_no_entry():
    both = CoverageMemoryObservation(TimeLeftObservation(gym.make("SeifExploreLarge-v2")))
    env = gym.make("SeifExploreLarge-v2")
    memories = policy_memories(both.observation_space, env)
    assert memories is not None
    observation, _ = env.reset(seed=0)
    first = memories.observe(observation, episode_start=True)
    with pytest.raises(ValueError, match="pose"):
        memories.observe({**observation, "pose": observation["pose"][:3]})
    # the clock did not count the refused step, the memory did not sweep from it
    second = memories.observe(observation)
    assert second[TIME_LEFT][0] == pytest.approx(first[TIME_LEFT][0] - 1 / 1000)
    np.testing.assert_array_equal(second[UNSWEPT], first[UNSWEPT])
