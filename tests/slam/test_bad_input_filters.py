"""Bad input to the filters' checked steps gets a clear ValueError and leaves the filter bit-identical.

* ``predict`` with a control or ``dt`` that float64 cannot carry: an increment that overflows, a predicted
  pose covariance that is not positive definite (EKF), or a pose information that differs from its
  closed form ``(G Omega_xx^-1 G^T + R)^-1`` by more than ``PREDICTION_TOLERANCE`` (the SEIF and ESEIF
  lose digits in their ``Phi - kappa`` subtraction; before this check, 1000 m/s left a SEIF whose
  ``pose_covariance`` raised ``LinAlgError`` while ``update`` went on).
* ``update`` with a range beyond the filter's ``max_range`` option (the default, None, checks nothing).

The state compared is every attribute of the filter, its information store and its recovery queue,
arrays raw (spare capacity included), so "unchanged" means bit-identical.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from seif_gym.slam import EIF, EKF, ESEIF, SEIF, RangeBearingSensor, VelocityMotionModel
from seif_gym.slam.base import PREDICTION_TOLERANCE, prediction_error

FILTERS = [SEIF, ESEIF, EKF, EIF]
IMPLEMENTATIONS = {SEIF: ("compiled", "reference"), ESEIF: ("compiled", "reference"), EKF: (None,), EIF: (None,)}
CASES = [(cls, impl) for cls in FILTERS for impl in IMPLEMENTATIONS[cls]]


def raw_state(filt) -> dict[str, object]:
    """Every array (raw bytes, capacity included) and scalar of the filter, its store and its queue."""
    state: dict[str, object] = {}
    owners = [("filter", filt)]
    owners += [
        (name, getattr(filt, attr)) for name, attr in (("store", "_store"), ("queue", "_queue")) if hasattr(filt, attr)
    ]
    for prefix, owner in owners:
        for name, value in vars(owner).items():
            if isinstance(value, np.ndarray):
                state[f"{prefix}.{name}"] = (value.dtype.str, value.shape, value.tobytes())
            elif isinstance(value, (int, float, bool, str, type(None))):
                state[f"{prefix}.{name}"] = value
            elif isinstance(value, dict):
                state[f"{prefix}.{name}"] = repr(value)
    return state


def started(cls, implementation, sensor=None, **options):
    if implementation is not None:
        options["implementation"] = implementation
    filt = cls(VelocityMotionModel(), sensor or RangeBearingSensor(max_range=5.0), [0.5, 0.5, 0.1], **options)
    filt.update([2.0, 3.0], [0.3, -0.8], [0, 1])
    filt.predict([1.0, 0.3], 0.1)
    filt.update([1.9, 2.9], [0.2, -0.9], [0, 1])
    return filt


def assert_refused_unchanged(filt, call, error, match):
    before = raw_state(filt)
    with pytest.raises(error, match=match):
        call(filt)
    after = raw_state(filt)
    changed = [key for key in before if before[key] != after.get(key)]
    assert before.keys() == after.keys() and not changed, f"changed by the refused call: {changed}"


# -- predict --------------------------------------------------------------------------------------------------

#: (control, dt) no filter can carry in float64: the motion model's increment overflows.
OVERFLOWING = {"v 1e200": ((1e200, 0.0), 1.0), "dt 1e300": ((1.0, 0.0), 1e300), "v 1e155": ((1e155, 0.3), 1.0)}
#: (control, dt) the SEIF and the ESEIF cannot carry in information form (the issue's cases).
BEYOND_INFORMATION_FORM = {"v 1000 m/s": ((1000.0, 0.0), 1.0), "dt 1e6": ((1.0, 0.3), 1e6),
                           "100 m in one step": ((100.0, 0.1), 1.0)}  # fmt: skip
NOT_FINITE = {"nan v": ((math.nan, 0.0), 0.1), "inf omega": ((1.0, -math.inf), 0.1), "inf dt": ((1.0, 0.0), math.inf),
              "nan dt": ((1.0, 0.0), math.nan), "zero dt": ((1.0, 0.0), 0.0)}  # fmt: skip


@pytest.mark.parametrize("cls, implementation", CASES)
@pytest.mark.parametrize("case", sorted(OVERFLOWING))
def test_predict_that_overflows_is_refused_naming_control_and_dt(cls, implementation, case):
    control, dt = OVERFLOWING[case]
    filt = started(cls, implementation)
    assert_refused_unchanged(filt, lambda f: f.predict(control, dt), ValueError, r"control \(.*\) and dt .*overflows")
    filt.predict([1.0, 0.3], 0.1)  # and it goes on
    filt.update([1.9, 2.9], [0.2, -0.9], [0, 1])
    assert np.isfinite(filt.pose_covariance).all()


@pytest.mark.parametrize("cls, implementation", CASES)
@pytest.mark.parametrize("case", sorted(NOT_FINITE))
def test_predict_with_non_finite_input_is_refused(cls, implementation, case):
    control, dt = NOT_FINITE[case]
    name = "control" if not all(map(math.isfinite, control)) else "dt"
    assert_refused_unchanged(started(cls, implementation), lambda f: f.predict(control, dt), ValueError, name)


@pytest.mark.parametrize("cls, implementation", [c for c in CASES if c[0] in (SEIF, ESEIF)])
@pytest.mark.parametrize("case", sorted(BEYOND_INFORMATION_FORM))
def test_sparse_filters_refuse_a_step_float64_cannot_carry(cls, implementation, case):
    control, dt = BEYOND_INFORMATION_FORM[case]
    filt = started(cls, implementation)
    assert_refused_unchanged(filt, lambda f: f.predict(control, dt), ValueError,
                             r"control \(.*\) and dt .*closed form.*the filter is unchanged")  # fmt: skip
    # the filter is sound: its covariance factors and it goes on
    assert np.all(np.linalg.eigvalsh(filt.covariance()) > 0)
    filt.predict([1.0, 0.3], 0.1)
    filt.update([1.9, 2.9], [0.2, -0.9], [0, 1])
    assert np.all(np.linalg.eigvalsh(filt.pose_covariance) > 0)


@pytest.mark.parametrize("cls", [EKF, EIF])
@pytest.mark.parametrize("case", sorted(BEYOND_INFORMATION_FORM))
def test_exact_filters_carry_what_the_sparse_ones_refuse(cls, case):
    """The EKF (covariance form) and the EIF (no cancellation in its marginalization) stay sound."""
    control, dt = BEYOND_INFORMATION_FORM[case]
    filt = started(cls, None)
    filt.predict(control, dt)
    assert np.all(np.linalg.eigvalsh(filt.pose_covariance) > 0)
    filt.update([1.9, 2.9], [0.2, -0.9], [0, 1])
    assert np.all(np.linalg.eigvalsh(filt.pose_covariance) > 0)


@pytest.mark.parametrize("cls, implementation", CASES)
def test_ordinary_steps_pass_the_check_and_the_trusted_path_computes_the_same(cls, implementation, ring_loop_run):
    """The check only reads: ``predict`` and ``predict_trusted`` leave bit-identical filters on a real run."""
    motion, sensor, run = ring_loop_run
    options = {} if implementation is None else {"implementation": implementation}
    checked = cls(motion, sensor, run.initial_pose, **options)
    trusted = cls(motion, sensor, run.initial_pose, **options)
    for t in range(60):
        checked.predict(run.controls[t], run.dt)
        trusted.predict_trusted(np.asarray(run.controls[t], dtype=np.float64), run.dt)
        checked.update(run.ranges[t], run.bearings[t], run.ids[t])
        trusted.update(run.ranges[t], run.bearings[t], run.ids[t])
    assert raw_state(checked) == raw_state(trusted)


def test_prediction_error_is_zero_for_the_closed_form_and_large_for_a_wrong_block():
    rng = np.random.default_rng(3)
    a = rng.standard_normal((3, 3))
    old = a @ a.T + 3 * np.eye(3)
    jacobian = np.eye(3) + 0.1 * rng.standard_normal((3, 3))
    noise = np.diag([0.01, 0.02, 0.003])
    exact = np.linalg.inv(jacobian @ np.linalg.inv(old) @ jacobian.T + noise)
    assert prediction_error(old, exact, jacobian, noise) < 1e-12
    assert prediction_error(old, 1.01 * exact, jacobian, noise) == pytest.approx(0.01 * math.sqrt(3))  # ||0.01 I||_F
    assert prediction_error(old, -exact, jacobian, noise) >= 1.0  # not positive definite
    assert prediction_error(old, exact * math.nan, jacobian, noise) == math.inf
    assert PREDICTION_TOLERANCE < 0.01


# -- update beyond max_range ----------------------------------------------------------------------------------


@pytest.mark.parametrize("cls, implementation", CASES)
def test_update_beyond_max_range_is_refused_naming_ranges_and_the_id(cls, implementation):
    filt = started(cls, implementation, max_range=5.5)
    assert_refused_unchanged(filt, lambda f: f.update([2.0, 50.0], [0.1, 0.2], [0, 7]), ValueError,
                             r"ranges: landmark id 7 measured at 50 m, beyond this filter's max_range 5.5 m")  # fmt: skip
    assert 7 not in filt.landmark_ids.tolist()
    filt.update([2.0, 5.4], [0.1, 0.2], [0, 7])  # within range: accepted
    assert 7 in filt.landmark_ids.tolist()


@pytest.mark.parametrize("cls, implementation", CASES)
def test_without_max_range_nothing_is_checked(cls, implementation):
    """The default (None) keeps what every existing caller computes: a far measurement is taken."""
    filt = started(cls, implementation)
    filt.update([2.0, 50.0], [0.1, 0.2], [0, 7])
    assert 7 in filt.landmark_ids.tolist()


@pytest.mark.parametrize("value, error", [(0.0, ValueError), (-1.0, ValueError), (math.inf, ValueError),
                                          (math.nan, ValueError), ("5", TypeError), (True, TypeError)])  # fmt: skip
def test_bad_max_range_option_is_refused(value, error):
    with pytest.raises(error, match="max_range"):
        SEIF(VelocityMotionModel(), RangeBearingSensor(), [0.0, 0.0, 0.0], max_range=value)
