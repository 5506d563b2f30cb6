"""Scores of a SLAM estimate against the truth: the one home of every metric seif_gym reports.

==========================  =====================================================================
name                        what it is
==========================  =====================================================================
:func:`map_error`           ``E_t``, the env's map error: mean over all true landmarks of the
                            capped position error, an unmapped landmark counted as ``d_cap``
:func:`filter_map_error`    :func:`map_error` of a filter's map (with the associator's audit
                            when correspondences are unknown)
:func:`pose_nees`           NEES of poses (heading error wrapped), batched: ``χ²(3)``, mean 3
:func:`nees`                NEES ``eᵀ P⁻¹ e`` of one error vector by a LAPACK Cholesky solve
:func:`map_nees`            joint NEES of the mapped landmarks, global and relative (anchor-free)
:data:`CHI2_95_2DOF`        95 % quantile of ``χ²(2)``: the landmark and pose ellipses
:data:`CHI2_975_3DOF`       97.5 % quantile of ``χ²(3)``: the upper bound of a consistent pose NEES
==========================  =====================================================================

The compiled kernels :func:`map_error_kernel` and :func:`nees_kernel` are
what the env computes in every step (and the vector env inside its own
compiled loop); :func:`map_error` and :func:`nees` are their checked
counterparts for Python callers.

Three NEES computations live here, one per caller's need, and they agree to
rounding (about ``1e-12`` relative), not bit for bit: the env's per-step
``info["pose_nees"]`` (:func:`nees_kernel`, a compiled Cholesky of the
``3 × 3`` block, callable from other kernels), the batched :func:`pose_nees`
(``numpy.linalg.solve`` over any leading axes) and the joint NEES of up to
``3 + 2n`` dimensions (:func:`nees`, LAPACK). Each caller keeps the one it
has always used, so that every number seif_gym has published is reproduced
bit for bit.

Examples
--------
>>> import numpy as np
>>> from seif_gym.metrics import map_error, pose_nees
>>> truth = np.array([[0.0, 0.0], [3.0, 4.0]])
>>> map_error(np.array([[0.0, 0.5]]), truth, np.array([0]), d_cap=2.0)  # (0.5 + 2) / 2
1.25
>>> float(pose_nees([1.0, 0.0, 0.0], [0.0, 0.0, 0.0], np.eye(3)))
1.0
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import scipy.linalg
from numba import njit
from numpy.typing import ArrayLike, NDArray

from seif_gym.slam.models import wrap_angle
from seif_gym.type_aliases import FloatArray
from seif_gym.validation import as_positive_scalar

if TYPE_CHECKING:  # annotations only
    from seif_gym.slam.association import AssociationAudit
    from seif_gym.slam.base import SlamFilter

__all__ = [
    "CHI2_95_2DOF",
    "CHI2_975_3DOF",
    "MIN_RELATIVE_LANDMARKS",
    "map_error",
    "filter_map_error",
    "map_error_kernel",
    "nees",
    "nees_kernel",
    "pose_nees",
    "map_nees",
]


#: 95 % quantile of the chi-square distribution with 2 degrees of freedom
#: (``scipy.stats.chi2.ppf(0.95, 2)``, exactly; tested): 95 % ellipses.
CHI2_95_2DOF: float = 5.991464547107979
#: 97.5 % quantile of the chi-square distribution with 3 degrees of freedom
#: (``scipy.stats.chi2.ppf(0.975, 3)``, exactly; tested).
CHI2_975_3DOF: float = 9.348403604496148
#: The relative map NEES needs at least this many mapped landmarks (one anchor and one more).
MIN_RELATIVE_LANDMARKS: int = 2


# -- map error ------------------------------------------------------------------------------------
@njit(cache=True)
def map_error_kernel(  # pragma: no cover - compiled
    estimates: FloatArray, truth: FloatArray, ids: NDArray[np.int64], d_cap: float
) -> float:
    """Compiled :func:`map_error` (unchecked: ``estimates`` (m, 2) C-contiguous float64, ``ids`` int64)."""
    total = d_cap * (truth.shape[0] - ids.shape[0])
    for k in range(ids.shape[0]):
        dx = estimates[k, 0] - truth[ids[k], 0]
        dy = estimates[k, 1] - truth[ids[k], 1]
        total += min(np.sqrt(dx * dx + dy * dy), d_cap)
    return total / truth.shape[0]


def _map_error(estimates: ArrayLike, truth: FloatArray, ids: ArrayLike, d_cap: float) -> float:
    """:func:`map_error` without the checks (the env's per-step path)."""
    return float(map_error_kernel(np.ascontiguousarray(estimates, dtype=np.float64), truth,
                                  np.asarray(ids, dtype=np.int64), float(d_cap)))  # fmt: skip


def map_error(estimates: ArrayLike, truth: ArrayLike, ids: ArrayLike, d_cap: float) -> float:
    """``E_t``: the mean over all true landmarks of ``min(error, d_cap)``, unmapped ones counted as ``d_cap``.

    Parameters
    ----------
    estimates : array_like, shape (m, 2)
        Estimated positions of the mapped landmarks.
    truth : array_like, shape (n, 2)
        True positions of all landmarks (``n ≥ 1``).
    ids : array_like of int, shape (m,)
        Row of ``truth`` of each estimate.
    d_cap : float
        Cap of one landmark's error, metres (positive).

    Returns
    -------
    float
        Metres.

    Raises
    ------
    ValueError
        If a shape is wrong, ``d_cap`` is not positive or an id is out of range.
    TypeError
        If ``d_cap`` is not a number.
    """
    estimates = np.ascontiguousarray(estimates, dtype=np.float64)
    if estimates.size == 0:
        estimates = estimates.reshape(0, 2)
    truth = np.ascontiguousarray(truth, dtype=np.float64)
    ids = np.asarray(ids)
    if truth.ndim != 2 or truth.shape[1] != 2 or truth.shape[0] < 1:
        raise ValueError(f"truth must have shape (n, 2) with n >= 1, got {truth.shape}")
    if estimates.ndim != 2 or estimates.shape[1] != 2:
        raise ValueError(f"estimates must have shape (m, 2), got {estimates.shape}")
    if ids.shape != (estimates.shape[0],) or (ids.size and ids.dtype.kind not in "iu"):
        raise ValueError(f"ids must be {estimates.shape[0]} integers (one per estimate), got shape {ids.shape} "
                         f"of {ids.dtype}")  # fmt: skip
    if ids.size and (ids.min() < 0 or ids.max() >= truth.shape[0]):
        raise ValueError(f"ids must lie in [0, {truth.shape[0]}), got {ids.min()} .. {ids.max()}")
    return _map_error(estimates, truth, ids, as_positive_scalar(d_cap, "d_cap"))


def filter_map_error(filt: SlamFilter, truth: FloatArray, d_cap: float, audit: AssociationAudit | None = None) -> float:
    """:func:`map_error` of ``filt``'s map (``E_t`` of the env's reward).

    Parameters
    ----------
    filt : SlamFilter
        Its ``landmarks`` and ``landmark_ids`` are scored.
    truth : ndarray, shape (n, 2)
        True positions of all landmarks.
    d_cap : float
        Cap of one landmark's error, metres.
    audit : AssociationAudit, optional
        With unknown correspondences the filter's landmarks carry the
        associator's ids: each is matched to the true landmark it was
        created from, and only the first landmark made for a true one
        counts (duplicates do not reduce the error).

    Returns
    -------
    float
        Metres.
    """
    ids, estimates = filt.landmark_ids, filt.landmarks
    if audit is not None:
        true = audit.true_ids(ids)
        _, first = np.unique(true, return_index=True)
        keep = first[true[first] >= 0]
        ids, estimates = true[keep], estimates[keep]
    return _map_error(estimates, truth, ids, d_cap)


# -- NEES -----------------------------------------------------------------------------------------
@njit(cache=True)
def nees_kernel(error: FloatArray, covariance: FloatArray) -> float:  # pragma: no cover - compiled
    """Compiled ``eᵀ P⁻¹ e`` by a Cholesky solve; ``inf`` if ``P`` is not positive definite (unchecked)."""
    n = error.shape[0]
    lower = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1):
            value = covariance[i, j]
            for k in range(j):
                value -= lower[i, k] * lower[j, k]
            if i == j:
                if value <= 0.0:
                    return np.inf
                lower[i, i] = np.sqrt(value)
            else:
                lower[i, j] = value / lower[j, j]
    total = 0.0
    y = np.zeros(n)
    for i in range(n):
        value = error[i]
        for k in range(i):
            value -= lower[i, k] * y[k]
        y[i] = value / lower[i, i]
        total += y[i] * y[i]
    return total


