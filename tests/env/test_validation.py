"""The shared input checks (``seif_gym.validation``): one home for the library, the env and its wrappers."""

from __future__ import annotations

import doctest

import numpy as np
import pytest

import seif_gym.validation
from seif_gym.validation import as_count, as_nonnegative_scalar, as_positive_scalar, as_real_scalar, as_scalar_between


def test_module_doctests_pass():
    results = doctest.testmod(seif_gym.validation)
    assert results.attempted > 0 and results.failed == 0


@pytest.mark.parametrize("value", [1, 2.5, np.float32(0.5), np.int64(3), np.array(4.0)])
def test_positive_scalars_come_back_as_floats(value):
    result = as_positive_scalar(value, "cell")
    assert type(result) is float and result == float(value)


@pytest.mark.parametrize(
    ("check", "value", "error", "message"),
    [
        (as_positive_scalar, 0.0, ValueError, "cell must be positive"),
        (as_positive_scalar, -1, ValueError, "cell must be positive"),
        (as_positive_scalar, float("inf"), ValueError, "cell must be finite"),
        (as_positive_scalar, float("nan"), ValueError, "cell must be finite"),
        (as_positive_scalar, True, TypeError, "cell must be a real number"),
        (as_positive_scalar, "2", TypeError, "cell must be a real number"),
        (as_positive_scalar, None, TypeError, "cell must be a real number"),
        (as_nonnegative_scalar, -0.5, ValueError, "cell must be non-negative"),
        (as_real_scalar, np.array([1.0]), TypeError, "cell must be a real number"),
    ],
)
def test_bad_scalars_raise_naming_the_argument(check, value, error, message):
    with pytest.raises(error, match=message):
        check(value, "cell")


def test_zero_is_non_negative():
    assert as_nonnegative_scalar(0, "wall_penalty") == 0.0


def test_the_env_and_the_coverage_memory_check_with_it():
    import gymnasium as gym

    from agents.baselines import Geometry
    from research.coverage_memory import CoverageMemory
    from seif_gym.envs.explore import RewardConfig, SensorConfig

    with pytest.raises(ValueError, match="sensor_range must be positive"):
        SensorConfig(sensor_range=0.0)
    with pytest.raises(TypeError, match="fov must be a real number"):
        SensorConfig(fov="wide")
    with pytest.raises(ValueError, match="wall_penalty must be non-negative"):
        RewardConfig(wall_penalty=-1.0)
    RewardConfig(wall_penalty=0.0)  # zero switches the penalty off
    # what passed the check is what the config keeps: a plain float, never the 0-d array it came as
    sensor = SensorConfig(sensor_range=np.array(8.0), fov=np.int64(3))
    assert type(sensor.sensor_range) is float and sensor.sensor_range == 8.0 and type(sensor.fov) is float
    geometry = Geometry.from_env(gym.make("SeifExplore-v2"))
    with pytest.raises(ValueError, match="cell must be positive"):
        CoverageMemory(geometry, cell=0.0)
    with pytest.raises(TypeError, match="near must be a real number"):
        CoverageMemory(geometry, near="far")


def test_the_metrics_the_decoder_and_the_shaping_check_with_it():
    import gymnasium as gym

    from agents.shaping import CoverageShaping
    from seif_gym.metrics import map_error
    from seif_gym.observation import ObservationDecoder

    truth = np.zeros((2, 2))
    with pytest.raises(ValueError, match="d_cap must be positive, got -1.0"):
        map_error(np.zeros((1, 2)), truth, [0], d_cap=-1.0)
    with pytest.raises(TypeError, match="d_cap must be a real number, got str"):
        map_error(np.zeros((1, 2)), truth, [0], d_cap="1")
    assert map_error(np.zeros((1, 2)), truth, [0], d_cap=np.float32(2.0)) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="arena_size must be finite"):
        ObservationDecoder(arena_size=float("inf"))
    assert ObservationDecoder(arena_size=np.int64(20)).arena_size == 20.0
    env = gym.make("SeifExplore-v2")
    with pytest.raises(ValueError, match="coef must be non-negative, got -1.0"):
        CoverageShaping(env, coef=-1.0)
    with pytest.raises(TypeError, match="gamma must be a real number, got bool"):
        CoverageShaping(env, gamma=True)


@pytest.mark.parametrize("value", [0, 3, np.int32(2), np.int64(7)])
def test_counts_come_back_as_ints(value):
    result = as_count(value, "sweeps")
    assert type(result) is int and result == int(value)


@pytest.mark.parametrize(
    ("value", "minimum", "error", "message"),
    [
        (2.0, 0, TypeError, "sweeps must be an int, got float"),
        (True, 0, TypeError, "sweeps must be an int, got bool"),
        (None, 0, TypeError, "sweeps must be an int"),
        (np.array(2), 0, TypeError, "sweeps must be an int"),
        (-1, 0, ValueError, "sweeps must be a non-negative int, got -1"),
        (0, 1, ValueError, "sweeps must be a positive int, got 0"),
        (1, 2, ValueError, "sweeps must be an int of at least 2, got 1"),
    ],
)
def test_bad_counts_raise_naming_the_argument(value, minimum, error, message):
    with pytest.raises(error, match=message):
        as_count(value, "sweeps", minimum=minimum)


