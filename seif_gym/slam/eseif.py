"""The Exactly Sparse Extended Information Filter (Walter, Eustice & Leonard, IJRR 2007).

The SEIF (:mod:`seif_gym.slam.seif`) bounds the robot's links by
*approximating* the posterior: its sparsification step enforces a conditional
independence that the posterior does not have, and the result can hold more
information than the data give (the filter becomes overconfident; Eustice,
Walter & Leonard, IROS 2005). The ESEIF bounds the same links without any
approximation of the information it keeps. When the active set would grow
past its bound ``k`` it *sparsifies by relocalization*:

1. split the scan's measurements into ``z_alpha`` and ``z_beta``, where
   ``z_beta`` are a few measurements of landmarks mapped before this scan
   (:func:`select_relocalization_landmarks`);
2. incorporate ``z_alpha`` as usual (:func:`seif_gym.slam.seif.measurement_update`);
3. marginalize the robot pose out (:func:`marginalize_robot`): exact, it only
   links the landmarks that were linked to the robot to one another;
4. start a new robot pose with no prior information and add the measurement
   factors of ``z_beta`` to it (the equations of the measurement update
   applied to the marginalized matrix). The new pose is linked to the
   ``z_beta`` landmarks only.

A scan with fewer than two landmarks mapped before it cannot relocalize
this way; it relocalizes by a *split*: two of its measurements inform both the
map (through the old pose) and the new pose, with information weights ``w``
and ``1 - w``, which covariance intersection shows to be conservative. Only a
lone measurement beyond the bound is left out. The bound holds after every
update (see :class:`ESEIF`, Notes).

Every step is exact Gaussian inference except that the information the
marginalized pose carried about the *current* pose (odometry and past
measurements, given the map) is discarded, and ``z_beta`` informs only the new
pose, not the map through the old one. Discarding information can only make
the filter less certain: the ESEIF is conservative with respect to the EIF
(see :class:`ESEIF`, Notes, for the argument; ``tests/slam/test_eseif.py`` checks
``Sigma_ESEIF - Sigma_EIF >= 0`` along a run).

Every step costs time in the size of the active set and of the scan, never in
the size of the map: marginalizing the robot touches only the block of the
robot and the landmarks linked to it. Like :mod:`seif_gym.slam.seif`, this
module has plain numpy *reference* functions and compiled (numba) twins used by
default; ``implementation="reference"`` runs the former.
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar, NamedTuple

import numpy as np
from numpy.typing import NDArray

from seif_gym.slam import _kernels
from seif_gym.slam._kernels import (
    _pose_information,
    marginalize_robot_block,
    relocalization_pose_information,
    select_relocalization_landmarks,
)
from seif_gym.slam.information import InformationStore
from seif_gym.slam.seif import SEIF, CompiledSEIFBackend, ReferenceSEIFBackend, SEIFBackend
from seif_gym.type_aliases import FloatArray, IntArray
from seif_gym.validation import as_count, as_scalar_between

__all__ = [
    "ESEIF",
    "RELOCALIZATION_RCOND",
    "marginalize_robot",
    "marginalize_robot_block",
    "relocalization_pose_information",
    "select_relocalization_landmarks",
]


#: A relocalization is refused when the pose information it would give has
#: ``lambda_min < RELOCALIZATION_RCOND * lambda_max`` (a degenerate geometry).
RELOCALIZATION_RCOND = 1e-9


# ---------------------------------------------------------------------------
# Reference functions (dense blocks, literal equations)
# ---------------------------------------------------------------------------
def marginalize_robot(omega: FloatArray, xi: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Marginalize the robot out of the block of the robot and the landmarks linked to it.

    Parameters
    ----------
    omega, xi : ndarray
        Information matrix (s, s) and vector (s,) of the block, robot first
        (rows 0-2), then every landmark with a non-zero robot link (the
        landmarks outside the block have ``Omega_xm = 0`` and are unaffected).

    Returns
    -------
    omega_marg, xi_marg : ndarray
        The same block with the robot rows and columns (and ``xi_x``) exactly
        zero, and the landmark block replaced by its Schur complement.

    Notes
    -----
    With ``m`` the landmarks of the block::

        Omega_mm' = Omega_mm - Omega_mx Omega_xx^-1 Omega_xm
        xi_m'     = xi_m     - Omega_mx Omega_xx^-1 xi_x
        Omega_xx' = 0,  Omega_xm' = 0,  xi_x' = 0

    ``(Omega_mm', xi_m')`` is the exact information form of the marginal
    ``p(m | data)``; its mean is the ``m`` part of ``Omega^-1 xi``. The landmark
    block becomes dense: every landmark linked to the robot is now linked to
    every other one. The zero robot rows are the "no prior" of the new pose
    that :class:`ESEIF` relocalizes next.
    """
    robot, rest = slice(0, 3), slice(3, len(xi))
    gain = np.linalg.solve(omega[robot, robot], omega[robot, rest]).T  # Omega_mx Omega_xx^-1
    omega_marg = np.zeros_like(omega)
    xi_marg = np.zeros_like(xi)
    omega_marg[rest, rest] = omega[rest, rest] - gain @ omega[robot, rest]
    omega_marg = 0.5 * (omega_marg + omega_marg.T)
    xi_marg[rest] = xi[rest] - gain @ xi[robot]
    return omega_marg, xi_marg


