"""The interface shared by every SLAM filter of :mod:`seif_gym.slam`.

:class:`SlamFilter` owns what all filters have in common: option checking,
input validation (done in full *before* any state changes, so a bad call
leaves the filter exactly as it was), and the bookkeeping between external
landmark ids and their order in the state vector. Subclasses implement the
estimation itself in ``_predict`` and ``_update``.
"""

from __future__ import annotations

import copy
import math
from abc import ABC, abstractmethod
from typing import Any, ClassVar

import numpy as np
import scipy.sparse
from numpy.typing import ArrayLike, NDArray

from seif_gym.slam.models import MotionModel, RangeBearingSensor, wrap_angle
from seif_gym.slam.noise_models import mahalanobis_squared
from seif_gym.type_aliases import FloatArray
from seif_gym.validation import (
    as_covariance,
    as_finite_array,
    as_finite_vector,
    as_id_array,
    as_positive_scalar,
)

__all__ = [
    "SlamFilter",
    "PREDICTION_TOLERANCE",
    "prediction_error",
    "InformationForm",
    "SparseInformationForm",
    "UnknownLandmarkError",
    "DEFAULT_INITIAL_POSE_COV",
    "COMMON_OPTIONS",
]


#: Initial pose covariance when none is given: the map frame is anchored at the
#: initial pose, so it is known almost exactly (a tiny variance keeps the
#: information matrix finite).
DEFAULT_INITIAL_POSE_COV: FloatArray = np.diag([1e-6, 1e-6, 1e-6])
DEFAULT_INITIAL_POSE_COV.setflags(write=False)


#: Options every filter takes beside its own ``OPTIONS`` (see :class:`SlamFilter`).
COMMON_OPTIONS: dict[str, Any] = {"innovation_gate": None, "max_range": None}

#: The largest relative error, in any direction, of the pose information a checked ``predict`` computes
#: (:func:`prediction_error`) that it accepts: at least six significant digits must survive the step.
PREDICTION_TOLERANCE = 1e-6


def prediction_error(
    old_information: FloatArray, new_information: FloatArray, jacobian: FloatArray, noise: FloatArray
) -> float:
    r"""Relative error of a motion step's pose information against its closed form, in the worst direction.

    Parameters
    ----------
    old_information, new_information : ndarray, shape (3, 3)
        ``Omega_xx`` (the pose's information given the map) before the step, and as the filter computed it after.
    jacobian, noise : ndarray, shape (3, 3)
        The step's ``G`` and ``R``.

    Returns
    -------
    float
        ``||C^T Omega'_xx C - I||_F`` with ``C C^T = P``: 0 when the computed ``Omega'_xx`` is exact, at
        least ``max_k |lambda_k - 1|`` over the eigenvalues of ``C^T Omega'_xx C`` (so at least 1 when
        ``Omega'_xx`` is not positive definite), ``inf`` when anything is not finite or ``P`` cannot be
        factored.

    Notes
    -----
    Given the map, the pose moves as ``x' = g(x, u) + w`` with ``w ~ N(0, R)``, so its information given
    the map after the step is exactly

    .. math:: \Omega'_{xx} = P^{-1}, \qquad P = G\, \Omega_{xx}^{-1} G^T + R,

    a 3 x 3 computation with no cancellation. An information filter's motion update reaches
    ``Omega'_xx`` by subtracting two large matrices (Probabilistic Robotics, Table 12.2: ``Phi - kappa``),
    which loses digits as ``G`` grows; this measures what is left, in constant time, as the relative
    error in every direction at once.
    """
    try:
        predicted = jacobian @ np.linalg.solve(old_information, jacobian.T) + noise
        factor = np.linalg.cholesky(predicted + predicted.T) * _SQRT_HALF  # of the symmetrized P
    except np.linalg.LinAlgError:
        return float("inf")
    scaled = factor.T @ new_information @ factor - _EYE3
    error = math.sqrt(float(np.vdot(scaled, scaled)))
    return error if math.isfinite(error) else float("inf")


_SQRT_HALF = math.sqrt(0.5)
_EYE3 = np.eye(3)
_EYE3.setflags(write=False)


