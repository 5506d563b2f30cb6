"""The sensor's blind zone (``min_range``) and the ``-v2`` envs that use it.

In ``-v0``/``-v1`` a robot driving over a landmark measured it at millimetres; the
bearing's information grows as ``1/r^2`` and made the SEIF's information matrix
indefinite (a training run stopped on the ``LinAlgError`` of ``info["pose_nees"]``).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import seif_gym
from seif_gym.slam.models import RangeBearingSensor
from seif_gym.slam.noise_models import RangeDependentSensor


def test_sensor_does_not_see_landmarks_within_min_range():
    landmarks = np.array([[0.2, 0.0], [0.0, 0.29], [0.31, 0.0], [-1.0, 0.0], [0.0, 9.0]])
    pose = np.zeros(3)
    for sensor in (RangeBearingSensor(min_range=0.3), RangeDependentSensor(min_range=0.3)):
        assert sensor.visible(pose, landmarks).tolist() == [False, False, True, True, False]
        _, _, ids = sensor.sample(pose, landmarks, np.random.default_rng(0))
        assert ids.tolist() == [2, 3]
    # the default blind zone is the point itself, as before min_range existed
    _, _, ids = RangeBearingSensor().sample(pose, landmarks, np.random.default_rng(0))
    assert ids.tolist() == [0, 1, 2, 3]


@pytest.mark.parametrize("value, error", [(-0.1, ValueError), (8.0, ValueError), (float("nan"), ValueError),
                                          ("0.3", TypeError), (True, TypeError)])  # fmt: skip
def test_sensor_refuses_bad_min_range(value, error):
    with pytest.raises(error, match="min_range"):
        RangeBearingSensor(max_range=8.0, min_range=value)


def test_versions_pin_the_blind_zone():
    for env_id, (kwargs, _) in seif_gym.VARIANTS.items():
        if env_id == seif_gym.MRCLAM_ID:  # the MRCLAM world numbers its own versions
            assert kwargs["sensor_min_range"] == 0.3
        elif env_id.endswith(("-v0", "-v1")):
            assert kwargs["sensor_min_range"] == 0.0, env_id
        else:
            assert kwargs["sensor_min_range"] == 0.3, env_id
    assert seif_gym.LATEST_VERSION == 2
    with pytest.raises(ValueError, match="sensor_min_range"):
        gym.make("SeifExplore-v2", sensor_min_range=6.0)


def _parked_on_a_landmark(env_id: str, steps: int = 40):
    """An episode whose robot stands still 2 cm from a landmark; the ids it measured."""
    probe = gym.make(env_id)
    probe.reset(seed=4)
    start = probe.unwrapped.world.pose.copy()
    probe.close()
    positions = ((start[0] + 0.02, start[1]), (start[0] + 2.0, start[1] + 1.0), (start[0] - 1.5, start[1] + 1.5))
    env = gym.make(env_id, layout="fixed", num_landmarks=3, landmark_positions=positions)
    _, info = env.reset(seed=4)
    np.testing.assert_array_equal(env.unwrapped.world.pose, start)  # the start does not depend on the layout
    seen = set()
    for _ in range(steps):
        _, _, terminated, truncated, info = env.step(np.zeros(2, dtype=np.float32))
        seen.update(info["measurements"].ids.tolist())
        assert np.isfinite(info["pose_nees"])
    return seen, env.unwrapped.filter


def _largest_information(filt) -> float:
    omega = filt.information_matrix
    omega = omega.toarray() if hasattr(omega, "toarray") else np.asarray(omega)
    assert np.all(np.linalg.eigvalsh(omega) > 0)
    return float(np.max(np.diag(omega)[3:]))  # the landmarks' (the pose's grows while it stands still)


def test_v2_robot_standing_on_a_landmark_does_not_measure_it():
    """-v2 never measures the landmark under the robot; -v1 (reproduced as it was) does, and its information explodes."""
    seen, filt = _parked_on_a_landmark("SeifExplore-v2")
    assert 0 not in seen and {1, 2} <= seen
    seen_v1, filt_v1 = _parked_on_a_landmark("SeifExplore-v1")
    assert 0 in seen_v1
    # the bearing of a landmark at ~2 cm: information ~1/r^2, hundreds of times what -v2 holds on any landmark
    assert _largest_information(filt_v1) > 100 * _largest_information(filt)