# ---------------------------------------------------------------------------
# Backends: the SEIF's, and the robot's marginalization
# ---------------------------------------------------------------------------
class ESEIFBackend(SEIFBackend):
    """A :class:`~seif_gym.slam.seif.SEIFBackend` that also marginalizes the robot out (step c)."""

    @abc.abstractmethod
    def marginalize_robot(self, store: InformationStore, block: IntArray) -> None:
        """:func:`marginalize_robot` on the block of the robot and ``block`` (its linked landmarks)."""


class CompiledESEIFBackend(CompiledSEIFBackend, ESEIFBackend):
    """The ESEIF's steps by the compiled kernels (the default)."""

    def marginalize_robot(self, store: InformationStore, block: IntArray) -> None:
        omega, xi, _ = _kernels.gather(*store.kernel_arrays(), block)
        omega, xi = marginalize_robot_block(omega, xi)
        store.reserve_degree(block, len(block))
        _kernels.scatter(*store.kernel_arrays()[:7], block, omega, xi)


class ReferenceESEIFBackend(ReferenceSEIFBackend, ESEIFBackend):
    """The ESEIF's steps by the plain functions (slow; for checking)."""

    def marginalize_robot(self, store: InformationStore, block: IntArray) -> None:
        omega, xi, _ = store.gather(block)
        omega, xi = marginalize_robot(omega, xi)
        store.scatter(block, omega, xi)


# ---------------------------------------------------------------------------
# The filter
# ---------------------------------------------------------------------------
class _UpdatePlan(NamedTuple):
    """How one scan is incorporated (positions index the scan's measurements)."""

    withheld: IntArray  # z_beta; empty for an ordinary update
    split: bool  # z_beta also informs the map through the old pose (weights split_weight, 1 - split_weight)


_ORDINARY = _UpdatePlan(np.empty(0, dtype=np.int64), False)


