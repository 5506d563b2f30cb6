"""Tests of the exact baselines :class:`EKF` and :class:`EIF`, and of the shared filter interface.

* On a 300-step loop-closing run the two agree to round-off, and so does the
  SEIF without sparsification and with exact mean recovery
  (docs/filters/math.md, "When the SEIF is exact").
* The EKF is consistent: its Monte-Carlo average pose NEES lies in the
  two-sided 95% chi-square band, and the same check rejects a covariance that
  is 5 times too small or too large.
* Landmark bookkeeping, capacity growth, and bad input leaving the filter
  unchanged.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse
from scipy.stats import chi2

from seif_gym.slam import EIF, EKF, SEIF, RangeBearingSensor, UnknownLandmarkError, VelocityMotionModel
from seif_gym.slam.simulation import (
    SimulatedRun,
    loop_controls,
    loop_start_pose,
    pose_nees,
    ring_landmarks,
    run_filter,
    simulate_run,
)

FILTERS = [EKF, EIF, SEIF]

LOOP_RADIUS = 10.0
LOOP_STEPS = 300
DT = 0.1


@pytest.fixture(scope="module")
def loop_run() -> tuple[VelocityMotionModel, RangeBearingSensor, SimulatedRun]:
    """300 steps around a circle of radius 10 (1.2 turns), 50 landmarks on a ring of radii 7-13."""
    rng = np.random.default_rng(20240611)
    motion = VelocityMotionModel()
    sensor = RangeBearingSensor(max_range=5.0)
    landmarks = ring_landmarks(50, LOOP_RADIUS - 3.0, LOOP_RADIUS + 3.0, rng)
    controls = loop_controls(LOOP_STEPS, DT, LOOP_RADIUS, turns=1.2)
    run = simulate_run(motion, sensor, landmarks, controls, DT, loop_start_pose(LOOP_RADIUS), rng)
    return motion, sensor, run


@pytest.fixture(scope="module")
def loop_results(loop_run):
    motion, sensor, run = loop_run
    ekf, eif = EKF(motion, sensor, run.initial_pose), EIF(motion, sensor, run.initial_pose)
    return run, ekf, run_filter(ekf, run), eif, run_filter(eif, run)


def _assert_close(actual, desired, name: str, rtol: float = 1e-8) -> None:
    """``assert_allclose`` with an ``atol`` tiny against the scale of ``desired``."""
    desired = np.asarray(desired)
    np.testing.assert_allclose(actual, desired, rtol=rtol, atol=1e-10 * np.max(np.abs(desired)), err_msg=name)


# -- EKF == EIF -------------------------------------------------------------------


def test_loop_scenario_is_what_the_equivalence_test_claims(loop_run):
    _, _, run = loop_run
    counts = run.measurement_counts
    assert 5.0 <= counts.mean() <= 10.0
    seen = np.unique(np.concatenate(run.ids))
    assert 30 <= len(seen) <= 60
    # the loop closes: landmarks seen in the first steps are seen again at the end
    first = set(np.concatenate(run.ids[:10]).tolist())
    last = set(np.concatenate(run.ids[-30:]).tolist())
    assert first & last
    # the heading crosses +-pi, so the wrapping paths are exercised
    assert np.any(np.abs(np.diff(run.true_poses[:, 2])) > math.pi)


def test_ekf_and_eif_agree_after_a_closed_loop(loop_results):
    run, ekf, ekf_result, eif, eif_result = loop_results
    np.testing.assert_array_equal(ekf.landmark_ids, eif.landmark_ids)
    assert ekf.state_dim == eif.state_dim == 3 + 2 * len(np.unique(np.concatenate(run.ids)))

    _assert_close(eif.pose, ekf.pose, "pose")
    _assert_close(eif.landmarks, ekf.landmarks, "landmarks")
    _assert_close(eif.mean, ekf.mean, "mean")
    _assert_close(eif.pose_covariance, ekf.pose_covariance, "pose covariance")
    for landmark_id in ekf.landmark_ids:
        _assert_close(
            eif.landmark_covariance(landmark_id), ekf.landmark_covariance(landmark_id), f"landmark {landmark_id}"
        )
    _assert_close(eif.covariance(), ekf.covariance(), "full covariance")
    # and at every step along the way
    _assert_close(eif_result["poses"], ekf_result["poses"], "pose trajectory")
    _assert_close(eif_result["pose_covariances"], ekf_result["pose_covariances"], "pose covariances")


@pytest.mark.parametrize("implementation", ["compiled", pytest.param("reference", marks=pytest.mark.slow)])
def test_seif_without_sparsification_equals_ekf_and_eif(loop_run, loop_results, implementation):
    motion, sensor, run = loop_run
    _, ekf, ekf_result, eif, _ = loop_results
    seif = SEIF(motion, sensor, run.initial_pose, max_active=None, mean_recovery="exact", implementation=implementation)
    seif_result = run_filter(seif, run)
    np.testing.assert_array_equal(seif.landmark_ids, ekf.landmark_ids)
    _assert_close(seif.mean, ekf.mean, "mean")
    _assert_close(seif.pose_covariance, ekf.pose_covariance, "pose covariance")
    for landmark_id in ekf.landmark_ids:
        _assert_close(
            seif.landmark_covariance(landmark_id), ekf.landmark_covariance(landmark_id), f"landmark {landmark_id}"
        )
    _assert_close(seif.covariance(), ekf.covariance(), "full covariance")
    _assert_close(seif.information_matrix.toarray(), eif.information_matrix.toarray(), "information matrix")
    _assert_close(seif.information_vector, eif.information_vector, "information vector")
    _assert_close(seif_result["poses"], ekf_result["poses"], "pose trajectory")
    _assert_close(seif_result["pose_covariances"], ekf_result["pose_covariances"], "pose covariances")


def test_filters_track_the_truth_on_the_loop(loop_results):
    run, ekf, ekf_result, _, _ = loop_results
    nees = pose_nees(run.true_poses[1:], ekf_result["poses"][1:], ekf_result["pose_covariances"][1:])
    assert np.median(nees) < 10.0
    truth = run.landmarks[ekf.landmark_ids]
    assert np.max(np.linalg.norm(ekf.landmarks - truth, axis=1)) < 1.0


def test_eif_information_form_is_consistent(loop_results):
    _, ekf, _, eif, _ = loop_results
    information = eif.information_matrix
    assert isinstance(information, scipy.sparse.csr_array)
    dense = information.toarray()
    assert dense.shape == (eif.state_dim, eif.state_dim)
    np.testing.assert_array_equal(dense, dense.T)  # exactly symmetric
    # without sparsification Omega fills in completely (why the EIF stores it dense)
    assert information.nnz == eif.state_dim**2
    xi = eif.information_vector
    assert not xi.flags.writeable
    _assert_close(dense @ eif.mean, xi, "xi = Omega mu", rtol=1e-9)
    np.testing.assert_allclose(dense @ ekf.covariance(), np.eye(eif.state_dim), rtol=0.0, atol=1e-8)


def test_eif_motion_update_matches_ekf_without_measurements():
    """Prediction only (with landmarks linked to the robot), many steps."""
    motion, sensor = VelocityMotionModel(), RangeBearingSensor()
    ekf, eif = EKF(motion, sensor, [0.0, 0.0, 3.0]), EIF(motion, sensor, [0.0, 0.0, 3.0])
    for filt in (ekf, eif):
        filt.update([2.0, 3.0, 4.0], [0.3, -1.0, 2.5], [10, 11, 12])
        for step in range(40):
            filt.predict([1.0, 0.4 * math.sin(step)], 0.1)
    _assert_close(eif.mean, ekf.mean, "mean")
    _assert_close(eif.covariance(), ekf.covariance(), "covariance")


# -- EKF consistency ------------------------------------------------------------------


def test_ekf_pose_nees_is_in_the_chi2_band():
    runs, steps, radius = 50, 60, 5.0
    rng = np.random.default_rng(0)
    motion = VelocityMotionModel(alphas=(0.002, 0.0002, 0.0002, 0.002, 0.0001, 0.0001))
    sensor = RangeBearingSensor(sigma_range=0.05, sigma_bearing=math.radians(1.0), max_range=4.0)
    landmarks = ring_landmarks(20, radius - 2.0, radius + 2.0, rng)
    controls = loop_controls(steps, DT, radius, turns=0.5)
    checked_steps = [20, 40, 60]
    nees = np.empty((runs, len(checked_steps)))
    for k in range(runs):
        run = simulate_run(motion, sensor, landmarks, controls, DT, loop_start_pose(radius), rng)
        result = run_filter(EKF(motion, sensor, run.initial_pose), run)
        nees[k] = pose_nees(
            run.true_poses[checked_steps], result["poses"][checked_steps], result["pose_covariances"][checked_steps]
        )
    average = nees.mean(axis=0)
    lower, upper = chi2.ppf([0.025, 0.975], 3 * runs) / runs
    assert np.all((lower < average) & (average < upper)), (average, lower, upper)
    # the check has teeth: a covariance scaled by 0.2 (NEES x 5) or by 5 (NEES / 5) fails it
    assert np.all(average / 0.2 > upper)
    assert np.all(average / 5.0 < lower)


# -- landmarks --------------------------------------------------------------------


@pytest.mark.parametrize("filter_class", FILTERS)
def test_adding_landmarks(filter_class):
    motion, sensor = VelocityMotionModel(), RangeBearingSensor()
    pose = np.array([1.0, -2.0, 0.5])
    filt = filter_class(motion, sensor, pose)
    assert filt.state_dim == 3 and filt.num_landmarks == 0
    assert filt.landmark_ids.shape == (0,)

    filt.update([2.0, 3.0], [0.25, -1.0], [7, 3])
    assert filt.state_dim == 7
    np.testing.assert_array_equal(filt.landmark_ids, [7, 3])
    # a first sighting puts the landmark where the inverse sensor model says
    expected = pose[:2] + 2.0 * np.array([math.cos(0.75), math.sin(0.75)])
    np.testing.assert_allclose(filt.landmarks[0], expected, rtol=1e-12)
    np.testing.assert_allclose(filt.pose, pose, atol=1e-12)
    # with covariance G_x Sigma_xx G_x^T + G_z Q G_z^T
    wrt_pose, wrt_measurement = sensor.inverse_jacobians(pose, [2.0], [0.25])
    expected_cov = (
        wrt_pose[0] @ filt.pose_covariance @ wrt_pose[0].T
        + wrt_measurement[0] @ sensor.noise_covariance @ wrt_measurement[0].T
    )
    np.testing.assert_allclose(filt.landmark_covariance(7), expected_cov, rtol=1e-8)

    filt.predict([1.0, 0.1], 0.1)
    filt.update([2.9, 4.0], [-1.1, 2.0], [3, 5])  # one known, one new
    assert filt.state_dim == 9
    np.testing.assert_array_equal(filt.landmark_ids, [7, 3, 5])
    assert filt.landmark_index(5) == 2
    assert filt.covariance().shape == (9, 9)

    for error in (UnknownLandmarkError, KeyError, ValueError):
        with pytest.raises(error, match="42"):
            filt.landmark_covariance(42)


@pytest.mark.parametrize("filter_class", FILTERS)
def test_capacity_grows_by_doubling(filter_class):
    motion, sensor = VelocityMotionModel(), RangeBearingSensor(max_range=50.0)
    filt = filter_class(motion, sensor, [0.0, 0.0, 0.0])
    sizes = {filt.memory_bytes}
    for landmark_id in range(40):
        angle = 2.0 * math.pi * landmark_id / 40 - math.pi
        filt.update([5.0 + 0.1 * landmark_id], [angle], [landmark_id])
        sizes.add(filt.memory_bytes)
    assert filt.num_landmarks == 40
    # capacities double (8, 16, 32, 64): at most a few jumps of more than 10%, not one per landmark
    ordered = sorted(sizes)
    jumps = sum(1 for small, large in zip(ordered, ordered[1:]) if large > 1.1 * small)
    assert jumps <= 3
    np.testing.assert_array_equal(filt.landmark_ids, np.arange(40))
    np.testing.assert_allclose(np.linalg.norm(filt.landmarks[5] - filt.pose[:2]), 5.5, rtol=1e-9)


@pytest.mark.parametrize("filter_class", FILTERS)
def test_empty_update_changes_nothing(filter_class):
    filt = filter_class(VelocityMotionModel(), RangeBearingSensor(), [0.0, 0.0, 0.0])
    filt.update([2.0], [0.5], [1])
    filt.predict([1.0, 0.2], 0.1)
    before = _snapshot(filt)
    filt.update([], [], [])
    after = _snapshot(filt)
    if isinstance(filt, SEIF):
        # amortized mean recovery runs in every update: only the mean may move, towards Omega^-1 xi
        del before["mean"]
        np.testing.assert_allclose(after["mean"], filt.exact_mean(), rtol=1e-9, atol=1e-12)
    for name, value in before.items():
        np.testing.assert_array_equal(after[name], value, err_msg=name)


# -- bad input --------------------------------------------------------------------


def _snapshot(filt) -> dict[str, np.ndarray]:
    state = {
        "mean": filt.mean.copy(),
        "covariance": filt.covariance().copy(),
        "landmark_ids": filt.landmark_ids.copy(),
        "pose_covariance": filt.pose_covariance.copy(),
    }
    if isinstance(filt, (EIF, SEIF)):
        state["information_matrix"] = filt.information_matrix.toarray()
        state["information_vector"] = filt.information_vector.copy()
    return state


def _started_filter(filter_class):
    filt = filter_class(VelocityMotionModel(), RangeBearingSensor(), [0.5, 0.5, 0.1])
    filt.update([2.0, 3.0], [0.3, -0.8], [0, 1])
    filt.predict([1.0, 0.3], 0.1)
    filt.update([1.9, 2.9], [0.2, -0.9], [0, 1])
    return filt


BAD_CALLS = {
    "nan control": (lambda f: f.predict([math.nan, 0.1], 0.1), ValueError, "control"),
    "inf control": (lambda f: f.predict([1.0, math.inf], 0.1), ValueError, "control"),
    "short control": (lambda f: f.predict([1.0], 0.1), ValueError, "control"),
    "negative dt": (lambda f: f.predict([1.0, 0.1], -0.1), ValueError, "dt"),
    "nan dt": (lambda f: f.predict([1.0, 0.1], math.nan), ValueError, "dt"),
    "negative range": (lambda f: f.update([-1.0, 2.0], [0.1, 0.2], [0, 99]), ValueError, "ranges"),
    "zero range": (lambda f: f.update([0.0], [0.1], [99]), ValueError, "ranges"),
    "nan bearing": (lambda f: f.update([1.0, 2.0], [math.nan, 0.2], [0, 99]), ValueError, "bearings"),
    "fewer bearings": (lambda f: f.update([1.0, 2.0], [0.1], [0, 99]), ValueError, "bearings"),
    "fewer ids": (lambda f: f.update([1.0, 2.0], [0.1, 0.2], [99]), ValueError, "ids"),
    "float ids": (lambda f: f.update([1.0, 2.0], [0.1, 0.2], [0.0, 99.0]), TypeError, "ids"),
    "repeated ids": (lambda f: f.update([1.0, 2.0], [0.1, 0.2], [99, 99]), ValueError, "ids"),
}


@pytest.mark.parametrize("filter_class", FILTERS)
@pytest.mark.parametrize("case", sorted(BAD_CALLS))
def test_bad_input_raises_and_leaves_the_filter_unchanged(filter_class, case):
    call, error, argument = BAD_CALLS[case]
    filt = _started_filter(filter_class)
    before = _snapshot(filt)
    with pytest.raises(error, match=argument):
        call(filt)
    after = _snapshot(filt)
    for name, value in before.items():
        np.testing.assert_array_equal(after[name], value, err_msg=name)
    with pytest.raises(UnknownLandmarkError):
        filt.landmark_covariance(99)
    # and the filter still works
    filt.update([1.0, 2.0], [0.1, 0.2], [0, 99])
    assert filt.num_landmarks == 3


@pytest.mark.parametrize("filter_class", FILTERS)
def test_unknown_option_is_refused(filter_class):
    with pytest.raises(TypeError, match="sparsity"):
        filter_class(VelocityMotionModel(), RangeBearingSensor(), [0.0, 0.0, 0.0], sparsity=4)


@pytest.mark.parametrize("filter_class", [EKF, EIF])
def test_failure_inside_an_update_leaves_the_filter_unchanged(filter_class, monkeypatch):
    filt = _started_filter(filter_class)
    before = _snapshot(filt)

    def broken_jacobian(pose, landmarks):
        raise RuntimeError("sensor failed")

    monkeypatch.setattr(filt.sensor, "jacobian", broken_jacobian)
    with pytest.raises(RuntimeError, match="sensor failed"):
        filt.update([1.9, 4.0], [0.2, 1.0], [0, 99])  # a known and a new landmark
    after = _snapshot(filt)
    for name, value in before.items():
        np.testing.assert_array_equal(after[name], value, err_msg=name)
