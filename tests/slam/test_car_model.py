"""Tests of ``seif_gym.slam.car_model``: the Ackermann model of the Victoria Park car.

The equations are those of ``docs/data/victoria_park.md`` ("The vehicle
model"). Jacobians are checked against central
differences with step ``H``: the truncation error is ``H**2`` times a third
derivative (tiny for these smooth functions at these scales) and the
rounding error ``~ eps |value| / H``, so ``1e-7`` absolute is ample for
entries of order one.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from seif_gym.slam import EIF, EKF, SEIF, RangeBearingSensor
from seif_gym.slam.car_model import AckermannLaserModel
from seif_gym.slam.models import wrap_angle

H = 1e-6
DT = 0.025


def central_difference(f, x, angle_rows=(2,), step=H):
    x = np.asarray(x, dtype=np.float64)
    columns = []
    for k in range(x.size):
        e = np.zeros_like(x)
        e[k] = step
        diff = np.asarray(f(x + e)) - np.asarray(f(x - e))
        for row in angle_rows:
            diff[row] = wrap_angle(float(diff[row]))
        columns.append(diff / (2 * step))
    return np.column_stack(columns)


def readme_step(pose, v_e, alpha, dt, L=2.83, H_enc=0.76, a=3.78, b=0.5):
    """The data README's equations, written out independently."""
    x, y, phi = pose
    v_c = v_e / (1 - math.tan(alpha) * H_enc / L)
    return np.array(
        [
            x + dt * (v_c * math.cos(phi) - v_c / L * math.tan(alpha) * (a * math.sin(phi) + b * math.cos(phi))),
            y + dt * (v_c * math.sin(phi) + v_c / L * math.tan(alpha) * (a * math.cos(phi) - b * math.sin(phi))),
            wrap_angle(phi + dt * v_c / L * math.tan(alpha)),
        ]
    )


CASES = [
    # pose, (v_e, alpha), dt
    (np.array([1.0, -2.0, 0.3]), (3.0, 0.2), DT),
    (np.array([-5.0, 7.0, -2.9]), (6.5, -0.55), DT),
    (np.array([0.0, 0.0, 3.1]), (0.5, 0.58), 0.2),
    (np.array([10.0, 3.0, -0.7]), (2.0, 0.0), DT),
    (np.array([2.0, 1.0, 1.2]), (-0.05, 0.1), 0.013),
]


@pytest.fixture
def model():
    return AckermannLaserModel()


@pytest.mark.parametrize("pose, control, dt", CASES)
def test_predict_matches_the_readme_equations(model, pose, control, dt):
    np.testing.assert_allclose(model.predict(pose, control, dt), readme_step(pose, *control, dt), rtol=0, atol=1e-12)


@pytest.mark.parametrize("pose, control, dt", CASES)
def test_state_jacobian_against_finite_differences(model, pose, control, dt):
    G = model.jacobian_state(pose, control, dt)
    numeric = central_difference(lambda p: model.predict(p, control, dt), pose)
    np.testing.assert_allclose(G, numeric, rtol=0, atol=1e-7)
    # linearize returns the same G and delta = g - pose
    delta, G_lin, R = model.linearize(pose, control, dt)
    np.testing.assert_array_equal(G_lin, G)
    step = model.predict(pose, control, dt) - pose
    step[2] = wrap_angle(float(step[2]))
    np.testing.assert_allclose(delta, step, rtol=0, atol=1e-12)


@pytest.mark.parametrize("pose, control, dt", CASES)
def test_control_jacobian_against_finite_differences(model, pose, control, dt):
    V = model.jacobian_control(pose, control, dt)
    numeric = central_difference(lambda u: model.predict(pose, u, dt), np.array(control, dtype=float))
    np.testing.assert_allclose(V, numeric, rtol=0, atol=1e-7)


@pytest.mark.parametrize("pose, control, dt", CASES)
def test_noise_is_the_propagated_control_noise_plus_floor(model, pose, control, dt):
    _, _, R = model.linearize(pose, control, dt)
    V = model.jacobian_control(pose, control, dt)
    M = model.control_covariance(control, dt)
    expected = V @ M @ V.T + model.noise_floor * dt / model.reference_dt * np.eye(3)
    np.testing.assert_allclose(R, expected, rtol=1e-12, atol=1e-20)
    np.testing.assert_array_equal(R, R.T)
    assert np.all(np.linalg.eigvalsh(R) > 0)


