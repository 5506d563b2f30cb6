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
9. **Open tentative landmarks** (``open_tentatives``; the ``"tentative"``
   preset and the defaults). No measurement is thrown away: one that
   step 6 defers, or that step 7 finds ambiguous (inside a gate, yet not
   taken, and not far enough to be a new landmark), starts a *tentative*
   landmark, recorded as the possible double of the landmark it is nearest
   to in ``d2``. Tentative landmarks are in the filter and are candidates
   like any other, so the next measurements of the same place pair with the
   tentative one and the scan's other measurements stay free for the old
   one. A tentative landmark is resolved by evidence:

   * chosen in one joint hypothesis with its old landmark (two measurements
     of one scan, so two landmarks), or with a landmark later merged into
     it, it is confirmed a landmark of its own;
   * after a loop closure has been accepted since it started, it is merged
     into its old landmark when ``m_old - m_new`` passes the ``gate`` on
     their joint marginal *and* the test is decisive: the gate's ellipse,
     ``sqrt(gate lambda_max)``, is narrower than ``landmark_separation``, so
     that two landmarks that far apart would fail it;
   * otherwise it stays tentative for ``tentative_scans`` scans, then it is
     a landmark of its own.

   A landmark about a metre from one mapped a loop ago, first seen just as
   the drift lays it onto the old one, is then neither discarded for scans
   on end nor confused with the old landmark once both are in view.

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

Modules
-------
``gating`` (steps 1 to 3 and the conditional likelihoods of step 5), ``jcbb`` (step 4), ``submap``
(:func:`rigid_submap_match` and :class:`CoverageGrid`) and ``associator`` (:class:`Associator`,
:class:`AssociationStats` and :class:`AssociationAudit`); every name is importable from this package.

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

import math
from typing import Any

from seif_gym.slam.association.associator import AssociationAudit, AssociationStats, Associator
from seif_gym.slam.association.gating import (
    conditional_loglik as conditional_loglik,
)
from seif_gym.slam.association.gating import (
    joint_innovation_covariance as joint_innovation_covariance,
)
from seif_gym.slam.association.gating import (
    pair_innovations as pair_innovations,
)
from seif_gym.slam.association.jcbb import jcbb
from seif_gym.slam.association.submap import CoverageGrid as CoverageGrid
from seif_gym.slam.association.submap import rigid_submap_match

__all__ = [
    "ASSOCIATOR_PRESETS",
    "Associator",
    "AssociationStats",
    "AssociationAudit",
    "jcbb",
    "make_associator",
    "rigid_submap_match",
]


#: The settings in which the presets of seif_gym up to 1.0 differ from today's ``Associator()`` defaults: pinned in
#: each of those presets, so that a preset computes what it always did whatever the defaults become.
_SETTINGS_OF_1_0: dict[str, Any] = {
    "gate": 0.999,
    "loop_merge": False,
    "tentative_closures": False,
    "open_tentatives": False,
    "joint_objective": "pairings",
    "exclusion_margin": None,
}

#: Named ``Associator`` settings. ``"individual"``: seif_gym 0.1's individual-compatibility
#: association, reproduced bit for bit (the env's ``-v0`` ids; ``joint=False`` also turns off the deferral of
#: lone loop closures); ``"joint"``: joint compatibility with deferred lone loop closures (the defaults up to
#: 1.0); ``"revisable"``: ``"joint"`` with merges (``loop_merge``) and tentative landmarks for deferred lone
#: closures (``tentative_closures``): association that is taken back; ``"likelihood"``: ``"revisable"`` with
#: the joint hypotheses ranked by their likelihood ratio against new landmarks (``joint_objective``), a 0.9999
#: gate, and new landmarks next to a landmark another measurement of the scan took (``exclusion_margin``: the
#: swapped assignment 100 times less likely); ``"tentative"``: ``"likelihood"`` with open tentative landmarks
#: (``open_tentatives``: an ambiguous measurement starts a tentative landmark instead of being discarded, and a
#: tentative landmark is merged only when the correspondence test can tell landmarks apart).
ASSOCIATOR_PRESETS: dict[str, dict[str, Any]] = {
    "individual": {**_SETTINGS_OF_1_0, "joint": False, "landmark_density": 0.0, "blanket_size": 0, "detection": 0.0},
    "joint": {**_SETTINGS_OF_1_0},
    "revisable": {**_SETTINGS_OF_1_0, "loop_merge": True, "tentative_closures": True},
    "likelihood": {
        **_SETTINGS_OF_1_0,
        "loop_merge": True,
        "tentative_closures": True,
        "joint_objective": "likelihood",
        "gate": 0.9999,
        "exclusion_margin": 2.0 * math.log(100.0),
    },
    "tentative": {
        "loop_merge": True,
        "tentative_closures": True,
        "open_tentatives": True,
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
        A key of :data:`ASSOCIATOR_PRESETS`: ``"joint"`` (joint compatibility, the
        pairing-vs-new-landmark test, deferred lone loop closures: the defaults up to 1.0),
        ``"individual"`` (seif_gym 0.1's associator, bit for bit), ``"revisable"`` (merges and
        tentative closures), ``"likelihood"`` (revisable, with hypotheses ranked by likelihood) or
        ``"tentative"`` (likelihood, with open tentative landmarks).
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
