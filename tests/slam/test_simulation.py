"""Tests of :mod:`seif_gym.slam.simulation`."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from seif_gym.slam import EKF, RangeBearingSensor, VelocityMotionModel, wrap_angle
from seif_gym.slam.simulation import (
    loop_controls,
    loop_start_pose,
    pose_nees,
    ring_landmarks,
    run_filter,
    simulate_run,
)


def test_loop_controls_drive_the_requested_turns():
    controls = loop_controls(100, 0.1, 4.0, turns=1.0)
    assert controls.shape == (100, 2)
    v, w = controls[0]
    np.testing.assert_allclose(v / w, 4.0)
    np.testing.assert_allclose(v * 100 * 0.1, 2.0 * math.pi * 4.0)
    # the default closes the loop with some overlap
    np.testing.assert_allclose(loop_controls(100, 0.1, 4.0)[0, 1] * 100 * 0.1, 1.2 * 2.0 * math.pi)
    np.testing.assert_allclose(loop_controls(10, 0.5, 2.0, speed=3.0)[0], [3.0, 1.5])
    with pytest.raises(ValueError, match="at most one"):
        loop_controls(10, 0.1, 2.0, speed=1.0, turns=1.0)
    with pytest.raises(ValueError, match="steps"):
        loop_controls(0, 0.1, 2.0)


def test_noise_free_loop_stays_on_the_circle_and_returns():
    radius, steps = 3.0, 90
    motion, sensor = VelocityMotionModel(), RangeBearingSensor(max_range=4.0)
    landmarks = ring_landmarks(12, 2.0, 4.0, np.random.default_rng(1))
    run = simulate_run(
        motion,
        sensor,
        landmarks,
        loop_controls(steps, 0.1, radius, turns=1.0),
        0.1,
        loop_start_pose(radius),
        noise_free=True,
    )
    np.testing.assert_allclose(np.linalg.norm(run.true_poses[:, :2], axis=1), radius, rtol=1e-12)
    np.testing.assert_allclose(run.true_poses[-1], run.true_poses[0], atol=1e-9)
    # the measurements are exactly the predicted ones of the visible landmarks
    for t in (0, 45, 89):
        pose = run.true_poses[t + 1]
        visible = np.flatnonzero(sensor.visible(pose, landmarks))
        np.testing.assert_array_equal(run.ids[t], visible)
        z = sensor.predict(pose, landmarks[visible])
        np.testing.assert_array_equal(run.ranges[t], z[:, 0])
        np.testing.assert_array_equal(run.bearings[t], z[:, 1])


def test_noisy_run_shapes_and_determinism():
    motion, sensor = VelocityMotionModel(), RangeBearingSensor(max_range=4.0)
    landmarks = ring_landmarks(12, 2.0, 4.0, np.random.default_rng(1))
    controls = loop_controls(30, 0.1, 3.0)

    def make(seed):
        return simulate_run(motion, sensor, landmarks, controls, 0.1, loop_start_pose(3.0), np.random.default_rng(seed))

    run = make(5)
    assert run.steps == 30
    assert run.true_poses.shape == (31, 3) and run.controls.shape == (30, 2)
    assert len(run.ranges) == len(run.bearings) == len(run.ids) == 30
    assert all(len(r) == len(b) == len(i) for r, b, i in zip(run.ranges, run.bearings, run.ids))
    assert all(i.dtype == np.int64 for i in run.ids)
    assert not run.true_poses.flags.writeable and not run.ranges[0].flags.writeable
    with pytest.raises(dataclasses.FrozenInstanceError):
        run.dt = 1.0  # type: ignore[misc]
    again = make(5)
    np.testing.assert_array_equal(run.true_poses, again.true_poses)
    assert not np.array_equal(run.true_poses, make(6).true_poses)
    with pytest.raises(TypeError, match="rng"):
        simulate_run(motion, sensor, landmarks, controls, 0.1, loop_start_pose(3.0))


def test_ring_landmarks_lie_on_the_ring():
    landmarks = ring_landmarks(40, 5.0, 7.0, np.random.default_rng(3))
    assert landmarks.shape == (40, 2)
    radii = np.linalg.norm(landmarks, axis=1)
    assert np.all((radii >= 5.0) & (radii <= 7.0))
    angles = np.sort(np.arctan2(landmarks[:, 1], landmarks[:, 0]))
    assert np.max(np.diff(angles)) < 2.0 * (2.0 * math.pi / 40)  # no big gap


def test_pose_nees_wraps_the_heading():
    cov = np.diag([0.01, 0.04, 0.0025])
    # a heading error of 2 pi - 0.05 is an error of -0.05
    value = pose_nees([1.0, 2.0, math.pi - 0.01], [0.9, 2.2, -math.pi + 0.04], cov)
    assert isinstance(value, float)
    np.testing.assert_allclose(value, 0.1**2 / 0.01 + 0.2**2 / 0.04 + 0.05**2 / 0.0025)
    batch = pose_nees(np.zeros((4, 3)), np.ones((4, 3)) * 0.1, np.broadcast_to(cov, (4, 3, 3)))
    assert batch.shape == (4,)
    with pytest.raises(ValueError, match="shape"):
        pose_nees(np.zeros(3), np.zeros(3), np.eye(2))


def test_run_filter_records_every_step():
    motion, sensor = VelocityMotionModel(), RangeBearingSensor(max_range=4.0)
    landmarks = ring_landmarks(12, 2.0, 4.0, np.random.default_rng(1))
    controls = loop_controls(30, 0.1, 3.0)
    run = simulate_run(motion, sensor, landmarks, controls, 0.1, loop_start_pose(3.0), noise_free=True)
    filt = EKF(motion, sensor, run.initial_pose)
    result = run_filter(filt, run)
    assert result["poses"].shape == (31, 3)
    assert result["pose_covariances"].shape == (31, 3, 3)
    assert result["step_seconds"].shape == (30,) and np.all(result["step_seconds"] > 0)
    np.testing.assert_array_equal(result["poses"][0], run.initial_pose)
    np.testing.assert_array_equal(result["poses"][-1], filt.pose)
    # noise-free data: only the linearization error remains
    error = result["poses"] - run.true_poses
    error[:, 2] = wrap_angle(error[:, 2])
    assert np.max(np.abs(error)) < 1e-3
