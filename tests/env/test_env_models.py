"""The env's motion and sensor models: Thrun's or per-second motion noise, constant or range-dependent range noise.

Recording and bit-exact replay with these models are in tests/env/test_episodes.py (its ``CALIBRATED`` cases).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import seif_gym  # noqa: F401  (registers the envs)
from seif_gym.envs.explore import SeifExploreEnv, make_models
from seif_gym.episodes import episode_models
from seif_gym.slam import RangeBearingSensor, VelocityMotionModel
from seif_gym.slam.noise_models import PerSecondVelocityMotionModel, RangeDependentSensor

PER_SECOND = (1e-4, 0.0, 2e-5, 4e-4, 0.01, 0.02, 0.0, 2e-4, 1e-4)
CALIBRATED = {"motion_model": "per_second", "motion_noise": PER_SECOND, "range_noise": (0.05, 0.07, 0.2)}


def test_calibrated_models_are_built_and_pass_the_env_checker():
    env = SeifExploreEnv(**CALIBRATED, dt=0.1)
    motion, sensor = env.motion, env.sensor
    assert isinstance(motion, PerSecondVelocityMotionModel) and isinstance(sensor, RangeDependentSensor)
    assert motion.forward == PER_SECOND[0:3] and motion.turn == PER_SECOND[3:6] and motion.lateral == PER_SECOND[6:9]
    assert sensor.range_slope == 0.05 and sensor.range_bounds == (0.07, 0.2)
    assert (
        sensor.sigma_bearing == env.sensor_config.sigma_bearing and sensor.max_range == env.sensor_config.sensor_range
    )
    check_env(env, skip_render_check=True)
    assert env.config["motion_model"] == "per_second" and env.config["range_noise"] == (0.05, 0.07, 0.2)
    assert env.observation_space == SeifExploreEnv().observation_space


def test_default_models_are_thrun_and_constant_noise():
    env = SeifExploreEnv()
    assert type(env.motion) is VelocityMotionModel and type(env.sensor) is RangeBearingSensor
    assert env.config["motion_model"] == "thrun" and env.config["range_noise"] is None


def test_replay_models_equal_the_env_models_and_accept_old_configs():
    env = SeifExploreEnv(**CALIBRATED)
    motion, sensor = episode_models(env.config)
    assert repr(motion) == repr(env.motion) and repr(sensor) == repr(env.sensor)
    # an episode recorded before these keys existed replays with Thrun's model and a constant noise
    old = {key: value for key, value in SeifExploreEnv().config.items() if key not in ("motion_model", "range_noise")}
    motion, sensor = make_models(old)
    assert type(motion) is VelocityMotionModel and type(sensor) is RangeBearingSensor


def test_calibrated_noise_is_dt_invariant_in_the_env():
    """The filter's pose covariance after one second of the same command hardly depends on the step."""
    covariances = []
    for dt in (0.05, 0.25):
        env = SeifExploreEnv(**CALIBRATED, dt=dt, filter="ekf", num_landmarks=1, sensor_range=0.1, sensor_min_range=0.0)
        env.reset(seed=0)
        for _ in range(round(1.0 / dt)):
            env.step(np.array([0.5, 0.2], dtype=np.float32))
        covariances.append(np.asarray(env.filter.pose_covariance).copy())
    np.testing.assert_allclose(covariances[0], covariances[1], rtol=0.1, atol=1e-9)
    thrun = []
    for dt in (0.05, 0.25):
        env = SeifExploreEnv(dt=dt, filter="ekf", num_landmarks=1, sensor_range=0.1, sensor_min_range=0.0)
        env.reset(seed=0)
        for _ in range(round(1.0 / dt)):
            env.step(np.array([0.5, 0.2], dtype=np.float32))
        thrun.append(np.asarray(env.filter.pose_covariance)[0, 0])
    assert thrun[1] > 2.0 * thrun[0]  # Thrun's model: fewer, longer steps give more covariance


def test_vector_env_falls_back_to_sync_and_equals_single_envs():
    vector = gym.make_vec("SeifExplore-v1", num_envs=2, **CALIBRATED)
    assert vector.unwrapped.backend == "sync"
    singles = [gym.make("SeifExplore-v1", **CALIBRATED) for _ in range(2)]
    observations, _ = vector.reset(seed=5)
    for index, env in enumerate(singles):
        single, _ = env.reset(seed=5 + index)
        for key in single:
            np.testing.assert_array_equal(observations[key][index], single[key])
    actions = np.array([[0.6, 0.1], [0.3, -0.4]], dtype=np.float32)
    for _ in range(5):
        observations, rewards, *_ = vector.step(actions)
        for index, env in enumerate(singles):
            single, reward, *_ = env.step(actions[index])
            assert reward == rewards[index]
            np.testing.assert_array_equal(observations["belief_map"][index], single["belief_map"])
    vector.close()
    assert gym.make_vec("SeifExplore-v1", num_envs=2).unwrapped.backend == "compiled"


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"motion_model": "ackermann"}, "motion_model"),
        ({"motion_model": "per_second"}, "motion_noise must be 9"),
        ({"motion_noise": PER_SECOND}, "motion_noise must be 6"),
        ({**CALIBRATED, "motion_noise": (-1.0,) + PER_SECOND[1:]}, "motion_noise"),
        ({"range_noise": (0.05, 0.3, 0.2)}, "range_noise"),
        ({"range_noise": (0.0, 0.07, 0.2)}, "range_noise"),
        ({"range_noise": (0.05, 0.07)}, "range_noise"),
        ({"range_noise": "loud"}, "range_noise"),
        ({"innovation_gate": -1.0}, "innovation_gate"),
        ({"innovation_gate": 0.0}, "innovation_gate"),
    ],
)
def test_bad_model_arguments_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SeifExploreEnv(**kwargs)


def test_a_calibration_file_configures_the_env():
    from seif_gym.datasets.mrclam.calibration import DATASET6, Calibration

    calibration = Calibration.load(DATASET6)
    env = SeifExploreEnv(**calibration.env_kwargs())
    assert isinstance(env.motion, PerSecondVelocityMotionModel) and isinstance(env.sensor, RangeDependentSensor)
    assert env.motion.forward == calibration.forward and env.motion.lateral == calibration.lateral
    assert env.sensor.range_bounds == calibration.range_bounds
    assert env.sensor.sigma_bearing == calibration.sigma_bearing


@pytest.mark.parametrize("filter_name", ["seif", "eseif", "ekf", "eif"])
def test_innovation_gate_reaches_every_filter(filter_name):
    env = SeifExploreEnv(filter=filter_name, innovation_gate=9.0)
    env.reset(seed=0)
    assert env.filter.options["innovation_gate"] == 9.0 and env.config["innovation_gate"] == 9.0
    plain = SeifExploreEnv(filter=filter_name)
    plain.reset(seed=0)
    assert plain.filter.options.get("innovation_gate") is None
    assert gym.make_vec("SeifExplore-v1", num_envs=1, innovation_gate=9.0).unwrapped.backend == "sync"