class ESEIF(SEIF):
    """Exactly Sparse Extended Information Filter SLAM with known correspondences.

    Same interface as :class:`~seif_gym.slam.seif.SEIF` (motion update, mean
    recovery, Markov-blanket marginals and the read-only state are the
    SEIF's); only the way the active set is bounded differs.

    Parameters
    ----------
    motion, sensor, initial_pose, initial_pose_cov
        See :class:`~seif_gym.slam.base.SlamFilter`.
    max_active : int or None, default 8
        Bound ``k`` (at least 2) on the landmarks linked to the robot after
        every update; ``None`` never sparsifies (the filter is then the exact
        EIF).
    relocalization_landmarks : int, default 2
        ``k_beta``: measurements withheld to relocalize the robot, at least 2
        and at most ``max_active``. Fewer leave more room for the active set
        to grow before the next relocalization (each one discards the pose's
        history); more give a better relocalized pose.
    split_weight : float, default 0.5
        ``w`` in ``(0, 1)``: the share of a ``z_beta`` measurement's
        information that goes to the map in a *split* relocalization (see
        Notes), the rest going to the new pose.
    mean_recovery : {"wavefront", "amortized", "exact"}, default "wavefront"
    recovery_landmarks, recovery_budget, recovery_relaxation, recovery_tolerance
    implementation : {"compiled", "reference"}, default "compiled"
        As for the SEIF.

    Attributes
    ----------
    relocalizations : int
        Sparsifications by relocalization performed so far (split ones included).
    split_relocalizations : int
        Those of them that were split (the scan had fewer than two landmarks
        mapped before it).
    discarded_measurements : int
        Measurements left out because no relocalization could keep the bound
        (a scan of a single landmark, not linked to the robot, while ``k``
        landmarks are).

    Notes
    -----
    **One update.** Let ``Gamma`` be the active landmarks (linked to the
    robot), ``O`` the landmarks of the scan and ``K`` those of ``O`` mapped
    before this scan.

    *Ordinary update*, when ``|Gamma u O| <= k``: the SEIF's measurement
    update (:func:`seif_gym.slam.seif.measurement_update`, Probabilistic
    Robotics Table 12.3) with all measurements, ``Gamma <- Gamma u O``, then
    mean recovery.

    *Sparsification by relocalization*, when ``|Gamma u O| > k``:

    (a) Choose ``z_beta``: ``k_beta`` measurements of landmarks in ``K``
        maximizing ``det sum J_i`` (:func:`select_relocalization_landmarks`);
        ``z_alpha`` is the rest of the scan, including every landmark new to
        the map (it needs the robot link to be initialised).
    (b) Incorporate ``z_alpha`` (the measurement update, linearized at the
        current mean)::

            Omega <- Omega + sum_alpha H_i^T Q^-1 H_i
            xi    <- xi    + sum_alpha H_i^T Q^-1 [wrap(z_i - z_hat_i) + H_i mu]

        so that ``Gamma <- Gamma u alpha``, then recover the mean (the
        linearization point of step d).
    (c) Marginalize the robot (:func:`marginalize_robot`), over the block of
        the robot and ``Gamma`` only (``Omega_xm = 0`` elsewhere)::

            Omega_mm <- Omega_mm - Omega_mx Omega_xx^-1 Omega_xm
            xi_m     <- xi_m     - Omega_mx Omega_xx^-1 xi_x
            Omega_xx, Omega_xm, xi_x <- 0

        The landmarks of ``Gamma`` become linked to one another (a dense
        block over ``|Gamma|``, at most ``k`` plus the scan, landmarks);
        nothing else changes.
    (d) Relocalize: a new pose ``x`` with no prior information, constrained
        by ``z_beta`` through the sensor model ``z_i = h(x, m_i) + v_i``,
        ``v_i ~ N(0, Q)``, linearized at ``(mu_x, mu_beta)``::

            Omega <- Omega + sum_beta H_i^T Q^-1 H_i
            xi    <- xi    + sum_beta H_i^T Q^-1 [wrap(z_i - z_hat_i) + H_i mu]

        ``Omega_xx = sum_beta H_x,i^T Q^-1 H_x,i`` (rank 3 for two or more
        landmarks in general position) and the robot is linked to the
        ``z_beta`` landmarks only: ``Gamma <- beta``, ``|beta| <= k``. This is
        the information form of Walter et al.'s relocalization
        ``x = g(m_beta, z_beta)`` by the inverse sensor model (with more than
        the 3 equations a pose needs, the linearized least-squares solution).
        The new mean is ``mu + Omega^-1 sum_beta H_i^T Q^-1 nu_i``: one
        Gauss-Newton step of the relocalization from the current estimate,
        which the mean recovery that follows computes.

    *Split relocalization*, when ``|Gamma u O| > k`` but fewer than two
    landmarks of ``K`` can relocalize (typically a scan of landmarks all new
    to the map): a relocalization needs two landmarks (one range-bearing
    measurement leaves the rotation about its landmark free), and a new
    landmark has no information but this scan's. So ``z_beta`` is chosen
    among *all* the scan's measurements (landmarks of this scan counted with
    ``P_i = 0``) and each ``z_beta`` measurement is used twice, as in
    covariance intersection: in (b) with information ``w Q^-1`` (so that a new
    landmark is initialised through the old pose), in (d) with ``(1 - w)
    Q^-1``. Treating the two uses as independent is conservative: the stacked
    measurement ``[z; z]`` has covariance ``[Q, Q; Q, Q]``, and::

        [Q/w, 0; 0, Q/(1-w)] - [Q, Q; Q, Q] = [(1-w)/w, -1; -1, w/(1-w)] (x) Q >= 0

    (the 2 x 2 factor has determinant 0 and positive trace). The map keeps
    every measurement; the bound holds after the update.

    *Discarded measurements*: only a scan with one measurement, of a
    landmark not in ``Gamma`` while ``|Gamma| = k``, or a degenerate geometry
    (``lambda_min(J) < RELOCALIZATION_RCOND lambda_max(J)``, e.g. coincident
    landmarks), cannot relocalize. Then the measurements of ``Gamma``'s
    landmarks are kept, and of the others as many as ``k - |Gamma|`` leaves
    room for (mapped landmarks first, then the nearest); the rest are left
    out (never added to the map) and counted in ``discarded_measurements``.
    Leaving data out can only lose information, so this too is conservative.

    **Why it is conservative.** Write the information matrix before (c) as
    ``Omega`` and its robot-marginal ``Omega_m'``. Then::

        Omega - [0, 0; 0, Omega_m'] = [I; Omega_mx Omega_xx^-1] Omega_xx [I, Omega_xx^-1 Omega_xm] >= 0

    so the ESEIF's matrix after (d), ``[0, 0; 0, Omega_m'] + B`` (``B`` the
    ``z_beta`` factors), holds no more information than the EIF's
    ``Omega + B``, which incorporates the same measurements at the same
    linearization point. (For a split relocalization the same holds with the
    ``w``-weighted factors: the EIF is the limit in which the old and the new
    pose are constrained to be equal, where the two weighted uses of ``z_beta``
    add up to one use.) Motion updates, measurement updates and
    marginalization are monotone (a matrix with less information stays below
    one with more), so by induction ``Sigma_ESEIF >= Sigma_EIF`` after every
    step whenever both filters linearize at the same points (exactly so on
    noise-free data). The SEIF's sparsification has no such bound.
    """

    OPTIONS: ClassVar[dict[str, Any]] = {**SEIF.OPTIONS, "relocalization_landmarks": 2, "split_weight": 0.5}
    BACKENDS: ClassVar[dict[str, SEIFBackend]] = {"compiled": CompiledESEIFBackend(),
                                                  "reference": ReferenceESEIFBackend()}  # fmt: skip
    _backend: ESEIFBackend
    _COUNTERS: ClassVar[tuple[str, ...]] = ("relocalizations", "split_relocalizations", "discarded_measurements")

    def _check_options(self, options: dict[str, Any]) -> None:
        super()._check_options(options)
        max_active = options["max_active"]
        if max_active is not None and max_active < 2:
            raise ValueError(
                f"max_active must be at least 2 or None (relocalization needs two landmarks), got {max_active}"
            )
        count = as_count(options["relocalization_landmarks"], "relocalization_landmarks", minimum=2)
        if max_active is not None and count > max_active:
            raise ValueError(f"relocalization_landmarks ({count}) must not exceed max_active ({max_active})")
        as_scalar_between(options["split_weight"], "split_weight", 0.0, 1.0)

    def _initialize(self, pose: FloatArray, pose_cov: FloatArray) -> None:
        super()._initialize(pose, pose_cov)
        self.relocalization_landmarks = int(self.options["relocalization_landmarks"])
        self.split_weight = float(self.options["split_weight"])
        self.relocalizations = 0
        self.split_relocalizations = 0
        self.discarded_measurements = 0
        self._plan = _ORDINARY

    # -- one update ----------------------------------------------------------------
    def _update_known(self, ranges: FloatArray, bearings: FloatArray, ids: IntArray) -> None:
        """The update of the measurements the gate kept; plans it (and what to leave out) first."""
        plan, kept = self._plan_update(ranges, bearings, ids)
        if kept is not None:
            ranges, bearings, ids = ranges[kept], bearings[kept], ids[kept]
        self._plan = plan
        try:
            super()._update_known(ranges, bearings, ids)
        finally:
            self._plan = _ORDINARY
        if kept is not None:
            self.discarded_measurements += len(kept) - int(np.count_nonzero(kept))

    def _measurement_step(
        self, ranges: FloatArray, bearings: FloatArray, indices: IntArray, is_new: NDArray[np.bool_]
    ) -> None:
        """One update (inside the SEIF's transaction): ordinary, or a sparsification by relocalization."""
        if np.any(is_new):
            self._add_landmarks(ranges[is_new], bearings[is_new])
        self._update_count += 1
        withheld, split = self._plan
        if len(withheld) == 0:
            self._incorporate(ranges, bearings, indices)
            self._recover_mean()
            return
        kept = np.ones(len(indices), dtype=bool)
        kept[withheld] = False
        self._incorporate(ranges[kept], bearings[kept], indices[kept])  # (b)
        if split:
            self._incorporate(ranges[withheld], bearings[withheld], indices[withheld], self.split_weight)
        self._recover_mean()
        self._marginalize_robot()  # (c)
        relocalization_weight = 1.0 - self.split_weight if split else 1.0
        self._relocalize(ranges[withheld], bearings[withheld], indices[withheld], relocalization_weight)  # (d)
        self._recover_mean()
        self.relocalizations += 1
        self.split_relocalizations += int(split)

    def _plan_update(
        self, ranges: FloatArray, bearings: FloatArray, ids: NDArray[np.int64]
    ) -> tuple[_UpdatePlan, NDArray[np.bool_] | None]:
        """Step (a): the plan of this update, and the mask of measurements to keep (``None``: all)."""
        if self.max_active is None or len(ids) == 0:
            return _ORDINARY, None
        indices = np.array([self._id_to_index.get(i, -1) for i in ids.tolist()], dtype=np.int64)
        mapped = indices >= 0
        active = np.zeros(len(ids), dtype=bool)
        active[mapped] = self._is_active[indices[mapped]]
        if len(self._active) + int(np.count_nonzero(~active)) <= self.max_active:
            return _ORDINARY, None
        store = self._store
        # the pose information of each measurement; a landmark new to the map sits where this
        # measurement puts it, with P = 0
        candidates = np.flatnonzero(mapped)
        information = np.empty((len(ids), 3, 3))
        information[candidates] = relocalization_pose_information(
            store.mean, store.landmark_info, indices[candidates], self._measurement_cov
        )
        new = np.flatnonzero(~mapped)
        heading = store.mean[2] + bearings[new]
        offsets = np.column_stack([ranges[new] * np.cos(heading), ranges[new] * np.sin(heading)])
        information[new] = _pose_information(offsets, np.zeros((len(new), 2, 2)), self._measurement_cov)
        if len(candidates) >= 2:  # Walter et al.'s relocalization
            chosen = select_relocalization_landmarks(
                information[candidates], self.relocalization_landmarks, RELOCALIZATION_RCOND
            )
            if len(chosen):
                return _UpdatePlan(candidates[chosen], False), None
        chosen = select_relocalization_landmarks(information, self.relocalization_landmarks, RELOCALIZATION_RCOND)
        if len(chosen):  # split relocalization
            return _UpdatePlan(np.sort(chosen), True), None
        # no relocalization possible: keep what fits in the bound
        room = self.max_active - len(self._active)
        others = np.flatnonzero(~active)
        order = np.lexsort((ranges[others], ~mapped[others]))  # mapped first, then the nearest
        kept = active.copy()
        kept[others[order[:room]]] = True
        return _ORDINARY, kept

    def _marginalize_robot(self) -> None:
        """Step (c): Schur complement over the robot, on the block of the robot and ``Gamma``."""
        self._backend.marginalize_robot(self._store, self._active)
        self._is_active[self._active] = False
        self._active = np.empty(0, dtype=np.int64)

    def _relocalize(self, ranges: FloatArray, bearings: FloatArray, indices: IntArray, weight: float) -> None:
        """Step (d): the ``z_beta`` factors on the new pose, which has no information before them."""
        self._incorporate(ranges, bearings, indices, weight)