def _check_max_range(max_range: Any) -> float | None:
    """``max_range``: None, or a positive finite bound on the ranges :meth:`SlamFilter.update` accepts."""
    if max_range is None:
        return None
    if isinstance(max_range, bool) or not isinstance(max_range, (int, float, np.integer, np.floating)):
        raise TypeError(f"max_range must be a positive number or None, got {type(max_range).__name__}")
    if not (np.isfinite(max_range) and float(max_range) > 0.0):
        raise ValueError(f"max_range must be positive and finite, got {max_range!r}")
    return float(max_range)


def _check_gate(gate: Any) -> float | None:
    """``innovation_gate``: None, or a positive threshold on the squared Mahalanobis distance."""
    if gate is None:
        return None
    if isinstance(gate, bool) or not isinstance(gate, (int, float, np.integer, np.floating)):
        raise TypeError(f"innovation_gate must be a positive number or None, got {type(gate).__name__}")
    if not float(gate) > 0.0:  # inf allowed: distances reported, nothing rejected
        raise ValueError(f"innovation_gate must be positive, got {gate!r}")
    return float(gate)


#: Landmark capacity the dense filters (EKF, EIF) allocate at construction; it doubles when exceeded.
INITIAL_LANDMARK_CAPACITY = 8


def symmetrized(matrix: FloatArray) -> FloatArray:
    """``(A + A^T) / 2`` as a new array (never in place: ``A.T`` aliases ``A``)."""
    return 0.5 * (matrix + matrix.T)


def merge_dense_rows(matrix: FloatArray, vectors: tuple[FloatArray, ...], dim: int, keep: int, remove: int) -> None:
    """``P^T M P`` and ``P^T v`` in place on a dense state matrix, then swap-remove ``remove``.

    ``matrix`` (an information matrix, or any array whose rows and columns
    follow the state) gets landmark ``remove``'s rows and columns added to
    landmark ``keep``'s; each of ``vectors`` gets its entries added likewise.
    Then the last landmark's rows, columns and entries move into ``remove``'s
    place and the last two of ``dim`` are zeroed. ``vectors`` may be empty.
    """
    a, b = 3 + 2 * keep, 3 + 2 * remove
    matrix[a : a + 2, :dim] += matrix[b : b + 2, :dim]
    matrix[:dim, a : a + 2] += matrix[:dim, b : b + 2]
    for vector in vectors:
        vector[a : a + 2] += vector[b : b + 2]
    swap_remove_dense(matrix, vectors, dim, remove)


def swap_remove_dense(matrix: FloatArray, vectors: tuple[FloatArray, ...], dim: int, remove: int) -> None:
    """Move the last landmark's rows and columns (and entries of ``vectors``) into ``remove``'s; zero the last."""
    b, last = 3 + 2 * remove, dim - 2
    if b != last:
        matrix[b : b + 2, :dim] = matrix[last:dim, :dim]
        matrix[:dim, b : b + 2] = matrix[:dim, last:dim]
        for vector in vectors:
            vector[b : b + 2] = vector[last:dim]
    matrix[last:dim, :dim] = 0.0
    matrix[:dim, last:dim] = 0.0
    for vector in vectors:
        vector[last:dim] = 0.0


class UnknownLandmarkError(KeyError, ValueError):
    """Raised when a landmark id is not in the filter's map."""

    def __str__(self) -> str:  # KeyError quotes its message; show it plainly
        return str(self.args[0]) if self.args else ""


class InformationForm(ABC):
    """The information-form interface: a filter that keeps ``Omega`` and ``xi`` (EIF, SEIF, ESEIF).

    What the env (``reward="information"``) and the renderer (the ``Omega`` panel, cheap ellipses)
    read of such a filter; an EKF is not one. ``isinstance(filt, InformationForm)`` asks.
    """

    @property
    @abstractmethod
    def information_matrix(self) -> scipy.sparse.csr_array:
        """``Omega`` in state order (robot, then landmarks)."""

    @property
    @abstractmethod
    def information_vector(self) -> FloatArray:
        """``xi`` in state order, shape (3 + 2n,)."""


class SparseInformationForm(InformationForm):
    """An information filter whose robot is linked only to a bounded set of *active* landmarks (SEIF, ESEIF)."""

    #: The bound ``k`` on the active landmarks (``None``: no bound).
    max_active: int | None

    @property
    @abstractmethod
    def active_landmarks(self) -> NDArray[np.int64]:
        """Ids of the landmarks linked to the robot, shape (a,)."""


