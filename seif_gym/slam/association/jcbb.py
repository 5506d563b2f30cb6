"""Joint compatibility branch and bound (Neira & Tardos 2001): step 4 of :mod:`seif_gym.slam.association`.

:func:`jcbb` runs the compiled search (``_jcbb_compiled``, growing the Cholesky factor of the joint
innovation covariance with ``_grow``) or the plain-Python reference :class:`_JointSearch`; both return
the same hypothesis.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg
from numba import njit

from seif_gym.slam.association.gating import _chi2_limit
from seif_gym.type_aliases import FloatArray, IntArray

__all__ = ["jcbb"]


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