def _nees(error: FloatArray, covariance: FloatArray) -> float:
    """:func:`nees` without the checks."""
    try:
        lower = scipy.linalg.cholesky(covariance, lower=True, check_finite=False)
    except (np.linalg.LinAlgError, ValueError):
        return math.inf
    y = scipy.linalg.solve_triangular(lower, error, lower=True, check_finite=False)
    return float(y @ y)


def _as_error_and_covariance(error: ArrayLike, covariance: ArrayLike) -> tuple[FloatArray, FloatArray]:
    error = np.asarray(error, dtype=np.float64)
    covariance = np.asarray(covariance, dtype=np.float64)
    if error.ndim != 1 or error.size == 0:
        raise ValueError(f"error must be a non-empty vector, got shape {error.shape}")
    if covariance.shape != (error.size, error.size):
        raise ValueError(f"covariance must have shape {(error.size, error.size)}, got {covariance.shape}")
    if not (np.all(np.isfinite(error)) and np.all(np.isfinite(covariance))):
        raise ValueError("error and covariance must be finite")
    return error, covariance


def nees(error: ArrayLike, covariance: ArrayLike) -> float:
    """Normalised estimation error squared ``eᵀ P⁻¹ e`` by a Cholesky solve.

    Parameters
    ----------
    error : array_like, shape (d,)
        Truth minus estimate (wrap angles yourself; :func:`pose_nees` does).
    covariance : array_like, shape (d, d)
        The estimate's covariance ``P`` (symmetric).

    Returns
    -------
    float
        ``χ²(d)``-distributed for a consistent estimate (mean ``d``);
        ``inf`` if ``P`` is not positive definite.

    Raises
    ------
    ValueError
        If the shapes do not match or a value is not finite.
    """
    return _nees(*_as_error_and_covariance(error, covariance))


