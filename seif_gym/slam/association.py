"""Maximum-likelihood data association for unknown correspondences.

:class:`Associator` turns one scan of range-bearing measurements into
landmark ids for any filter of :mod:`seif_gym.slam` (EKF, EIF, SEIF, …):
an id already in the map (the measurement is of that landmark), a fresh id
(a new landmark), or ``-1`` (ambiguous: the measurement is discarded).

Algorithm, per scan (Probabilistic Robotics, sections 10.3 and 12.7)
--------------------------------------------------------------------
1. **Candidates.** Each measurement ``z_i = (r_i, phi_i)`` is projected into
   the map at the estimated pose, ``p_i = (x + r_i cos(phi_i + theta), ...)``.
   Mapped landmarks within ``candidate_radius + 3 (sqrt(lambda_max(Sigma_xy))
   + r_i sigma_theta)`` of ``p_i`` are its candidates (a compiled linear scan
   over the landmark means, ``O(n m)`` for ``n`` landmarks and ``m``
   measurements).
2. **Innovation covariances.** One joint covariance ``P`` of the pose and all
   candidates of the scan comes from the filter's ``local_joint_covariance``:
   exact for the EKF/EIF; for the SEIF the Markov-blanket block (robot, its
   active landmarks, the candidates and their neighbours in ``Omega``, all
   or the ``n`` most strongly linked of each: ``neighbours``), factorised on
   its own, never a dense inverse of ``Omega`` (section 12.7). The block,
   and so the cost, is bounded whatever the size of the map.
   For each (measurement, candidate) pair, with the Jacobian ``H`` of the
   range-bearing model over ``(x, y, theta, m_x, m_y)``::

       nu  = z_i - h(mu_x, mu_j)      (bearing wrapped)
       S   = H P_[x,j] H^T + Q
       d2  = nu^T S^-1 nu             (Mahalanobis distance, 2 dof)

   With signatures (e.g. the trunk diameters of Victoria Park), the
   difference between the measured signature and the landmark's running
   mean over its ``c_j`` measurements adds a third term
   ``(s_i - s_j)^2 / (sigma_s(r_i)^2 (1 + 1/c_j))``, with
   ``sigma_s(r)^2 = signature_sigma^2 + (signature_per_metre r)^2``, and a
   third degree of freedom.
3. **Gate** (``gate`` probability of the chi-square distribution with 2, or
   3, dof): pairs with ``d2`` above it are impossible.
4. **Joint compatibility** (Neira & Tardos 2001, :func:`jcbb`). The
   individually best assignment (``scipy.optimize.linear_sum_assignment`` on
   ``d2 + ln det S``, mutual exclusion) seeds a branch and bound over all
   gated pairs of the scan: the hypothesis with the most pairings whose
   *joint* Mahalanobis distance (joint innovation covariance of all its
   pairings, :func:`joint_innovation_covariance`) passes the ``joint_gate``
   chi-square bound with ``2 |H|`` dof; ties go to the smallest joint
   ``d2 + ln det S``. Budget ``max_nodes`` per scan. With
   ``joint_objective="likelihood"`` the hypothesis maximises instead
   ``sum_k (-ln 2 pi - ln lambda_k) - (d2_H + ln det S_H) / 2``, its
   log-likelihood ratio against "every measurement of it is an unmapped
   landmark" (``lambda_k`` the density of step 5): counting pairings takes two
   unmapped trees that fall inside the gates of two old landmarks over the one
   old landmark really in view.
5. **Pairing or new landmark** (loop closure). For each pairing of the
   hypothesis, its likelihood given the others (:func:`conditional_loglik`)
   is compared with the likelihood that the measurement is an unmapped
   landmark: ``landmark_density * r`` (per unit of range and bearing), times
   the probability that such a landmark lies more than ``landmark_separation``
   from the paired one, times ``(1 - detection)^c`` where ``c`` counts the
   scans that had the measurement's cell well inside their footprint
   (:class:`CoverageGrid`: an unmapped landmark there would have been seen).
   The worst pairing below is dropped, repeatedly. A lone pairing with a
   landmark mapped a loop ago (large ``S``) is not enough evidence; several
   coherent ones are (their conditional covariances are small).
6. **Lone loop closures are deferred** (with ``joint``). A pair whose
   landmark was last associated more than ``closure_age`` scans ago closes
   a loop. One old landmark alone is weak evidence (an unmapped landmark a
   metre from it explains the measurement as well, and a false closure
   corrupts the whole map), so closing pairs are accepted only once at
   least ``closure_pairings`` distinct old landmarks have been proposed in
   this scan and the last ``closure_window`` scans; until then their
   measurements are discarded (they lie inside a gate, so they are not new
   landmarks either) and counted in ``stats.deferred``.
7. **New landmarks.** A measurement left without a landmark is a new
   landmark if its smallest ``d2`` to any landmark exceeds the larger
   threshold ``new_landmark`` (a chi-square probability too); otherwise it is
   ambiguous and discarded with id ``-1``; with ``exclusion_margin``, a
   landmark that another measurement of the scan took with a ``d2`` smaller by
   that margin does not count (mutual exclusion). With ``min_separation`` a
   measurement that projects closer than that to a mapped landmark is never
   a new landmark either (a prior on the map: real trees are not 1 m apart).
8. **Merges** (``loop_merge``, off by default). Every ``merge_every`` scans
   the landmarks started lately are matched against those started a loop
   ago by a rigid motion within a loop's drift (:func:`rigid_submap_match`);
   each inlier of a distinctive match is merged into its old landmark
   (``filt.merge_landmarks``). This takes back the duplicates a filter
   starts when it is too confident to accept a closure (the SEIF's), using
   the map's geometry rather than the covariance that failed. With
   ``tentative_closures`` a deferred lone closure (step 6) starts a
   tentative landmark instead of being discarded, merged into its old one
   once a closure is accepted and the correspondence test passes. The
   ``"revisable"`` preset turns both on; the ``"likelihood"`` preset adds
   ``joint_objective="likelihood"``, a 0.9999 gate and ``exclusion_margin``
   (:data:`ASSOCIATOR_PRESETS`).

For SEIF-type filters the covariance of step 2 comes from
:func:`seif_gym.slam.marginals.breadth_first_joint_covariance` (a block of at
most ``blanket_size`` landmarks grown by breadth-first search through
``Omega`` from the robot's active landmarks and from the candidates) instead
of the Markov blanket, which conditions on the loop and is far too tight for
landmarks mapped a loop ago (``blanket_size=0`` restores it).

The cost per scan is bounded for the SEIF by ``blanket_size`` and
``max_nodes``, whatever the size of the map, apart from the linear candidate
search. Accuracy and cost on the loop-closing runs
(``benchmarks/association.py``) are in ``docs/filters/fidelity.md`` and
``docs/performance_notes.md``.

Use
---
:meth:`Associator.update` associates a scan, then calls ``filt.update_trusted``
with the measurements whose ids are ``>= 0``:

>>> associator = Associator()                             # doctest: +SKIP
>>> ids = associator.update(filt, ranges, bearings)       # doctest: +SKIP

With a simulator, :class:`AssociationAudit` scores the decisions against the
true ids (and maps the associator's ids to true ones, e.g. for a map error).
"""

from __future__ import annotations

import functools
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.linalg
import scipy.optimize
import scipy.stats
from numba import njit
from numpy.typing import ArrayLike

from seif_gym.slam._kernels import range_bearing_jacobian
from seif_gym.slam.marginals import breadth_first_joint_covariance, supports_breadth_first
from seif_gym.type_aliases import FloatArray, IntArray
from seif_gym.validation import as_count, as_finite_array, as_positive_scalar

if TYPE_CHECKING:  # for annotations only
    from seif_gym.slam.base import SlamFilter
    from seif_gym.slam.models import RangeBearingSensor

__all__ = [
    "ASSOCIATOR_PRESETS",
    "Associator",
    "AssociationStats",
    "AssociationAudit",
    "jcbb",
    "make_associator",
    "rigid_submap_match",
]


#: Cost of a forbidden pair in the assignment problem (far above any gated cost).
_FORBIDDEN = 1e9


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