def test_scalars_between_exclude_both_ends():
    assert as_scalar_between(np.float32(0.5), "split_weight", 0.0, 1.0) == 0.5
    for value in (0.0, 1.0, -0.1, 1.1):
        with pytest.raises(ValueError, match="split_weight must lie strictly between 0.0 and 1.0"):
            as_scalar_between(value, "split_weight", 0.0, 1.0)
    with pytest.raises(TypeError, match="split_weight must be a real number"):
        as_scalar_between("half", "split_weight", 0.0, 1.0)
    with pytest.raises(ValueError, match="split_weight must be finite"):
        as_scalar_between(float("nan"), "split_weight", 0.0, 1.0)


def test_the_filters_and_their_helpers_check_with_it():
    from seif_gym.slam import ESEIF, SEIF, Associator
    from seif_gym.slam.batched import BatchedSEIF
    from seif_gym.slam.marginals import breadth_first_nodes
    from seif_gym.slam.models import RangeBearingSensor, VelocityMotionModel
    from seif_gym.slam.scenarios import FIDELITY_SCENARIOS, make_loop_run
    from seif_gym.slam.simulation import loop_controls, ring_landmarks
    from seif_gym.world import BatchedWorld, WorldConfig

    motion, sensor, start = VelocityMotionModel(), RangeBearingSensor(), [0.0, 0.0, 0.0]
    cases = [
        (lambda: SEIF(motion, sensor, start, max_active=0), ValueError, "max_active must be a positive int"),
        (lambda: SEIF(motion, sensor, start, max_active=4.0), TypeError, "max_active must be an int"),
        (
            lambda: SEIF(motion, sensor, start, recovery_budget=-1),
            ValueError,
            "recovery_budget must be a non-negative int",
        ),
        (lambda: SEIF(motion, sensor, start, recovery_landmarks=True), TypeError, "recovery_landmarks must be an int"),
        (lambda: SEIF(motion, sensor, start, recovery_relaxation=2.0), ValueError, "recovery_relaxation must lie"),
        (lambda: SEIF(motion, sensor, start, recovery_tolerance=-1e-3), ValueError, "recovery_tolerance must be non-"),
        (lambda: ESEIF(motion, sensor, start, split_weight=1), ValueError, "split_weight must lie strictly"),
        (lambda: ESEIF(motion, sensor, start, relocalization_landmarks=1), ValueError, "relocalization_landmarks"),
        (lambda: SEIF(motion, sensor, start).refine_mean(sweeps=1.5), TypeError, "sweeps must be an int"),
        (lambda: BatchedSEIF(0, 10, motion, sensor), ValueError, "num_filters must be a positive int"),
        (lambda: BatchedSEIF(2, 10, motion, sensor, max_landmark_id=-1), ValueError, "max_landmark_id must be"),
        (lambda: Associator(merge_every=0), ValueError, "merge_every must be a positive int"),
        (lambda: loop_controls(10.0, 0.1, 5.0), TypeError, "steps must be an int"),
        (lambda: ring_landmarks(0, 1.0, 2.0, np.random.default_rng(0)), ValueError, "n must be a positive int"),
        (lambda: make_loop_run(FIDELITY_SCENARIOS["circle"], -1), ValueError, "seed must be a non-negative int"),
        (lambda: BatchedWorld(1, WorldConfig(), motion, sensor, buffer=3), ValueError, "buffer must be an int of"),
    ]
    for build, error, message in cases:
        with pytest.raises(error, match=message):
            build()
    filt = SEIF(motion, sensor, start)
    with pytest.raises(TypeError, match="max_landmarks must be an int"):
        breadth_first_nodes(filt._store, np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64), 2.0)


def test_the_observation_config_vector_env_select_and_benchmark_check_with_it(tmp_path):
    from agents import benchmark
    from research.select import select_checkpoints
    from seif_gym.envs.vector import SeifExploreVectorEnv
    from seif_gym.observation import ObservationConfig

    config = ObservationConfig(map_extent=np.float32(8.0), std_scale=2)
    assert type(config.map_extent) is float and type(config.std_scale) is float and config.std_scale == 2.0
    cases = [
        (lambda: ObservationConfig(map_extent="wide"), TypeError, "map_extent must be a real number"),
        (lambda: ObservationConfig(coverage_resolution=0.0), ValueError, "coverage_resolution must be positive"),
        (lambda: ObservationConfig(map_size=2.0), TypeError, "map_size must be an int"),
        (lambda: SeifExploreVectorEnv(2, max_episode_steps=0), ValueError, "max_episode_steps must be a positive int"),
        (lambda: SeifExploreVectorEnv(2, max_episode_steps=10.0), TypeError, "max_episode_steps must be an int"),
        (lambda: select_checkpoints([tmp_path], "SeifExplore-v1", {}, seed=1.5), TypeError, "seed must be an int"),
        (lambda: benchmark.run_benchmark(["SeifExplore-v1"], ["random"], 1.5, 0, tmp_path), TypeError, "episodes"),
    ]
    for build, error, message in cases:
        with pytest.raises(error, match=message):
            build()
    assert not list(tmp_path.iterdir())  # refused before anything was written
