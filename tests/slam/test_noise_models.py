"""Tests of ``seif_gym.slam.noise_models`` and of the innovation gate every filter takes.

* :class:`PerSecondVelocityMotionModel`: Jacobians against central
  differences, ``R`` against its definition, the dt-invariance of the predicted
  covariance (one second in 1, 10 or 100 steps), sampling against ``R``.
* :class:`CommandCorrection`, :class:`CorrectedMotionModel`: the definition,
  the Jacobian against central differences, the chain rule.
* :class:`RangeDependentSensor`: ``sigma_r(r) = clip(a r, lo, hi)``, its
  derivative, sampling, and every filter with it (EKF = EIF = SEIF = ESEIF
  without sparsification; a flat ``sigma_r`` equals the constant sensor).
* The innovation gate: ``d^2`` against ``nu^T (H Sigma H^T + Q)^-1 nu`` built
  from the EKF's full covariance, outliers rejected and reported by every
  filter, a gate of ``inf`` changes nothing, a failed update leaves the
  filter (and its gate counters) bit-identical.

Finite differences use a step ``H``; their tolerances are a rounding term
``~ eps |value| / H`` plus a truncation term ``~ H^2``.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from seif_gym.slam import (
    EIF,
    EKF,
    ESEIF,
    SEIF,
    RangeBearingSensor,
    VelocityMotionModel,
    _kernels,
)
from seif_gym.slam.models import wrap_angle
from seif_gym.slam.noise_models import (
    CommandCorrection,
    CorrectedMotionModel,
    PerSecondVelocityMotionModel,
    RangeDependentSensor,
    mahalanobis_squared,
)
from seif_gym.slam.simulation import (
    loop_controls,
    loop_start_pose,
    ring_landmarks,
    simulate_run,
)

EPS = np.finfo(np.float64).eps
H = 1e-6
FILTERS = (EKF, EIF, SEIF, ESEIF)


def central_difference(f, x, angle_rows=(), step=H):
    """Jacobian of ``f`` at ``x`` by central differences; rows in ``angle_rows`` are wrapped."""
    x = np.asarray(x, dtype=np.float64)
    columns = []
    for k in range(x.size):
        e = np.zeros_like(x)
        e[k] = step
        diff = np.asarray(f(x + e), dtype=np.float64) - np.asarray(f(x - e), dtype=np.float64)
        diff = diff.reshape(-1).copy()
        for row in angle_rows:
            diff[row] = wrap_angle(float(diff[row]))
        columns.append(diff / (2.0 * step))
    return np.column_stack(columns)


@pytest.fixture(scope="module")
def per_second():
    return PerSecondVelocityMotionModel(
        forward=(2e-4, 0.05, 1e-4), turn=(3e-4, 0.02, 0.01), lateral=(1e-5, 0.01, 0.0), noise_floor=1e-9
    )


MOTION_CASES = [
    (np.array([0.3, -1.2, 2.9]), np.array([0.09, 0.4]), 0.01),
    (np.array([1.0, 2.0, -3.1]), np.array([0.5, -1.3]), 0.25),
    (np.array([-4.0, 0.5, 0.2]), np.array([1.7, 0.0]), 1.0),
    (np.array([2.0, -1.0, 1.0]), np.array([0.0, 0.6]), 0.1),
    (np.array([0.0, 0.0, 0.0]), np.array([0.3, 1e-7]), 2.0),
]


# ---------------------------------------------------------------------------
# PerSecondVelocityMotionModel
# ---------------------------------------------------------------------------
class TestPerSecondMotion:
    @pytest.mark.parametrize("pose, control, dt", MOTION_CASES)
    def test_state_jacobian_matches_fd(self, per_second, pose, control, dt):
        _, G, _ = per_second.linearize(pose, control, dt)
        fd = central_difference(lambda p: per_second.predict(p, control, dt), pose, angle_rows=(2,))
        np.testing.assert_allclose(G, fd, rtol=0, atol=1e-8)
        np.testing.assert_array_equal(per_second.jacobian_state(pose, control, dt), G)

    @pytest.mark.parametrize("pose, control, dt", MOTION_CASES)
    def test_control_jacobian_matches_fd(self, per_second, pose, control, dt):
        V = per_second.jacobian_control(pose, control, dt)
        fd = central_difference(lambda u: per_second.predict(pose, u, dt), control, angle_rows=(2,))
        np.testing.assert_allclose(V, fd, rtol=0, atol=1e-8 * max(1.0, dt**2))

    @pytest.mark.parametrize("pose, control, dt", MOTION_CASES)
    def test_kinematics_equal_thrun_model(self, per_second, pose, control, dt):
        thrun = VelocityMotionModel()
        delta, G, _ = per_second.linearize(pose, control, dt)
        thrun_delta, thrun_G, _ = thrun.linearize(pose, control, dt)
        np.testing.assert_allclose(delta, thrun_delta, rtol=0, atol=1e-15)
        np.testing.assert_allclose(G, thrun_G, rtol=0, atol=1e-15)
        np.testing.assert_allclose(per_second.jacobian_control(pose, control, dt),
                                   thrun.jacobian_control(pose, control, dt), rtol=0, atol=1e-15)  # fmt: skip

    @pytest.mark.parametrize("pose, control, dt", MOTION_CASES)
    def test_noise_matches_definition(self, per_second, pose, control, dt):
        """``R = V diag(q_v, q_w)/dt V^T + q_l dt n n^T + floor dt I`` with the rates of the docstring."""
        v, w = control
        f, t, l_ = per_second.forward, per_second.turn, per_second.lateral
        q_v = f[0] + f[1] * v * v + f[2] * w * w
        q_w = t[0] + t[1] * v * v + t[2] * w * w
        q_l = l_[0] + l_[1] * v * v + l_[2] * w * w
        np.testing.assert_allclose(per_second.noise_rates(control), [q_v, q_w, q_l], rtol=1e-15)
        V = per_second.jacobian_control(pose, control, dt)
        mid = pose[2] + 0.5 * w * dt
        n = np.array([-math.sin(mid), math.cos(mid), 0.0])
        expected = V @ np.diag([q_v / dt, q_w / dt]) @ V.T + q_l * dt * np.outer(n, n) + 1e-9 * dt * np.eye(3)
        R = per_second.noise_covariance(pose, control, dt)
        np.testing.assert_allclose(R, expected, rtol=1e-12, atol=1e-18)
        np.testing.assert_array_equal(R, R.T)
        assert np.all(np.linalg.eigvalsh(R) > 0)
        np.testing.assert_allclose(per_second.control_covariance(control, dt), np.diag([q_v / dt, q_w / dt]))

    @staticmethod
    def _propagate(model, pose, control, seconds, steps):
        """Pose covariance after ``seconds`` of ``control`` in ``steps`` equal steps (EKF prediction)."""
        cov = np.zeros((3, 3))
        dt = seconds / steps
        for _ in range(steps):
            delta, G, R = model.linearize(pose, control, dt)
            cov = G @ cov @ G.T + R
            pose = pose + delta
        return cov

    @pytest.mark.parametrize("control", [(0.09, 0.3), (0.09, -0.57), (0.5, -0.8), (0.2, 0.0)])
    def test_one_second_in_1_10_100_steps(self, per_second, control):
        """The belief does not depend on how finely the second is cut (to first order)."""
        pose = np.array([1.0, -2.0, 0.4])
        control = np.array(control)
        covs = {n: self._propagate(per_second, pose, control, 1.0, n) for n in (1, 10, 100)}
        # the heading is a random walk: its variance is q_w T (+ floor) exactly, however many steps
        for n in (1, 10, 100):
            assert covs[n][2, 2] == pytest.approx(per_second.noise_rates(control)[1] + 1e-9, rel=1e-12)
        # the rest differs by terms of order v^2 q_w dt^2 per unit time (heading noise turning into
        # cross-track error within a step), which vanish quadratically as the steps shrink
        scale = np.sqrt(np.outer(np.diag(covs[100]), np.diag(covs[100])))
        gap = {n: np.max(np.abs(covs[n] - covs[100]) / scale) for n in (1, 10)}
        assert gap[1] < 0.25
        assert gap[10] < gap[1] / 50.0 + 1e-12
        # Thrun's model, noise held over the step: 100 steps give ~100 times less variance than one
        thrun = VelocityMotionModel(alphas=(0.05, 0.0, 0.02, 0.01, 0.0, 0.0), noise_floor=1e-12)
        ratio = (
            self._propagate(thrun, pose, control, 1.0, 1)[2, 2] / self._propagate(thrun, pose, control, 1.0, 100)[2, 2]
        )
        assert ratio == pytest.approx(100.0, rel=1e-4)

    @pytest.mark.parametrize("control", [(0.09, 0.3), (0.5, -0.8)])
    def test_first_order_limit_is_the_same(self, per_second, control):
        """``Sigma_N(T) / T`` tends to the same per-second rate for N = 1, 10, 100 as ``T -> 0``."""
        pose = np.array([1.0, -2.0, 0.4])
        control = np.array(control)
        seconds = 1e-3
        rates = [self._propagate(per_second, pose, control, seconds, n) / seconds for n in (1, 10, 100)]
        for rate in rates[:2]:
            np.testing.assert_allclose(rate, rates[2], rtol=2e-3, atol=1e-3 * np.abs(rates[2]).max())

    def test_standing_still_is_exactly_dt_invariant(self, per_second):
        pose = np.array([0.0, 0.0, 0.3])
        covs = [self._propagate(per_second, pose, np.zeros(2), 1.0, n) for n in (1, 10, 100)]
        for cov in covs[:2]:
            np.testing.assert_allclose(cov, covs[2], rtol=1e-12, atol=1e-20)
        # a pure random walk: the per-second rates themselves, forward along the heading, lateral across
        e, n = np.array([math.cos(0.3), math.sin(0.3)]), np.array([-math.sin(0.3), math.cos(0.3)])
        position = 2e-4 * np.outer(e, e) + 1e-5 * np.outer(n, n) + 1e-9 * np.eye(2)
        np.testing.assert_allclose(covs[0][:2, :2], position, rtol=1e-9, atol=1e-20)
        assert covs[0][2, 2] == pytest.approx(3e-4 + 1e-9, rel=1e-12)

    def test_sampled_second_matches_propagated_covariance(self, per_second):
        """Monte Carlo: 100 sampled 10 ms steps spread as the linearized 1 s covariance."""
        rng = np.random.default_rng(3)
        pose0 = np.array([0.5, 0.5, 0.1])
        control = np.array([0.5, 0.6])
        draws = 4000
        poses = np.tile(pose0, (draws, 1))
        for _ in range(100):
            poses = np.array([per_second.sample_trusted(p, control, 0.01, rng) for p in poses])
        mean = per_second.predict(pose0, control, 1.0)
        errors = poses - mean
        errors[:, 2] = wrap_angle(errors[:, 2])
        empirical = errors.T @ errors / draws
        expected = self._propagate(per_second, pose0, control, 1.0, 100)
        # standard error of a variance from 4000 draws: sqrt(2 / 4000) ~ 2.2 %; 5 standard errors
        np.testing.assert_allclose(np.diag(empirical), np.diag(expected), rtol=0.12)

    def test_sample_reproducible_and_zero_noise_is_predict(self):
        pose, control, dt = np.array([1.0, 2.0, 0.3]), np.array([0.4, -0.2]), 0.3
        model = PerSecondVelocityMotionModel(forward=(1e-3, 0, 0), turn=(1e-3, 0, 0), lateral=(1e-4, 0, 0))
        a = model.sample(pose, control, dt, np.random.default_rng(5))
        b = model.sample(pose, control, dt, np.random.default_rng(5))
        np.testing.assert_array_equal(a, b)
        quiet = PerSecondVelocityMotionModel()
        np.testing.assert_allclose(quiet.sample(pose, control, dt, np.random.default_rng(5)),
                                   quiet.predict(pose, control, dt), atol=1e-15)  # fmt: skip

    @pytest.mark.parametrize(
        "kwargs, error, name",
        [
            ({"forward": (1e-3, -1.0, 0.0)}, ValueError, "forward"),
            ({"turn": (1e-3, 0.0)}, ValueError, "turn"),
            ({"lateral": (np.nan, 0.0, 0.0)}, ValueError, "lateral"),
            ({"forward": "abc"}, TypeError, "forward"),
            ({"noise_floor": 0.0}, ValueError, "noise_floor"),
        ],
    )
    def test_bad_constructor_arguments(self, kwargs, error, name):
        with pytest.raises(error, match=name):
            PerSecondVelocityMotionModel(**kwargs)

    def test_bad_inputs_name_the_argument(self, per_second):
        pose, control = np.zeros(3), np.array([0.1, 0.1])
        with pytest.raises(ValueError, match="control"):
            per_second.linearize(pose, [0.1, np.inf], 0.1)
        with pytest.raises(ValueError, match="pose"):
            per_second.linearize([0.0, 0.0], control, 0.1)
        with pytest.raises(ValueError, match="dt"):
            per_second.linearize(pose, control, 0.0)
        with pytest.raises(TypeError, match="rng"):
            per_second.sample(pose, control, 0.1, 3)


# ---------------------------------------------------------------------------
# CommandCorrection, CorrectedMotionModel
# ---------------------------------------------------------------------------
CORRECTION = CommandCorrection(
    speed_scale=0.95, turn_slowdown=1.2, speed_offset=0.001, turn_scale=0.93, turn_offset=-0.002
)


class TestCommandCorrection:
    def test_definition(self):
        controls = np.array([[0.09, 0.3], [0.05, -0.5], [0.0, 0.1], [0.08, 0.0], [0.1, 2.0]])
        v, w = controls.T
        expected = np.column_stack([0.95 * v * np.maximum(0.0, 1.0 - 1.2 * np.abs(w)) + 0.001, 0.93 * w - 0.002])
        np.testing.assert_allclose(CORRECTION.apply(controls), expected, rtol=1e-15, atol=1e-18)
        for control, row in zip(controls, expected):
            np.testing.assert_allclose(CORRECTION.apply(control), row, rtol=1e-15, atol=1e-18)

    @pytest.mark.parametrize("control", [(0.09, 0.3), (0.05, -0.5), (-0.04, 0.2), (0.1, -2.0)])
    def test_jacobian_matches_fd(self, control):
        fd = central_difference(CORRECTION.apply, control)
        np.testing.assert_allclose(CORRECTION.jacobian(control), fd, rtol=0, atol=1e-9)

    def test_identity(self):
        identity = CommandCorrection()
        assert identity.is_identity and not CORRECTION.is_identity
        controls = np.random.default_rng(0).normal(size=(20, 2))
        np.testing.assert_array_equal(identity.apply(controls), controls)
        assert CommandCorrection(**CORRECTION.to_dict()) == CORRECTION

    @pytest.mark.parametrize(
        "kwargs, error, name",
        [
            ({"speed_scale": 0.0}, ValueError, "speed_scale"),
            ({"turn_scale": -1.0}, ValueError, "turn_scale"),
            ({"turn_slowdown": -0.1}, ValueError, "turn_slowdown"),
            ({"speed_offset": np.nan}, ValueError, "speed_offset"),
            ({"turn_offset": "x"}, TypeError, "turn_offset"),
        ],
    )
    def test_bad_parameters(self, kwargs, error, name):
        with pytest.raises(error, match=name):
            CommandCorrection(**kwargs)

    def test_bad_controls(self):
        with pytest.raises(ValueError, match="control"):
            CORRECTION.apply([[0.1, 0.2, 0.3]])
        with pytest.raises(ValueError, match="control"):
            CORRECTION.apply([0.1, np.nan])


class TestCorrectedMotion:
    @pytest.mark.parametrize("pose, control, dt", MOTION_CASES[:4])
    def test_is_the_model_at_the_corrected_control(self, per_second, pose, control, dt):
        model = CorrectedMotionModel(per_second, CORRECTION)
        corrected = CORRECTION.apply(control)
        for mine, theirs in zip(model.linearize(pose, control, dt), per_second.linearize(pose, corrected, dt)):
            np.testing.assert_array_equal(mine, theirs)
        np.testing.assert_array_equal(model.predict(pose, control, dt), per_second.predict(pose, corrected, dt))
        np.testing.assert_array_equal(model.sample(pose, control, dt, np.random.default_rng(1)),
                                      per_second.sample(pose, corrected, dt, np.random.default_rng(1)))  # fmt: skip

    @pytest.mark.parametrize("pose, control, dt", [MOTION_CASES[k] for k in (0, 1, 3)])
    def test_control_jacobian_chain_rule_matches_fd(self, per_second, pose, control, dt):
        model = CorrectedMotionModel(per_second, CORRECTION)
        fd = central_difference(lambda u: model.predict(pose, u, dt), control, angle_rows=(2,))
        np.testing.assert_allclose(model.jacobian_control(pose, control, dt), fd, rtol=0, atol=1e-8)

    def test_filter_with_corrected_model_equals_corrected_controls(self, per_second):
        """An EKF fed raw commands through the wrapper equals one fed corrected commands, bit for bit."""
        sensor = RangeBearingSensor()
        a = EKF(CorrectedMotionModel(per_second, CORRECTION), sensor, np.zeros(3))
        b = EKF(per_second, sensor, np.zeros(3))
        for control in np.random.default_rng(2).uniform(-0.5, 0.5, (20, 2)):
            a.predict(control, 0.1)
            b.predict(CORRECTION.apply(control), 0.1)
        np.testing.assert_array_equal(a.mean, b.mean)
        np.testing.assert_array_equal(a.covariance(), b.covariance())

    def test_bad_arguments(self, per_second):
        with pytest.raises(TypeError, match="model"):
            CorrectedMotionModel(object(), CORRECTION)
        with pytest.raises(TypeError, match="correction"):
            CorrectedMotionModel(per_second, {"speed_scale": 1.0})


# ---------------------------------------------------------------------------
# RangeDependentSensor
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def ranged():
    return RangeDependentSensor(range_slope=0.05, range_bounds=(0.06, 0.3), sigma_bearing=0.01, max_range=9.0)


class TestRangeDependentSensor:
    def test_sigma_definition_and_covariances(self, ranged):
        r = np.array([0.5, 1.0, 1.2, 3.0, 5.9, 6.0, 8.0])
        sigma = np.clip(0.05 * r, 0.06, 0.3)
        np.testing.assert_allclose(ranged.range_sigma(r), sigma, rtol=1e-15)
        covs = ranged.measurement_covariances(r)
        np.testing.assert_allclose(covs[:, 0, 0], sigma**2, rtol=1e-15)
        np.testing.assert_array_equal(covs[:, 1, 1], 1e-4)
        np.testing.assert_array_equal(covs[:, 0, 1], 0.0)
        np.testing.assert_allclose(ranged.noise_covariance, np.diag([0.09, 1e-4]))  # the largest Q
        assert ranged.range_dependent and not RangeBearingSensor.range_dependent

    @pytest.mark.parametrize("r", [0.3, 1.5, 3.7, 5.0, 7.5])
    def test_sigma_derivative_matches_fd(self, ranged, r):
        fd = central_difference(lambda x: ranged.range_sigma(x), np.array([r]), step=1e-5)
        assert ranged.range_sigma_derivative([r])[0] == pytest.approx(fd[0, 0], abs=1e-9)

    def test_measurement_model_and_jacobian_are_the_sensors(self, ranged):
        pose = np.array([0.4, -0.3, 0.7])
        landmarks = np.array([[2.0, 1.0], [-1.0, 3.0]])
        plain = RangeBearingSensor(sigma_bearing=0.01, max_range=9.0)
        np.testing.assert_array_equal(ranged.predict(pose, landmarks), plain.predict(pose, landmarks))
        H_all = ranged.jacobian(pose, landmarks)
        for k, landmark in enumerate(landmarks):

            def h(state):
                return ranged.predict(state[:3], state[3:][None])[0]

            fd = central_difference(h, np.concatenate([pose, landmark]), angle_rows=(1,))
            np.testing.assert_allclose(H_all[k], fd, rtol=0, atol=1e-8)

    def test_sample_noise_grows_with_range(self, ranged):
        rng = np.random.default_rng(11)
        pose = np.zeros(3)
        landmarks = np.array([[1.0, 0.0], [0.0, 3.0], [-7.0, 0.0]])
        draws = np.array([ranged.sample(pose, landmarks, rng)[0] for _ in range(4000)])
        std = draws.std(axis=0)
        # 4000 draws: a standard deviation's standard error is ~1.1 %
        np.testing.assert_allclose(std, np.clip(0.05 * np.array([1.0, 3.0, 7.0]), 0.06, 0.3), rtol=0.06)
        _, _, ids = ranged.sample(pose, landmarks, np.random.default_rng(1), ids=np.array([7, 8, 9]))
        np.testing.assert_array_equal(ids, [7, 8, 9])

    @pytest.mark.parametrize(
        "kwargs, error, name",
        [
            ({"range_slope": 0.0}, ValueError, "range_slope"),
            ({"range_bounds": (0.3, 0.1)}, ValueError, "range_bounds"),
            ({"range_bounds": (0.0, 0.1)}, ValueError, "range_bounds"),
            ({"range_bounds": (0.1,)}, ValueError, "range_bounds"),
            ({"sigma_bearing": -1.0}, ValueError, "sigma_bearing"),
        ],
    )
    def test_bad_parameters(self, kwargs, error, name):
        with pytest.raises(error, match=name):
            RangeDependentSensor(**kwargs)

    def test_bad_ranges(self, ranged):
        with pytest.raises(ValueError, match="ranges"):
            ranged.range_sigma([1.0, np.nan])
        with pytest.raises(TypeError, match="ranges"):
            ranged.measurement_covariances("far")


# ---------------------------------------------------------------------------
# the filters with these models
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def ranged_run():
    """A 200-step loop among 40 landmarks, range noise growing with range, per-second motion noise."""
    rng = np.random.default_rng(21)
    motion = PerSecondVelocityMotionModel(forward=(1e-3, 0.0, 0.0), turn=(5e-4, 0.0, 0.0), lateral=(1e-4, 0.0, 0.0))
    sensor = RangeDependentSensor(range_slope=0.03, range_bounds=(0.03, 0.2), sigma_bearing=0.01, max_range=5.0)
    landmarks = ring_landmarks(40, 6.0, 12.0, rng)
    run = simulate_run(motion, sensor, landmarks, loop_controls(200, 0.1, radius=9.0), 0.1, loop_start_pose(9.0), rng)
    return motion, sensor, run


def _run(filt, run, steps=None):
    for t in range(run.steps if steps is None else steps):
        filt.predict(run.controls[t], run.dt)
        filt.update(run.ranges[t], run.bearings[t], run.ids[t])
    return filt


def _exact_options(cls) -> dict:
    return {"max_active": None, "mean_recovery": "exact"} if cls in (SEIF, ESEIF) else {}


class TestFiltersWithRangeNoise:
    def test_exact_filters_agree(self, ranged_run):
        motion, sensor, run = ranged_run
        filters = [_run(cls(motion, sensor, run.initial_pose, **_exact_options(cls)), run) for cls in FILTERS]
        reference = filters[0]
        for filt in filters[1:]:
            np.testing.assert_allclose(filt.mean, reference.mean, rtol=0, atol=1e-8)
            np.testing.assert_allclose(filt.covariance(), reference.covariance(), rtol=1e-6, atol=1e-12)

    @pytest.mark.parametrize("cls", FILTERS)
    def test_flat_range_noise_equals_constant_sensor(self, ranged_run, cls):
        _, _, run = ranged_run
        motion = VelocityMotionModel()
        flat = RangeDependentSensor(range_slope=0.01, range_bounds=(0.1, 0.1), sigma_bearing=0.01, max_range=5.0)
        plain = RangeBearingSensor(sigma_range=0.1, sigma_bearing=0.01, max_range=5.0)
        options = {"max_active": 4} if cls in (SEIF, ESEIF) else {}
        a = _run(cls(motion, flat, run.initial_pose, **options), run, 80)
        b = _run(cls(motion, plain, run.initial_pose, **options), run, 80)
        np.testing.assert_allclose(a.mean, b.mean, rtol=0, atol=1e-10)

    @pytest.mark.parametrize("cls", [SEIF, ESEIF])
    def test_compiled_equals_reference(self, ranged_run, cls):
        motion, sensor, run = ranged_run
        a = _run(cls(motion, sensor, run.initial_pose, max_active=3), run, 80)
        b = _run(cls(motion, sensor, run.initial_pose, max_active=3, implementation="reference"), run, 80)
        np.testing.assert_allclose(a.mean, b.mean, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.information_matrix.toarray(), b.information_matrix.toarray(), rtol=1e-9, atol=1e-6)

    def test_range_noise_weighs_far_landmarks_less(self):
        """One update with a near and a far landmark: the far one gets the larger posterior variance."""
        sensor = RangeDependentSensor(range_slope=0.05, range_bounds=(0.01, 1.0), sigma_bearing=0.01)
        filt = EKF(VelocityMotionModel(), sensor, np.zeros(3))
        filt.update([1.0, 6.0], [0.0, 0.0], [1, 2])
        assert filt.landmark_covariance(1)[0, 0] == pytest.approx(0.05**2 + 1e-6, rel=1e-3)
        assert filt.landmark_covariance(2)[0, 0] == pytest.approx(0.3**2 + 1e-6, rel=1e-3)


# ---------------------------------------------------------------------------
# the innovation gate
# ---------------------------------------------------------------------------
def _outlier_step(run, t):
    """Step ``t``'s measurements with the first bearing turned by 3 rad (a misread barcode)."""
    bearings = np.array(run.bearings[t], dtype=np.float64)
    bearings[0] = wrap_angle(float(bearings[0] + 3.0))
    return np.array(run.ranges[t]), bearings, np.array(run.ids[t])