class SlamFilter(ABC):
    r"""Base class of the SLAM filters (``EKF``, ``EIF``, ``SEIF``, ...).

    Parameters
    ----------
    motion : MotionModel
        Provides ``linearize(pose, control, dt) -> (delta, G, R)`` and
        ``validate_control``; :class:`~seif_gym.slam.models.VelocityMotionModel`
        or the Victoria Park car model.
    sensor : RangeBearingSensor
        Provides ``noise_covariance`` (2, 2) and the range-bearing model. A
        sensor with ``range_dependent = True`` (such as
        :class:`~seif_gym.slam.noise_models.RangeDependentSensor`) gives each
        measurement its own ``Q`` through ``measurement_covariances(ranges)``.
    initial_pose : array_like, shape (3,)
        ``(x, y, theta)`` of the robot at time 0.
    initial_pose_cov : array_like, shape (3, 3), optional
        Its covariance; defaults to :data:`DEFAULT_INITIAL_POSE_COV`.
    **options
        Filter-specific options, listed in the subclass's ``OPTIONS``, and
        the options every filter takes (:data:`COMMON_OPTIONS`):
        ``innovation_gate`` (float or None, default None), a threshold on the
        squared Mahalanobis distance of a measurement's innovation; see
        Notes; ``max_range`` (float or None, default None), the farthest
        range :meth:`update` accepts: a measurement beyond it raises
        ``ValueError`` (a sensor's noise carries its readings a little past
        its nominal ``max_range``, so give it a margin, for example
        ``sensor.max_range + 5 * sensor.sigma_range``; None checks nothing).
        An unknown option raises ``TypeError``.

    Attributes
    ----------
    gated_measurements : int
        Measurements rejected by the innovation gate so far.
    last_gated_ids : ndarray of int64
        Ids of the measurements the gate rejected in the last update.
    last_mahalanobis : ndarray of float64
        ``d^2`` of each measurement of the last update (in the order given;
        NaN for a landmark not yet in the map); empty without a gate.

    Notes
    -----
    *Innovation gate.* With ``innovation_gate = g``, each measurement ``z_i``
    of a landmark already in the map is tested before the update against the
    current belief: with ``nu_i = wrap(z_i - h(mu))``,
    ``S_i = H_i Sigma_i H_i^T + Q_i`` (``Sigma_i`` the joint covariance of the
    pose and landmark ``i`` from :meth:`local_joint_covariance`: exact for the
    EKF and the EIF, the constant-time Markov blanket for the SEIF and the
    ESEIF) and

    .. math:: d_i^2 = \nu_i^T S_i^{-1} \nu_i,

    a measurement with ``d_i^2 > g`` is rejected (left out of the update and
    reported in the attributes above). ``d_i^2`` is chi-square with 2 degrees
    of freedom for a consistent filter: ``g = 13.8`` rejects 0.1 % of good
    measurements. ``g = inf`` reports the distances and rejects nothing. A
    landmark seen for the first time cannot be tested. Rejecting is not a
    failure: the rest of the update goes on; an update that fails leaves the
    attributes as they were.
    """

    #: Option names and defaults of the subclass.
    OPTIONS: ClassVar[dict[str, Any]] = {}

    def __init__(
        self,
        motion: MotionModel,
        sensor: RangeBearingSensor,
        initial_pose: ArrayLike,
        initial_pose_cov: ArrayLike | None = None,
        **options: Any,
    ) -> None:
        if not callable(getattr(motion, "linearize", None)) or not callable(getattr(motion, "validate_control", None)):
            raise TypeError(
                f"motion must provide linearize(pose, control, dt) and validate_control(control), "
                f"got {type(motion).__name__}"
            )
        noise = getattr(sensor, "noise_covariance", None)
        if noise is None or np.shape(noise) != (2, 2):
            raise TypeError(
                f"sensor must be a range-bearing sensor with a (2, 2) noise_covariance, got {type(sensor).__name__}"
            )
        unknown = sorted(set(options) - set(self.OPTIONS) - set(COMMON_OPTIONS))
        if unknown:
            valid = ", ".join([*self.OPTIONS, *COMMON_OPTIONS])
            raise TypeError(
                f"{type(self).__name__} got unknown option(s) {', '.join(map(repr, unknown))}; valid options: {valid}"
            )
        gate = _check_gate(options.get("innovation_gate"))
        self.max_range: float | None = _check_max_range(options.get("max_range"))
        pose = as_finite_vector(initial_pose, "initial_pose", 3).copy()
        pose[2] = wrap_angle(float(pose[2]))
        cov = (
            DEFAULT_INITIAL_POSE_COV
            if initial_pose_cov is None
            else as_covariance(initial_pose_cov, "initial_pose_cov", 3)
        )
        self.motion = motion
        self.sensor = sensor
        # the inputs are validated here once; the models' unchecked paths skip a second check
        self._linearize = getattr(motion, "linearize_trusted", motion.linearize)
        self._measurement_cov: FloatArray = np.array(noise, dtype=np.float64)
        self._measurement_info: FloatArray = np.asarray(np.linalg.inv(self._measurement_cov), dtype=np.float64)
        self._range_noise = bool(getattr(sensor, "range_dependent", False))
        if self._range_noise and not callable(getattr(sensor, "measurement_covariances", None)):
            raise TypeError(
                f"sensor is range_dependent but has no measurement_covariances(ranges), got {type(sensor).__name__}"
            )
        self.innovation_gate: float | None = gate
        self.gated_measurements = 0
        self.last_gated_ids: NDArray[np.int64] = np.empty(0, dtype=np.int64)
        self.last_mahalanobis: FloatArray = np.empty(0)
        self._id_to_index: dict[int, int] = {}
        self._ids: NDArray[np.int64] = np.zeros(16, dtype=np.int64)
        self.options: dict[str, Any] = {**self.OPTIONS, **options}
        self._check_options(self.options)
        self._initialize(pose, np.array(cov, dtype=np.float64))

    # -- hooks for subclasses ------------------------------------------------
    def _check_options(self, options: dict[str, Any]) -> None:  # noqa: B027 (optional hook: no options by default)
        """Validate ``options`` (raise ``TypeError``/``ValueError``)."""

    @abstractmethod
    def _initialize(self, pose: FloatArray, pose_cov: FloatArray) -> None:
        """Set up the state for a robot at ``pose`` with covariance ``pose_cov``."""

    @abstractmethod
    def _predict(self, control: FloatArray, dt: float, verify: bool = False) -> None:
        """Motion update with validated inputs.

        With ``verify``, the step checks what it computes (:meth:`_check_motion`, and for an information
        form :meth:`_check_pose_information`) and raises ``ValueError`` with the filter unchanged when
        float64 cannot carry it.
        """

    @abstractmethod
    def _update(
        self, ranges: FloatArray, bearings: FloatArray, indices: NDArray[np.int64], is_new: NDArray[np.bool_]
    ) -> None:
        """Measurement update with validated inputs.

        ``indices`` are state orders of the observed landmarks; the ones with
        ``is_new`` were appended to the id table just before the call and must
        be added to the state (initialised from their measurement).
        """

    # -- public interface ----------------------------------------------------
    def predict(self, control: ArrayLike, dt: float) -> None:
        """Motion update with ``control = (v, omega)`` applied for ``dt`` seconds.

        Raises
        ------
        ValueError
            If ``control`` or ``dt`` is not finite (``dt`` not positive), or if the step is beyond what the
            filter can compute in float64: its increment, Jacobian or noise overflow, the predicted pose
            covariance (EKF) is not positive definite, or the pose information an information filter
            computes differs from its closed form by more than :data:`PREDICTION_TOLERANCE`
            (:func:`prediction_error`). The filter is then unchanged.
        """
        control = self.motion.validate_control(control)
        dt = as_positive_scalar(dt, "dt")
        self._predict(control, dt, verify=True)

    def update(self, ranges: ArrayLike, bearings: ArrayLike, ids: ArrayLike) -> None:
        """Measurement update with known correspondences.

        Parameters
        ----------
        ranges, bearings : array_like, shape (m,)
            Measured ranges (positive) and bearings (radians, robot frame).
        ids : array_like of int, shape (m,)
            External landmark ids, distinct. An id not yet in the map adds a
            landmark, initialised from its measurement.
        """
        ranges, bearings, ids = self.validate_measurements(ranges, bearings, ids)
        self._check_ranges(ranges, ids)
        self.update_trusted(ranges, bearings, ids)

    def _check_ranges(self, ranges: FloatArray, ids: NDArray[np.int64]) -> None:
        """Refuse ranges beyond the ``max_range`` option (nothing to check without one)."""
        if self.max_range is None:
            return
        beyond = np.flatnonzero(ranges > self.max_range)
        if len(beyond):
            k = int(beyond[0])
            raise ValueError(
                f"ranges: landmark id {int(ids[k])} measured at {float(ranges[k]):g} m, beyond this filter's "
                f"max_range {self.max_range:g} m ({len(beyond)} of {len(ranges)} measurements beyond it)"
            )

    def predict_trusted(self, control: FloatArray, dt: float) -> None:
        """:meth:`predict` without input checks, for simulators whose controls are valid by construction."""
        self._predict(control, float(dt))

    # -- checks of a motion step (``predict``; never the trusted path) -----------------------------
    @staticmethod
    def _refuse_motion(control: FloatArray, dt: float, reason: str) -> None:
        raise ValueError(
            f"control {tuple(float(c) for c in control)} and dt {dt:g}: {reason}; the filter is unchanged "
            f"(split the step into shorter ones, or check the units)"
        )

    def _check_motion(self, control: FloatArray, dt: float, delta: FloatArray, jacobian: FloatArray,
                      noise: FloatArray) -> None:  # fmt: skip
        """Refuse a step whose increment, Jacobian or noise is not finite (float64 overflow)."""
        if not (np.isfinite(delta).all() and np.isfinite(jacobian).all() and np.isfinite(noise).all()):
            self._refuse_motion(control, dt, "the motion model's increment, Jacobian or noise overflows float64")

    def _check_pose_information(self, control: FloatArray, dt: float, old_information: FloatArray,
                                new_information: FloatArray, jacobian: FloatArray, noise: FloatArray) -> None:  # fmt: skip
        """Refuse a step whose computed pose information is off its closed form by more than the tolerance."""
        error = prediction_error(old_information, new_information, jacobian, noise)
        if not error <= PREDICTION_TOLERANCE:
            self._refuse_motion(
                control,
                dt,
                f"the predicted pose information differs from its closed form (G Omega_xx^-1 G^T + R)^-1 by "
                f"{error:.1e} (relative; tolerance {PREDICTION_TOLERANCE:g}): float64 cannot carry this step "
                f"in information form",
            )

    def update_trusted(self, ranges: FloatArray, bearings: FloatArray, ids: NDArray[np.int64]) -> None:
        """:meth:`update` without input checks (float64 ranges > 0, bearings, distinct int64 ids).

        Applies the innovation gate (class Notes) when the filter has one.
        """
        if self.innovation_gate is None or len(ids) == 0:
            self._update_known(ranges, bearings, ids)
            return
        distances = self.innovation_distances_trusted(ranges, bearings, ids)
        rejected = distances > self.innovation_gate  # NaN (a new landmark) is never rejected
        if rejected.any():
            kept = ~rejected
            self._update_known(ranges[kept], bearings[kept], ids[kept])
        else:
            self._update_known(ranges, bearings, ids)
        # reported only once the update has gone through
        self.gated_measurements += int(np.count_nonzero(rejected))
        self.last_gated_ids = ids[rejected].astype(np.int64)
        self.last_gated_ids.setflags(write=False)
        distances.setflags(write=False)
        self.last_mahalanobis = distances

    def innovation_distances(self, ranges: ArrayLike, bearings: ArrayLike, ids: ArrayLike) -> FloatArray:
        """Squared Mahalanobis distance ``d^2`` of each measurement's innovation (class Notes), shape (m,).

        NaN for a landmark not in the map. Changes nothing; costs what
        :meth:`local_joint_covariance` costs (constant time for the SEIF).
        """
        ranges, bearings, ids = self.validate_measurements(ranges, bearings, ids)
        return self.innovation_distances_trusted(ranges, bearings, ids)

    def innovation_distances_trusted(
        self, ranges: FloatArray, bearings: FloatArray, ids: NDArray[np.int64]
    ) -> FloatArray:
        """:meth:`innovation_distances` without input checks."""
        distances = np.full(len(ids), np.nan)
        index = np.array([self._id_to_index.get(i, -1) for i in ids.tolist()], dtype=np.int64)
        mapped = np.flatnonzero(index >= 0)
        if len(mapped) == 0:
            return distances
        indices = index[mapped]
        joint = self.local_joint_covariance(indices)  # (3 + 2k) over the pose and these landmarks
        mean = self._mean_vector()
        pose = mean[:3].copy()
        landmarks = mean[3 + 2 * indices[:, None] + np.arange(2)]
        jacobians = self.sensor.jacobian(pose, landmarks)  # (k, 2, 5)
        innovations = np.column_stack([ranges[mapped], bearings[mapped]]) - self.sensor.predict(pose, landmarks)
        innovations[:, 1] = wrap_angle(innovations[:, 1])
        rows = np.empty((len(indices), 5), dtype=np.int64)
        rows[:, :3] = np.arange(3)
        rows[:, 3:] = 3 + 2 * np.arange(len(indices))[:, None] + np.arange(2)
        blocks = joint[rows[:, :, None], rows[:, None, :]]  # (k, 5, 5): pose and landmark i
        covariances = np.einsum("kac,kcd,kbd->kab", jacobians, blocks, jacobians) + self._noise_covariances(
            ranges[mapped]
        )
        distances[mapped] = mahalanobis_squared(innovations, covariances)
        return distances

    def _noise_covariances(self, ranges: FloatArray) -> FloatArray:
        """``Q_i`` of each measurement, shape (m, 2, 2)."""
        if self._range_noise:
            return np.asarray(self.sensor.measurement_covariances(ranges), dtype=np.float64)
        return np.broadcast_to(self._measurement_cov, (len(ranges), 2, 2))

    def _noise_informations(self, ranges: FloatArray) -> FloatArray | None:
        """``Q_i^-1`` of each measurement (m, 2, 2) for a range-dependent sensor; None when all share ``Q``."""
        if not self._range_noise:
            return None
        return np.asarray(np.linalg.inv(self._noise_covariances(ranges)), dtype=np.float64)

    def _update_known(self, ranges: FloatArray, bearings: FloatArray, ids: NDArray[np.int64]) -> None:
        """The update with the measurements the gate kept: new ids appended, then :meth:`_update`."""
        if len(ids) == 0:
            self._update(ranges, bearings, np.empty(0, np.int64), np.empty(0, bool))
            return
        indices = np.empty(len(ids), dtype=np.int64)
        is_new = np.zeros(len(ids), dtype=bool)
        n = len(self._id_to_index)
        for k, landmark_id in enumerate(ids.tolist()):
            index = self._id_to_index.get(landmark_id)
            if index is None:
                is_new[k] = True
                index = n
                n += 1
            indices[k] = index
        new_ids = ids[is_new]
        # a failed update must leave the id table bit-identical too (also its spare capacity)
        saved_ids = (self._ids, self._ids[n - len(new_ids) : n].copy())
        if len(new_ids):
            self._append_ids(new_ids)
        try:
            self._update(ranges, bearings, indices, is_new)
        except BaseException:
            self._remove_last_ids(len(new_ids))
            self._ids = saved_ids[0]
            self._ids[n - len(new_ids) : n] = saved_ids[1]
            raise

    @staticmethod
    def validate_measurements(
        ranges: ArrayLike, bearings: ArrayLike, ids: ArrayLike
    ) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
        """Check a measurement set; returns float64 ranges, bearings and int64 ids."""
        ranges = as_finite_array(ranges, "ranges", (None,))
        bearings = as_finite_array(bearings, "bearings", (None,))
        if bearings.shape != ranges.shape:
            raise ValueError(f"bearings must have the same length as ranges ({len(ranges)}), got {len(bearings)}")
        ids = as_id_array(ids, "ids", len(ranges))
        if np.any(ranges <= 0.0):
            raise ValueError(f"ranges must be positive, got {ranges[ranges <= 0.0]}")
        if len(ids) > 1 and len(set(ids.tolist())) != len(ids):
            raise ValueError("ids must be distinct within one update")
        return ranges, bearings, ids

    # -- id bookkeeping ------------------------------------------------------
    def _append_ids(self, new_ids: NDArray[np.int64]) -> None:
        n = len(self._id_to_index)
        if n + len(new_ids) > len(self._ids):
            grown = np.zeros(max(2 * len(self._ids), n + len(new_ids)), dtype=np.int64)
            grown[:n] = self._ids[:n]
            self._ids = grown
        self._ids[n : n + len(new_ids)] = new_ids
        for offset, landmark_id in enumerate(new_ids.tolist()):
            self._id_to_index[landmark_id] = n + offset

    def _remove_last_ids(self, count: int) -> None:
        n = len(self._id_to_index)
        for landmark_id in self._ids[n - count : n].tolist():
            del self._id_to_index[landmark_id]

    def merge_landmarks(self, keep_id: int | np.integer, remove_id: int | np.integer) -> None:
        r"""Declare two mapped landmarks one and the same: condition on ``m_keep = m_remove``, drop ``remove_id``.

        The data association's way of taking back a duplicate: a landmark
        started for a measurement of one already in the map (for example at a
        loop closure the filter was too confident to accept) is folded into
        the old one once the evidence shows they coincide
        (:class:`~seif_gym.slam.association.Associator`, ``loop_merge``).

        Parameters
        ----------
        keep_id, remove_id : int
            Ids of two distinct mapped landmarks. ``keep_id`` stays;
            ``remove_id`` leaves the map and the landmark last in the state
            order takes its place (:meth:`landmark_index` changes for that one).

        Notes
        -----
        The constraint is linear, so the merge is exact for the belief: with
        ``P`` the map from the reduced state to the full one that copies
        ``m_keep`` into ``m_remove`` (Thrun et al., IJRR 2004, the SEIF's
        correspondence merge),

        .. math:: \Omega' = P^T \Omega P, \qquad \xi' = P^T \xi,

        which adds ``m_remove``'s rows and columns of ``Omega`` and ``xi`` into
        ``m_keep``'s. In covariance form (the EKF) the same belief is the
        conditioning on the noise-free measurement ``m_remove - m_keep = 0``
        followed by the marginalization of ``m_remove``. Fails with the filter
        untouched, like an update.
        """
        i, j = self.landmark_index(keep_id), self.landmark_index(remove_id)
        if i == j:
            raise ValueError(f"keep_id and remove_id must name different landmarks, got {keep_id!r} twice")
        self._merge(i, j)
        # id bookkeeping: the last landmark takes the removed one's place in the state order
        last = self.num_landmarks - 1
        last_id = int(self._ids[last])
        del self._id_to_index[int(remove_id)]
        if j != last:
            self._ids[j] = last_id
            self._id_to_index[last_id] = j

    @abstractmethod
    def _merge(self, keep: int, remove: int) -> None:
        """:meth:`merge_landmarks` on state orders (``remove`` then swap-removed); atomic."""

    def landmark_index(self, landmark_id: int | np.integer) -> int:
        """Order of landmark ``landmark_id`` in the state (0 for the first landmark)."""
        if isinstance(landmark_id, bool) or not isinstance(landmark_id, (int, np.integer)):
            raise TypeError(f"landmark_id must be an integer, got {type(landmark_id).__name__}")
        index = self._id_to_index.get(int(landmark_id))
        if index is None:
            raise UnknownLandmarkError(f"landmark_id {landmark_id} is not in the map")
        return index

    def __deepcopy__(self, memo: dict[int, Any]) -> SlamFilter:
        """A deep copy, equal to what the generic ``copy.deepcopy`` makes.

        The id → index map holds only ints, so a new dict of its items is its
        deep copy (the generic walk would visit its items one call at a time,
        and planners such as ``info_gain`` copy the filter once per candidate
        arc). Every other attribute is deep-copied.
        """
        copied = type(self).__new__(type(self))
        memo[id(self)] = copied
        for name, value in self.__dict__.items():
            copied.__dict__[name] = dict(value) if name == "_id_to_index" else copy.deepcopy(value, memo)
        return copied

    # -- read-only belief ----------------------------------------------------
    @property
    def num_landmarks(self) -> int:
        """Number of landmarks in the map."""
        return len(self._id_to_index)

    @property
    def landmark_ids(self) -> NDArray[np.int64]:
        """External ids of the mapped landmarks, in state order, shape (n,)."""
        ids = self._ids[: self.num_landmarks].copy()
        ids.setflags(write=False)
        return ids

    @property
    def state_dim(self) -> int:
        """Length of the state vector ``3 + 2 n``."""
        return 3 + 2 * self.num_landmarks

    @property
    def mean(self) -> FloatArray:
        """Full state mean ``(x, y, theta, m1x, m1y, ...)``, shape (3 + 2n,)."""
        mean = self._mean_vector().copy()
        mean.setflags(write=False)
        return mean

    @property
    def pose(self) -> FloatArray:
        """Estimated robot pose ``(x, y, theta)``, shape (3,)."""
        pose = self._mean_vector()[:3].copy()
        pose.setflags(write=False)
        return pose

    @property
    def landmarks(self) -> FloatArray:
        """Estimated landmark positions in the order of :attr:`landmark_ids`, shape (n, 2)."""
        landmarks = self._mean_vector()[3:].reshape(-1, 2).copy()
        landmarks.setflags(write=False)
        return landmarks

    @property
    def pose_covariance(self) -> FloatArray:
        """Marginal covariance of the pose, shape (3, 3)."""
        cov = self._marginal_covariance(np.arange(3))
        cov.setflags(write=False)
        return cov

    def landmark_covariance(self, landmark_id: int | np.integer) -> FloatArray:
        """Marginal covariance of landmark ``landmark_id``, shape (2, 2)."""
        index = self.landmark_index(landmark_id)
        cov = self._marginal_covariance(np.array([3 + 2 * index, 4 + 2 * index]))
        cov.setflags(write=False)
        return cov

    def local_marginals(self, landmark_indices: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Pose covariance (3, 3) and covariances (k, 2, 2) of the landmarks at ``landmark_indices``.

        ``landmark_indices`` are state orders (``landmark_index(id)``). Exact
        marginals for the EKF and the EIF; the SEIF overrides this with its
        constant-time Markov-blanket approximation. Meant for per-step
        consumers such as the env's observation and data association.
        """
        return self.local_marginals_trusted(self._check_landmark_indices(landmark_indices))

    def local_marginals_trusted(self, indices: NDArray[np.int64]) -> tuple[FloatArray, FloatArray]:
        """:meth:`local_marginals` without input checks (valid, distinct int64 state orders)."""
        pose_cov = self._marginal_covariance(np.arange(3))
        covs = np.empty((len(indices), 2, 2))
        for k, index in enumerate(indices.tolist()):
            covs[k] = self._marginal_covariance(np.array([3 + 2 * index, 4 + 2 * index]))
        return pose_cov, covs

    def local_joint_covariance(self, landmark_indices: ArrayLike) -> FloatArray:
        """Joint covariance (3 + 2k, 3 + 2k) of the pose and the landmarks at ``landmark_indices``.

        Ordered ``(x, y, theta, m_i1x, m_i1y, ...)``, cross-covariances
        included (what data association needs for ``H Sigma H^T + Q``).
        Exact here (the EKF slices it); the SEIF overrides it with its
        constant-time Markov-blanket version.
        """
        indices = self._check_landmark_indices(landmark_indices)
        state = np.concatenate([np.arange(3), (3 + 2 * indices[:, None] + np.arange(2)).ravel()]).astype(np.int64)
        return self._marginal_covariance(state)

    def _check_landmark_indices(self, landmark_indices: ArrayLike) -> NDArray[np.int64]:
        indices = np.asarray(landmark_indices)
        if indices.ndim != 1 or (indices.size and not np.issubdtype(indices.dtype, np.integer)):
            raise TypeError(f"landmark_indices must be a 1-D array of integers, got {indices.dtype} {indices.shape}")
        indices = indices.astype(np.int64, copy=False)
        if len(indices) and (int(indices.min()) < 0 or int(indices.max()) >= self.num_landmarks):
            raise ValueError(f"landmark_indices must lie in [0, {self.num_landmarks}), got {indices}")
        return indices

    def landmark_std(self) -> FloatArray:
        """One uncertainty per landmark, ``sqrt(trace)`` of its 2x2 covariance, shape (n,).

        Exact marginals for the EKF and the EIF; the SEIF's constant-time
        version uses each landmark's own information block (a lower bound).
        """
        variances = self._marginal_variances()[3:]
        return np.sqrt(variances[0::2] + variances[1::2])

    def _marginal_variances(self) -> FloatArray:
        """Diagonal of the covariance, shape (3 + 2n,)."""
        return np.diag(self._full_covariance()).copy()

    def covariance(self) -> FloatArray:
        """The full dense covariance (3 + 2n, 3 + 2n).

        For tests and evaluation only: it costs O(n^3) for the information
        filters and is never used in a filter step.
        """
        return self._full_covariance()

    @property
    def memory_bytes(self) -> int:
        """Bytes held by the filter's state arrays (capacity included)."""
        return self._state_nbytes() + self._ids.nbytes

    @abstractmethod
    def _mean_vector(self) -> FloatArray: ...

    @abstractmethod
    def _marginal_covariance(self, state_indices: NDArray[np.int64]) -> FloatArray: ...

    @abstractmethod
    def _full_covariance(self) -> FloatArray: ...

    @abstractmethod
    def _state_nbytes(self) -> int: ...

    def __repr__(self) -> str:
        options = ", ".join(f"{k}={v!r}" for k, v in self.options.items())
        return f"{type(self).__name__}(landmarks={self.num_landmarks}{', ' if options else ''}{options})"