class _JointSearch:
    """Joint compatibility branch and bound (Neira & Tardos 2001), plain Python: the reference.

    Finds the hypothesis (at most one landmark per measurement, each landmark at most once) with the
    most pairings whose joint Mahalanobis distance ``nu_H^T S_H^-1 nu_H`` passes the chi-square gate
    with ``2 |H|`` degrees of freedom; ties go to the smallest joint negative log-likelihood
    ``d2_H + ln det S_H``. The joint distance grows as pairings are added, so a branch is cut as
    soon as it fails the gate; the "leave this measurement unpaired" branch is cut when it cannot
    reach more pairings than the best hypothesis so far. ``S_H`` is extended one 2x2 block at a time
    (a Cholesky factor grown by one block row), so each node costs ``O(|H|^2)``.
    """

    def __init__(
        self,
        nu: FloatArray,
        cov: FloatArray,
        pair_meas: IntArray,
        pair_landmark: IntArray,
        gate: float,
        max_nodes: int,
        gains: FloatArray | None = None,
        noise_logdet: float = -np.inf,
    ) -> None:
        self.nu, self.cov = nu, cov
        self.pair_landmark = pair_landmark
        measurements = np.unique(pair_meas)
        options = [np.flatnonzero(pair_meas == i) for i in measurements]
        self.options = options
        self.limits = [_chi2_limit(float(gate), 2 * p) if p else 0.0 for p in range(len(options) + 1)]
        self.max_nodes = max_nodes
        self.nodes = 0
        self.gains = gains
        self.remaining = _remaining_gains(gains, options, noise_logdet) if gains is not None else None
        # (pairings, d2 + ln det S_H, score, pairs) of the best hypothesis so far; the empty one to start
        self.best: tuple[int, float, float, list[int]] = (0, 0.0, 0.0, [])

    def score(self, pairs: list[int], cost: float) -> float:
        """With ``gains``: ``sum_k gains[k] - (d2_H + ln det S_H) / 2``, the objective maximised.

        With ``gains[k] = -ln(2 pi) - ln(lambda_k)`` (``lambda_k`` the density of the measurement
        under "a new landmark") this is the log-likelihood ratio of the hypothesis against "every
        measurement a new landmark".
        """
        assert self.gains is not None
        return float(sum(self.gains[k] for k in pairs)) - 0.5 * cost

    def _better(self, pairs: list[int], cost: float) -> bool:
        count, best_cost, best_score, _ = self.best
        if self.gains is not None:
            return self.score(pairs, cost) > best_score
        return len(pairs) > count or (len(pairs) == count and cost < best_cost)

    def _record(self, pairs: list[int], cost: float) -> None:
        self.best = (len(pairs), cost, self.score(pairs, cost) if self.gains is not None else 0.0, list(pairs))

    def run(self, initial: list[int] | None = None) -> list[int]:
        if initial:
            state = self._state_of(initial)
            if state is not None and (self.gains is None or self._better(list(initial), state[2] + state[3])):
                self._record(list(initial), state[2] + state[3])
        self._search(0, [], np.zeros((0, 0)), np.zeros(0), 0.0, 0.0, set())
        return self.best[3]

    def _state_of(self, pairs: list[int]) -> tuple[FloatArray, FloatArray, float, float] | None:
        state: tuple[list[int], FloatArray, FloatArray, float, float] = ([], np.zeros((0, 0)), np.zeros(0), 0.0, 0.0)
        for k in pairs:
            grown = self._extend(state[0], state[1], state[2], state[3], state[4], k)
            if grown is None:
                return None
            state = (state[0] + [k], *grown)
        return state[1:]

    def _extend(
        self, pairs: list[int], lower: FloatArray, white: FloatArray, d2: float, logdet: float, k: int
    ) -> tuple[FloatArray, FloatArray, float, float] | None:
        """``(L, w, d2, ln det)`` of ``pairs + [k]``, or None when it fails the joint gate."""
        idx = np.array([2 * p + a for p in pairs for a in (0, 1)], dtype=np.int64)
        block = self.cov[2 * k : 2 * k + 2, 2 * k : 2 * k + 2]
        if len(pairs):
            # numpy's stubs have no overload of ix_ for an array next to a list
            cross = self.cov[np.ix_(idx, [2 * k, 2 * k + 1])]  # type: ignore[list-item]
            b = scipy.linalg.solve_triangular(lower, cross, lower=True)
            schur = block - b.T @ b
            resid = self.nu[k] - b.T @ white
        else:
            b = np.zeros((0, 2))
            schur, resid = block, self.nu[k]
        try:
            lc = np.linalg.cholesky(schur)
        except np.linalg.LinAlgError:
            return None
        wc = scipy.linalg.solve_triangular(lc, resid, lower=True)
        d2 = d2 + float(wc @ wc)
        if d2 > self.limits[len(pairs) + 1]:
            return None
        size = 2 * len(pairs)
        grown = np.zeros((size + 2, size + 2))
        grown[:size, :size] = lower
        grown[size:, :size] = b.T
        grown[size:, size:] = lc
        return grown, np.concatenate([white, wc]), d2, logdet + 2.0 * float(np.log(np.diag(lc)).sum())

    def _search(
        self,
        level: int,
        pairs: list[int],
        lower: FloatArray,
        white: FloatArray,
        d2: float,
        logdet: float,
        used: set[int],
    ) -> None:
        self.nodes += 1
        if level == len(self.options):
            if self._better(pairs, d2 + logdet):
                self._record(pairs, d2 + logdet)
            return
        for k in self.options[level]:
            if self.nodes >= self.max_nodes:
                return
            if int(self.pair_landmark[k]) in used:
                continue
            grown = self._extend(pairs, lower, white, d2, logdet, int(k))
            if grown is None:
                continue
            used.add(int(self.pair_landmark[k]))
            grown_lower, grown_white, grown_d2, grown_logdet = grown
            self._search(level + 1, pairs + [int(k)], grown_lower, grown_white, grown_d2, grown_logdet, used)
            used.discard(int(self.pair_landmark[k]))
        if self.remaining is not None:  # the skip branch can still beat the best: cut it otherwise
            promising = self.score(pairs, d2 + logdet) + self.remaining[level + 1] > self.best[2]
        else:
            promising = len(pairs) + len(self.options) - level - 1 >= self.best[0]
        if promising and self.nodes < self.max_nodes:
            self._search(level + 1, pairs, lower, white, d2, logdet, used)


def _remaining_gains(gains: FloatArray, options: list[IntArray], noise_logdet: float) -> FloatArray:
    """``remaining[l]``: an upper bound on what levels ``l, l+1, ...`` can add to the score.

    A pairing adds ``gains[k] - (delta d2 + delta ln det) / 2``; ``delta d2 >= 0``, and the
    conditional innovation covariance of a pairing is at least the sensor noise (``S_H`` is a
    covariance plus the noise's block diagonal), so ``delta ln det >= noise_logdet``.
    """
    best = np.array([max(0.0, float(np.max(gains[o])) - 0.5 * noise_logdet) for o in options])
    return np.concatenate([np.cumsum(best[::-1])[::-1], [0.0]])


@functools.lru_cache(maxsize=4096)
def _chi2_limit(probability: float, dof: int) -> float:
    """``scipy.stats.chi2.ppf(probability, dof)``, cached (the joint gate's bound per hypothesis size)."""
    return float(scipy.stats.chi2.ppf(probability, dof))


@njit(cache=True)
def _jcbb_compiled(
    nu: FloatArray,
    cov: FloatArray,
    option_start: IntArray,
    option_pairs: IntArray,
    pair_landmark: IntArray,
    limits: FloatArray,
    max_nodes: int,
    initial: IntArray,
    gains: FloatArray,
    remaining: FloatArray,
    by_likelihood: bool,
) -> IntArray:
    """:class:`_JointSearch`, compiled: the same depth-first order, cuts, ties and node budget.

    Level ``l`` (a measurement) has the options ``option_pairs[option_start[l]:option_start[l + 1]]``.
    The recursion is unrolled into per-level arrays; the Cholesky factor of ``S_H`` grows by one
    block row per pairing, so the prefix of ``lower`` is the factor at every depth (backtracking
    only forgets rows). With ``by_likelihood`` the objective is :meth:`_JointSearch.score` and
    ``remaining[l]`` bounds what levels ``l..`` can still add to it. Returns the chosen pairs (unsorted).
    """
    levels = option_start.shape[0] - 1
    size = 2 * levels + 2
    lower = np.zeros((size, size))
    white = np.zeros(size)
    d2s = np.zeros(levels + 2)
    logdets = np.zeros(levels + 2)
    gain_sums = np.zeros(levels + 2)
    chosen = np.zeros(levels + 1, dtype=np.int64)
    used = np.zeros(int(pair_landmark.max()) + 1 if pair_landmark.shape[0] else 1, dtype=np.bool_)
    best_count: int = 0  # declared: initial.shape[0] is Any to numpy's stubs
    best_cost = 0.0
    best_score = 0.0  # the empty hypothesis
    best = np.zeros(levels + 1, dtype=np.int64)
    # the initial hypothesis, extended in its order; it is the incumbent when it passes the gate
    ok = True
    for p in range(initial.shape[0]):
        if not _grow(nu, cov, lower, white, d2s, logdets, chosen, p, initial[p], limits):
            ok = False
            break
        chosen[p] = initial[p]
        gain_sums[p + 1] = gain_sums[p] + gains[initial[p]]
    if ok and initial.shape[0] > 0:
        count = initial.shape[0]
        initial_cost = float(d2s[count] + logdets[count])
        initial_score = float(gain_sums[count]) - 0.5 * initial_cost
        if not by_likelihood or initial_score > best_score:
            best_count = count
            best_cost = initial_cost
            best_score = initial_score
            best[:count] = initial
    nodes = 0
    next_option = np.zeros(levels + 1, dtype=np.int64)
    npairs = np.zeros(levels + 2, dtype=np.int64)
    taken = np.full(levels + 1, -1, dtype=np.int64)
    level = 0
    entering = True
    while level >= 0:
        if entering:
            entering = False
            nodes += 1
            p = npairs[level]
            if level == levels:
                cost = d2s[p] + logdets[p]
                score = gain_sums[p] - 0.5 * cost
                if by_likelihood:
                    improves = score > best_score
                else:
                    improves = p > best_count or (p == best_count and cost < best_cost)
                if improves:
                    best_count = p
                    best_cost = cost
                    best_score = score
                    best[:p] = chosen[:p]
                level -= 1
                if level >= 0 and taken[level] >= 0:
                    used[pair_landmark[taken[level]]] = False
                    taken[level] = -1
                continue
            next_option[level] = option_start[level]
        p = npairs[level]
        end = option_start[level + 1]
        descended = False
        while next_option[level] < end:
            k = option_pairs[next_option[level]]
            next_option[level] += 1
            if nodes >= max_nodes:
                next_option[level] = end + 1  # the budget is spent: return, no skip branch
                break
            if used[pair_landmark[k]]:
                continue
            if not _grow(nu, cov, lower, white, d2s, logdets, chosen, p, k, limits):
                continue
            chosen[p] = k
            gain_sums[p + 1] = gain_sums[p] + gains[k]
            used[pair_landmark[k]] = True
            taken[level] = k
            npairs[level + 1] = p + 1
            level += 1
            entering = True
            descended = True
            break
        if descended:
            continue
        if next_option[level] == end:
            next_option[level] = end + 1
            if by_likelihood:
                promising = gain_sums[p] - 0.5 * (d2s[p] + logdets[p]) + remaining[level + 1] > best_score
            else:
                promising = p + levels - level - 1 >= best_count
            if promising and nodes < max_nodes:
                taken[level] = -1
                npairs[level + 1] = p
                level += 1
                entering = True
                continue
        level -= 1
        if level >= 0 and taken[level] >= 0:
            used[pair_landmark[taken[level]]] = False
            taken[level] = -1
    return best[:best_count].copy()