def test_trusted_paths_equal_checked_paths(model):
    pose, control, dt = CASES[1]
    for a, b in zip(model.linearize(pose, control, dt), model.linearize_trusted(pose, np.array(control), dt)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(model.predict(pose, control, dt), model.predict_trusted(pose, control, dt))


def test_noise_does_not_depend_on_how_an_interval_is_split(model):
    """Two half steps give the noise of one whole step (to first order): R grows linearly with dt."""
    pose, control = np.array([0.0, 0.0, 0.4]), (4.0, 0.1)
    _, G1, R1 = model.linearize(pose, control, 0.0125)
    middle = model.predict(pose, control, 0.0125)
    _, G2, R2 = model.linearize(middle, control, 0.0125)
    _, _, R = model.linearize(pose, control, 0.025)
    # equal up to the heading change within the step (omega dt ~ 0.005 rad here)
    np.testing.assert_allclose(G2 @ R1 @ G2.T + R2, R, rtol=1e-2)


def test_encoder_speed_correction(model):
    """Straight ahead the encoder speed is the axle speed; in a left turn the inner (left) wheel is slower."""
    straight = model.displacement(np.zeros(3), (2.0, 0.0), 1.0)
    np.testing.assert_allclose(straight, [2.0, 0.0, 0.0], atol=1e-15)
    turn = model.displacement(np.zeros(3), (2.0, 0.3), 0.01)
    v_c = 2.0 / (1 - math.tan(0.3) * 0.76 / 2.83)
    assert turn[2] == pytest.approx(0.01 * v_c * math.tan(0.3) / 2.83)
    assert v_c > 2.0


def test_sample_is_unbiased_and_matches_the_noise(model):
    rng = np.random.default_rng(0)
    pose, control, dt = np.array([1.0, 2.0, 0.5]), (5.0, 0.2), DT
    samples = np.array([model.sample(pose, control, dt, rng) for _ in range(20000)])
    mean = model.predict(pose, control, dt)
    _, _, R = model.linearize(pose, control, dt)
    floor = model.noise_floor * np.eye(3)  # not sampled
    errors = samples - mean
    errors[:, 2] = wrap_angle(errors[:, 2])
    assert np.all(np.abs(errors.mean(0)) < 4 * np.sqrt(np.diag(R) / len(samples)))
    np.testing.assert_allclose(np.cov(errors.T), R - floor, rtol=0.05, atol=1e-12)


def test_validation(model):
    with pytest.raises(ValueError, match="steering"):
        model.validate_control((1.0, 1.3))
    with pytest.raises(ValueError):
        model.predict(np.zeros(3), (np.nan, 0.0), DT)
    with pytest.raises(ValueError):
        model.predict(np.zeros(3), (1.0, 0.0), 0.0)
    with pytest.raises(ValueError):
        AckermannLaserModel(max_steering=1.6)
    with pytest.raises(TypeError):
        model.sample(np.zeros(3), (1.0, 0.0), DT, rng=0)


@pytest.mark.parametrize("filter_class", [SEIF, EIF, EKF])
def test_every_filter_runs_with_the_car_model(model, filter_class):
    """The filters take the car model through the same interface as the velocity model."""
    sensor = RangeBearingSensor(sigma_range=0.5, sigma_bearing=math.radians(1.0), max_range=40.0, fov=math.pi)
    filt = filter_class(model, sensor, np.zeros(3))
    rng = np.random.default_rng(1)
    landmarks = np.array([[10.0, 5.0], [15.0, -4.0], [20.0, 8.0]])
    truth = np.zeros(3)
    for step in range(200):
        control = (3.0, 0.05)
        truth = model.sample(truth, control, DT, rng)
        filt.predict(control, DT)
        if step % 8 == 7:
            ranges, bearings, ids = sensor.sample(truth, landmarks, rng)
            filt.update(ranges, bearings, ids)
    assert np.hypot(*(filt.pose[:2] - truth[:2])) < 0.5
    assert filt.num_landmarks == 3
