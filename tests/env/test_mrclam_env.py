"""``SeifExploreMRCLAM-v0`` (seif_gym/envs/mrclam.py) and the walls and fixed layouts it is built from."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import seif_gym  # noqa: F401  (registers the envs)
from seif_gym.envs.explore import SeifExploreEnv
from seif_gym.envs.mrclam import MRCLAM_CALIBRATION, MRCLAM_ORIGIN, mrclam_kwargs
from seif_gym.slam.noise_models import PerSecondVelocityMotionModel, RangeDependentSensor


def test_the_variant_is_the_calibrated_world():
    world = json.loads(MRCLAM_CALIBRATION.read_text())["world"]
    env = gym.make("SeifExploreMRCLAM-v0")
    base = env.unwrapped
    config = base.world_config
    survey = np.array(world["landmarks"])
    np.testing.assert_allclose(np.array(config.landmark_positions) + MRCLAM_ORIGIN, survey, atol=1e-6)
    hx, hy = config.half_extent
    assert 5.0 < 2 * hx < 5.5 and 10.0 < 2 * hy < 11.0 and config.arena_size >= 2 * max(hx, hy)
    x_min, x_max, y_min, y_max = np.array(world["bounds"]) - np.repeat(MRCLAM_ORIGIN, 2)
    assert -hx < x_min and x_max < hx and -hy < y_min and y_max < hy  # where the robots drove is inside
    assert (
        base.robot_config.max_speed == world["max_speed"] and base.robot_config.max_turn_rate == world["max_turn_rate"]
    )
    assert isinstance(base.motion, PerSecondVelocityMotionModel) and isinstance(base.sensor, RangeDependentSensor)
    assert abs(base.sensor.fov - world["fov"]) < 1e-3 and env.spec.max_episode_steps == 1200
    assert gym.make_vec("SeifExploreMRCLAM-v0", num_envs=1).unwrapped.backend == "sync"


def test_the_variant_passes_both_env_checkers():
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    check_env(gym.make("SeifExploreMRCLAM-v0").unwrapped)
    sb3_check_env(gym.make("SeifExploreMRCLAM-v0"), warn=True)


def test_the_robot_stays_inside_the_rectangular_walls():
    env = SeifExploreEnv(**{**mrclam_kwargs(), "max_speed": 1.0})  # fast, to reach the walls
    _, info = env.reset(seed=4)
    hx, hy = env.world_config.half_extent
    contacts = 0
    for _ in range(400):
        _, _, terminated, _, info = env.step(np.array([1.0, 0.05], dtype=np.float32))
        x, y = info["true_pose"][:2]
        assert abs(x) <= hx + 1e-9 and abs(y) <= hy + 1e-9
        contacts += info["wall_contact"]
        if terminated:
            break
    assert contacts > 0
    np.testing.assert_array_equal(env.world.landmarks, np.array(env.world_config.landmark_positions))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"arena_extent": (30.0, 5.0)}, "arena_extent"),
        ({"arena_extent": (5.0,)}, "arena_extent"),
        ({"arena_extent": (5.0, 5.0), "layout": "loop"}, "square"),
        ({"layout": "fixed"}, "landmark_positions"),
        ({"landmark_positions": ((0.0, 0.0),)}, "landmark_positions"),
        ({"layout": "fixed", "num_landmarks": 2, "landmark_positions": ((0.0, 0.0),)}, "landmark_positions"),
        ({"layout": "fixed", "num_landmarks": 1, "landmark_positions": ((50.0, 0.0),)}, "inside the walls"),
    ],
)
def test_bad_walls_and_layouts_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SeifExploreEnv(**kwargs)


def test_uniform_layout_fills_narrow_walls():
    env = SeifExploreEnv(arena_extent=(6.0, 16.0), num_landmarks=200)
    env.reset(seed=0)
    landmarks = env.world.landmarks
    assert np.all(np.abs(landmarks[:, 0]) <= 2.0) and np.all(np.abs(landmarks[:, 1]) <= 7.0)
    assert landmarks[:, 1].max() - landmarks[:, 1].min() > 10.0


def test_describe_world_measures_simulated_logs():
    from seif_gym.datasets.mrclam import calibration as mc

    logs = mc.simulate_logs(mc.Calibration.load(mc.DATASET6), np.random.default_rng(2), robots=(1,), duration=120.0, fov=1.1, max_range=6.0, outlier_fraction=0.0,
                            frame_period=0.3)  # fmt: skip
    world = mc.describe_world(list(logs.values()))
    log = logs[1]
    np.testing.assert_array_equal(np.array(world["landmarks"]), log.landmarks.positions)
    assert world["bounds"] == [log.ground_truth.x.min(), log.ground_truth.x.max(), log.ground_truth.y.min(),
                               log.ground_truth.y.max()]  # fmt: skip
    assert 0.9 < world["fov"] <= 1.1 + 0.05 and world["max_range"] <= 6.5
    assert abs(world["frame_period"] - 0.3) < 0.05
    assert world["max_speed"] == float(np.max(np.abs(log.odometry.controls[:, 0])))
    with pytest.raises(ValueError, match="at least one log"):
        mc.describe_world([])
    # the world survives the file round trip and configures the variant
    assert mc.Calibration.from_dict(mc.Calibration(world=world).to_dict()).world == world


def test_correlated_range_errors_are_a_stationary_ar1_process():
    """range_error_time: each landmark's unit range error is AR(1) with rho = exp(-dt / tau), variance 1."""
    from seif_gym.world import World

    env = SeifExploreEnv(num_landmarks=1, sensor_range=50.0, fov=2 * np.pi, range_error_time=2.0, dt=0.5)
    env.reset(seed=0)
    world = env.world
    assert world.range_error_memory == pytest.approx(np.exp(-0.25))
    truth = float(np.hypot(*(world.landmarks[0] - world.pose[:2])))
    rng = np.random.default_rng(1)
    errors = np.array([world.measure(rng)[0][0] - truth for _ in range(20000)]) / env.sensor_config.sigma_range
    assert abs(np.mean(errors)) < 0.1 and abs(np.std(errors) - 1.0) < 0.06
    lag1 = np.corrcoef(errors[:-1], errors[1:])[0, 1]
    assert lag1 == pytest.approx(np.exp(-0.25), abs=0.03)
    white = World(world.config, env.motion, env.sensor, world.landmarks, world.pose)
    samples = np.array([white.measure(rng)[0][0] for _ in range(5000)])
    assert abs(np.corrcoef(samples[:-1], samples[1:])[0, 1]) < 0.05  # the default: white
    with pytest.raises(ValueError, match="range_error_memory"):
        World(world.config, env.motion, env.sensor, world.landmarks, world.pose, range_error_memory=1.0)
    with pytest.raises(ValueError, match="range_error_time"):
        SeifExploreEnv(range_error_time=0.0)


def test_the_variant_has_the_logs_range_error_time():
    from seif_gym.envs.mrclam import range_error_time

    data = json.loads(MRCLAM_CALIBRATION.read_text())
    tau = range_error_time(data)
    assert 10.0 < tau < 25.0  # rho(5 s) = 0.71-0.80 on Dataset 6
    assert gym.make("SeifExploreMRCLAM-v0").unwrapped.sensor_config.range_error_time == round(tau, 2)
    assert range_error_time({}) is None
