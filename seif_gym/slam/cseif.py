"""A conservative sparse extended information filter: certified sparsification in constant time.

The SEIF (:mod:`seif_gym.slam.seif`) removes the robot's link to a landmark by
conditioning on that landmark's mean: cheap and accurate, but the result can
hold more information than the data give (it can be overconfident). The ESEIF
(:mod:`seif_gym.slam.eseif`) is conservative, but only because it throws the
pose's information away and relocalizes from a few landmarks.
:class:`ConservativeSEIF` removes one robot link at a time, like the SEIF, by
*subtracting* a positive semidefinite matrix ``S`` supported on the block of
the robot and its active landmarks (conservative sparsification in the sense of
Vial, Durrant-Whyte & Bailey, IROS 2011; the bounded-clique view of generic node
removal, Carlevaris-Bianco, Kaess & Eustice, T-RO 2014)::

    Omega~ = Omega - S,   S >= 0,   S_{x m0} = Omega_{x m0},   xi~ = xi - S mu

so that ``Omega~ <= Omega`` (``Sigma~ >= Sigma``, nothing is made more certain),
the link is exactly zero and the mean is kept.

**The certificate.** Subtracting ``S`` keeps ``Omega~`` positive definite only
if ``S`` is below the information that the *whole* map holds in its directions
(``lambda_max(S Sigma) < 1`` with the exact covariance), which no constant-time
computation on a bounded block can bound: the Markov-blanket covariance can
underestimate it by any factor (``docs/filters/fidelity.md`` measures it on a
loop). The filter therefore
keeps a split of its information matrix that certifies every cut locally::

    Omega = Omega_A + Omega_B,   Omega_A >= 0 with zero robot rows,
                                 Omega_B >= 0 supported on the robot and the active landmarks

``Omega_B`` (the *local* information: the robot's prior and odometry, and the
measurements of the active landmarks since they became active) is
``Omega`` on the active block minus ``A``, the active landmarks' block of
``Omega_A``, which the filter stores (a dense matrix over the active set, never
over the map). A cut with ``S <= c Omega_B``, ``c < 1``, gives
``Omega~ >= Omega_A + (1 - c) Omega_B >= (1 - c) Omega``: positive definite,
whatever the rest of the map holds. See :class:`ConservativeSEIF`, Notes, for
how the split is kept through every step.

Every step costs time in the size of the active set (at most
``max(max_active_hard, |scan|)`` landmarks), never in the size of the map; memory is the
SEIF's plus one ``2a x 2a`` matrix for ``a`` active landmarks.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from seif_gym.slam import _kernels
from seif_gym.slam.seif import SEIF
from seif_gym.type_aliases import FloatArray, IntArray
from seif_gym.validation import as_count, as_scalar_between

__all__ = [
    "ConservativeSEIF",
    "cut_direction",
    "apply_cut",
    "local_information",
]


def _sqrtm_psd(matrix: FloatArray) -> FloatArray:
    """Symmetric square root of a positive semidefinite matrix (negative round-off clipped)."""
    values, vectors = np.linalg.eigh(0.5 * (matrix + matrix.T))
    return np.asarray((vectors * np.sqrt(np.clip(values, 0.0, None))) @ vectors.T)


def local_information(omega: FloatArray, map_info: FloatArray) -> FloatArray:
    """``Omega_B``: the block ``omega`` over the robot and the active landmarks, less ``A`` on the landmarks.

    Parameters
    ----------
    omega : ndarray, shape (3 + 2a, 3 + 2a)
        ``Omega`` over the robot and the ``a`` active landmarks (robot first).
    map_info : ndarray, shape (2a, 2a)
        ``A``: the active landmarks' block of ``Omega_A`` (robot rows are zero there).

    Returns
    -------
    ndarray, shape (3 + 2a, 3 + 2a)
        ``Omega_B = omega - (0 (+) A)``.
    """
    local = omega.copy()
    local[3:, 3:] -= map_info
    return local


def cut_direction(omega: FloatArray, local: FloatArray, position: int) -> tuple[FloatArray, float]:
    """The factor ``U`` of the cut of the robot's link to the landmark at block ``position``, and its cost.

    Parameters
    ----------
    omega : ndarray, shape (s, s)
        ``Omega`` over the robot and the active landmarks (robot first).
    local : ndarray, shape (s, s)
        ``Omega_B`` over the same block (:func:`local_information`).
    position : int
        Block position of the landmark ``m0`` (rows ``3 + 2 position``, ``4 + 2 position``).

    Returns
    -------
    U : ndarray, shape (s, 2)
        ``S = U U^T`` is the matrix to subtract; ``S_{x m0} = Omega_{x m0}``.
    cost : float
        ``c = lambda_max(U^T Omega_B^+ U)``: ``S <= c Omega_B``. ``inf`` when
        ``Omega_B`` is singular on the robot and ``m0`` (the cut cannot be certified).

    Notes
    -----
    With ``b = (x, m0)``, ``r`` the other active landmarks, ``B = Omega_{x m0}``
    and ``P = [Omega_B]_bb^-1`` (the covariance of ``b`` given ``r`` in the local
    information alone), the cut is::

        M = B^T P_xx B,   N = P_{m0 m0}
        D = N^-1/2 (N^1/2 M N^1/2)^1/2 N^-1/2        (the geometric mean N^-1 # M)
        u = [B D^-1/2 ; D^1/2]                       (so that u_x u_m0^T = B)
        U_b = u,   U_r = [Omega_B]_rb P u
        c = lambda_max(u^T P u)

    ``S = U U^T = [Omega_B]_{:b} (P u)(P u)^T [Omega_B]_{b:}``, and for any
    ``W`` with ``W^T [Omega_B]_bb W <= c I`` the bound
    ``[Omega_B]_{:b} W W^T [Omega_B]_{b:} <= c [Omega_B]_{:b} [Omega_B]_bb^-1 [Omega_B]_{b:} <= c Omega_B``
    holds (the last matrix is ``Omega_B`` less its Schur complement on ``r``).
    ``U_r`` is the extension of ``u`` that minimises ``tr(U^T Omega_B^+ U)``,
    and ``D`` minimises ``tr(B D^-1 B^T P_xx) + tr(D P_{m0 m0})``, the first-order
    Kullback-Leibler divergence of the cut (Vial et al.'s objective, here
    measured with the local information).
    """
    size = len(omega)
    rows = np.array([0, 1, 2, 3 + 2 * position, 4 + 2 * position])
    link = omega[:3, 3 + 2 * position : 5 + 2 * position]
    if not np.any(link):
        return np.zeros((size, 2)), 0.0
    block = local[np.ix_(rows, rows)]
    try:
        cov = np.linalg.inv(np.linalg.cholesky(block))
    except np.linalg.LinAlgError:
        return np.zeros((size, 2)), float("inf")
    cov = cov.T @ cov
    m = link.T @ cov[:3, :3] @ link
    m = m + 1e-12 * np.trace(m) * np.eye(2)
    root_n = _sqrtm_psd(cov[3:, 3:])
    try:
        inverse_root_n = np.linalg.inv(root_n)
        d = inverse_root_n @ _sqrtm_psd(root_n @ m @ root_n) @ inverse_root_n
        root_d = _sqrtm_psd(d)
        u = np.vstack([link @ np.linalg.inv(root_d), root_d])
    except np.linalg.LinAlgError:
        return np.zeros((size, 2)), float("inf")
    weights = cov @ u
    cost = float(np.linalg.eigvalsh(u.T @ weights)[-1])
    if not np.isfinite(cost):
        return np.zeros((size, 2)), float("inf")
    factor = local[:, rows] @ weights
    factor[rows] = u
    return factor, cost


def apply_cut(
    omega: FloatArray,
    xi: FloatArray,
    mu: FloatArray,
    map_info: FloatArray,
    position: int,
    factor: FloatArray,
    compiled: bool = False,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Subtract ``S = U U^T`` and move the landmark's remaining local information into ``Omega_A``.

    Parameters
    ----------
    omega, xi, mu : ndarray
        ``Omega`` (s, s), ``xi`` and ``mu`` (s,) over the robot and the active landmarks.
    map_info : ndarray, shape (s - 3, s - 3)
        ``A`` over the active landmarks.
    position : int
        Block position of the landmark being deactivated.
    factor : ndarray, shape (s, 2)
        ``U`` of :func:`cut_direction`.
    compiled : bool, default False
        Run the compiled kernel :func:`~seif_gym.slam._kernels.apply_cut_block` (the same
        operations in the same order, with numba's matrix products and 2 x 2 solve; the filter's
        compiled implementation and the batched filters of
        :class:`~seif_gym.slam.batched.BatchedConservativeSEIF` share it) instead of numpy.

    Returns
    -------
    omega, xi : ndarray
        The block after the cut (the robot-``m0`` blocks exactly zero).
    map_info : ndarray, shape (s - 5, s - 5)
        ``A`` over the landmarks that stay active.

    Notes
    -----
    ::

        Omega~ = Omega - U U^T   (robot-m0 blocks set to exact zeros)
        xi~    = xi - U U^T mu
        Omega_B~ = Omega~ - (0 (+) A) = [[K, C], [C^T, E]]     (m0 last, C's robot rows zero)
        A~ = A_kk + C E^-1 C^T                                 (over the landmarks kept)

    ``Omega_B~`` splits into ``[[C E^-1 C^T, C], [C^T, E]]`` (positive
    semidefinite, no robot rows: it joins ``Omega_A``) and its Schur complement
    ``K - C E^-1 C^T`` (positive semidefinite, on the robot and the landmarks
    kept: the new ``Omega_B``). ``Omega`` itself does not change in the move.
    """
    if compiled:
        omega, xi, map_info = _kernels.apply_cut_block(omega, xi, mu, map_info, position, factor)
        return omega, xi, map_info
    size = len(xi)
    cut = factor @ factor.T
    m0 = np.array([3 + 2 * position, 4 + 2 * position])
    omega = omega - cut
    omega[:3, m0] = 0.0
    omega[m0, :3] = 0.0
    omega = 0.5 * (omega + omega.T)
    xi = xi - cut @ mu
    local = local_information(omega, map_info)
    kept = np.setdiff1d(np.arange(3, size), m0)
    coupling = local[np.ix_(kept, m0)]
    moved = coupling @ np.linalg.solve(local[np.ix_(m0, m0)], coupling.T)
    kept_landmark_rows = kept - 3
    new_map_info = map_info[np.ix_(kept_landmark_rows, kept_landmark_rows)] + moved
    return omega, xi, 0.5 * (new_map_info + new_map_info.T)


class ConservativeSEIF(SEIF):
    """Sparse extended information filter SLAM whose sparsification is certified conservative.

    Same interface as :class:`~seif_gym.slam.seif.SEIF` (motion and
    measurement updates, mean recovery, Markov-blanket marginals and the
    read-only state are the SEIF's); only the sparsification differs.

    Parameters
    ----------
    motion, sensor, initial_pose, initial_pose_cov
        See :class:`~seif_gym.slam.base.SlamFilter`.
    max_active : int or None, default 8
        ``k``: after each update the robot's links are cut (the cheapest
        certified cut first) until at most ``k`` remain. ``None`` never
        sparsifies (the filter is then the exact EIF).
    max_active_hard : int or None, default None
        ``H``, the hard bound on the active set (at least ``max_active``;
        ``None``: ``2 max_active``). When no cut can be certified the active
        set may grow past ``k`` up to ``max(H, |scan|)``; a measurement of a
        landmark not yet active that would take it further is left out
        (counted in ``discarded_measurements``). Every step thus costs time in
        ``max(H, |scan|)``.
    cut_budget : float, default 0.9
        ``c_max`` in ``(0, 1)``: a cut must satisfy ``S <= c Omega_B`` with
        ``c <= c_max`` (see Notes), so that each cut keeps
        ``Omega~ >= (1 - c_max) Omega``.
    recovery_budget : int, default 512
        Queued landmarks relaxed per update by the wavefront recovery (the
        SEIF's option, with a larger default: a cut keeps the mean but leaves
        the landmark links weaker than the SEIF's, so a loop closure's
        correction needs more relaxations to travel through the map).
    mean_recovery, recovery_landmarks, recovery_relaxation, recovery_tolerance, implementation
        As for the SEIF.

    Attributes
    ----------
    cuts : int
        Robot links removed so far.
    deferred_cuts : int
        Updates that ended with more than ``k`` active landmarks because no
        cut could be certified.
    discarded_measurements : int
        Measurements left out to keep the hard bound.

    Notes
    -----
    **The split.** The filter keeps ``Omega = Omega_A + Omega_B`` with
    ``Omega_A >= 0`` zero in the robot's rows and ``Omega_B >= 0`` zero
    outside the robot and the active set ``Gamma``; it stores ``A``, the block
    of ``Omega_A`` over ``Gamma``, so that ``Omega_B`` is the gathered block of
    ``Omega`` less ``A`` (:func:`local_information`). Each step keeps it:

    * *start*: ``Omega_B`` is the pose prior, ``Omega_A = 0``;
    * *motion update* (Probabilistic Robotics, Table 12.2): ``lambda``,
      ``kappa`` involve only the robot's rows, which ``Omega_A`` lacks, so
      ``Omega_bar = Omega_A + motion_update(Omega_B)`` exactly; the update of a
      positive semidefinite matrix is positive semidefinite; ``A`` is unchanged;
    * *measurement update*: ``H_i^T Q^-1 H_i`` joins ``Omega_B``; a landmark that
      becomes active brings its rows of ``Omega`` (all of them in ``Omega_A``)
      into ``A``, whose new rows are ``Omega``'s before the update;
    * *cut* of the link to ``m0`` (:func:`cut_direction`, :func:`apply_cut`)::

          Omega~ = Omega - S,   xi~ = xi - S mu,   S = U U^T <= c Omega_B,  c <= c_max < 1

      then ``m0``'s conditional part of ``Omega_B - S`` moves to ``Omega_A``;
    * *merging two landmarks* (data association's revision): ``A`` is reset
      to the robot-marginal ``Omega_GammaGamma - Omega_Gammax Omega_xx^-1 Omega_xGamma``
      (so that ``Omega_B`` is the robot's conditional factor, rank 3, a valid
      if pessimistic split); cuts resume as measurements add to ``Omega_B``.

    **Why it is conservative and stays positive definite.** ``S >= 0`` gives
    ``Omega~ <= Omega``; ``S <= c Omega_B`` gives
    ``Omega~ >= Omega_A + (1 - c) Omega_B >= (1 - c) Omega > 0``. Motion and
    measurement updates are monotone (a matrix with less information stays
    below one with more, at the same linearization points), so on noise-free
    data, where every filter linearizes at the truth,
    ``Sigma_CSEIF >= Sigma_EIF`` after every step (``tests/slam/test_cseif.py``).
    Leaving a measurement out only loses information.

    **Which link.** Among the active landmarks not observed in this update,
    the one with the smallest certified cost ``c``; cuts repeat until ``k``
    remain or the cheapest cost exceeds ``c_max``. Each cut costs
    ``O(a^3)`` for ``a`` active landmarks, whatever the size of the map.
    """

    OPTIONS: ClassVar[dict[str, Any]] = {
        **SEIF.OPTIONS,
        "recovery_budget": 512,
        "max_active_hard": None,
        "cut_budget": 0.9,
    }
    _COUNTERS: ClassVar[tuple[str, ...]] = ("_map_info", "cuts", "deferred_cuts", "discarded_measurements")

    def _check_options(self, options: dict[str, Any]) -> None:
        super()._check_options(options)
        hard = options["max_active_hard"]
        if hard is not None:
            as_count(hard, "max_active_hard", minimum=1)
            if options["max_active"] is None:
                raise ValueError("max_active_hard needs max_active (None never sparsifies)")
            if hard < options["max_active"]:
                raise ValueError(f"max_active_hard ({hard}) must be at least max_active ({options['max_active']})")
        as_scalar_between(options["cut_budget"], "cut_budget", 0.0, 1.0)

    def _initialize(self, pose: FloatArray, pose_cov: FloatArray) -> None:
        super()._initialize(pose, pose_cov)
        hard = self.options["max_active_hard"]
        self.max_active_hard: int | None = (
            None if self.max_active is None else (2 * self.max_active if hard is None else int(hard))
        )
        self.cut_budget = float(self.options["cut_budget"])
        self.cuts = 0
        self.deferred_cuts = 0
        self.discarded_measurements = 0
        # A: Omega_A over the active landmarks, in the order of self._active (replaced, never written in place)
        self._map_info: FloatArray = np.zeros((0, 0))

    # -- the hard bound ------------------------------------------------------------
    def _update_known(self, ranges: FloatArray, bearings: FloatArray, ids: NDArray[np.int64]) -> None:
        """The update; measurements that would take the active set past the hard bound are left out."""
        kept = self._within_hard_bound(ranges, ids)
        if kept is not None:
            ranges, bearings, ids = ranges[kept], bearings[kept], ids[kept]
        super()._update_known(ranges, bearings, ids)
        if kept is not None:
            self.discarded_measurements += len(kept) - int(np.count_nonzero(kept))

    def _within_hard_bound(self, ranges: FloatArray, ids: NDArray[np.int64]) -> NDArray[np.bool_] | None:
        """Mask of the measurements to keep (``None``: all): the active ones, then mapped, then the nearest.

        After the update at most ``max(max_active_hard, |scan|)`` landmarks are active.
        """
        if self.max_active_hard is None or len(ids) == 0:
            return None
        indices = np.array([self._id_to_index.get(i, -1) for i in ids.tolist()], dtype=np.int64)
        mapped = indices >= 0
        active = np.zeros(len(ids), dtype=bool)
        active[mapped] = self._is_active[indices[mapped]]
        others = np.flatnonzero(~active)
        room = max(self.max_active_hard, len(np.unique(ids))) - len(self._active)
        if len(np.unique(ids[others])) <= room:
            return None
        order = np.lexsort((ranges[others], ~mapped[others]))  # mapped first, then the nearest
        kept = active.copy()
        kept[others[order[: max(room, 0)]]] = True
        return kept

    # -- the split: A follows the active set -------------------------------------------
    def _incorporate(self, ranges: FloatArray, bearings: FloatArray, indices: IntArray, weight: float = 1.0) -> None:
        """The SEIF's measurement update; a landmark that becomes active brings its rows of ``Omega`` into ``A``."""
        if len(indices) == 0 or self.max_active is None:
            super()._incorporate(ranges, bearings, indices, weight)
            return
        old = self._active
        newly = indices[~self._is_active[indices]]
        newly = newly[np.sort(np.unique(newly, return_index=True)[1])]  # first occurrence order
        block = np.concatenate([old, newly])
        if len(newly):
            omega, _, _ = _kernels.gather(*self._store.kernel_arrays(), block)
            grown = omega[3:, 3:].copy()
            grown[: 2 * len(old), : 2 * len(old)] = self._map_info
        super()._incorporate(ranges, bearings, indices, weight)
        if len(newly):
            self._map_info = self._reordered(grown, block, self._active)

    @staticmethod
    def _reordered(map_info: FloatArray, order: IntArray, target: IntArray) -> FloatArray:
        """``map_info`` over the landmarks ``order`` rearranged into the order ``target`` (a permutation)."""
        position = {int(i): p for p, i in enumerate(order.tolist())}
        perm = np.array([position[int(i)] for i in target.tolist()], dtype=np.int64)
        rows = (2 * perm[:, None] + np.arange(2)).ravel()
        return np.ascontiguousarray(map_info[np.ix_(rows, rows)])

    def _merge_step(self, keep: int, remove: int) -> None:
        super()._merge_step(keep, remove)
        if self.max_active is None:
            return
        # the robot-marginal over the active set: a valid (pessimistic) split, O(a^3)
        omega, _, _ = _kernels.gather(*self._store.kernel_arrays(), self._active)
        gain = np.linalg.solve(omega[:3, :3], omega[:3, 3:])
        map_info = omega[3:, 3:] - omega[3:, :3] @ gain
        self._map_info = 0.5 * (map_info + map_info.T)

    # -- sparsification -----------------------------------------------------------------
    def _sparsify(self) -> None:
        """Cut the cheapest certified robot links until ``k`` remain (:func:`cut_direction`, :func:`apply_cut`)."""
        if self.max_active is None:
            return
        store = self._store
        deferred = False
        while len(self._active) > self.max_active:
            recent = self._last_observed[self._active] == self._update_count
            candidates = np.flatnonzero(~recent)
            if len(candidates) == 0:
                break
            omega, xi, mu = _kernels.gather(*store.kernel_arrays(), self._active)
            local = local_information(omega, self._map_info)
            position, factor, cost = self._cheapest_cut(omega, local, candidates)
            if not cost <= self.cut_budget:
                deferred = True
                break
            compiled = self.options["implementation"] == "compiled"
            omega, xi, map_info = apply_cut(omega, xi, mu, self._map_info, position, factor, compiled=compiled)
            store.reserve_degree(self._active, len(self._active))
            _kernels.scatter(*store.kernel_arrays()[:7], self._active, omega, xi)
            gone = int(self._active[position])
            self._active = np.delete(self._active, position)
            self._is_active[gone] = False
            self._map_info = map_info
            self.cuts += 1
        self.deferred_cuts += int(deferred)

    def _cheapest_cut(
        self, omega: FloatArray, local: FloatArray, candidates: IntArray
    ) -> tuple[int, FloatArray, float]:
        """The cheapest cut among the block positions ``candidates``: its position, ``U`` and cost.

        The compiled kernel (:func:`~seif_gym.slam._kernels.cheapest_cut`), or :func:`cut_direction` for
        each candidate with ``implementation="reference"``; the first of equal costs wins.
        """
        if self.options["implementation"] == "compiled":
            position, factor, cost = _kernels.cheapest_cut(omega, local, np.asarray(candidates, dtype=np.int64))
            return int(position), factor, float(cost)
        best: tuple[int, FloatArray, float] | None = None
        for position in candidates.tolist():
            factor, cost = cut_direction(omega, local, position)
            if best is None or cost < best[2]:
                best = (position, factor, cost)
        assert best is not None
        return best

    def _state_nbytes(self) -> int:
        return super()._state_nbytes() + self._map_info.nbytes