@njit(cache=True)
def _grow(
    nu: FloatArray,
    cov: FloatArray,
    lower: FloatArray,
    white: FloatArray,
    d2s: FloatArray,
    logdets: FloatArray,
    chosen: IntArray,
    p: int,
    k: int,
    limits: FloatArray,
) -> bool:
    """Extend the factor of the first ``p`` pairings of ``chosen`` by pair ``k`` (block row ``p``); False if it fails the gate."""
    rows = 2 * p
    b = np.empty((rows, 2))
    for c in range(2):
        for r in range(rows):
            acc = cov[2 * chosen[r // 2] + r % 2, 2 * k + c]
            for j in range(r):
                acc -= lower[r, j] * b[j, c]
            b[r, c] = acc / lower[r, r]
    s00 = cov[2 * k, 2 * k]
    s10 = cov[2 * k + 1, 2 * k]
    s11 = cov[2 * k + 1, 2 * k + 1]
    r0 = nu[k, 0]
    r1 = nu[k, 1]
    for j in range(rows):
        s00 -= b[j, 0] * b[j, 0]
        s10 -= b[j, 1] * b[j, 0]
        s11 -= b[j, 1] * b[j, 1]
        r0 -= b[j, 0] * white[j]
        r1 -= b[j, 1] * white[j]
    if not s00 > 0.0:
        return False
    l00 = math.sqrt(s00)
    l10 = s10 / l00
    t = s11 - l10 * l10
    if not t > 0.0:
        return False
    l11 = math.sqrt(t)
    w0 = r0 / l00
    w1 = (r1 - l10 * w0) / l11
    d2 = d2s[p] + w0 * w0 + w1 * w1
    if d2 > limits[p + 1]:
        return False
    for j in range(rows):
        lower[rows, j] = b[j, 0]
        lower[rows + 1, j] = b[j, 1]
    lower[rows, rows] = l00
    lower[rows, rows + 1] = 0.0
    lower[rows + 1, rows] = l10
    lower[rows + 1, rows + 1] = l11
    white[rows] = w0
    white[rows + 1] = w1
    d2s[p + 1] = d2
    logdets[p + 1] = logdets[p] + 2.0 * (math.log(l00) + math.log(l11))
    return True


def jcbb(
    nu: FloatArray,
    cov: FloatArray,
    pair_meas: IntArray,
    pair_landmark: IntArray,
    gate: float = 0.999,
    max_nodes: int = 5000,
    initial: list[int] | None = None,
    compiled: bool = True,
    gains: FloatArray | None = None,
    noise_logdet: float = -np.inf,
) -> IntArray:
    """Joint compatibility branch and bound over candidate pairs (see :class:`_JointSearch`).

    Parameters
    ----------
    nu : ndarray, shape (K, 2)
        Innovation of each pair.
    cov : ndarray, shape (2K, 2K)
        Their joint covariance (:func:`joint_innovation_covariance`).
    pair_meas, pair_landmark : ndarray of int, shape (K,)
        Measurement and landmark of each pair.
    gate : float
        Chi-square probability of the joint gate (``2 |H|`` degrees of freedom).
    max_nodes : int
        Search budget; the best hypothesis found so far is returned when it runs out.
    initial : list of int, optional
        A hypothesis to start from (e.g. the individually best assignment).
    compiled : bool
        Run the compiled search (``_jcbb_compiled``) rather than the plain-Python reference
        :class:`_JointSearch`; both return the same hypothesis.
    gains : ndarray, shape (K,), optional
        Rank the jointly compatible hypotheses by likelihood rather than by their number of
        pairings: maximise ``sum_k gains[k] - (d2_H + ln det S_H) / 2`` (:meth:`_JointSearch.score`).
    noise_logdet : float
        With ``gains``: a lower bound on ``ln det`` of any pairing's conditional innovation
        covariance (that of the sensor noise), which bounds the search; ``-inf`` searches everything.

    Returns
    -------
    ndarray of int64
        The indices of the chosen pairs.
    """
    pair_meas = np.asarray(pair_meas, dtype=np.int64)
    pair_landmark = np.asarray(pair_landmark, dtype=np.int64)
    if gains is not None:
        gains = np.ascontiguousarray(gains, dtype=np.float64)
        if gains.shape != pair_meas.shape:
            raise ValueError(f"gains must have one entry per pair, shape {pair_meas.shape}, got {gains.shape}")
        if not np.isfinite(gains).all():
            raise ValueError("gains must be finite")
        if not isinstance(noise_logdet, (int, float)) or math.isnan(noise_logdet) or noise_logdet == math.inf:
            raise ValueError(f"noise_logdet must be a real number or -inf, got {noise_logdet!r}")
    if not compiled:
        search = _JointSearch(nu, cov, pair_meas, pair_landmark, gate, max_nodes, gains, noise_logdet)
        return np.array(sorted(search.run(initial)), dtype=np.int64)
    order = np.argsort(pair_meas, kind="stable")  # each measurement's options in increasing pair order
    levels = len(np.unique(pair_meas))
    option_start = np.zeros(levels + 1, dtype=np.int64)
    option_start[1:] = np.cumsum(np.unique(pair_meas, return_counts=True)[1])
    limits = np.array([0.0] + [_chi2_limit(float(gate), 2 * p) for p in range(1, levels + 1)])
    start = np.asarray(initial if initial else [], dtype=np.int64)
    if gains is None:
        pair_gains, remaining = np.zeros(len(pair_meas)), np.zeros(levels + 1)
    else:
        options = [order[option_start[level] : option_start[level + 1]] for level in range(levels)]
        pair_gains, remaining = gains, _remaining_gains(gains, options, noise_logdet)
    found = _jcbb_compiled(
        np.ascontiguousarray(nu, dtype=np.float64),
        np.ascontiguousarray(cov, dtype=np.float64),
        option_start,
        order.astype(np.int64),
        pair_landmark,
        limits,
        int(max_nodes),
        start,
        pair_gains,
        remaining,
        gains is not None,
    )
    return np.sort(found).astype(np.int64)


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


def rigid_submap_match(
    recent: FloatArray, old: FloatArray, tolerance: float, max_rotation: float, max_shift: float
) -> tuple[list[tuple[int, int]], int]:
    """The rigid motion that lays most of ``recent`` onto ``old``, within the drift bounds.

    Every pair of ``recent`` points (more than 1 m apart) is matched with
    every pair of ``old`` points at the same distance (within ``tolerance``),
    both ways round; each such match fixes a rotation and a translation. One
    is kept when its rotation is within ``max_rotation`` (radians) and it
    moves the centroid of ``recent`` by at most ``max_shift`` (metres): a
    loop's drift, not an arbitrary motion. Its inliers are the ``recent``
    points that land within ``tolerance`` of an ``old`` one, one to one.

    Parameters
    ----------
    recent, old : ndarray, shape (a, 2), (b, 2)
        Estimated positions: landmarks started lately, and landmarks mapped
        long ago, near the robot.
    tolerance, max_rotation, max_shift : float
        As above.

    Returns
    -------
    pairs : list of (int, int)
        ``(row of recent, row of old)`` of the best hypothesis's inliers.
    second : int
        Inliers of the best hypothesis that shares no pair with it (how
        distinctive the match is).

    Raises
    ------
    TypeError, ValueError
        Naming the argument: points that are not finite ``(n, 2)`` arrays,
        bounds that are not positive finite numbers.
    """
    recent, old = as_finite_array(recent, "recent", (None, 2)), as_finite_array(old, "old", (None, 2))
    tolerance = as_positive_scalar(tolerance, "tolerance")
    max_rotation = as_positive_scalar(max_rotation, "max_rotation")
    max_shift = as_positive_scalar(max_shift, "max_shift")
    if len(recent) < 2 or len(old) < 2:
        return [], 0
    ri, rj = np.triu_indices(len(recent), 1)
    oi, oj = np.triu_indices(len(old), 1)
    recent_gap = np.linalg.norm(recent[ri] - recent[rj], axis=1)
    old_gap = np.linalg.norm(old[oi] - old[oj], axis=1)
    wide = recent_gap > 1.0
    ri, rj, recent_gap = ri[wide], rj[wide], recent_gap[wide]
    a, b = np.nonzero(np.abs(recent_gap[:, None] - old_gap[None, :]) < tolerance)
    if len(a) == 0:
        return [], 0
    # both orientations of each old pair
    start = np.concatenate([recent[ri[a]], recent[ri[a]]])
    end = np.concatenate([recent[rj[a]], recent[rj[a]]])
    to_start = np.concatenate([old[oi[b]], old[oj[b]]])
    to_end = np.concatenate([old[oj[b]], old[oi[b]]])
    u, v = end - start, to_end - to_start
    rotation = np.arctan2(v[:, 1], v[:, 0]) - np.arctan2(u[:, 1], u[:, 0])
    rotation = (rotation + np.pi) % (2.0 * np.pi) - np.pi
    cos, sin = np.cos(rotation), np.sin(rotation)
    shift = to_start - np.column_stack([cos * start[:, 0] - sin * start[:, 1], sin * start[:, 0] + cos * start[:, 1]])
    centre = recent.mean(axis=0)
    moved_centre = np.column_stack([cos * centre[0] - sin * centre[1], sin * centre[0] + cos * centre[1]]) + shift
    plausible = (np.abs(rotation) <= max_rotation) & (np.hypot(*(moved_centre - centre).T) <= max_shift)
    hypotheses: list[tuple[int, frozenset[tuple[int, int]]]] = []
    for h in np.flatnonzero(plausible).tolist():
        moved = recent @ np.array([[cos[h], sin[h]], [-sin[h], cos[h]]]) + shift[h]
        distance = np.linalg.norm(moved[:, None, :] - old[None, :, :], axis=2)
        nearest = distance.argmin(axis=1)
        close = np.flatnonzero(distance[np.arange(len(recent)), nearest] < tolerance)
        if len(np.unique(nearest[close])) < len(close):
            continue  # two recent landmarks on one old one: not a rigid copy
        hypotheses.append((len(close), frozenset(zip(close.tolist(), nearest[close].tolist()))))
    if not hypotheses:
        return [], 0
    hypotheses.sort(key=lambda item: -item[0])
    best = hypotheses[0][1]
    second = max((count for count, pairs in hypotheses if not pairs & best), default=0)
    return sorted(best), second


class CoverageGrid:
    """How often each cell of a uniform grid lay well inside the sensor's footprint (a dict of cells).

    A cell counts once per scan when its centre is within ``max_range - margin`` of the estimated
    pose and ``fov / 2`` of the heading (``margin`` the larger of 1 m and 20% of the range, so that
    the pose error does not count cells at the footprint's edge). A landmark in a cell seen ``c``
    times that is still not in the map is unlikely: each of those scans would have detected it.
    Cost per scan: the cells of one footprint (bounded), whatever the size of the map.
    """

    def __init__(self) -> None:
        self.cells: dict[tuple[int, int], int] = {}
        self.cell = 0.0

    def _setup(self, sensor: RangeBearingSensor) -> None:
        self.cell = max(1.0, float(sensor.max_range) / 10.0)

    def add_scan(self, pose: FloatArray, sensor: RangeBearingSensor) -> None:
        """Count the cells well inside the footprint of a scan from ``pose``."""
        if not self.cell:
            self._setup(sensor)
        reach = float(sensor.max_range) - max(1.0, 0.2 * float(sensor.max_range))
        if reach <= 0.0:
            return
        c = self.cell
        low = np.floor((pose[:2] - reach) / c).astype(np.int64)
        high = np.floor((pose[:2] + reach) / c).astype(np.int64)
        ix, iy = np.meshgrid(np.arange(low[0], high[0] + 1), np.arange(low[1], high[1] + 1), indexing="ij")
        dx = (ix + 0.5) * c - pose[0]
        dy = (iy + 0.5) * c - pose[1]
        inside = dx * dx + dy * dy <= reach * reach
        half_fov = 0.5 * float(getattr(sensor, "fov", 2.0 * math.pi))
        if half_fov < math.pi:
            inside &= np.abs((np.arctan2(dy, dx) - pose[2] + np.pi) % (2.0 * np.pi) - np.pi) <= half_fov
        cells = self.cells
        for key in zip(ix[inside].tolist(), iy[inside].tolist()):
            cells[key] = cells.get(key, 0) + 1

    def counts(self, points: FloatArray) -> FloatArray:
        """How many scans covered the cell of each point (0 before any scan)."""
        if not self.cell:
            return np.zeros(len(points))
        keys = np.floor(np.asarray(points) / self.cell).astype(np.int64).tolist()
        return np.array([self.cells.get((a, b), 0) for a, b in keys], dtype=np.float64)


@dataclass
class AssociationStats:
    """Counts of the decisions made so far (measurements)."""

    associated: int = 0
    new: int = 0
    discarded: int = 0
    scans: int = 0
    #: loop-closing pairs deferred (their measurements discarded) for want of enough of them in one scan
    deferred: int = 0
    #: landmarks merged into others (``loop_merge``)
    merged: int = 0
    #: sum of the Mahalanobis distances ``d2`` of the associated measurements
    nis_sum: float = 0.0

    @property
    def total(self) -> int:
        """Measurements decided so far."""
        return self.associated + self.new + self.discarded

    @property
    def mean_nis(self) -> float:
        """Mean ``d2`` of the associated measurements: about 2 (3 with signatures) for a consistent filter."""
        return self.nis_sum / self.associated if self.associated else float("nan")


@dataclass
class _Signatures:
    """Running mean and variance of each landmark's signature (Welford), by landmark id."""

    count: dict = field(default_factory=dict)
    mean: dict = field(default_factory=dict)
    m2: dict = field(default_factory=dict)

    def add(self, landmark_id: int, value: float) -> None:
        n = self.count.get(landmark_id, 0) + 1
        mean = self.mean.get(landmark_id, 0.0)
        delta = value - mean
        mean += delta / n
        self.count[landmark_id] = n
        self.mean[landmark_id] = mean
        self.m2[landmark_id] = self.m2.get(landmark_id, 0.0) + delta * (value - mean)

    def merge(self, keep: int, remove: int) -> None:
        """Pool ``remove``'s statistics into ``keep``'s (Chan et al.'s parallel update) and drop ``remove``."""
        n_b = self.count.pop(remove, 0)
        mean_b, m2_b = self.mean.pop(remove, 0.0), self.m2.pop(remove, 0.0)
        n_a = self.count.get(keep, 0)
        if n_b == 0:
            return
        mean_a, m2_a = self.mean.get(keep, 0.0), self.m2.get(keep, 0.0)
        n = n_a + n_b
        delta = mean_b - mean_a
        self.count[keep] = n
        self.mean[keep] = mean_a + delta * n_b / n
        self.m2[keep] = m2_a + m2_b + delta**2 * n_a * n_b / n


class Associator:
    """Maximum-likelihood data association with chi-square gating and mutual exclusion.

    Parameters
    ----------
    gate : float
        Probability of the chi-square gate (0.999: ``d2 <= 13.8`` with 2 dof;
        a 0.99 gate would discard 1% of the correct pairs by design).
    new_landmark : float
        Chi-square probability above which an unassigned measurement starts a
        new landmark (0.99999: ``d2 > 23.0`` with 2 dof). Must be ``>= gate``;
        measurements in between are discarded.
    candidate_radius : float
        Base radius of the Euclidean candidate search around each projected
        measurement, metres; the pose uncertainty widens it (module docstring).
    signature_sigma : float or None
        Enables signature gating: standard deviation of a signature
        measurement is ``sqrt(signature_sigma^2 + (signature_per_metre r)^2)``.
        ``None`` ignores signatures even when they are given.
    signature_per_metre : float
        Growth of the signature noise with range (Victoria Park's trunk
        diameters are arc lengths quantised to 0.5 degrees).
    min_separation : float
        A measurement whose projection lies closer than this (metres) to a
        mapped landmark never starts a new landmark (it is discarded
        instead): a prior on how close two landmarks can be (0: off).
    first_id : int
        Id given to the first new landmark; later ones count up.
    neighbours : bool or int
        For SEIF-type filters, which neighbours of the candidates enter the
        Markov-blanket block (``local_joint_covariance(..., neighbours=)``):
        all (``True``), none (``False``) or the ``n`` most strongly linked of
        each candidate (an int: a block of bounded size). Used when
        ``blanket_size`` is 0.
    joint : bool
        Joint compatibility branch and bound over each scan (step 4).
    joint_gate : float
        Chi-square probability of the joint gate.
    landmark_density : float
        Density of unmapped landmarks (per square metre) of the test of a
        pairing against a new landmark (step 5); 0 turns the test off.
    landmark_separation : float
        Metres: an unmapped landmark is assumed at least this far from a mapped one.
    max_nodes : int
        Branch-and-bound budget per scan.
    blanket_size : int
        SEIF-type filters: landmarks of the breadth-first covariance block
        (:mod:`seif_gym.slam.marginals`); 0 uses the filter's Markov blanket.
    detection : float
        Probability that a scan detects a landmark well inside its footprint
        (:class:`CoverageGrid`); 0 ignores the coverage.
    closure_age : int
        With ``joint``: a pair whose landmark was last associated more than
        this many scans ago closes a loop (step 6); 0 turns the deferral off.
    closure_pairings : int
        Distinct loop-closing landmarks, in this scan and the closing pairs
        proposed over the last ``closure_window`` scans, needed before any
        closing pair is accepted; fewer: the closing measurements are
        discarded (``-1``). 1 turns the deferral off.
    closure_window : int
        Scans over which proposed closing pairs count towards
        ``closure_pairings``.
    loop_merge : bool
        Revise the association (step 8): fold landmarks started lately into
        old ones when a rigid copy of the old map shows (through the filter's
        ``merge_landmarks``); off by default (the envs' ``-v0``/``-v1``
        association does not merge).
    merge_every : int
        Scans between two searches for a copy.
    merge_recent : int
        A landmark started within this many scans is *recent*; one started
        more than ``closure_age`` scans ago is *old*.
    merge_radius : float
        Metres: both sets are taken within this distance of the robot.
    merge_tolerance : float
        Metres: an inlier lands this close to its old landmark.
    merge_inliers : int
        Inliers needed to merge.
    merge_margin : int
        The best match needs this many inliers more than the best match that
        shares no pair with it.
    merge_rotation, merge_shift : float
        Degrees and metres: the largest drift (rotation, and motion of the
        recent landmarks' centroid) a copy may show.
    tentative_closures : bool
        A deferred lone closure (step 6) starts a tentative landmark instead
        of being discarded; once its old landmark is associated again (the
        closure accepted) and the two pass the correspondence test on the
        joint marginal of ``m_old - m_new`` (the ``gate``), it is merged into
        the old one; after ``closure_window`` scans it stays a landmark of its
        own.
    exclusion_margin : float or None
        Mutual exclusion for new landmarks (step 7): a landmark taken by
        another measurement of the scan whose ``d2`` is smaller by at least
        this much no longer stops a measurement from starting a new landmark
        (the swapped assignment is ``exp(margin / 2)`` times less likely).
        ``None`` (the default): every gated landmark stops it.
    joint_objective : {"pairings", "likelihood"}
        What the branch and bound maximises among the jointly compatible
        hypotheses (step 4): the number of pairings (Neira & Tardos; the
        default), or the likelihood ratio of the hypothesis against "each of
        its measurements is an unmapped landmark", with the density of step 5
        (:func:`jcbb`'s ``gains``), so that one good pairing can beat two poor
        ones where new landmarks are plausible.

    Notes
    -----
    See the module docstring for the algorithm. :meth:`associate` is the
    decision alone; :meth:`update` also applies it to the filter. Ids are the
    associator's own: with a simulator, map them to the true landmarks by the
    true id of the measurement that created each (``created``).
    """

    def __init__(
        self,
        gate: float = 0.999,
        new_landmark: float = 0.99999,
        candidate_radius: float = 3.0,
        signature_sigma: float | None = None,
        signature_per_metre: float = 0.0,
        min_separation: float = 0.0,
        first_id: int = 0,
        neighbours: bool | int = True,
        joint: bool = True,
        joint_gate: float = 0.999,
        landmark_density: float = 1.0,
        landmark_separation: float = 1.0,
        max_nodes: int = 2000,
        blanket_size: int = 128,
        detection: float = 0.5,
        closure_age: int = 60,
        closure_pairings: int = 2,
        closure_window: int = 40,
        loop_merge: bool = False,
        merge_every: int = 10,
        merge_recent: int = 40,
        merge_radius: float = 15.0,
        merge_tolerance: float = 0.2,
        merge_inliers: int = 4,
        merge_margin: int = 2,
        merge_rotation: float = 10.0,
        merge_shift: float = 3.0,
        tentative_closures: bool = False,
        exclusion_margin: float | None = None,
        joint_objective: str = "pairings",
    ) -> None:
        for name, value in (("gate", gate), ("new_landmark", new_landmark)):
            if not isinstance(value, (int, float)) or not 0.0 < float(value) < 1.0:
                raise ValueError(f"{name} must be a probability in (0, 1), got {value!r}")
        if new_landmark < gate:
            raise ValueError(f"new_landmark ({new_landmark}) must be at least gate ({gate})")
        if not math.isfinite(candidate_radius) or candidate_radius <= 0:
            raise ValueError(f"candidate_radius must be positive, got {candidate_radius!r}")
        if not math.isfinite(min_separation) or not 0.0 <= min_separation <= candidate_radius:
            raise ValueError(f"min_separation must lie in [0, candidate_radius], got {min_separation!r}")
        if signature_sigma is not None and (not math.isfinite(signature_sigma) or signature_sigma <= 0):
            raise ValueError(f"signature_sigma must be positive or None, got {signature_sigma!r}")
        if not math.isfinite(signature_per_metre) or signature_per_metre < 0:
            raise ValueError(f"signature_per_metre must be non-negative, got {signature_per_metre!r}")
        if not 0.0 < float(joint_gate) < 1.0:
            raise ValueError(f"joint_gate must be a probability in (0, 1), got {joint_gate!r}")
        if not math.isfinite(landmark_density) or landmark_density < 0:
            raise ValueError(f"landmark_density must be non-negative, got {landmark_density!r}")
        if not math.isfinite(landmark_separation) or landmark_separation < 0:
            raise ValueError(f"landmark_separation must be non-negative, got {landmark_separation!r}")
        if not 0.0 <= detection < 1.0:
            raise ValueError(f"detection must lie in [0, 1), got {detection!r}")
        for name, value, low in (
            ("max_nodes", max_nodes, 1),
            ("blanket_size", blanket_size, 0),
            ("closure_age", closure_age, 0),
            ("closure_pairings", closure_pairings, 1),
            ("closure_window", closure_window, 0),
            ("merge_every", merge_every, 1),
            ("merge_recent", merge_recent, 1),
            ("merge_inliers", merge_inliers, 2),
            ("merge_margin", merge_margin, 0),
        ):
            as_count(value, name, minimum=low)
        self.gate = float(gate)
        self.new_landmark = float(new_landmark)
        self.candidate_radius = float(candidate_radius)
        self.signature_sigma = None if signature_sigma is None else float(signature_sigma)
        self.signature_per_metre = float(signature_per_metre)
        if isinstance(neighbours, bool):
            self.neighbours: bool | int = neighbours
        elif isinstance(neighbours, int) and neighbours >= 0:
            self.neighbours = int(neighbours)
        else:
            raise ValueError(f"neighbours must be a bool or a non-negative int, got {neighbours!r}")
        self.min_separation = float(min_separation)
        self.joint = bool(joint)
        self.joint_gate = float(joint_gate)
        self.landmark_density = float(landmark_density)
        self.landmark_separation = float(landmark_separation)
        self.max_nodes = int(max_nodes)
        self.blanket_size = int(blanket_size)
        self.detection = float(detection)
        self.closure_age = int(closure_age)
        self.closure_pairings = int(closure_pairings)
        self.closure_window = int(closure_window)
        for name, flag in (("loop_merge", loop_merge), ("tentative_closures", tentative_closures)):
            if not isinstance(flag, bool):
                raise TypeError(f"{name} must be a bool, got {type(flag).__name__}")
        self.tentative_closures = tentative_closures
        if exclusion_margin is not None:
            if isinstance(exclusion_margin, bool) or not isinstance(exclusion_margin, (int, float)):
                raise TypeError(f"exclusion_margin must be a number or None, got {type(exclusion_margin).__name__}")
            if not math.isfinite(exclusion_margin) or exclusion_margin < 0:
                raise ValueError(f"exclusion_margin must be non-negative and finite, got {exclusion_margin!r}")
            exclusion_margin = float(exclusion_margin)
        self.exclusion_margin = exclusion_margin
        if joint_objective not in ("pairings", "likelihood"):
            raise ValueError(f"joint_objective must be 'pairings' or 'likelihood', got {joint_objective!r}")
        self.joint_objective = joint_objective
        #: tentative landmark id -> (the old landmark id it may be, the scan that started it)
        self.tentatives: dict[int, tuple[int, int]] = {}
        self._deferred = np.empty(0, dtype=np.int64)  # pairs of the last scan's deferred lone closures
        self._closure_accepted = -1  # the last scan that accepted loop-closing pairs
        self.loop_merge = loop_merge
        self.merge_every = int(merge_every)
        self.merge_recent = int(merge_recent)
        self.merge_radius = as_positive_scalar(merge_radius, "merge_radius")
        self.merge_tolerance = as_positive_scalar(merge_tolerance, "merge_tolerance")
        self.merge_inliers = int(merge_inliers)
        self.merge_margin = int(merge_margin)
        self.merge_rotation = as_positive_scalar(merge_rotation, "merge_rotation")
        self.merge_shift = as_positive_scalar(merge_shift, "merge_shift")
        #: landmark id -> the scan that started it
        self.started: dict[int, int] = {}
        #: ``(kept id, removed id)`` of the merges made by the last :meth:`associate`, before its scan
        self.merges: list[tuple[int, int]] = []
        self._proposals: deque[tuple[int, int]] = deque()  # (scan, landmark id) of recent closing pairs
        #: landmark id -> index of the last scan that associated a measurement with it (or created it)
        self.last_seen: dict[int, int] = {}
        self._coverage = CoverageGrid()
        self._last_points = np.empty((0, 2))
        self._thresholds = {
            dof: (float(scipy.stats.chi2.ppf(self.gate, dof)), float(scipy.stats.chi2.ppf(self.new_landmark, dof)))
            for dof in (2, 3)
        }
        self.next_id = int(first_id)
        self.stats = AssociationStats()
        self.signatures = _Signatures()
        #: per new landmark id, the index of the measurement (within its scan) that created it: the last scan's
        self.created: dict[int, int] = {}

    def __repr__(self) -> str:
        return (
            f"Associator(gate={self.gate}, new_landmark={self.new_landmark}, candidate_radius={self.candidate_radius}, "
            f"min_separation={self.min_separation}, signature_sigma={self.signature_sigma}, "
            f"signature_per_metre={self.signature_per_metre})"
        )

    def thresholds(self, with_signatures: bool = False) -> tuple[float, float]:
        """``(gate, new landmark)`` thresholds on ``d2`` (2 dof, or 3 with signatures)."""
        return self._thresholds[3 if with_signatures else 2]

    # -- the decision ---------------------------------------------------------------
    def distances(
        self, filt: SlamFilter, ranges: ArrayLike, bearings: ArrayLike, signatures: ArrayLike | None = None
    ) -> tuple[IntArray, IntArray, FloatArray, FloatArray]:
        """Candidate pairs of a scan: ``(measurement, landmark index, d2, ln det S)``, all (p,).

        ``landmark index`` is the state order in ``filt``. Signatures add their
        term to ``d2`` (see the class Notes) when enabled.
        """
        return self._pairs(filt, ranges, bearings, signatures)[:4]

    def _pairs(
        self, filt: SlamFilter, ranges: ArrayLike, bearings: ArrayLike, signatures: ArrayLike | None = None
    ) -> tuple[IntArray, IntArray, FloatArray, FloatArray, FloatArray]:
        """:meth:`distances` plus the squared Euclidean distance of each pair (projected measurement to landmark)."""
        ranges = np.ascontiguousarray(ranges, dtype=np.float64)
        bearings = np.ascontiguousarray(bearings, dtype=np.float64)
        empty = np.empty(0, dtype=np.int64)
        if filt.num_landmarks == 0 or len(ranges) == 0:
            return empty, empty, np.empty(0), np.empty(0), np.empty(0)
        pose = np.asarray(filt.pose, dtype=np.float64)
        landmarks = np.ascontiguousarray(filt.landmarks)
        pose_cov, _ = filt.local_marginals(empty)
        angle = bearings + pose[2]
        points = np.column_stack([pose[0] + ranges * np.cos(angle), pose[1] + ranges * np.sin(angle)])
        spread = math.sqrt(max(float(np.linalg.eigvalsh(pose_cov[:2, :2])[-1]), 0.0))
        sigma_theta = math.sqrt(max(float(pose_cov[2, 2]), 0.0))
        self._last_points = points
        radii = self.candidate_radius + 3.0 * (spread + ranges * sigma_theta)
        pair_meas, pair_landmark, euclid2 = _candidates(landmarks, points, radii)
        if self.tentatives and len(pair_meas):
            # a tentative landmark is no candidate: the association and the closure decision see the map
            # as without it, and the measurements deferred for its old landmark go to it (associate)
            tentative_ids = np.fromiter(self.tentatives, dtype=np.int64, count=len(self.tentatives))
            open_pairs = ~np.isin(filt.landmark_ids[pair_landmark], tentative_ids)
            pair_meas, pair_landmark, euclid2 = pair_meas[open_pairs], pair_landmark[open_pairs], euclid2[open_pairs]
        if len(pair_meas) == 0:
            return empty, empty, np.empty(0), np.empty(0), np.empty(0)
        unique, pair_slot = np.unique(pair_landmark, return_inverse=True)
        pair_slot = pair_slot.astype(np.int64)
        joint = self._joint_covariance(filt, unique)
        noise = np.asarray(filt.sensor.noise_covariance, dtype=np.float64)
        d2, logdet = _pair_distances(pose, landmarks[unique], joint, noise, ranges, bearings, pair_meas, pair_slot)
        if signatures is not None and self.signature_sigma is not None:
            d2 = d2 + self._signature_term(filt, signatures, ranges, pair_meas, pair_landmark)
        self._last = (pose, landmarks[unique], joint, noise, ranges, bearings, pair_slot)
        return pair_meas, pair_landmark, d2, logdet, euclid2

    def _joint_covariance(self, filt: SlamFilter, indices: IntArray) -> FloatArray:
        if self.blanket_size > 0 and supports_breadth_first(filt):
            return breadth_first_joint_covariance(filt, indices, self.blanket_size)
        method: Callable[..., FloatArray] = filt.local_joint_covariance  # SEIF-type filters take neighbours
        try:
            return method(indices, neighbours=self.neighbours)
        except TypeError:  # exact filters take no neighbours option
            return method(indices)

    def _signature_term(
        self, filt: SlamFilter, signatures: ArrayLike, ranges: FloatArray, pair_meas: IntArray, pair_landmark: IntArray
    ) -> FloatArray:
        assert self.signature_sigma is not None  # the caller checks
        signatures = np.asarray(signatures, dtype=np.float64)
        ids = filt.landmark_ids[pair_landmark].tolist()
        means = np.array([self.signatures.mean.get(i, np.nan) for i in ids])
        counts = np.array([self.signatures.count.get(i, 0) for i in ids], dtype=np.float64)
        variance = self.signature_sigma**2 + (self.signature_per_metre * ranges[pair_meas]) ** 2
        # the landmark's mean averages ``count`` measurements of about the same noise
        term = (signatures[pair_meas] - means) ** 2 / (variance * (1.0 + 1.0 / np.maximum(counts, 1.0)))
        return np.where(np.isnan(means), 1.0, term)  # no signature yet: the expected value of the term

    def associate(
        self, filt: SlamFilter, ranges: ArrayLike, bearings: ArrayLike, signatures: ArrayLike | None = None
    ) -> IntArray:
        """Landmark ids for one scan: a mapped id, a new id, or ``-1`` (discarded).

        Parameters
        ----------
        filt : SlamFilter
            Any filter of :mod:`seif_gym.slam` (after its motion update to the
            scan's time).
        ranges, bearings : array_like, shape (m,)
            The scan's measurements (bearings in the robot frame).
        signatures : array_like, shape (m,), optional
            A scalar signature per measurement (Victoria Park: the trunk
            diameter); used when ``signature_sigma`` is set, and recorded for
            the landmarks they are assigned to.

        Returns
        -------
        ndarray of int64, shape (m,)
            Distinct ids ``>= 0`` for the measurements to use, ``-1`` for the
            discarded ones. New ids are allocated here (``next_id``); the
            measurement that created each is in :attr:`created`.
        """
        self.merges = self._merge_copies(filt) if self.loop_merge else []
        if self.tentative_closures:
            self.merges += self._resolve_tentatives(filt)
        self._deferred = np.empty(0, dtype=np.int64)
        ranges = np.asarray(ranges, dtype=np.float64)  # for len(); _pairs converts it anyway
        m = len(ranges)
        ids = np.full(m, -1, dtype=np.int64)
        use_signatures = signatures is not None and self.signature_sigma is not None
        gate, new_threshold = self.thresholds(use_signatures)
        pair_meas, pair_landmark, d2, logdet, euclid2 = self._pairs(filt, ranges, bearings, signatures)
        chosen = np.empty(0, dtype=np.int64)  # pairs assigned
        gated = np.flatnonzero(d2 <= gate)
        if len(gated):
            rows, row_of = np.unique(pair_meas[gated], return_inverse=True)
            cols, col_of = np.unique(pair_landmark[gated], return_inverse=True)
            cost = np.full((len(rows), len(cols)), _FORBIDDEN)
            cost[row_of, col_of] = d2[gated] + logdet[gated]  # negative log-likelihood (up to a constant)
            pair_of = np.full((len(rows), len(cols)), -1, dtype=np.int64)
            pair_of[row_of, col_of] = gated
            if len(rows) == 1:
                r_idx, c_idx = np.zeros(1, dtype=np.int64), np.array([np.argmin(cost[0])])
            elif len(cols) == 1:
                r_idx, c_idx = np.array([np.argmin(cost[:, 0])]), np.zeros(1, dtype=np.int64)
            else:
                r_idx, c_idx = scipy.optimize.linear_sum_assignment(cost)
            ok = cost[r_idx, c_idx] < _FORBIDDEN
            chosen = pair_of[r_idx[ok], c_idx[ok]]
            if self.joint and len(rows) > 1 or self.landmark_density > 0.0:
                chosen = self._joint_decision(gated, chosen, pair_meas, pair_landmark, logdet, euclid2)
            if self.joint and self.closure_age > 0 and self.closure_pairings > 1 and len(chosen):
                chosen = self._defer_lone_closures(filt, chosen, pair_landmark)
            ids[pair_meas[chosen]] = filt.landmark_ids[pair_landmark[chosen]]
        deferred_to_tentative = 0
        # new landmark: far from every mapped landmark (also those other measurements took: an
        # unmapped landmark next to a mapped one is ambiguous until the robot can tell them apart),
        # but with exclusion_margin one that another measurement took far more likely does not count
        best = np.full(m, np.inf)
        considered = self._unexcluded(pair_meas, pair_landmark, d2, chosen)
        np.minimum.at(best, pair_meas[considered], d2[considered])
        new = (ids < 0) & (best > new_threshold)
        if self.min_separation > 0.0 and len(pair_meas):
            # and not closer than min_separation to a mapped landmark (a physical prior on the map)
            near = euclid2 < self.min_separation**2
            new[pair_meas[near]] = False
        tentative: dict[int, int] = {}  # measurement -> the old landmark id it was deferred from
        if self.tentative_closures and len(self._deferred):
            pending = {old_id: new_id for new_id, (old_id, _) in self.tentatives.items()}
            for k in self._deferred.tolist():
                measurement, old_id = int(pair_meas[k]), int(filt.landmark_ids[pair_landmark[k]])
                if old_id in pending:  # the old landmark's tentative double takes it
                    ids[measurement] = pending[old_id]
                    deferred_to_tentative += 1
                else:
                    tentative[measurement] = old_id
            new[list(tentative)] = True
        count_new = int(new.sum())
        ids[new] = self.next_id + np.arange(count_new)
        for k, old_id in tentative.items():
            self.tentatives[int(ids[k])] = (old_id, self.stats.scans + 1)
        self.created = {int(i): int(k) for k, i in zip(np.flatnonzero(new).tolist(), ids[new].tolist())}
        self.next_id += count_new
        stats = self.stats
        stats.scans += 1
        stats.new += count_new
        stats.associated += len(chosen) + deferred_to_tentative
        stats.discarded += m - len(chosen) - count_new
        stats.nis_sum += float(d2[chosen].sum())
        for i in ids[ids >= 0].tolist():
            self.last_seen[i] = stats.scans
        for i in ids[new].tolist():
            self.started[i] = stats.scans
        if self.detection > 0.0:
            self._coverage.add_scan(np.asarray(filt.pose, dtype=np.float64), filt.sensor)
        if signatures is not None:
            values = np.asarray(signatures, dtype=np.float64)
            for k in np.flatnonzero(ids >= 0).tolist():
                self.signatures.add(int(ids[k]), float(values[k]))
        return ids

    def _unexcluded(self, pair_meas: IntArray, pair_landmark: IntArray, d2: FloatArray, chosen: IntArray) -> np.ndarray:
        """Mask of the pairs that can stop a measurement from starting a new landmark (step 7).

        With ``exclusion_margin``, a pair is left out when another measurement of the scan took its
        landmark (``chosen``) with a ``d2`` smaller by at least the margin; otherwise every pair counts.
        """
        considered = np.ones(len(pair_meas), dtype=bool)
        if self.exclusion_margin is None or not len(chosen):
            return considered
        order = np.argsort(pair_landmark[chosen])
        taken_landmark = pair_landmark[chosen][order]
        taken_d2 = d2[chosen][order]
        taken_meas = pair_meas[chosen][order]
        pos = np.minimum(np.searchsorted(taken_landmark, pair_landmark), len(taken_landmark) - 1)
        hit = taken_landmark[pos] == pair_landmark
        excluded = hit & (taken_meas[pos] != pair_meas) & (d2 - taken_d2[pos] >= self.exclusion_margin)
        return ~excluded

    def _merge(self, filt: SlamFilter, keep: int, remove: int) -> None:
        """``filt.merge_landmarks(keep, remove)`` and the associator's own records of ``remove`` folded into ``keep``."""
        filt.merge_landmarks(keep, remove)
        self.last_seen[keep] = max(self.last_seen.get(keep, 0), self.last_seen.pop(remove, 0))
        self.started.pop(remove, None)
        self.tentatives.pop(remove, None)
        self.signatures.merge(keep, remove)

    def _merge_copies(self, filt: SlamFilter) -> list[tuple[int, int]]:
        """Step 8: merge recent landmarks that form a rigid copy of old ones into them (``loop_merge``).

        Every ``merge_every`` scans, the landmarks near the robot started in
        the last ``merge_recent`` scans are matched against those near it
        started more than ``closure_age`` scans ago (:func:`rigid_submap_match`).
        With ``merge_inliers`` inliers or more, ``merge_margin`` more than any
        disjoint alternative, each inlier is merged into its old landmark
        (``filt.merge_landmarks``). A duplicate started at a loop closure the
        filter was too confident to accept is taken back this way; the test
        uses only the map's relative geometry, so it does not rely on the
        covariance the closure got wrong.
        """
        now = self.stats.scans
        if now == 0 or now % self.merge_every:
            return []
        ids = filt.landmark_ids
        if len(ids) < 2 * self.merge_inliers:
            return []
        positions = np.asarray(filt.landmarks)
        pose = np.asarray(filt.pose)
        # one vectorised pass over the means (as the candidate search); Python work only near the robot
        near = np.flatnonzero(np.hypot(positions[:, 0] - pose[0], positions[:, 1] - pose[1]) < self.merge_radius)
        age = np.array([now - self.started.get(i, -(10**9)) for i in ids[near].tolist()], dtype=np.int64)
        recent_rows, old_rows = near[age < self.merge_recent], near[age > self.closure_age]
        if len(recent_rows) < self.merge_inliers or len(old_rows) < self.merge_inliers:
            return []
        pairs, second = rigid_submap_match(positions[recent_rows], positions[old_rows], self.merge_tolerance,
                                           math.radians(self.merge_rotation), self.merge_shift)  # fmt: skip
        if len(pairs) < self.merge_inliers or len(pairs) - second < self.merge_margin:
            return []
        merges = []
        for r, o in pairs:
            keep, remove = int(ids[old_rows[o]]), int(ids[recent_rows[r]])
            self._merge(filt, keep, remove)
            merges.append((keep, remove))
        self.stats.merged += len(merges)
        return merges

    def _resolve_tentatives(self, filt: SlamFilter) -> list[tuple[int, int]]:
        """Merge each tentative landmark whose closure was accepted and whose correspondence test passes."""
        if not self.tentatives:
            return []
        now = self.stats.scans
        gate = self._thresholds[2][0]
        merges = []
        landmarks = None  # the map's means, read once per call (and again after a merge reorders them)
        for new_id, (old_id, started) in list(self.tentatives.items()):
            try:
                i, j = filt.landmark_index(old_id), filt.landmark_index(new_id)
            except KeyError:  # merged away meanwhile (a copy of the old map)
                del self.tentatives[new_id]
                continue
            if max(self.last_seen.get(old_id, 0), self._closure_accepted) >= started:  # a closure accepted since
                joint = self._joint_covariance(filt, np.array([i, j], dtype=np.int64))
                difference_cov = joint[3:5, 3:5] + joint[5:7, 5:7] - joint[3:5, 5:7] - joint[5:7, 3:5]
                if landmarks is None:
                    landmarks = filt.landmarks
                difference = landmarks[i] - landmarks[j]
                if float(difference @ np.linalg.solve(difference_cov, difference)) <= gate:
                    self._merge(filt, old_id, new_id)
                    merges.append((old_id, new_id))
                    landmarks = None
                    continue
            if now - started > self.closure_window:
                del self.tentatives[new_id]
        self.stats.merged += len(merges)
        return merges

    def _joint_decision(
        self,
        gated: IntArray,
        chosen: IntArray,
        pair_meas: IntArray,
        pair_landmark: IntArray,
        logdet: FloatArray,
        euclid2: FloatArray,
    ) -> IntArray:
        """JCBB over the gated pairs from the assignment ``chosen``, then the test against new landmarks."""
        pose, candidates, joint, noise, ranges, bearings, pair_slot = self._last
        nu, H = pair_innovations(pose, candidates, ranges, bearings, pair_meas[gated], pair_slot[gated])
        cov = joint_innovation_covariance(H, pair_slot[gated], pair_meas[gated], joint, noise)
        position = {int(k): p for p, k in enumerate(gated.tolist())}
        seed = [position[int(k)] for k in chosen.tolist()]
        local = np.array(seed, dtype=np.int64)

        def log_new_landmark(pairs: IntArray) -> FloatArray:
            """The log density of each pair's measurement under "an unmapped landmark" (step 5)."""
            r = ranges[pair_meas[pairs]]
            sigma2 = r * np.exp(0.5 * logdet[pairs])  # isotropic Cartesian variance of the projected offset
            inside = scipy.stats.ncx2.cdf(self.landmark_separation**2 / sigma2, 2, euclid2[pairs] / sigma2)
            unseen = (1.0 - self.detection) ** self._coverage.counts(self._last_points[pair_meas[pairs]])
            return np.log(self.landmark_density * r * np.maximum((1.0 - inside) * unseen, 1e-300))

        by_likelihood = self.joint_objective == "likelihood" and self.landmark_density > 0.0
        log_new_gated = log_new_landmark(gated) if by_likelihood else None
        if self.joint and len(np.unique(pair_meas[gated])) > 1:
            gains, noise_logdet = None, -math.inf  # rank the hypotheses by their number of pairings
            if log_new_gated is not None:  # or by their likelihood ratio against new landmarks
                gains, noise_logdet = -math.log(2.0 * math.pi) - log_new_gated, float(np.linalg.slogdet(noise)[1])
            local = jcbb(nu, cov, pair_meas[gated], pair_landmark[gated], self.joint_gate, self.max_nodes,
                         initial=seed, gains=gains, noise_logdet=noise_logdet)  # fmt: skip
        if self.landmark_density > 0.0:
            log_new = log_new_landmark(gated[local]) if log_new_gated is None else log_new_gated[local]
            keep = np.ones(len(local), dtype=bool)
            while keep.any():
                margin = conditional_loglik(nu, cov, local[keep]) - log_new[keep]
                worst = int(np.argmin(margin))
                if margin[worst] >= 0.0:
                    break
                keep[np.flatnonzero(keep)[worst]] = False
            local = local[keep]
        return gated[np.sort(local)]

    def _defer_lone_closures(self, filt: SlamFilter, chosen: IntArray, pair_landmark: IntArray) -> IntArray:
        """Drop the loop-closing pairs of ``chosen`` until enough distinct landmarks back them.

        A pair closes a loop when its landmark was last associated more than ``closure_age`` scans
        ago. Its measurement is discarded (it lies inside the gate of a mapped landmark, so it is
        not a new landmark either) unless the closing landmarks of this scan and of the closing
        pairs proposed in the last ``closure_window`` scans number at least ``closure_pairings``.
        """
        ids = filt.landmark_ids[pair_landmark[chosen]].tolist()
        now = self.stats.scans
        closing = np.array([now - self.last_seen.get(int(i), now) > self.closure_age for i in ids], dtype=bool)
        if not closing.any():
            return chosen
        proposals = self._proposals
        while proposals and proposals[0][0] < now - self.closure_window:
            proposals.popleft()
        current = {int(i) for i, c in zip(ids, closing.tolist()) if c}
        proposals.extend((now, i) for i in current)
        if len(current | {i for _, i in proposals}) >= self.closure_pairings:
            self._closure_accepted = now
            return chosen
        self.stats.deferred += int(closing.sum())
        self._deferred = chosen[closing]
        return chosen[~closing]

    def update(
        self, filt: SlamFilter, ranges: ArrayLike, bearings: ArrayLike, signatures: ArrayLike | None = None
    ) -> IntArray:
        """:meth:`associate`, then ``filt.update_trusted`` with the kept measurements; returns the ids."""
        ranges = np.ascontiguousarray(ranges, dtype=np.float64)
        bearings = np.ascontiguousarray(bearings, dtype=np.float64)
        ids = self.associate(filt, ranges, bearings, signatures)
        keep = ids >= 0
        filt.update_trusted(ranges[keep], bearings[keep], ids[keep])
        return ids


class AssociationAudit:
    """Scores an :class:`Associator` against the true ids of a simulation.

    Each associator id is attributed to the true landmark of the measurement
    that created it. A decision *agrees* with the truth when a measurement is
    associated with a landmark attributed to its own true id, or starts a new
    landmark for a true landmark that has none yet; a discarded measurement,
    a wrong association or a duplicate landmark is an error.

    Merges (``Associator(loop_merge=True)``) revise the score: a duplicate
    merged into the landmark of its own true id is a duplicate no more, and
    the measurement that started it now informs the right landmark (it
    agrees); a merge of two different true landmarks turns every agreeing
    measurement of the removed one into an error. The figures are then those
    of the final map; ``duplicates_started`` keeps the count at the time of
    the decisions.

    Attributes
    ----------
    true_of : dict
        Associator id -> true id.
    agree, errors, discarded, total : int
        Counts over everything recorded (``errors`` includes ``discarded``).
    duplicates : int
        Landmarks of the map started for a true landmark that already had one
        (each is also counted in ``errors``).
    duplicates_started : int
        Duplicates ever started (merged ones included).
    merges_right, merges_wrong : int
        Merges of two landmarks of one true id, and of different ones.
    """

    def __init__(self) -> None:
        self.true_of: dict[int, int] = {}
        self._mapped: set[int] = set()
        self._seen: set[int] = set()
        self._duplicate: set[int] = set()  # associator ids started as duplicates, still in the map
        self._agreeing: dict[int, int] = {}  # associator id -> its agreeing measurements
        self.agree = self.errors = self.discarded = self.total = 0
        self.duplicates = self.duplicates_started = 0
        self.merges_right = self.merges_wrong = 0

    def record(self, associator: Associator, ids: ArrayLike, true_ids: ArrayLike) -> int:
        """Score one scan: ``ids`` from ``associator.associate``/``update``, ``true_ids`` the truth.

        The merges the associator made before this scan (``associator.merges``)
        are scored first. Returns the number of measurements of this scan that
        disagree.
        """
        for keep, remove in associator.merges:
            self._merge(keep, remove)
        ids = np.asarray(ids)  # for len()
        errors = 0
        for k, (given, true) in enumerate(zip(np.asarray(ids).tolist(), np.asarray(true_ids).tolist())):
            if given < 0:
                ok = False
                self.discarded += 1
            elif associator.created.get(given) == k:
                ok = true not in self._mapped
                if not ok:
                    self.duplicates += 1
                    self.duplicates_started += 1
                    self._duplicate.add(given)
                self.true_of[given] = true
                self._mapped.add(true)
            else:
                ok = self.true_of.get(given) == true
            if ok and given >= 0:
                self._agreeing[given] = self._agreeing.get(given, 0) + 1
            errors += not ok
        self._seen.update(np.asarray(true_ids).tolist())
        self.total += len(ids)
        self.errors += errors
        self.agree += len(ids) - errors
        return errors

    def _merge(self, keep: int, remove: int) -> None:
        agreeing = self._agreeing.pop(remove, 0)
        if self.true_of.get(keep) == self.true_of.get(remove):
            self.merges_right += 1
            if remove in self._duplicate:  # its first measurement now informs its own landmark
                self.duplicates -= 1
                self.errors -= 1
                self.agree += 1
                agreeing += 1
            self._agreeing[keep] = self._agreeing.get(keep, 0) + agreeing
        else:
            self.merges_wrong += 1
            self.errors += agreeing
            self.agree -= agreeing
            if remove in self._duplicate:
                self.duplicates -= 1  # no longer a landmark of the map (its measurements are errors now)
        self._duplicate.discard(remove)

    @property
    def true_landmarks(self) -> int:
        """Number of distinct true landmarks measured so far."""
        return len(self._seen)

    @property
    def duplicate_fraction(self) -> float:
        """Duplicate landmarks (created for a true landmark already mapped) over the true landmarks measured."""
        return self.duplicates / self.true_landmarks if self._seen else float("nan")

    @property
    def agreement(self) -> float:
        """Fraction of the recorded measurements whose decision agrees with the truth."""
        return self.agree / self.total if self.total else float("nan")

    def true_ids(self, landmark_ids: ArrayLike) -> IntArray:
        """The true id attributed to each of ``landmark_ids`` (associator ids; -1 if unknown)."""
        return np.array([self.true_of.get(int(i), -1) for i in np.asarray(landmark_ids).tolist()], dtype=np.int64)


#: Named ``Associator`` settings. ``"individual"``: seif_gym 0.1's individual-compatibility
#: association, reproduced bit for bit (the env's ``-v0`` ids; ``joint=False`` also turns off the deferral of
#: lone loop closures); ``"joint"``: the defaults; ``"revisable"``: the defaults with merges (``loop_merge``) and
#: tentative landmarks for deferred lone closures (``tentative_closures``): association that is taken back;
#: ``"likelihood"``: ``"revisable"`` with the joint hypotheses ranked by their likelihood ratio against new landmarks
#: (``joint_objective``), a 0.9999 gate, and new landmarks next to a landmark another measurement of the scan took
#: (``exclusion_margin``: the swapped assignment 100 times less likely).
ASSOCIATOR_PRESETS: dict[str, dict[str, Any]] = {
    "individual": {"joint": False, "landmark_density": 0.0, "blanket_size": 0, "detection": 0.0},
    "joint": {},
    "revisable": {"loop_merge": True, "tentative_closures": True},
    "likelihood": {
        "loop_merge": True,
        "tentative_closures": True,
        "joint_objective": "likelihood",
        "gate": 0.9999,
        "exclusion_margin": 2.0 * math.log(100.0),
    },
}


def make_associator(preset: str = "joint", **overrides: Any) -> Associator:
    """An :class:`Associator` with the settings of a named preset.

    Parameters
    ----------
    preset : str
        A key of :data:`ASSOCIATOR_PRESETS`: ``"joint"`` (the defaults: joint compatibility, the
        pairing-vs-new-landmark test, deferred lone loop closures), ``"individual"`` (seif_gym
        0.1's associator, bit for bit), ``"revisable"`` (merges and tentative closures) or
        ``"likelihood"`` (revisable, with hypotheses ranked by likelihood).
    **overrides
        Further :class:`Associator` keyword arguments; they take precedence over the preset's.

    Returns
    -------
    Associator

    Raises
    ------
    ValueError
        ``preset`` is not a key of :data:`ASSOCIATOR_PRESETS` (or an override is invalid).
    """
    if not isinstance(preset, str) or preset not in ASSOCIATOR_PRESETS:
        raise ValueError(f"preset must be one of {tuple(ASSOCIATOR_PRESETS)}, got {preset!r}")
    return Associator(**{**ASSOCIATOR_PRESETS[preset], **overrides})
