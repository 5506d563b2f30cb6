"""Tests of ``seif_gym.slam.models``: velocity motion model, range-bearing sensor, ``wrap_angle``.

Reference: docs/filters/math.md, sections "Motion update" and "Measurement update".

Finite differences are central differences with a fixed step ``H``. Their error
is bounded by a truncation term (``H**2`` times a third derivative, tiny here)
plus a rounding term ``~ eps * |value| / H``; the tolerances below are written
from these two terms rather than picked to pass. A difference of an *angle*
output is always wrapped before dividing by ``2 H``: ``predict`` returns
wrapped headings and bearings, so a raw difference across the cut at +-pi would
be off by 2 pi.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from seif_gym.slam.models import RangeBearingSensor, VelocityMotionModel, wrap_angle

EPS = np.finfo(np.float64).eps
H = 1e-6  # finite-difference step
TWO_PI = 2.0 * math.pi


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------
def central_difference(f, x, angle_rows=(), step=H):
    """Jacobian of ``f`` at ``x`` by central differences; rows in ``angle_rows`` are wrapped."""
    x = np.asarray(x, dtype=np.float64)
    columns = []
    for k in range(x.size):
        e = np.zeros_like(x)
        e[k] = step
        diff = np.asarray(f(x + e), dtype=np.float64) - np.asarray(f(x - e), dtype=np.float64)
        diff = np.array(diff, dtype=np.float64).reshape(-1)
        for row in angle_rows:
            diff[row] = wrap_angle(float(diff[row]))
        columns.append(diff / (2.0 * step))
    return np.column_stack(columns)


def in_half_open_pi_interval(a) -> bool:
    a = np.asarray(a, dtype=np.float64)
    return bool(np.all((a >= -math.pi) & (a < math.pi)))


def angle_diff(a, b):
    return wrap_angle(np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64))


def book_displacement(theta, v, w, dt):
    """Thrun Table 5.3 / docs/filters/math.md form, valid for |w| > 0."""
    r = v / w
    return np.array(
        [
            -r * math.sin(theta) + r * math.sin(theta + w * dt),
            r * math.cos(theta) - r * math.cos(theta + w * dt),
            w * dt,
        ]
    )


# ---------------------------------------------------------------------------
# deterministic case tables (generated once at import, seeded)
# ---------------------------------------------------------------------------
_SPECIAL_OMEGAS = [0.0, -0.0, 1e-9, -1e-9, 1e-6, -1e-6, 1e-3, -1e-3]


def _motion_cases():
    rng = np.random.default_rng(20240601)
    cases = []
    # every special omega, each with a few random poses, speeds and steps
    for w in _SPECIAL_OMEGAS:
        for _ in range(3):
            pose = np.array([rng.uniform(-10, 10), rng.uniform(-10, 10), rng.uniform(-math.pi, math.pi)])
            cases.append((pose, np.array([rng.uniform(-3, 3), w]), float(rng.uniform(0.05, 2.0))))
    # omega on both sides of the series/closed-form switch of sinc (|w dt / 2| = 1e-4)
    for half in (0.99999e-4, 1e-4, 1.00001e-4, -1.00001e-4):
        cases.append((np.array([0.3, -1.2, 2.9]), np.array([1.7, 2 * half / 0.5]), 0.5))
    # moderate random controls
    for _ in range(20):
        pose = np.array([rng.uniform(-10, 10), rng.uniform(-10, 10), rng.uniform(-math.pi, math.pi)])
        control = np.array([rng.uniform(-3, 3), rng.uniform(-3, 3)])
        cases.append((pose, control, float(rng.uniform(0.01, 2.0))))
    # large omega * dt (several turns per step)
    for w, dt in ((10.0, 2.0), (-25.0, 1.0), (100.0, 0.5), (-1000.0, 1.0), (7.0, 3.0)):
        pose = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-math.pi, math.pi)])
        cases.append((pose, np.array([rng.uniform(-3, 3), w]), dt))
    # v = 0 (turning on the spot), v = w = 0, headings at the cut
    cases.append((np.array([1.0, 2.0, -math.pi]), np.array([0.0, 0.7]), 0.3))
    cases.append((np.array([1.0, 2.0, 3.1]), np.array([0.0, 0.0]), 0.3))
    cases.append((np.array([-4.0, 0.5, math.pi - 1e-9]), np.array([1.0, 1e-9]), 1.0))
    return cases


MOTION_CASES = _motion_cases()


def _case_id(case):
    pose, control, dt = case
    return f"th={pose[2]:.3g},v={control[0]:.3g},w={control[1]:.3g},dt={dt:.3g}"


motion_case = pytest.mark.parametrize("pose,control,dt", MOTION_CASES, ids=[_case_id(c) for c in MOTION_CASES])

MODERATE_CASES = [c for c in MOTION_CASES if 0.05 <= abs(c[1][1]) <= 5.0]
ZERO_OMEGA_CASES = [c for c in MOTION_CASES if c[1][1] == 0.0]


def _fd_tolerance(pose, control, dt):
    """Rounding bound of a central difference of g plus a (generous) truncation bound."""
    scale = max(1.0, float(np.max(np.abs(pose))), abs(control[0]) * dt, abs(control[1]) * dt)
    rounding = 20.0 * EPS * scale / H
    # third derivatives of g w.r.t. theta are <= |v| dt, w.r.t. omega <= |v| dt^4
    truncation = H * H * (abs(control[0]) * dt * (1.0 + dt**3))
    return 1e-9 + rounding + truncation


@pytest.fixture(scope="module")
def motion():
    return VelocityMotionModel(alphas=(0.01, 0.002, 0.003, 0.02, 0.001, 0.002), noise_floor=1e-9)


# ---------------------------------------------------------------------------
# wrap_angle
# ---------------------------------------------------------------------------
WRAP_VALUES = [
    0.0,
    -0.0,
    1.0,
    -1.0,
    math.pi,
    -math.pi,
    math.pi - 1e-12,
    -math.pi + 1e-12,
    math.pi + 1e-12,
    float(np.nextafter(math.pi, 0.0)),
    float(np.nextafter(math.pi, 4.0)),
    3 * math.pi,
    -3 * math.pi,
    7.5,
    -7.5,
    100.0,
    -1234.5678,
    1e6,
    -1e-300,
]


class TestWrapAngle:
    @pytest.mark.parametrize("value", WRAP_VALUES)
    def test_float_in_range_and_same_angle(self, value):
        out = wrap_angle(value)
        assert isinstance(out, float)
        assert in_half_open_pi_interval(out), out
        # same direction: the difference is a multiple of 2 pi
        turns = (value - out) / TWO_PI
        assert abs(turns - round(turns)) < 1e-9
        assert math.cos(out) == pytest.approx(math.cos(value), abs=1e-9)
        assert math.sin(out) == pytest.approx(math.sin(value), abs=1e-9)

    @pytest.mark.parametrize("value", WRAP_VALUES)
    def test_idempotent(self, value):
        once = wrap_angle(value)
        assert wrap_angle(once) == once

    def test_inside_interval_unchanged(self):
        values = np.linspace(-math.pi, math.pi, 1001, endpoint=False)
        np.testing.assert_allclose(wrap_angle(values), values, rtol=0, atol=4 * EPS)

    def test_pi_maps_to_minus_pi(self):
        assert wrap_angle(math.pi) == -math.pi
        assert wrap_angle(-math.pi) == -math.pi
        assert wrap_angle(3 * math.pi) == pytest.approx(-math.pi, abs=1e-15)
        np.testing.assert_array_equal(wrap_angle(np.array([math.pi, -math.pi])), [-math.pi, -math.pi])

    def test_array_in_range_shape_and_idempotent(self):
        rng = np.random.default_rng(1)
        values = np.concatenate(
            [rng.uniform(-100, 100, 5000), np.array(WRAP_VALUES), np.arange(-20, 21) * math.pi]
        ).reshape(-1, 4)[:1264]
        out = wrap_angle(values)
        assert isinstance(out, np.ndarray)
        assert out.shape == values.shape
        assert out.dtype == np.float64
        assert in_half_open_pi_interval(out)
        np.testing.assert_array_equal(wrap_angle(out), out)
        np.testing.assert_allclose(np.cos(out), np.cos(values), atol=1e-12)
        np.testing.assert_allclose(np.sin(out), np.sin(values), atol=1e-12)

    def test_array_matches_float_path(self):
        values = np.array(WRAP_VALUES)
        np.testing.assert_array_equal(wrap_angle(values), [wrap_angle(float(v)) for v in values])

    def test_list_input_gives_array(self):
        out = wrap_angle([0.0, 4.0, -4.0])
        assert isinstance(out, np.ndarray)
        np.testing.assert_allclose(out, [0.0, 4.0 - TWO_PI, -4.0 + TWO_PI], atol=1e-15)

    # (x + pi) % (2 pi) rounds up to 2 pi for the float just below -pi; wrap_angle folds it back
    @pytest.mark.parametrize("as_array", [False, True])
    def test_just_below_minus_pi(self, as_array):
        value = float(np.nextafter(-math.pi, -math.inf))
        out = wrap_angle(np.array([value]))[0] if as_array else wrap_angle(value)
        assert in_half_open_pi_interval(out), repr(out)


# ---------------------------------------------------------------------------
# VelocityMotionModel: Jacobians against finite differences
# ---------------------------------------------------------------------------
class TestMotionJacobians:
    @motion_case
    def test_jacobian_state_matches_fd_of_predict(self, motion, pose, control, dt):
        G = motion.jacobian_state(pose, control, dt)
        fd = central_difference(lambda p: motion.predict(p, control, dt), pose, angle_rows=(2,))
        assert G.shape == (3, 3)
        np.testing.assert_allclose(G, fd, rtol=0, atol=_fd_tolerance(pose, control, dt))

    @motion_case
    def test_jacobian_control_matches_fd_of_predict(self, motion, pose, control, dt):
        V = motion.jacobian_control(pose, control, dt)
        fd = central_difference(lambda u: motion.predict(pose, u, dt), control, angle_rows=(2,))
        assert V.shape == (3, 2)
        np.testing.assert_allclose(V, fd, rtol=0, atol=_fd_tolerance(pose, control, dt))

    @motion_case
    def test_jacobian_control_matches_fd_of_displacement(self, motion, pose, control, dt):
        V = motion.jacobian_control(pose, control, dt)
        fd = central_difference(lambda u: motion.displacement(pose, u, dt), control)
        np.testing.assert_allclose(V, fd, rtol=0, atol=_fd_tolerance(pose, control, dt))

    @motion_case
    def test_jacobian_state_matches_fd_of_displacement(self, motion, pose, control, dt):
        # d delta / d pose = Delta = G - I (delta is not wrapped)
        G = motion.jacobian_state(pose, control, dt)
        fd = central_difference(lambda p: motion.displacement(p, control, dt), pose)
        np.testing.assert_allclose(G - np.eye(3), fd, rtol=0, atol=_fd_tolerance(pose, control, dt))

    @motion_case
    def test_jacobian_state_structure(self, motion, pose, control, dt):
        G = motion.jacobian_state(pose, control, dt)
        dx, dy, _ = motion.displacement(pose, control, dt)
        expected = np.array([[1.0, 0.0, -dy], [0.0, 1.0, dx], [0.0, 0.0, 1.0]])
        np.testing.assert_allclose(G, expected, rtol=0, atol=1e-15)

    @pytest.mark.parametrize("pose,control,dt", MODERATE_CASES, ids=[_case_id(c) for c in MODERATE_CASES])
    def test_jacobian_state_equals_book_delta(self, motion, pose, control, dt):
        theta, (v, w) = pose[2], control
        r = v / w
        expected = np.eye(3)
        expected[0, 2] = -r * math.cos(theta) + r * math.cos(theta + w * dt)
        expected[1, 2] = -r * math.sin(theta) + r * math.sin(theta + w * dt)
        np.testing.assert_allclose(
            motion.jacobian_state(pose, control, dt), expected, rtol=0, atol=1e-12 * max(1, abs(r))
        )

    @pytest.mark.parametrize("pose,control,dt", ZERO_OMEGA_CASES, ids=[_case_id(c) for c in ZERO_OMEGA_CASES])
    def test_jacobians_at_zero_omega_are_the_limits(self, motion, pose, control, dt):
        theta, v = pose[2], control[0]
        G = motion.jacobian_state(pose, control, dt)
        np.testing.assert_allclose(G[:, 2], [-v * dt * math.sin(theta), v * dt * math.cos(theta), 1.0], atol=1e-15)
        V = motion.jacobian_control(pose, control, dt)
        # limit of eq. 7.11 at w = 0: dx/dw = -v dt^2 sin(theta) / 2, dy/dw = v dt^2 cos(theta) / 2
        expected = np.array(
            [
                [dt * math.cos(theta), -0.5 * v * dt * dt * math.sin(theta)],
                [dt * math.sin(theta), 0.5 * v * dt * dt * math.cos(theta)],
                [0.0, dt],
            ]
        )
        np.testing.assert_allclose(V, expected, rtol=0, atol=1e-14)

    @pytest.mark.parametrize("sign", [1.0, -1.0])
    @pytest.mark.parametrize("v", [2.3, -0.4])
    def test_continuous_across_sinc_switch(self, motion, sign, v):
        """The series (|w dt/2| < 1e-4) and closed forms of sinc agree where they meet.

        w is put 1e-12 (relative) on either side of |w dt / 2| = 1e-4, so the true
        change of V and delta is ~1e-16. The closed form of d sinc / da loses
        ~eps / a = 2e-12 to cancellation at a = 1e-4, which enters V[:, 1] times
        |v| dt^2 / 2: that is the tolerance on V.
        """
        pose, dt = np.array([0.2, 0.1, 0.7]), 0.8
        w0 = sign * 2e-4 / dt
        lo, hi = [v, w0 * (1 - 1e-12)], [v, w0 * (1 + 1e-12)]
        tol_v = 1e-15 + 4 * EPS / 1e-4 * abs(v) * dt * dt / 2
        np.testing.assert_allclose(
            motion.jacobian_control(pose, lo, dt), motion.jacobian_control(pose, hi, dt), rtol=0, atol=tol_v
        )
        np.testing.assert_allclose(
            motion.displacement(pose, lo, dt), motion.displacement(pose, hi, dt), rtol=0, atol=1e-15
        )


# ---------------------------------------------------------------------------
# VelocityMotionModel: displacement and predict
# ---------------------------------------------------------------------------
class TestMotionDisplacement:
    @pytest.mark.parametrize("pose,control,dt", MODERATE_CASES, ids=[_case_id(c) for c in MODERATE_CASES])
    def test_matches_book_form(self, motion, pose, control, dt):
        got = motion.displacement(pose, control, dt)
        expected = book_displacement(pose[2], control[0], control[1], dt)
        # the book form loses ~eps * |v / w| to cancellation
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12 * max(1.0, abs(control[0] / control[1])))

    @pytest.mark.parametrize("theta", [0.0, 0.4, -1.3, math.pi / 2, -math.pi, 3.0])
    @pytest.mark.parametrize("v", [0.0, 1.0, -2.5])
    @pytest.mark.parametrize("dt", [0.01, 1.0])
    def test_straight_line_at_zero_omega(self, motion, theta, v, dt):
        for w in (0.0, -0.0):
            got = motion.displacement([3.0, -1.0, theta], [v, w], dt)
            np.testing.assert_allclose(
                got, [v * dt * math.cos(theta), v * dt * math.sin(theta), 0.0], rtol=1e-15, atol=1e-300
            )

    @pytest.mark.parametrize("w", [1e-9, -1e-9, 1e-6, -1e-6, 1e-3, -1e-3])
    @pytest.mark.parametrize("theta", [0.0, 1.1, -2.7])
    def test_small_omega_matches_taylor_expansion(self, motion, w, theta):
        """delta = straight line + first-order arc term + O(w^2 dt^3 v)."""
        v, dt = 1.7, 0.9
        got = motion.displacement([0.0, 0.0, theta], [v, w], dt)
        first_order = np.array(
            [
                v * dt * math.cos(theta) - 0.5 * v * w * dt * dt * math.sin(theta),
                v * dt * math.sin(theta) + 0.5 * v * w * dt * dt * math.cos(theta),
                w * dt,
            ]
        )
        np.testing.assert_allclose(got, first_order, rtol=0, atol=abs(v) * (w * dt) ** 2 * dt + 4 * EPS)
        # and it is strictly better than the straight line when the arc term is resolvable
        if abs(w) >= 1e-6:
            straight = np.array([v * dt * math.cos(theta), v * dt * math.sin(theta), w * dt])
            arc = 0.5 * abs(v * w) * dt * dt
            assert np.max(np.abs(got - straight)) == pytest.approx(
                arc * max(abs(math.sin(theta)), abs(math.cos(theta))), rel=1e-2
            )

    @motion_case
    def test_predict_is_pose_plus_displacement_wrapped(self, motion, pose, control, dt):
        delta = motion.displacement(pose, control, dt)
        pred = motion.predict(pose, control, dt)
        assert pred.shape == (3,)
        assert in_half_open_pi_interval(pred[2])
        np.testing.assert_allclose(pred[:2], pose[:2] + delta[:2], rtol=0, atol=1e-15 * max(1, np.max(np.abs(pose))))
        assert abs(angle_diff(pred[2], pose[2] + delta[2])) <= 8 * EPS * max(1.0, abs(delta[2]))
        # delta's angle is w dt, never wrapped
        assert delta[2] == control[1] * dt

    @pytest.mark.parametrize(
        "theta,w,dt",
        [
            (3.0, 1.0, 0.5),
            (-3.0, -1.0, 0.5),
            (math.pi - 1e-9, 1e-6, 1.0),
            (0.0, math.pi, 1.0),
            (0.1, 20.0, 1.0),
            (-math.pi, -1e-9, 1.0),
        ],
    )
    def test_predict_wraps_heading(self, motion, theta, w, dt):
        pred = motion.predict([0.0, 0.0, theta], [1.0, w], dt)
        assert in_half_open_pi_interval(pred[2]), pred[2]
        assert abs(angle_diff(pred[2], theta + w * dt)) < 1e-12

    def test_predict_does_not_mutate_inputs(self, motion):
        pose, control = np.array([1.0, 2.0, 3.0]), np.array([1.0, 2.0])
        motion.predict(pose, control, 1.0)
        motion.linearize(pose, control, 1.0)
        motion.sample(pose, control, 1.0, np.random.default_rng(0))
        np.testing.assert_array_equal(pose, [1.0, 2.0, 3.0])
        np.testing.assert_array_equal(control, [1.0, 2.0])

    def test_accepts_lists_and_ints(self, motion):
        np.testing.assert_array_equal(motion.predict([0, 0, 0], [1, 0], 2), [2.0, 0.0, 0.0])


# ---------------------------------------------------------------------------
# VelocityMotionModel: linearize / noise
# ---------------------------------------------------------------------------
class TestMotionLinearize:
    @motion_case
    def test_consistent_with_displacement_and_jacobian(self, motion, pose, control, dt):
        delta, G, R = motion.linearize(pose, control, dt)
        np.testing.assert_allclose(delta, motion.displacement(pose, control, dt), rtol=0, atol=0)
        np.testing.assert_allclose(G, motion.jacobian_state(pose, control, dt), rtol=0, atol=0)
        np.testing.assert_array_equal(R, motion.noise_covariance(pose, control, dt))

    @motion_case
    def test_noise_formula(self, motion, pose, control, dt):
        _, _, R = motion.linearize(pose, control, dt)
        v, w = control
        a1, a2, a3, a4, a5, a6 = motion.alphas
        M = np.diag([a1 * v * v + a2 * w * w, a3 * v * v + a4 * w * w])
        np.testing.assert_allclose(motion.control_covariance(control), M, rtol=1e-15, atol=0)
        V = motion.jacobian_control(pose, control, dt)
        expected = (
            V @ M @ V.T + np.diag([0.0, 0.0, (a5 * v * v + a6 * w * w) * dt * dt]) + motion.noise_floor * np.eye(3)
        )
        np.testing.assert_allclose(R, expected, rtol=1e-12, atol=1e-15 * np.max(np.abs(expected)))

    @motion_case
    def test_noise_symmetric_positive_definite(self, motion, pose, control, dt):
        _, _, R = motion.linearize(pose, control, dt)
        assert R.shape == (3, 3)
        assert np.all(np.isfinite(R))
        np.testing.assert_allclose(R, R.T, rtol=0, atol=4 * EPS * np.max(np.abs(R)))
        np.linalg.cholesky(0.5 * (R + R.T))
        # R - floor I is positive semi-definite, so every eigenvalue is >= floor
        eig = np.linalg.eigvalsh(0.5 * (R + R.T))
        assert eig.min() >= motion.noise_floor - 8 * EPS * np.max(np.abs(R))

    @pytest.mark.parametrize("floor", [1e-12, 1e-9, 1e-3])
    @pytest.mark.parametrize("theta", [0.0, -math.pi, 2.0])
    def test_standing_still(self, floor, theta):
        model = VelocityMotionModel(alphas=(0.1, 0.2, 0.3, 0.4, 0.5, 0.6), noise_floor=floor)
        pose = [1.0, -2.0, theta]
        delta, G, R = model.linearize(pose, [0.0, 0.0], 0.5)
        np.testing.assert_array_equal(delta, [0.0, 0.0, 0.0])
        np.testing.assert_array_equal(G, np.eye(3))
        np.testing.assert_allclose(R, floor * np.eye(3), rtol=1e-15, atol=0)
        np.linalg.cholesky(R)
        # sampling at rest does not move the robot (all control variances vanish)
        np.testing.assert_array_equal(
            model.sample(pose, [0.0, 0.0], 0.5, np.random.default_rng(3)), model.predict(pose, [0.0, 0.0], 0.5)
        )

    def test_zero_alphas_gives_floor_only(self):
        model = VelocityMotionModel(alphas=(0.0,) * 6, noise_floor=1e-6)
        _, _, R = model.linearize([0.0, 0.0, 0.3], [2.0, -1.0], 0.7)
        np.testing.assert_allclose(R, 1e-6 * np.eye(3), rtol=1e-15, atol=0)

    @pytest.mark.parametrize("k", range(6))
    def test_each_alpha_enters_where_it_should(self, k):
        """Switch on one alpha at a time; compare with the hand-written contribution."""
        alphas = [0.0] * 6
        alphas[k] = 0.3
        model = VelocityMotionModel(alphas=tuple(alphas), noise_floor=1e-12)
        pose, control, dt = np.array([0.0, 0.0, 0.5]), np.array([1.5, -0.8]), 0.4
        v, w = control
        _, _, R = model.linearize(pose, control, dt)
        V = model.jacobian_control(pose, control, dt)
        var = 0.3 * (v * v if k % 2 == 0 else w * w)
        if k < 2:
            expected = var * np.outer(V[:, 0], V[:, 0])
        elif k < 4:
            expected = var * np.outer(V[:, 1], V[:, 1])
        else:
            expected = np.diag([0.0, 0.0, var * dt * dt])
        np.testing.assert_allclose(R - 1e-12 * np.eye(3), expected, rtol=1e-12, atol=1e-15)


# ---------------------------------------------------------------------------
# VelocityMotionModel: sampling
# ---------------------------------------------------------------------------
class TestMotionSample:
    @motion_case
    def test_zero_alphas_equals_predict(self, pose, control, dt):
        model = VelocityMotionModel(alphas=(0.0,) * 6)
        got = model.sample(pose, control, dt, np.random.default_rng(0))
        np.testing.assert_allclose(got, model.predict(pose, control, dt), rtol=0, atol=0)

    @motion_case
    def test_reproducible_per_seed(self, motion, pose, control, dt):
        a = motion.sample(pose, control, dt, np.random.default_rng(42))
        b = motion.sample(pose, control, dt, np.random.default_rng(42))
        np.testing.assert_array_equal(a, b)
        assert in_half_open_pi_interval(a[2])
        if abs(control[0]) > 0.1:  # the noise is large enough to tell seeds apart
            c = motion.sample(pose, control, dt, np.random.default_rng(43))
            assert not np.array_equal(a, c)

    @pytest.mark.parametrize(
        "pose,control",
        [
            (np.array([1.0, -2.0, 0.3]), np.array([1.0, 0.5])),
            (np.array([0.0, 0.0, math.pi - 0.01]), np.array([0.8, 0.3])),  # heading crosses the cut
            (np.array([5.0, 5.0, -1.2]), np.array([-0.6, 0.0])),  # straight line, backwards
        ],
    )
    def test_empirical_covariance_matches_noise_covariance(self, pose, control):
        """Over a short arc with small noise, the linearised R is the sample covariance.

        Sampling error: with N = 20000 draws a whitened covariance entry has
        standard error <= sqrt(2 / N) = 1 %.

        Linearisation error: R = V M V^T is first order. The weakest direction
        of R is the sideways displacement not explained by the heading change,
        y_perp - (v dt / 2) theta = -(v dt^2 / 2) gamma, of variance
        (v dt^2 / 2)^2 s_g^2. The largest neglected term there is the
        second-order (dt^2 / 2) dv dw, of variance (dt^2 / 2)^2 s_v^2 s_w^2: a
        relative bias s_v^2 s_w^2 / (v^2 s_g^2) independent of dt. With the
        alphas below it is < 0.1 % (it would be ~4 % with a1 = 0.01, a5 = 0.001),
        and 500 000 draws over 5 seeds confirm a bias < 0.4 % on every whitened
        entry. A tolerance of 5 % (~5 standard errors) is therefore honest.
        """
        model = VelocityMotionModel(alphas=(0.002, 0.001, 0.001, 0.005, 0.005, 0.005), noise_floor=1e-15)
        s_v2, s_w2, s_g2 = (
            0.002 * control[0] ** 2 + 0.001 * control[1] ** 2,
            0.001 * control[0] ** 2 + 0.005 * control[1] ** 2,
            0.005 * control[0] ** 2 + 0.005 * control[1] ** 2,
        )
        assert s_v2 * s_w2 / (control[0] ** 2 * s_g2) < 1e-3  # the premise above
        dt, n = 0.1, 20000
        rng = np.random.default_rng(2024)
        draws = np.array([model.sample(pose, control, dt, rng) for _ in range(n)])
        pred = model.predict(pose, control, dt)
        err = draws - pred
        err[:, 2] = wrap_angle(err[:, 2])
        R = model.noise_covariance(pose, control, dt)
        # mean of the error: zero to first order
        std = np.sqrt(np.diag(R))
        assert np.all(np.abs(err.mean(axis=0)) <= 5 * std / math.sqrt(n) + 1e-3 * std)
        S = np.cov(err.T)
        # variances within 5 %
        np.testing.assert_allclose(np.diag(S), np.diag(R), rtol=0.05)
        # whitened covariance close to the identity
        L = np.linalg.cholesky(R)
        Linv = np.linalg.inv(L)
        W = Linv @ S @ Linv.T
        np.testing.assert_allclose(W, np.eye(3), rtol=0, atol=0.05)


# ---------------------------------------------------------------------------
# VelocityMotionModel: input validation
# ---------------------------------------------------------------------------
GOOD_POSE, GOOD_CONTROL, GOOD_DT = np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.1]), 0.1
METHODS = ["predict", "displacement", "jacobian_state", "jacobian_control", "linearize", "noise_covariance", "sample"]


def _call(model, method, pose=GOOD_POSE, control=GOOD_CONTROL, dt=GOOD_DT, rng=None):
    if method == "sample":
        return model.sample(pose, control, dt, np.random.default_rng(0) if rng is None else rng)
    return getattr(model, method)(pose, control, dt)


BAD_CONTROLS = [
    ([math.nan, 0.0], ValueError),
    ([0.0, math.nan], ValueError),
    ([math.inf, 0.0], ValueError),
    ([1.0, -math.inf], ValueError),
    ([1.0, 2.0, 3.0], ValueError),
    ([1.0], ValueError),
    ([[1.0, 2.0]], ValueError),
    (1.0, ValueError),
    ("ab", TypeError),
    (None, TypeError),
    ([1.0, "x"], TypeError),
]
BAD_POSES = [
    ([0.0, 0.0], ValueError),
    ([0.0, 0.0, 0.0, 0.0], ValueError),
    ([0.0, math.nan, 0.0], ValueError),
    ([0.0, 0.0, math.inf], ValueError),
    (None, TypeError),
]
BAD_DTS = [
    (0.0, ValueError),
    (-0.0, ValueError),
    (-0.1, ValueError),
    (math.nan, ValueError),
    (math.inf, ValueError),
    (-math.inf, ValueError),
    ("0.1", TypeError),
    (None, TypeError),
    (True, TypeError),
    (np.array([0.1]), TypeError),
]


class TestMotionValidation:
    @pytest.mark.parametrize("method", METHODS)
    @pytest.mark.parametrize("control,error", BAD_CONTROLS, ids=[repr(c) for c, _ in BAD_CONTROLS])
    def test_bad_control(self, motion, method, control, error):
        with pytest.raises(error, match=r"\bcontrol\b"):
            _call(motion, method, control=control)

    @pytest.mark.parametrize("control,error", BAD_CONTROLS, ids=[repr(c) for c, _ in BAD_CONTROLS])
    def test_bad_control_validate_and_covariance(self, motion, control, error):
        with pytest.raises(error, match=r"\bcontrol\b"):
            motion.validate_control(control)
        with pytest.raises(error, match=r"\bcontrol\b"):
            motion.control_covariance(control)

    @pytest.mark.parametrize("method", METHODS)
    @pytest.mark.parametrize("pose,error", BAD_POSES, ids=[repr(p) for p, _ in BAD_POSES])
    def test_bad_pose(self, motion, method, pose, error):
        with pytest.raises(error, match=r"\bpose\b"):
            _call(motion, method, pose=pose)

    @pytest.mark.parametrize("method", METHODS)
    @pytest.mark.parametrize("dt,error", BAD_DTS, ids=[repr(d) for d, _ in BAD_DTS])
    def test_bad_dt(self, motion, method, dt, error):
        with pytest.raises(error, match=r"\bdt\b"):
            _call(motion, method, dt=dt)

    @pytest.mark.parametrize("rng", [None, 0, np.random.RandomState(0), "seed", np.random.default_rng(0).bit_generator])
    def test_bad_rng(self, motion, rng):
        with pytest.raises(TypeError, match=r"\brng\b"):
            motion.sample(GOOD_POSE, GOOD_CONTROL, GOOD_DT, rng)

    def test_validate_control_returns_float_array(self, motion):
        out = motion.validate_control([1, 2])
        assert out.dtype == np.float64 and out.shape == (2,)
        np.testing.assert_array_equal(out, [1.0, 2.0])

    @pytest.mark.parametrize(
        "alphas,error",
        [
            ((-0.01, 0, 0, 0, 0, 0), ValueError),
            ((0, 0, 0, 0, 0, -1e-12), ValueError),
            ((0.1,) * 5, ValueError),
            ((0.1,) * 7, ValueError),
            ((), ValueError),
            ((0, 0, math.nan, 0, 0, 0), ValueError),
            ((0, 0, 0, math.inf, 0, 0), ValueError),
            ("abcdef", TypeError),
            (None, TypeError),
        ],
    )
    def test_bad_alphas(self, alphas, error):
        with pytest.raises(error, match=r"\balphas\b"):
            VelocityMotionModel(alphas=alphas)

    @pytest.mark.parametrize(
        "floor,error",
        [(0.0, ValueError), (-1e-9, ValueError), (math.nan, ValueError), (math.inf, ValueError), ("1e-9", TypeError)],
    )
    def test_bad_noise_floor(self, floor, error):
        with pytest.raises(error, match=r"\bnoise_floor\b"):
            VelocityMotionModel(noise_floor=floor)

    def test_valid_constructor_stores_floats(self):
        model = VelocityMotionModel(alphas=[0, 1, 2, 3, 4, 5], noise_floor=2)
        assert model.alphas == (0.0, 1.0, 2.0, 3.0, 4.0, 5.0)
        assert all(type(a) is float for a in model.alphas)
        assert model.noise_floor == 2.0


# ---------------------------------------------------------------------------
# RangeBearingSensor
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def sensor():
    return RangeBearingSensor(sigma_range=0.1, sigma_bearing=math.radians(2.0), max_range=8.0, fov=TWO_PI)


def _landmark_at(pose, r, bearing):
    pose = np.asarray(pose, dtype=np.float64)
    return np.array([pose[0] + r * math.cos(pose[2] + bearing), pose[1] + r * math.sin(pose[2] + bearing)])


def _sensor_cases():
    rng = np.random.default_rng(777)
    cases = []
    for _ in range(25):
        pose = np.array([rng.uniform(-10, 10), rng.uniform(-10, 10), rng.uniform(-math.pi, math.pi)])
        cases.append((pose, _landmark_at(pose, rng.uniform(0.5, 10.0), rng.uniform(-math.pi, math.pi))))
    # bearings at the cut: landmark just behind the robot, on either side
    for theta in (0.0, 1.0, -2.5, math.pi - 1e-9, -math.pi):
        for bearing in (math.pi - 1e-7, -math.pi + 1e-7, math.pi - 1e-12, -math.pi, 0.0, math.pi / 2):
            pose = np.array([1.5, -0.5, theta])
            cases.append((pose, _landmark_at(pose, 3.0, bearing)))
    return cases


SENSOR_CASES = _sensor_cases()
sensor_case = pytest.mark.parametrize(
    "pose,landmark", SENSOR_CASES, ids=[f"th={p[2]:.4g},m=({m[0]:.4g},{m[1]:.4g})" for p, m in SENSOR_CASES]
)


def _sensor_fd_tol(pose, landmark):
    r = float(np.hypot(*(landmark - pose[:2])))
    scale = max(1.0, float(np.max(np.abs(pose))), float(np.max(np.abs(landmark))))
    return 1e-9 + 20.0 * EPS * scale / (H * min(1.0, r)) + H * H / r**3


class TestSensorPredictJacobian:
    @sensor_case
    def test_predict_formula(self, sensor, pose, landmark):
        z = sensor.predict(pose, landmark)
        assert z.shape == (1, 2)
        d = landmark - pose[:2]
        assert z[0, 0] == pytest.approx(math.hypot(*d), rel=1e-15)
        assert in_half_open_pi_interval(z[:, 1])
        assert abs(angle_diff(z[0, 1], math.atan2(d[1], d[0]) - pose[2])) < 1e-15 * 8

    def test_predict_many(self, sensor):
        pose = np.array([1.0, 2.0, 0.5])
        lms = np.array([[2.0, 2.0], [1.0, 5.0], [-3.0, 2.0], [1.0, -1.0]])
        z = sensor.predict(pose, lms)
        assert z.shape == (4, 2)
        np.testing.assert_allclose(z[:, 0], [1.0, 3.0, 4.0, 3.0], rtol=1e-15)
        np.testing.assert_allclose(
            z[:, 1], wrap_angle(np.array([0.0, math.pi / 2, math.pi, -math.pi / 2]) - 0.5), atol=1e-15
        )

    def test_directly_behind_is_minus_pi(self, sensor):
        z = sensor.predict([0.0, 0.0, 0.0], [[-2.0, 0.0]])
        assert z[0, 1] == -math.pi

    @sensor_case
    def test_jacobian_matches_fd(self, sensor, pose, landmark):
        Hj = sensor.jacobian(pose, landmark)
        assert Hj.shape == (1, 2, 5)
        x = np.concatenate([pose, landmark])
        fd = central_difference(lambda y: sensor.predict(y[:3], y[3:])[0], x, angle_rows=(1,))
        np.testing.assert_allclose(Hj[0], fd, rtol=0, atol=_sensor_fd_tol(pose, landmark))

    @sensor_case
    def test_jacobian_matches_seif_md_formula(self, sensor, pose, landmark):
        d = landmark - pose[:2]
        q = d @ d
        sq = math.sqrt(q)
        expected = (
            np.array(
                [
                    [-sq * d[0], -sq * d[1], 0.0, sq * d[0], sq * d[1]],
                    [d[1], -d[0], -q, -d[1], d[0]],
                ]
            )
            / q
        )
        np.testing.assert_allclose(sensor.jacobian(pose, landmark)[0], expected, rtol=1e-13, atol=1e-15)

    def test_jacobian_many_landmarks_stacks(self, sensor):
        pose = np.array([0.5, -1.0, 2.0])
        lms = np.array([m for p, m in SENSOR_CASES[:10]])
        Hs = sensor.jacobian(pose, lms)
        assert Hs.shape == (10, 2, 5)
        for i, m in enumerate(lms):
            np.testing.assert_array_equal(Hs[i], sensor.jacobian(pose, m)[0])

    def test_jacobian_refuses_coincident_landmark(self, sensor):
        with pytest.raises(ValueError, match=r"\blandmarks\b"):
            sensor.jacobian([1.0, 2.0, 0.3], [[5.0, 5.0], [1.0, 2.0]])


class TestSensorInverse:
    @sensor_case
    def test_inverse_recovers_landmark(self, sensor, pose, landmark):
        z = sensor.predict(pose, landmark)
        m = sensor.inverse(pose, *z.T)
        assert m.shape == (1, 2)
        np.testing.assert_allclose(m[0], landmark, rtol=0, atol=1e-13 * max(1.0, np.max(np.abs(landmark))))

    def test_inverse_then_predict_round_trip(self, sensor):
        pose = np.array([-2.0, 3.0, -2.9])
        ranges = np.array([0.5, 2.0, 7.5, 3.3])
        bearings = np.array([0.0, math.pi - 1e-7, -math.pi + 1e-7, 1.2])
        z = sensor.predict(pose, sensor.inverse(pose, ranges, bearings))
        np.testing.assert_allclose(z[:, 0], ranges, rtol=1e-13)
        np.testing.assert_allclose(angle_diff(z[:, 1], bearings), 0.0, atol=1e-13)

    def test_inverse_scalar_inputs(self, sensor):
        m = sensor.inverse([1.0, 1.0, math.pi / 2], 2.0, 0.0)
        np.testing.assert_allclose(m, [[1.0, 3.0]], atol=1e-15)

    @sensor_case
    def test_inverse_jacobians_match_fd(self, sensor, pose, landmark):
        r, phi = sensor.predict(pose, landmark)[0]
        Gx, Gz = sensor.inverse_jacobians(pose, r, phi)
        assert Gx.shape == (1, 2, 3) and Gz.shape == (1, 2, 2)
        tol = 1e-9 + 20.0 * EPS * max(1.0, np.max(np.abs(pose)), r) / H + H * H * r
        fd_pose = central_difference(lambda p: sensor.inverse(p, r, phi)[0], pose)
        fd_meas = central_difference(lambda z: sensor.inverse(pose, z[0], z[1])[0], np.array([r, phi]))
        np.testing.assert_allclose(Gx[0], fd_pose, rtol=0, atol=tol)
        np.testing.assert_allclose(Gz[0], fd_meas, rtol=0, atol=tol)

    @sensor_case
    def test_inverse_jacobians_are_inverse_of_H(self, sensor, pose, landmark):
        z = sensor.predict(pose, landmark)
        Gx, Gz = sensor.inverse_jacobians(pose, *z.T)
        Hj = sensor.jacobian(pose, landmark)[0]
        Hx, Hm = Hj[:, :3], Hj[:, 3:]
        Hm_inv = np.linalg.inv(Hm)
        scale = max(1.0, z[0, 0])
        np.testing.assert_allclose(Gz[0], Hm_inv, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(Gx[0], -Hm_inv @ Hx, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(Gz[0] @ Hm, np.eye(2), rtol=0, atol=1e-12 * scale)

    def test_inverse_length_mismatch(self, sensor):
        with pytest.raises(ValueError, match=r"\bbearings\b"):
            sensor.inverse([0.0, 0.0, 0.0], [1.0, 2.0], [0.1])
        with pytest.raises(ValueError, match=r"\bbearings\b"):
            sensor.inverse_jacobians([0.0, 0.0, 0.0], [1.0, 2.0], [0.1, 0.2, 0.3])

    @pytest.mark.parametrize("method", ["inverse", "inverse_jacobians"])
    def test_inverse_non_finite(self, sensor, method):
        with pytest.raises(ValueError, match=r"\branges\b"):
            getattr(sensor, method)([0.0, 0.0, 0.0], [math.nan], [0.1])
        with pytest.raises(ValueError, match=r"\bbearings\b"):
            getattr(sensor, method)([0.0, 0.0, 0.0], [1.0], [math.inf])
        with pytest.raises(ValueError, match=r"\bpose\b"):
            getattr(sensor, method)([0.0, 0.0], [1.0], [0.1])


class TestSensorVisible:
    @pytest.mark.parametrize("theta", [0.0, 1.0, -2.0, 3.0, -math.pi])
    @pytest.mark.parametrize("fov", [math.radians(90.0), math.radians(180.0), 1.0, TWO_PI - 0.2])
    def test_fov_boundary(self, theta, fov):
        sensor = RangeBearingSensor(max_range=10.0, fov=fov)
        pose = np.array([2.0, -1.0, theta])
        half = 0.5 * fov
        lms = np.array(
            [
                _landmark_at(pose, 4.0, half - 1e-7),
                _landmark_at(pose, 4.0, -half + 1e-7),
                _landmark_at(pose, 4.0, half + 1e-7),
                _landmark_at(pose, 4.0, -half - 1e-7),
                _landmark_at(pose, 4.0, 0.0),
                _landmark_at(pose, 4.0, math.pi - 0.05),  # behind: outside every fov here
                _landmark_at(pose, 4.0, -math.pi + 0.05),
            ]
        )
        mask = sensor.visible(pose, lms)
        assert mask.dtype == np.bool_ and mask.shape == (7,)
        np.testing.assert_array_equal(mask, [True, True, False, False, True, False, False])

    def test_full_fov_sees_all_around(self):
        sensor = RangeBearingSensor(max_range=10.0, fov=TWO_PI)
        pose = np.array([0.0, 0.0, 2.0])
        bearings = np.linspace(-math.pi, math.pi, 37)
        lms = np.array([_landmark_at(pose, 5.0, b) for b in bearings])
        assert sensor.visible(pose, lms).all()

    @pytest.mark.parametrize("max_range", [0.5, 8.0, 100.0])
    def test_max_range_boundary(self, max_range):
        sensor = RangeBearingSensor(max_range=max_range, fov=TWO_PI)
        pose = np.array([0.0, 0.0, 0.0])
        lms = np.array(
            [
                [max_range, 0.0],  # exactly at the range: seen (<=)
                [0.0, -max_range * (1 - 1e-9)],
                [-max_range * (1 + 1e-9), 0.0],
                [0.0, max_range * 1.5],
            ]
        )
        np.testing.assert_array_equal(sensor.visible(pose, lms), [True, True, False, False])

    def test_coincident_landmark_not_visible(self, sensor):
        np.testing.assert_array_equal(sensor.visible([1.0, 1.0, 0.0], [[1.0, 1.0], [2.0, 1.0]]), [False, True])

    def test_range_and_fov_combined(self):
        sensor = RangeBearingSensor(max_range=5.0, fov=math.radians(120.0))
        pose = np.array([0.0, 0.0, math.pi / 2])
        lms = np.array([[0.0, 4.0], [0.0, 6.0], [0.0, -4.0], [4.0, 0.0], [2.0, 3.0]])
        # [ahead in range, ahead too far, behind, 90 deg right (outside 60), ~33.7 deg right]
        np.testing.assert_array_equal(sensor.visible(pose, lms), [True, False, False, False, True])


class TestSensorSample:
    @staticmethod
    def _scene():
        pose = np.array([1.0, -2.0, 2.8])
        rng = np.random.default_rng(5)
        n = 40
        lms = np.column_stack([rng.uniform(-12, 14, n), rng.uniform(-15, 11, n)])
        return pose, lms

    @pytest.mark.parametrize("fov", [TWO_PI, math.radians(100.0)])
    def test_returns_only_visible_with_ids(self, fov):
        sensor = RangeBearingSensor(max_range=8.0, fov=fov)
        pose, lms = self._scene()
        mask = sensor.visible(pose, lms)
        assert 0 < mask.sum() < len(lms)
        ranges, bearings, ids = sensor.sample(pose, lms, np.random.default_rng(0))
        assert ids.dtype == np.int64
        np.testing.assert_array_equal(ids, np.flatnonzero(mask))
        assert ranges.shape == bearings.shape == ids.shape
        assert np.all(ranges >= 0.0)
        assert in_half_open_pi_interval(bearings)
        # noisy values are near the true ones (within 6 sigma)
        z = sensor.predict(pose, lms[mask])
        assert np.all(np.abs(ranges - z[:, 0]) < 6 * sensor.sigma_range)
        assert np.all(np.abs(angle_diff(bearings, z[:, 1])) < 6 * sensor.sigma_bearing)
        # custom ids follow the same mask
        custom = np.arange(len(lms), dtype=np.int32) * 10 + 7
        _, _, got = sensor.sample(pose, lms, np.random.default_rng(0), ids=custom)
        np.testing.assert_array_equal(got, custom[mask])
        assert got.dtype == np.int64

    def test_reproducible_per_seed(self, sensor):
        pose, lms = self._scene()
        a = sensor.sample(pose, lms, np.random.default_rng(11))
        b = sensor.sample(pose, lms, np.random.default_rng(11))
        c = sensor.sample(pose, lms, np.random.default_rng(12))
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(a[2], c[2])
        assert not np.array_equal(a[0], c[0])

    def test_nothing_visible(self, sensor):
        r, b, ids = sensor.sample([0.0, 0.0, 0.0], [[100.0, 0.0]], np.random.default_rng(0))
        assert r.shape == b.shape == ids.shape == (0,)

    def test_ranges_reflected_positive(self):
        sensor = RangeBearingSensor(sigma_range=1.0, sigma_bearing=0.1, max_range=5.0)
        lms = np.tile([[0.05, 0.0]], (2000, 1))
        r, _, _ = sensor.sample([0.0, 0.0, 0.0], lms, np.random.default_rng(1))
        assert len(r) == 2000 and np.all(r >= 0.0)

    @pytest.mark.parametrize("sigma_range,sigma_bearing", [(0.1, math.radians(2.0)), (0.5, 0.3), (0.02, 1e-3)])
    def test_empirical_noise_std(self, sigma_range, sigma_bearing):
        """N = 20000 independent draws: the sample std has relative error sqrt(1/(2N)) = 0.5 %.

        Tolerance 3 % (6 standard errors) on the std, 5 sigma / sqrt(N) on the mean,
        0.04 (5.7 standard errors) on the range-bearing correlation. Half the
        landmarks are just behind the robot, so the bearing noise crosses the cut.
        """
        sensor = RangeBearingSensor(sigma_range=sigma_range, sigma_bearing=sigma_bearing, max_range=100.0)
        n = 20000
        rng = np.random.default_rng(99)
        pose = np.array([0.5, 0.5, -1.0])
        bearing = np.where(np.arange(n) % 2 == 0, rng.uniform(-1, 1, n), math.pi - rng.uniform(-0.01, 0.01, n))
        r = rng.uniform(10.0, 50.0, n)
        lms = np.column_stack([pose[0] + r * np.cos(pose[2] + bearing), pose[1] + r * np.sin(pose[2] + bearing)])
        ranges, bearings, ids = sensor.sample(pose, lms, np.random.default_rng(123))
        assert len(ids) == n
        z = sensor.predict(pose, lms)
        er = ranges - z[:, 0]
        eb = angle_diff(bearings, z[:, 1])
        assert abs(er.mean()) < 5 * sigma_range / math.sqrt(n)
        assert abs(eb.mean()) < 5 * sigma_bearing / math.sqrt(n)
        assert er.std(ddof=1) == pytest.approx(sigma_range, rel=0.03)
        assert eb.std(ddof=1) == pytest.approx(sigma_bearing, rel=0.03)
        assert abs(np.corrcoef(er, eb)[0, 1]) < 0.04
        np.testing.assert_array_equal(sensor.noise_covariance, np.diag([sigma_range**2, sigma_bearing**2]))

    @pytest.mark.parametrize("rng", [None, 1, np.random.RandomState(0), "rng"])
    def test_bad_rng(self, sensor, rng):
        with pytest.raises(TypeError, match=r"\brng\b"):
            sensor.sample([0.0, 0.0, 0.0], [[1.0, 0.0]], rng)

    @pytest.mark.parametrize("ids", [[1], [1, 2, 3], [1.0, 2.0], [[1, 2]]])
    def test_bad_ids(self, sensor, ids):
        with pytest.raises(ValueError, match=r"\bids\b"):
            sensor.sample([0.0, 0.0, 0.0], [[1.0, 0.0], [2.0, 0.0]], np.random.default_rng(0), ids=ids)


class TestSensorValidation:
    @pytest.mark.parametrize("name", ["sigma_range", "sigma_bearing", "max_range", "fov"])
    @pytest.mark.parametrize(
        "value,error",
        [
            (0.0, ValueError),
            (-0.1, ValueError),
            (math.nan, ValueError),
            (math.inf, ValueError),
            ("1", TypeError),
            (None, TypeError),
            (True, TypeError),
        ],
    )
    def test_bad_constructor_argument(self, name, value, error):
        with pytest.raises(error, match=rf"\b{name}\b"):
            RangeBearingSensor(**{name: value})

    @pytest.mark.parametrize("fov", [TWO_PI + 1e-9, 7.0, 100.0])
    def test_fov_above_two_pi(self, fov):
        with pytest.raises(ValueError, match=r"\bfov\b"):
            RangeBearingSensor(fov=fov)

    def test_fov_two_pi_allowed_and_attributes(self):
        s = RangeBearingSensor(sigma_range=0.2, sigma_bearing=0.05, max_range=3, fov=TWO_PI)
        assert (s.sigma_range, s.sigma_bearing, s.max_range, s.fov) == (0.2, 0.05, 3.0, TWO_PI)
        np.testing.assert_array_equal(s.noise_covariance, np.diag([0.2**2, 0.05**2]))
        with pytest.raises(ValueError):
            s.noise_covariance[0, 0] = 1.0  # read-only

    @pytest.mark.parametrize("method", ["predict", "jacobian", "visible"])
    @pytest.mark.parametrize(
        "landmarks,error",
        [
            ([1.0, 2.0, 3.0], ValueError),
            ([[1.0, 2.0, 3.0]], ValueError),
            ([[math.nan, 1.0]], ValueError),
            ("ab", TypeError),
            (None, (TypeError, ValueError)),
        ],
    )
    def test_bad_landmarks(self, sensor, method, landmarks, error):
        with pytest.raises(error, match=r"\blandmarks\b"):
            getattr(sensor, method)([0.0, 0.0, 0.0], landmarks)

    @pytest.mark.parametrize("method", ["predict", "jacobian", "visible"])
    @pytest.mark.parametrize("pose", [[0.0, 0.0], [0.0, math.inf, 0.0]])
    def test_bad_pose(self, sensor, method, pose):
        with pytest.raises(ValueError, match=r"\bpose\b"):
            getattr(sensor, method)(pose, [[1.0, 0.0]])
