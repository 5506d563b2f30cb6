"""Copies of a SEIF rolled forward under the measurements they expect: a planner's look-ahead.

For each of ``c`` constant controls ``u_k``, a copy of the filter is advanced
``horizon`` steps; each step is

1. the motion update with ``u_k`` for ``dt`` seconds (:func:`~seif_gym.slam.seif.motion_update`);
   the pose estimate after it is ``poses[k, t]``;
2. the update (measurement update, mean recovery, sparsification, as
   :meth:`SEIF.update <seif_gym.slam.seif.SEIF.update>` runs them) with the
   noise-free measurements the sensor model predicts,
   ``z_i = (|m_i - p|, wrap(atan2(m_iy - p_y, m_ix - p_x) - p_theta))``
   (:meth:`RangeBearingSensor.predict_trusted
   <seif_gym.slam.models.RangeBearingSensor.predict_trusted>`), from the
   predicted pose ``p`` to the estimate ``m_i`` of every mapped landmark *at the
   start of the rollout*, for the landmarks with ``0 < r_i <= max_range`` and,
   when the field of view is narrower than a full turn, ``|phi_i| <= fov / 2``.
   The sensor's blind zone (``min_range``) is not applied: the look-ahead keeps
   a landmark the robot would pass too close to. A step without such a
   landmark is an update with no measurement (recovery and sparsification
   still run).

At the end, each copy gives its pose covariance from the Markov blanket
(``local_marginals``) and its landmarks' conditional standard deviations
(``landmark_std``).

:func:`expected_rollouts` runs every copy of a :class:`~seif_gym.slam.seif.SEIF`
or an :class:`~seif_gym.slam.eseif.ESEIF` (wavefront recovery, compiled
implementation, no innovation gate, one measurement covariance, Thrun's
velocity motion model) in compiled code: the copies are rows of arrays with a
leading copy axis (:class:`~seif_gym.slam.batched.BatchedSEIF`'s layout),
advanced step by step for all copies at once by
:func:`seif_gym.slam._kernels.rollout_step` with the kernels the filters run,
without the journal that lets a filter undo a failed step (a scratch copy is
thrown away) and with no Python object per copy. Any other filter goes
through :func:`expected_rollouts_reference`, which deep-copies the filter once
per control and calls its ``predict_trusted`` and ``update_trusted``. Both give the same numbers, bit for bit
(``tests/slam/test_rollout.py``): the compiled path computes every value with the
same operations in the same order, and leaves the angles ``atan2`` to numpy,
whose vectorised ``arctan2`` can round differently from the C library's.
Neither changes the filter given.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from seif_gym.slam import _kernels
from seif_gym.slam.base import SlamFilter
from seif_gym.slam.eseif import ESEIF, RELOCALIZATION_RCOND
from seif_gym.slam.models import RangeBearingSensor, VelocityMotionModel
from seif_gym.slam.seif import SEIF
from seif_gym.type_aliases import FloatArray
from seif_gym.validation import as_count, as_finite_array, as_positive_scalar

__all__ = [
    "Rollouts",
    "expected_rollouts",
    "expected_rollouts_trusted",
    "expected_rollouts_reference",
    "compiled_rollouts_support",
]


@dataclass(frozen=True)
class Rollouts:
    """What :func:`expected_rollouts` gives for ``c`` controls over ``horizon`` steps of ``n`` landmarks.

    Attributes
    ----------
    poses : ndarray, shape (c, horizon, 3)
        ``poses[k, t]``: copy ``k``'s pose estimate after the motion update of step ``t``.
    pose_covariances : ndarray, shape (c, 3, 3)
        Each copy's pose covariance at the end (``local_marginals`` with no landmark).
    landmark_std : ndarray, shape (c, n)
        Each copy's ``landmark_std()`` at the end.
    """

    poses: FloatArray
    pose_covariances: FloatArray
    landmark_std: FloatArray


def compiled_rollouts_support(filt: SlamFilter) -> str | None:
    """``None`` if :func:`expected_rollouts` rolls ``filt`` in compiled code, else the reason why not."""
    if type(filt) not in (SEIF, ESEIF):
        return f"a {type(filt).__name__} (only a SEIF or an ESEIF)"
    assert isinstance(filt, SEIF)
    options = filt.options
    if options["mean_recovery"] != "wavefront" or options["implementation"] != "compiled":
        return f"mean_recovery={options['mean_recovery']!r}, implementation={options['implementation']!r}"
    if filt.innovation_gate is not None:
        return "an innovation gate"
    if type(filt.motion) is not VelocityMotionModel:
        return f"a {type(filt.motion).__name__} motion model (only a VelocityMotionModel)"
    if type(filt.sensor) is not RangeBearingSensor or getattr(filt.sensor, "range_dependent", False):
        return f"a {type(filt.sensor).__name__} sensor (only a RangeBearingSensor)"
    return None


def _check(filt: SlamFilter, controls: ArrayLike, dt: float, horizon: int) -> tuple[FloatArray, float, int]:
    if not isinstance(filt, SlamFilter):
        raise TypeError(f"filt must be a SlamFilter, got {type(filt).__name__}")
    controls = as_finite_array(controls, "controls", (None, 2))
    if len(controls) == 0:
        raise ValueError("controls must hold at least one (v, omega) row")
    for control in controls:
        filt.motion.validate_control(control)
    return (np.ascontiguousarray(controls, dtype=np.float64), float(as_positive_scalar(dt, "dt")),
            as_count(horizon, "horizon", minimum=1))  # fmt: skip


def expected_rollouts(filt: SlamFilter, controls: ArrayLike, dt: float, horizon: int) -> Rollouts:
    """Roll a copy of ``filt`` ``horizon`` steps under each of ``controls`` (module docstring).

    Parameters
    ----------
    filt : SlamFilter
        The belief; left unchanged.
    controls : array_like, shape (c, 2)
        ``(v, omega)`` of each copy, held for the whole horizon.
    dt : float
        Seconds per step.
    horizon : int
        Steps (at least 1).

    Returns
    -------
    Rollouts

    Raises
    ------
    TypeError
        If ``filt`` is not a filter.
    ValueError
        If ``controls``, ``dt`` or ``horizon`` is invalid.
    """
    controls, dt, horizon = _check(filt, controls, dt, horizon)
    return expected_rollouts_trusted(filt, controls, dt, horizon)


def expected_rollouts_trusted(filt: SlamFilter, controls: FloatArray, dt: float, horizon: int) -> Rollouts:
    """:func:`expected_rollouts` without input checks (C-contiguous float64 controls the motion model accepts)."""
    if compiled_rollouts_support(filt) is not None:
        return _reference(filt, controls, dt, horizon)
    assert isinstance(filt, SEIF)
    return _compiled(filt, controls, dt, horizon)


def expected_rollouts_reference(filt: SlamFilter, controls: ArrayLike, dt: float, horizon: int) -> Rollouts:
    """:func:`expected_rollouts` by deep copies of ``filt`` and its own steps (any filter; slow)."""
    controls, dt, horizon = _check(filt, controls, dt, horizon)
    return _reference(filt, controls, dt, horizon)


def _reference(filt: SlamFilter, controls: FloatArray, dt: float, horizon: int) -> Rollouts:
    sensor = filt.sensor
    n = filt.num_landmarks
    ids = np.array(filt.landmark_ids, dtype=np.int64)
    landmarks = np.array(filt.landmarks, dtype=np.float64)
    half_fov = 0.5 * float(sensor.fov)
    poses = np.empty((len(controls), horizon, 3))
    pose_covariances = np.empty((len(controls), 3, 3))
    landmark_std = np.empty((len(controls), n))
    empty_f, empty_i = np.empty(0), np.empty(0, dtype=np.int64)
    for k, control in enumerate(controls):
        copied = copy.deepcopy(filt)
        for t in range(horizon):
            copied.predict_trusted(control, dt)
            pose = np.array(copied.pose, dtype=np.float64)
            poses[k, t] = pose
            if n:
                z = sensor.predict_trusted(pose, landmarks)
                visible = (z[:, 0] > 0.0) & (z[:, 0] <= sensor.max_range)
                if half_fov < math.pi:
                    visible &= np.abs(z[:, 1]) <= half_fov
                if visible.any():
                    copied.update_trusted(z[visible, 0].copy(), z[visible, 1].copy(), ids[visible])
                    continue
            copied.update_trusted(empty_f, empty_f, empty_i)
        pose_covariances[k] = copied.local_marginals(empty_i)[0]
        if n:
            landmark_std[k] = copied.landmark_std()
    return Rollouts(poses, pose_covariances, landmark_std)


# -- the compiled path ------------------------------------------------------------------------------
#: Neighbour slots each landmark's list gets beyond the most any uses now (more are added when needed).
_SPARE_DEGREE = 64


class _Copies:
    """``c`` copies of a SEIF's state in arrays with a leading copy axis (:class:`BatchedSEIF`'s layout).

    Landmark ``i``'s id is ``i`` (the state order): the rollout never adds a landmark. The neighbour
    lists hold ``degree`` slots, grown by :meth:`grow` when a step needs more.
    """

    def __init__(self, filt: SEIF, count: int) -> None:
        store = filt._store
        n = store.num_landmarks
        cap = max(n, 1)
        used = int(store.neighbour_count[:n].max()) if n else 0
        degree = max(min(used + _SPARE_DEGREE, n - 1), used, 1)
        c = count
        self.robot_info = np.empty((c, 3, 3))
        self.robot_info[:] = store.robot_info
        self.robot_links = np.empty((c, cap, 3, 2))
        self.robot_links[:, :n] = store.robot_links[:n]
        self.landmark_info = np.empty((c, cap, 2, 2))
        self.landmark_info[:, :n] = store.landmark_info[:n]
        self.neighbour_index = np.empty((c, cap, degree), dtype=np.int64)
        self.neighbour_index[:, :n, :used] = store.neighbour_index[:n, :used]
        self.neighbour_info = np.empty((c, cap, degree, 2, 2))
        self.neighbour_info[:, :n, :used] = store.neighbour_info[:n, :used]
        self.neighbour_count = np.empty((c, cap), dtype=np.int64)
        self.neighbour_count[:, :n] = store.neighbour_count[:n]
        dim = 3 + 2 * n
        self.information_vector = np.empty((c, dim))
        self.information_vector[:] = store.information_vector[:dim]
        self.mean = np.empty((c, dim))
        self.mean[:] = store.mean[:dim]
        self.block_position = np.full((c, cap), -1, dtype=np.int64)
        active = filt._active
        self.active = np.empty((c, cap), dtype=np.int64)
        self.active[:, : len(active)] = active
        self.is_active = np.empty((c, cap), dtype=bool)
        self.is_active[:, :n] = filt._is_active[:n]
        self.last_observed = np.empty((c, cap), dtype=np.int64)
        self.last_observed[:, :n] = filt._last_observed[:n]
        self.counters = np.empty((c, 4), dtype=np.int64)
        self.counters[:] = (n, len(active), filt._update_count, filt._round_robin)
        self.id_to_index = np.empty((c, cap), dtype=np.int64)
        self.id_to_index[:] = np.arange(cap)
        self.ids = np.empty((c, cap), dtype=np.int64)  # written only for a new landmark: never
        ordered = filt._queue.ordered()  # the FIFO's order is all the recovery reads of it
        self.queue = np.empty((c, cap), dtype=np.int64)
        self.queue[:, : len(ordered)] = ordered
        self.queued = np.empty((c, cap), dtype=bool)
        self.queued[:, :n] = filt._queue.queued[:n]
        self.queue_state = np.zeros((c, 2), dtype=np.int64)
        self.queue_state[:, 1] = len(ordered)
        self.eseif_counters = np.zeros((c, 3), dtype=np.int64)

    def grow(self, degree: int) -> None:
        """Room for ``degree`` neighbours per landmark (the slots in use kept)."""
        index = np.empty(self.neighbour_index.shape[:2] + (degree,), dtype=np.int64)
        info = np.empty(self.neighbour_info.shape[:2] + (degree, 2, 2))
        old = self.neighbour_index.shape[2]
        index[:, :, :old] = self.neighbour_index
        info[:, :, :old] = self.neighbour_info
        self.neighbour_index, self.neighbour_info = index, info

    def arrays(self) -> tuple[np.ndarray, ...]:
        """The arrays in the order of :func:`~seif_gym.slam._kernels.rollout_step`."""
        return (self.robot_info, self.robot_links, self.landmark_info, self.neighbour_index, self.neighbour_info,
                self.neighbour_count, self.information_vector, self.mean, self.block_position, self.active,
                self.counters, self.is_active, self.last_observed, self.id_to_index, self.ids, self.queue,
                self.queued, self.queue_state, self.eseif_counters)  # fmt: skip


def _compiled(filt: SEIF, controls: FloatArray, dt: float, horizon: int) -> Rollouts:
    count = len(controls)
    n = filt.num_landmarks
    copies = _Copies(filt, count)
    motion = filt.motion
    assert isinstance(motion, VelocityMotionModel)
    sensor = filt.sensor
    landmarks = np.array(filt.landmarks, dtype=np.float64)
    landmark_x, landmark_y = landmarks[:, 0].copy(), landmarks[:, 1].copy()
    eseif = isinstance(filt, ESEIF)
    options = (
        np.array(motion.alphas, dtype=np.float64), float(motion.noise_floor), np.array(filt._measurement_info),
        np.array(filt._measurement_cov), eseif, -1 if filt.max_active is None else filt.max_active,
        filt.relocalization_landmarks if isinstance(filt, ESEIF) else 0,
        filt.split_weight if isinstance(filt, ESEIF) else 0.5, RELOCALIZATION_RCOND, filt.recovery_landmarks,
        filt.recovery_budget, filt.recovery_relaxation, filt.recovery_tolerance, landmark_x, landmark_y,
        float(sensor.max_range), 0.5 * float(sensor.fov),
    )  # fmt: skip
    dx, dy = np.empty((count, n)), np.empty((count, n))
    angle = dx
    poses = np.empty((count, horizon, 3))
    pose_covariances = np.empty((count, 3, 3))
    landmark_std = np.empty((count, n))
    for t in range(horizon + 1):
        if t > 0 and n:
            angle = np.arctan2(dy, dx)  # numpy's, as RangeBearingSensor.predict_trusted's
        start = 0
        while start >= 0:
            start, degree = _kernels.rollout_step(t, start, horizon, *copies.arrays(), controls, dt, *options, dx, dy,
                                                  angle, poses, pose_covariances, landmark_std)  # fmt: skip
            if start >= 0:
                copies.grow(min(max(degree, 2 * copies.neighbour_index.shape[2]), max(n - 1, 1)))
    return Rollouts(poses, pose_covariances, landmark_std)