def pose_nees(true_pose: ArrayLike, est_pose: ArrayLike, cov: ArrayLike) -> FloatArray | float:
    """Normalized estimation error squared of poses, heading error wrapped.

    ``e = true - est`` with ``e_theta`` wrapped to ``[-pi, pi)``, and
    ``NEES = e^T cov^-1 e``. For a consistent filter it is chi-square
    distributed with 3 degrees of freedom (mean 3).

    Parameters
    ----------
    true_pose, est_pose : array_like, shape (..., 3)
    cov : array_like, shape (..., 3, 3)
        Estimated pose covariances (symmetric positive definite).

    Returns
    -------
    float or ndarray, shape (...)
        A float for single poses.

    Raises
    ------
    ValueError
        If the shapes do not match.
    """
    true_pose = np.asarray(true_pose, dtype=np.float64)
    est_pose = np.asarray(est_pose, dtype=np.float64)
    cov = np.asarray(cov, dtype=np.float64)
    if true_pose.shape[-1:] != (3,) or est_pose.shape != true_pose.shape or cov.shape != true_pose.shape + (3,):
        raise ValueError(
            f"expected poses of shape (..., 3) and covariances (..., 3, 3), got {true_pose.shape}, "
            f"{est_pose.shape} and {cov.shape}"
        )
    error = true_pose - est_pose
    error[..., 2] = wrap_angle(error[..., 2])
    value = np.einsum("...i,...i->...", error, np.linalg.solve(cov, error[..., None])[..., 0])
    return float(value) if value.ndim == 0 else value


def map_nees(truth: ArrayLike, estimate: ArrayLike, covariance: ArrayLike) -> tuple[float, float]:
    """Joint NEES of the mapped landmarks: ``(global, relative)``.

    Parameters
    ----------
    truth, estimate : array_like, shape (m, 2)
        True and estimated positions of the ``m ≥ 1`` mapped landmarks, in
        the same order.
    covariance : array_like, shape (2m, 2m)
        Their joint covariance (the map block of the filter's exact
        covariance), in the same order.

    Returns
    -------
    global_nees : float
        ``e_Lᵀ Σ_L⁻¹ e_L``, ``2m`` dof.
    relative_nees : float
        The joint NEES of ``d_i = m_i − m_0`` (``i = 1 .. m−1``),
        ``dᵀ (A Σ_L Aᵀ)⁻¹ d`` with ``A`` the difference operator: ``2(m−1)``
        dof, the same for any anchor or spanning tree of pairs (they are
        invertible linear maps of each other), so it scores the map's shape
        with the common translation removed. ``nan`` for fewer than
        :data:`MIN_RELATIVE_LANDMARKS` landmarks.

    Raises
    ------
    ValueError
        If the shapes do not match.
    """
    truth = np.asarray(truth, dtype=np.float64)
    estimate = np.asarray(estimate, dtype=np.float64)
    covariance = np.asarray(covariance, dtype=np.float64)
    if truth.ndim != 2 or truth.shape[1] != 2 or truth.shape[0] < 1 or estimate.shape != truth.shape:
        raise ValueError(f"truth and estimate must have the same shape (m, 2), m >= 1, got {truth.shape} and "
                         f"{estimate.shape}")  # fmt: skip
    m = len(truth)
    if covariance.shape != (2 * m, 2 * m):
        raise ValueError(f"covariance must have shape {(2 * m, 2 * m)}, got {covariance.shape}")
    return _map_nees(truth, estimate, covariance)


def _map_nees(truth: FloatArray, estimate: FloatArray, cov: FloatArray) -> tuple[float, float]:
    """:func:`map_nees` without the checks."""
    error = (truth - estimate).reshape(-1)
    global_nees = _nees(error, cov)
    m = len(truth)
    if m < MIN_RELATIVE_LANDMARKS:
        return global_nees, math.nan
    # d_i = m_i - m_0 for i >= 1: A = [-1 | I] per coordinate
    relative_error = error[2:] - np.tile(error[:2], m - 1)
    c00, c0r, crr = cov[:2, :2], cov[:2, 2:], cov[2:, 2:]
    tiled = np.tile(c0r, (m - 1, 1))  # rows: (m-1)*2 copies of the anchor's cross-covariance
    relative_cov = crr - tiled - tiled.T + np.tile(c00, (m - 1, m - 1))
    return global_nees, _nees(relative_error, 0.5 * (relative_cov + relative_cov.T))
