"""The shared input checks (``seif_gym.validation``): one home for the library, the env and its wrappers."""

from __future__ import annotations

import doctest

import numpy as np
import pytest

import seif_gym.validation
from seif_gym.validation import as_nonnegative_scalar, as_positive_scalar, as_real_scalar


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
    from agents.coverage_memory import CoverageMemory
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
