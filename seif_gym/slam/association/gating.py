"""Gating of measurement-landmark pairs: candidate search, innovations and their covariances, chi-square limits.

Steps 1 to 3 of the algorithm of :mod:`seif_gym.slam.association`, and the pieces of step 5
(:func:`conditional_loglik`): the compiled candidate search and per-pair Mahalanobis distances, the
innovations and Jacobians of a scan's pairs, their joint covariance, and the cached chi-square bounds.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import scipy.stats
from numba import njit

from seif_gym.slam._kernels import range_bearing_jacobian
from seif_gym.type_aliases import FloatArray, IntArray

__all__ = ["conditional_loglik", "joint_innovation_covariance", "pair_innovations"]


@njit(cache=True)
def _candidates(landmarks: FloatArray, points: FloatArray, radii: FloatArray) -> tuple[IntArray, IntArray, FloatArray]:
    """Pairs ``(i, j)`` with ``|landmarks[j] - points[i]| < radii[i]``, and that squared distance.

    Two passes (count, then fill) over all landmarks: ``O(n m)`` for ``n`` landmarks and ``m`` points.
    """
    m = points.shape[0]
    n = landmarks.shape[0]
    count = 0
    for i in range(m):
        px = points[i, 0]
        py = points[i, 1]
        r2 = radii[i] * radii[i]
        for j in range(n):
            dx = landmarks[j, 0] - px
            dy = landmarks[j, 1] - py
            if dx * dx + dy * dy < r2:
                count += 1
    meas = np.empty(count, dtype=np.int64)
    cand = np.empty(count, dtype=np.int64)
    dist2 = np.empty(count)
    k = 0
    for i in range(m):
        px = points[i, 0]
        py = points[i, 1]
        r2 = radii[i] * radii[i]
        for j in range(n):
            dx = landmarks[j, 0] - px
            dy = landmarks[j, 1] - py
            e2 = dx * dx + dy * dy
            if e2 < r2:
                meas[k] = i
                cand[k] = j
                dist2[k] = e2
                k += 1
    return meas, cand, dist2


@njit(cache=True)
def _pair_distances(
    pose: FloatArray,
    landmarks: FloatArray,
    joint: FloatArray,
    noise: FloatArray,
    ranges: FloatArray,
    bearings: FloatArray,
    pair_meas: IntArray,
    pair_slot: IntArray,
) -> tuple[FloatArray, FloatArray]:
    """Mahalanobis distance and ``ln det S`` of each (measurement, candidate) pair.

    Pair ``k`` is measurement ``pair_meas[k]`` and the candidate in slot
    ``s = pair_slot[k]``: mean ``landmarks[s]``, rows ``3 + 2 s`` and ``4 + 2 s``
    of ``joint`` (the covariance of the pose and the candidates).
    """
    count = pair_meas.shape[0]
    d2 = np.empty(count)
    logdet = np.empty(count)
    x = pose[0]
    y = pose[1]
    theta = pose[2]
    H = np.zeros((2, 5))
    P = np.empty((5, 5))
    rows = np.empty(5, dtype=np.int64)
    rows[0] = 0
    rows[1] = 1
    rows[2] = 2
    for k in range(count):
        i = pair_meas[k]
        s = pair_slot[k]
        mx = landmarks[s, 0]
        my = landmarks[s, 1]
        dx = mx - x
        dy = my - y
        q = range_bearing_jacobian(dx, dy, H)
        sq = math.sqrt(q)
        rows[3] = 3 + 2 * s
        rows[4] = 4 + 2 * s
        for a in range(5):
            for b in range(5):
                P[a, b] = joint[rows[a], rows[b]]
        S = H @ P @ H.T
        s00 = S[0, 0] + noise[0, 0]
        s01 = 0.5 * (S[0, 1] + S[1, 0]) + noise[0, 1]
        s11 = S[1, 1] + noise[1, 1]
        det = s00 * s11 - s01 * s01
        nu0 = ranges[i] - sq
        nu1 = (bearings[i] - (math.atan2(dy, dx) - theta) + math.pi) % (2.0 * math.pi) - math.pi
        d2[k] = (s11 * nu0 * nu0 - 2.0 * s01 * nu0 * nu1 + s00 * nu1 * nu1) / det
        logdet[k] = math.log(det)
    return d2, logdet


def pair_innovations(
    pose: FloatArray,
    landmarks: FloatArray,
    ranges: FloatArray,
    bearings: FloatArray,
    pair_meas: IntArray,
    pair_slot: IntArray,
) -> tuple[FloatArray, FloatArray]:
    """Innovations ``nu`` (K, 2) and Jacobians ``H`` (K, 2, 5) of (measurement, candidate) pairs.

    Pair ``k`` is measurement ``pair_meas[k]`` and the landmark ``landmarks[pair_slot[k]]``; ``H``'s
    columns are ``(x, y, theta, m_x, m_y)`` (:class:`~seif_gym.slam.models.RangeBearingSensor`), the bearing
    innovation is wrapped.
    """
    d = landmarks[pair_slot] - pose[:2]
    q = np.einsum("ki,ki->k", d, d)
    sq = np.sqrt(q)
    dx, dy = d[:, 0], d[:, 1]
    H = np.zeros((len(pair_meas), 2, 5))
    H[:, 0, 0], H[:, 0, 1], H[:, 0, 3], H[:, 0, 4] = -dx / sq, -dy / sq, dx / sq, dy / sq
    H[:, 1, 0], H[:, 1, 1], H[:, 1, 2], H[:, 1, 3], H[:, 1, 4] = dy / q, -dx / q, -1.0, -dy / q, dx / q
    nu = np.empty((len(pair_meas), 2))
    nu[:, 0] = ranges[pair_meas] - sq
    nu[:, 1] = (bearings[pair_meas] - (np.arctan2(dy, dx) - pose[2]) + np.pi) % (2.0 * np.pi) - np.pi
    return nu, H


def joint_innovation_covariance(
    H: FloatArray, pair_slot: IntArray, pair_meas: IntArray, joint: FloatArray, noise: FloatArray
) -> FloatArray:
    """Covariance ``(2K, 2K)`` of the innovations of K pairs: ``H P H^T`` plus ``Q`` within a measurement.

    ``joint`` is the covariance of the pose and the candidates (slot ``s`` at rows ``3 + 2 s, 4 + 2 s``).
    Two pairs of one measurement share its noise ``Q`` (they are never in one hypothesis).
    """
    count = len(pair_slot)
    dense = np.zeros((2 * count, joint.shape[0]))
    rows = np.arange(2 * count).reshape(count, 2)
    dense[rows, :3] = H[:, :, :3]  # (K, 2, 3) into rows, the pose columns
    cols = 3 + 2 * pair_slot
    dense[rows[:, :, None], np.stack([cols, cols + 1], axis=1)[:, None, :]] = H[:, :, 3:]
    cov = dense @ joint @ dense.T
    same = pair_meas[:, None] == pair_meas[None, :]
    cov += np.kron(same, noise)
    return 0.5 * (cov + cov.T)


@functools.lru_cache(maxsize=4096)
def _chi2_limit(probability: float, dof: int) -> float:
    """``scipy.stats.chi2.ppf(probability, dof)``, cached (the joint gate's bound per hypothesis size)."""
    return float(scipy.stats.chi2.ppf(probability, dof))


def conditional_loglik(nu: FloatArray, cov: FloatArray, pairs: IntArray) -> FloatArray:
    """``ln p(nu_k | nu_(H - k))`` of each pair ``k`` of hypothesis ``pairs`` (Gaussian, 2 dof).

    With ``Lambda = S_H^-1``: conditional covariance ``Lambda_kk^-1`` and residual
    ``Lambda_kk^-1 (Lambda nu)_k``.
    """
    idx = np.array([2 * p + a for p in pairs for a in (0, 1)], dtype=np.int64)
    precision = np.linalg.inv(cov[np.ix_(idx, idx)])
    weighted = (precision @ nu[pairs].reshape(-1)).reshape(-1, 2)
    out = np.empty(len(pairs))
    for t in range(len(pairs)):
        block = precision[2 * t : 2 * t + 2, 2 * t : 2 * t + 2]
        d2 = float(weighted[t] @ np.linalg.solve(block, weighted[t]))
        out[t] = -0.5 * (d2 - math.log(np.linalg.det(block)) + 2.0 * math.log(2.0 * math.pi))
    return out