def _gated_step(run, start=30):
    for t in range(start, run.steps):
        if len(run.ids[t]) >= 2 and run.ids[t][0] in set(np.concatenate(run.ids[:t]).tolist()):
            return t
    raise AssertionError("no step re-observes a mapped landmark")


class TestInnovationGate:
    def test_distance_matches_definition_from_full_covariance(self, ranged_run):
        motion, sensor, run = ranged_run
        filt = _run(EKF(motion, sensor, run.initial_pose), run, 40)
        filt.predict(run.controls[40], run.dt)
        ranges, bearings, ids = run.ranges[41], run.bearings[41], run.ids[41]
        distances = filt.innovation_distances(ranges, bearings, ids)
        mean, cov = filt.mean, filt.covariance()
        for k, landmark_id in enumerate(ids.tolist()):
            if landmark_id not in set(filt.landmark_ids.tolist()):
                assert np.isnan(distances[k])
                continue
            j = 3 + 2 * filt.landmark_index(landmark_id)
            d = mean[j : j + 2] - mean[:2]
            q = d @ d
            Hfull = np.zeros((2, len(mean)))
            Hfull[:, :3] = [[-d[0] / np.sqrt(q), -d[1] / np.sqrt(q), 0.0], [d[1] / q, -d[0] / q, -1.0]]
            Hfull[:, j : j + 2] = [[d[0] / np.sqrt(q), d[1] / np.sqrt(q)], [-d[1] / q, d[0] / q]]
            S = Hfull @ cov @ Hfull.T + sensor.measurement_covariances([ranges[k]])[0]
            nu = np.array([ranges[k] - np.sqrt(q), wrap_angle(float(bearings[k] - np.arctan2(d[1], d[0]) + mean[2]))])
            assert distances[k] == pytest.approx(nu @ np.linalg.solve(S, nu), rel=1e-9)

    def test_mahalanobis_closed_form(self):
        rng = np.random.default_rng(0)
        nu = rng.normal(size=(6, 2))
        A = rng.normal(size=(6, 2, 2))
        S = A @ A.transpose(0, 2, 1) + 0.1 * np.eye(2)
        expected = [n @ np.linalg.solve(s, n) for n, s in zip(nu, S)]
        np.testing.assert_allclose(mahalanobis_squared(nu, S), expected, rtol=1e-12)
        with pytest.raises(ValueError, match="positive definite"):
            mahalanobis_squared(nu[:1], -S[:1])

    @pytest.mark.parametrize("cls", FILTERS)
    def test_outlier_rejected_and_reported(self, ranged_run, cls):
        motion, sensor, run = ranged_run
        options = {"max_active": 4} if cls in (SEIF, ESEIF) else {}
        gated = _run(cls(motion, sensor, run.initial_pose, innovation_gate=13.8, **options), run, 30)
        t = _gated_step(run)
        for s in range(30, t):
            gated.predict(run.controls[s], run.dt)
            gated.update(run.ranges[s], run.bearings[s], run.ids[s])
        gated.predict(run.controls[t], run.dt)
        without = copy.deepcopy(gated)
        before = gated.gated_measurements
        ranges, bearings, ids = _outlier_step(run, t)
        gated.update(ranges, bearings, ids)
        assert gated.gated_measurements == before + 1
        np.testing.assert_array_equal(gated.last_gated_ids, ids[:1])
        assert gated.last_mahalanobis[0] > 13.8 and len(gated.last_mahalanobis) == len(ids)
        # the same as an update without the outlier
        without.update(ranges[1:], bearings[1:], ids[1:])
        np.testing.assert_array_equal(gated.mean, without.mean)

    @pytest.mark.parametrize("cls", FILTERS)
    def test_infinite_gate_changes_nothing(self, ranged_run, cls):
        motion, sensor, run = ranged_run
        options = {"max_active": 4} if cls in (SEIF, ESEIF) else {}
        a = _run(cls(motion, sensor, run.initial_pose, innovation_gate=np.inf, **options), run, 60)
        b = _run(cls(motion, sensor, run.initial_pose, **options), run, 60)
        np.testing.assert_array_equal(a.mean, b.mean)
        assert a.gated_measurements == 0 and len(a.last_mahalanobis) == len(run.ids[59])
        assert len(b.last_mahalanobis) == 0
        assert "innovation_gate=inf" in repr(a) and "innovation_gate" not in repr(b)

    def test_default_filter_has_no_gate_in_its_options(self):
        filt = EKF(VelocityMotionModel(), RangeBearingSensor(), np.zeros(3))
        assert filt.innovation_gate is None and repr(filt) == "EKF(landmarks=0)"

    @pytest.mark.parametrize("gate, error", [(-1.0, ValueError), (0.0, ValueError), (np.nan, ValueError),
                                             ("13.8", TypeError), (True, TypeError)])  # fmt: skip
    def test_bad_gate(self, gate, error):
        for cls in FILTERS:
            with pytest.raises(error, match="innovation_gate"):
                cls(VelocityMotionModel(), RangeBearingSensor(), np.zeros(3), innovation_gate=gate)

    @pytest.mark.parametrize("cls", [SEIF, ESEIF])
    def test_failed_gated_update_leaves_filter_unchanged(self, ranged_run, cls, monkeypatch):
        motion, sensor, run = ranged_run
        filt = _run(cls(motion, sensor, run.initial_pose, innovation_gate=13.8, max_active=4), run, 30)
        t = _gated_step(run)
        for s in range(30, t):
            filt.predict(run.controls[s], run.dt)
            filt.update(run.ranges[s], run.bearings[s], run.ids[s])
        filt.predict(run.controls[t], run.dt)
        reference = copy.deepcopy(filt)
        before = _state(filt)

        def fail(*args, **kwargs):
            raise np.linalg.LinAlgError("injected")

        monkeypatch.setattr(_kernels, "measurement_update", fail)
        with pytest.raises(np.linalg.LinAlgError):
            filt.update(*_outlier_step(run, t))
        assert _state(filt) == before
        monkeypatch.undo()
        filt.update(*_outlier_step(run, t))
        reference.update(*_outlier_step(run, t))
        assert _state(filt) == _state(reference)
        assert filt.gated_measurements == reference.gated_measurements > 0


def _state(filt) -> dict:
    """Every array and scalar of a SEIF (store and queue included), raw."""
    state = {}
    for prefix, owner in (("filter", filt), ("store", filt._store), ("queue", filt._queue)):
        for name, value in vars(owner).items():
            if isinstance(value, np.ndarray):
                state[f"{prefix}.{name}"] = (value.dtype.str, value.shape, value.tobytes())
            elif isinstance(value, (int, float, bool, str, type(None))):
                state[f"{prefix}.{name}"] = value
    return state
