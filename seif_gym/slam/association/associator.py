"""The associator: :class:`Associator`, its statistics, and :class:`AssociationAudit`.

The algorithm is described in :mod:`seif_gym.slam.association`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import scipy.optimize
import scipy.stats
from numpy.typing import ArrayLike

from seif_gym.slam.association.gating import (
    _candidates,
    _pair_distances,
    conditional_loglik,
    joint_innovation_covariance,
    pair_innovations,
)
from seif_gym.slam.association.jcbb import jcbb
from seif_gym.slam.association.submap import CoverageGrid, rigid_submap_match
from seif_gym.slam.marginals import breadth_first_joint_covariance, supports_breadth_first
from seif_gym.type_aliases import FloatArray, IntArray
from seif_gym.validation import as_count, as_positive_scalar

if TYPE_CHECKING:  # for annotations only
    from seif_gym.slam.base import SlamFilter

__all__ = ["Associator", "AssociationAudit", "AssociationStats"]


#: Cost of a forbidden pair in the assignment problem (far above any gated cost).
_FORBIDDEN = 1e9


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
        Probability of the chi-square gate (0.9999: ``d2 <= 18.4`` with 2 dof;
        a 0.99 gate would discard 1% of the correct pairs by design; 0.999,
        ``d2 <= 13.8``, up to 1.0).
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
        ``merge_landmarks``); on by default (off up to 1.0, and in the
        ``"individual"`` and ``"joint"`` presets).
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
        (Default on; off up to 1.0.) A deferred lone closure (step 6) starts a tentative landmark instead
        of being discarded; once its old landmark is associated again (the
        closure accepted) and the two pass the correspondence test on the
        joint marginal of ``m_old - m_new`` (the ``gate``), it is merged into
        the old one; after ``closure_window`` scans it stays a landmark of its
        own.
    open_tentatives : bool
        (Default on; ignored without ``tentative_closures``.) Step 9: tentative landmarks are
        candidates like any other (the map is not read as without them); each
        deferred lone closure, and each ambiguous measurement (inside a gate,
        not taken, not far enough for a new landmark), starts its own
        tentative landmark instead of being discarded. A tentative landmark
        chosen in one joint hypothesis with its old landmark (two
        measurements of one scan) is confirmed a landmark of its own. One is
        merged into its old landmark once a closure has been accepted since it
        started, the two pass the correspondence test on the marginal of
        ``m_old - m_new`` (the ``gate``) *and* the test can tell landmarks
        ``landmark_separation`` apart (the gate's ellipse,
        ``sqrt(gate lambda_max)``, is narrower than the separation). Only the
        tentative landmarks among the last scan's candidates are tested (a
        bounded set); one neither merged nor confirmed after
        ``tentative_scans`` scans stays a landmark of its own.
    tentative_scans : int
        With ``open_tentatives``: scans a tentative landmark waits for its
        resolution.
    exclusion_margin : float or None
        Mutual exclusion for new landmarks (step 7): a landmark taken by
        another measurement of the scan whose ``d2`` is smaller by at least
        this much no longer stops a measurement from starting a new landmark
        (the swapped assignment is ``exp(margin / 2)`` times less likely).
        Default ``2 ln 100`` (100 times); ``None`` (the default up to 1.0):
        every gated landmark stops it.
    joint_objective : {"pairings", "likelihood"}
        What the branch and bound maximises among the jointly compatible
        hypotheses (step 4): the number of pairings (Neira & Tardos; the
        default up to 1.0), or the likelihood ratio (the default) of the hypothesis against "each of
        its measurements is an unmapped landmark", with the density of step 5
        (:func:`jcbb`'s ``gains``), so that one good pairing can beat two poor
        ones where new landmarks are plausible.

    Notes
    -----
    The defaults are the ``"tentative"`` preset; the defaults of seif_gym up to 1.0 are the ``"joint"``
    preset (:data:`~seif_gym.slam.association.ASSOCIATOR_PRESETS`). See the module docstring for the algorithm. :meth:`associate` is the
    decision alone; :meth:`update` also applies it to the filter. Ids are the
    associator's own: with a simulator, map them to the true landmarks by the
    true id of the measurement that created each (``created``).
    """

    def __init__(
        self,
        gate: float = 0.9999,
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
        loop_merge: bool = True,
        merge_every: int = 10,
        merge_recent: int = 40,
        merge_radius: float = 15.0,
        merge_tolerance: float = 0.2,
        merge_inliers: int = 4,
        merge_margin: int = 2,
        merge_rotation: float = 10.0,
        merge_shift: float = 3.0,
        tentative_closures: bool = True,
        open_tentatives: bool = True,
        tentative_scans: int = 400,
        exclusion_margin: float | None = 2.0 * math.log(100.0),
        joint_objective: str = "likelihood",
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
            ("tentative_scans", tentative_scans, 1),
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
        flags = (("loop_merge", loop_merge), ("tentative_closures", tentative_closures),
                 ("open_tentatives", open_tentatives))  # fmt: skip
        for name, flag in flags:
            if not isinstance(flag, bool):
                raise TypeError(f"{name} must be a bool, got {type(flag).__name__}")
        self.tentative_closures = tentative_closures
        self.open_tentatives = open_tentatives and tentative_closures  # no tentative landmarks: nothing to open
        self.tentative_scans = int(tentative_scans)
        #: open_tentatives: tentative landmark id -> the landmark ids chosen in a scan with it (never its double)
        self._coseen: dict[int, set[int]] = {}
        self._near: set[int] = set()  # open_tentatives: the ids of the last scan's candidates and decisions
        self._local: set[int] = set()  # open_tentatives: tentative landmarks whose old landmark was in view
        self._misses: dict[int, int] = {}  # open_tentatives: tentative landmark -> scans that passed it over
        self._last_near: dict[int, int] = {}  # open_tentatives: tentative landmark -> the last scan it was by the robot
        self._miss_limit = math.ceil(math.log(0.01) / math.log1p(-self.detection)) if self.detection > 0.0 else 0
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
        if self.tentatives and len(pair_meas) and not self.open_tentatives:
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
            if self.open_tentatives and self.tentatives and len(chosen):
                self._confirm_tentatives(filt.landmark_ids[pair_landmark[chosen]])
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
        blocked = np.zeros(m, dtype=bool)
        if self.min_separation > 0.0 and len(pair_meas):
            # and not closer than min_separation to a mapped landmark (a physical prior on the map)
            blocked[pair_meas[euclid2 < self.min_separation**2]] = True
            new &= ~blocked
        tentative: dict[int, int] = {}  # measurement -> the old landmark id it was deferred from
        if self.tentative_closures and len(self._deferred):
            pending = {old_id: new_id for new_id, (old_id, _) in self.tentatives.items()}
            for k in self._deferred.tolist():
                measurement, old_id = int(pair_meas[k]), int(filt.landmark_ids[pair_landmark[k]])
                if old_id in pending and not self.open_tentatives:  # the old landmark's tentative double takes it
                    ids[measurement] = pending[old_id]
                    deferred_to_tentative += 1
                else:
                    tentative[measurement] = old_id
            new[list(tentative)] = True
        if self.open_tentatives and len(pair_meas):
            # an ambiguous measurement (inside a gate, yet not taken) starts a tentative landmark, the double of
            # the landmark it is closest to in d2, rather than being thrown away; the resolution decides later
            ambiguous = (ids < 0) & ~new & ~blocked
            if ambiguous.any():
                order = np.lexsort((d2, pair_meas))
                first = order[np.r_[True, pair_meas[order][1:] != pair_meas[order][:-1]]]
                for k in first[ambiguous[pair_meas[first]]].tolist():
                    tentative[int(pair_meas[k])] = int(filt.landmark_ids[pair_landmark[k]])
                new[ambiguous] = True
        count_new = int(new.sum())
        ids[new] = self.next_id + np.arange(count_new)
        for k, old_id in tentative.items():
            self.tentatives[int(ids[k])] = (old_id, self.stats.scans + 1)
            if self.open_tentatives and self.stats.scans - self.last_seen.get(old_id, -(10**9)) <= self.closure_age:
                self._local.add(int(ids[k]))  # the double of a landmark in view: no loop closure to wait for
        if self.open_tentatives:
            seen = set(ids[ids >= 0].tolist())
            for i in seen.intersection(self.tentatives):
                self._coseen.setdefault(i, set()).update(seen - {i})
            self._near = seen.union(filt.landmark_ids[np.unique(pair_landmark)].tolist()) if len(pair_meas) else seen
            self._count_misses(filt, seen)
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

    def _count_misses(self, filt: SlamFilter, seen: set[int]) -> None:
        """``open_tentatives``: count the scans that passed over a tentative landmark for its old landmark.

        A miss is a scan that took the old landmark, not the tentative one, while the tentative one lay well
        inside the footprint (1 m, or 20% of the range, inside its edges): a landmark there would have been
        measured with probability ``detection``. After ``ln 0.01 / ln(1 - detection)`` misses in a row
        (7 at 0.5) the tentative landmark was a stray measurement of its old one: it is merged into it.
        """
        if self.detection <= 0.0:
            return
        sensor = filt.sensor
        reach = float(sensor.max_range) - max(1.0, 0.2 * float(sensor.max_range))
        half_fov = 0.5 * float(getattr(sensor, "fov", 2.0 * math.pi))
        pose = np.asarray(filt.pose, dtype=np.float64)
        for new_id in self._near.intersection(self.tentatives):
            if new_id in seen:
                self._misses.pop(new_id, None)
                continue
            if self.tentatives[new_id][0] not in seen:
                continue
            dx, dy = filt.landmarks[filt.landmark_index(new_id)] - pose[:2]
            r = math.hypot(dx, dy)
            off = abs((math.atan2(dy, dx) - pose[2] + math.pi) % (2.0 * math.pi) - math.pi)
            inside = r <= reach and (half_fov >= math.pi or (off < half_fov and r * math.sin(half_fov - off) >= 1.0))
            if inside:
                self._misses[new_id] = self._misses.get(new_id, 0) + 1

    def _confirm_tentatives(self, hypothesis: IntArray) -> None:
        """``open_tentatives``: a tentative landmark chosen with its own old landmark is a landmark of its own.

        ``hypothesis`` holds the landmark ids of the scan's joint hypothesis (before lone closures are deferred):
        two of its landmarks are measured by two measurements, so they are two landmarks.
        """
        chosen = set(hypothesis.tolist())
        for i in chosen.intersection(self.tentatives):
            self._coseen.setdefault(i, set()).update(chosen - {i})
            if self.tentatives[i][0] in chosen:
                del self.tentatives[i]
                self._coseen.pop(i, None)
                self._local.discard(i)
                self._last_near.pop(i, None)
                self._misses.pop(i, None)

    def _merge(self, filt: SlamFilter, keep: int, remove: int) -> None:
        """``filt.merge_landmarks(keep, remove)`` and the associator's own records of ``remove`` folded into ``keep``."""
        filt.merge_landmarks(keep, remove)
        self.last_seen[keep] = max(self.last_seen.get(keep, 0), self.last_seen.pop(remove, 0))
        self.started.pop(remove, None)
        self.tentatives.pop(remove, None)
        self._local.discard(remove)
        self._last_near.pop(remove, None)
        self._misses.pop(remove, None)
        self.signatures.merge(keep, remove)
        if self._coseen:
            self._coseen.pop(remove, None)
            for others in self._coseen.values():
                if remove in others:
                    others.discard(remove)
                    others.add(keep)

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
        life = self.tentative_scans if self.open_tentatives else self.closure_window
        near = self._near if self.open_tentatives else None
        for new_id, (old_id, started) in list(self.tentatives.items()):
            if new_id not in self.tentatives:  # confirmed by a merge of this call
                continue
            if near is not None and new_id not in near and old_id not in near:
                last_near = self._last_near.get(new_id, started)
            else:
                last_near = now
                if near is not None:
                    self._last_near[new_id] = now
            if now - last_near > self.closure_window:
                # open_tentatives: only the tentative landmarks by the robot lately are tested (a bounded set)
                if now - started > life:
                    del self.tentatives[new_id]
                    self._coseen.pop(new_id, None)
                    self._local.discard(new_id)
                    self._last_near.pop(new_id, None)
                    self._misses.pop(new_id, None)
                self._misses.pop(new_id, None)
                continue
            try:
                i, j = filt.landmark_index(old_id), filt.landmark_index(new_id)
            except KeyError:  # merged away meanwhile (a copy of the old map)
                del self.tentatives[new_id]
                self._coseen.pop(new_id, None)
                self._local.discard(new_id)
                self._last_near.pop(new_id, None)
                self._misses.pop(new_id, None)
                continue
            distinct = self.open_tentatives and old_id in self._coseen.get(new_id, ())
            if not distinct and self._miss_limit and self._misses.get(new_id, 0) >= self._miss_limit:
                self._merge(filt, old_id, new_id)  # passed over for its old landmark, again and again
                merges.append((old_id, new_id))
                landmarks = None
                continue
            ready = new_id in self._local or max(self.last_seen.get(old_id, 0), self._closure_accepted) >= started
            if not distinct and ready:
                # a closure accepted since: the correspondence test on m_old - m_new
                joint = self._joint_covariance(filt, np.array([i, j], dtype=np.int64))
                difference_cov = joint[3:5, 3:5] + joint[5:7, 5:7] - joint[3:5, 5:7] - joint[5:7, 3:5]
                if landmarks is None:
                    landmarks = filt.landmarks
                difference = landmarks[i] - landmarks[j]
                passes = float(difference @ np.linalg.solve(difference_cov, difference)) <= gate
                if passes and self.open_tentatives:  # and only when it would fail for two separate landmarks
                    passes = gate * float(np.linalg.eigvalsh(difference_cov)[-1]) < self.landmark_separation**2
                if passes:
                    self._merge(filt, old_id, new_id)
                    merges.append((old_id, new_id))
                    landmarks = None
                    continue
            if distinct or now - started > life:
                del self.tentatives[new_id]
                self._coseen.pop(new_id, None)
                self._local.discard(new_id)
                self._last_near.pop(new_id, None)
                self._misses.pop(new_id, None)
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
