"""Merging two landmarks (``SlamFilter.merge_landmarks``) and the association that uses it (``loop_merge``).

The merge conditions the belief on ``m_keep = m_remove``. In information form
that is ``Omega' = P^T Omega P``, ``xi' = P^T xi``, checked here against the
dense product; in covariance form (the EKF) it is a noise-free measurement
update followed by a marginalization, an independent derivation that must
agree with the EIF to round-off.
"""

from __future__ import annotations

import numpy as np
import pytest

from seif_gym.slam import EIF, EKF, ESEIF, SEIF
from seif_gym.slam import ekf as ekf_module
from seif_gym.slam.association import ASSOCIATOR_PRESETS, AssociationAudit, Associator, rigid_submap_match
from seif_gym.slam.base import UnknownLandmarkError
from seif_gym.slam.information import InformationStore
from seif_gym.slam.scenarios import FIDELITY_SCENARIOS, make_loop_run
from tests.slam.test_step_failures import InjectedFailure, assert_same_state, failing, state_of


def run_filters(steps: int = 120) -> tuple[dict, object]:
    motion, sensor, run = make_loop_run(FIDELITY_SCENARIOS["circle"], 0)
    filters = {
        "ekf": EKF(motion, sensor, run.initial_pose),
        "eif": EIF(motion, sensor, run.initial_pose),
        "seif": SEIF(motion, sensor, run.initial_pose, max_active=4),
        "eseif": ESEIF(motion, sensor, run.initial_pose, max_active=4),
    }
    for t in range(steps):
        for filt in filters.values():
            filt.predict(run.controls[t], run.dt)
            filt.update(run.ranges[t], run.bearings[t], run.ids[t])
    return filters, run


def substitution(num_landmarks: int, keep: int, remove: int) -> np.ndarray:
    """``P``: the reduced state (``remove`` gone, the last landmark in its place) to the full one."""
    last = num_landmarks - 1
    dim = 3 + 2 * num_landmarks
    p = np.zeros((dim, dim - 2))
    p[:3, :3] = np.eye(3)
    for k in range(num_landmarks):
        source = keep if k == remove else k  # m_remove is m_keep
        reduced = remove if source == last else source
        p[3 + 2 * k : 5 + 2 * k, 3 + 2 * reduced : 5 + 2 * reduced] = np.eye(2)
    return p


@pytest.fixture(scope="module")
def filters_and_run():
    return run_filters()


@pytest.mark.parametrize("name", ["eif", "seif", "eseif"])
@pytest.mark.parametrize("which", ["middle", "keep_last", "remove_last"])
def test_information_merge_is_the_substitution(filters_and_run, name, which):
    import copy

    filt = copy.deepcopy(filters_and_run[0][name])
    ids = filt.landmark_ids
    n = len(ids)
    keep, remove = {"middle": (3, 10), "keep_last": (n - 1, 5), "remove_last": (2, n - 1)}[which]
    omega = filt.information_matrix.toarray()
    xi = np.array(filt.information_vector)
    p = substitution(n, keep, remove)
    last_id = int(ids[-1])
    active_before = len(filt.active_landmarks) if name != "eif" else 0
    filt.merge_landmarks(int(ids[keep]), int(ids[remove]))
    np.testing.assert_allclose(filt.information_matrix.toarray(), p.T @ omega @ p, rtol=0, atol=1e-9)
    # xi' = P^T xi, up to the EIF's re-wrap of the heading (xi follows mu: xi' + 2 pi m Omega' e_theta)
    column = (p.T @ omega @ p)[:, 2]
    turns = [
        m for m in (0, -1, 1) if np.allclose(filt.information_vector, p.T @ xi + 2 * np.pi * m * column, atol=1e-6)
    ]
    assert turns and (turns[0] == 0 or name == "eif"), turns
    assert filt.num_landmarks == n - 1 and int(ids[remove]) not in filt.landmark_ids.tolist()
    if remove != n - 1:
        assert filt.landmark_index(last_id) == remove and filt.landmark_ids[remove] == last_id
    if name != "eif":  # no robot link more (one fewer when both were active), only on the active landmarks
        links = np.abs(filt._store.robot_links[: filt.num_landmarks]).sum(axis=(1, 2)) > 0
        assert len(filt.active_landmarks) <= active_before
        assert set(filt.landmark_ids[links].tolist()) <= set(filt.active_landmarks.tolist())
        assert filt._is_active[: filt.num_landmarks].sum() == len(filt.active_landmarks)


def test_ekf_merge_equals_eif_merge_and_filtering_goes_on(filters_and_run):
    import copy

    filters, run = filters_and_run
    ekf, eif = copy.deepcopy(filters["ekf"]), copy.deepcopy(filters["eif"])
    ids = ekf.landmark_ids
    keep, remove = int(ids[4]), int(ids[9])
    for filt in (ekf, eif):
        filt.merge_landmarks(keep, remove)
    np.testing.assert_array_equal(ekf.landmark_ids, eif.landmark_ids)
    np.testing.assert_allclose(ekf.mean, eif.mean, rtol=0, atol=1e-8)
    np.testing.assert_allclose(ekf.covariance(), eif.covariance(), rtol=0, atol=1e-9)
    # the merged landmark sits where the conditioning put both: between the two, never outside
    for t in range(120, 160):
        for filt in (ekf, eif):
            filt.predict(run.controls[t], run.dt)
            seen = run.ids[t] != remove
            filt.update(run.ranges[t][seen], run.bearings[t][seen], run.ids[t][seen])
    np.testing.assert_allclose(ekf.mean, eif.mean, rtol=0, atol=1e-7)


def test_store_merge_and_swap_remove_keep_links_symmetric():
    rng = np.random.default_rng(3)
    store = InformationStore(capacity=8, degree=2)
    store.add_landmarks(rng.normal(size=(6, 2)))
    for i, j in [(0, 1), (1, 2), (2, 5), (3, 5), (4, 0)]:
        block = rng.normal(size=(2, 2))
        store.reserve_degree(np.array([i, j]), 1)
        store._add_link(i, j, block)
        store._add_link(j, i, block.T)
    for i in range(6):
        store.landmark_info[i] = np.eye(2) * (5 + i)
    dense = store.to_sparse().toarray()
    store.merge(1, 5)
    np.testing.assert_allclose(store.to_sparse().toarray(), substitution(6, 1, 5).T @ dense @ substitution(6, 1, 5))
    for i in range(store.num_landmarks):
        for slot in range(store.neighbour_count[i]):
            j = store.neighbour_index[i, slot]
            assert 0 <= j < store.num_landmarks and j != i
            np.testing.assert_array_equal(store.neighbour_info[j, store.find_neighbour(j, i)],
                                          store.neighbour_info[i, slot].T)  # fmt: skip


def test_merge_validates_and_leaves_the_filter_alone(filters_and_run):
    import copy

    for name in ("ekf", "seif"):
        filt = copy.deepcopy(filters_and_run[0][name])
        before = np.array(filt.mean), filt.landmark_ids.copy()
        ids = filt.landmark_ids
        with pytest.raises(ValueError, match="keep_id and remove_id"):
            filt.merge_landmarks(int(ids[0]), int(ids[0]))
        with pytest.raises(UnknownLandmarkError, match="landmark_id"):
            filt.merge_landmarks(int(ids[0]), 10**6)
        with pytest.raises(TypeError, match="landmark_id"):
            filt.merge_landmarks(1.5, int(ids[0]))
        np.testing.assert_array_equal(filt.mean, before[0])
        np.testing.assert_array_equal(filt.landmark_ids, before[1])


@pytest.mark.parametrize("target", ["merge", "push"])
def test_seif_merge_failure_leaves_the_filter_bit_identical(filters_and_run, monkeypatch, target):
    import copy

    from seif_gym.slam import seif as seif_module

    filt = copy.deepcopy(filters_and_run[0]["seif"])
    ids = filt.landmark_ids
    before = state_of(filt)
    if target == "merge":  # the store fully merged, then a failure
        monkeypatch.setattr(InformationStore, "merge", failing(InformationStore.merge, call_through=True))
    else:  # the last stage: rebuilding the recovery queue
        monkeypatch.setattr(seif_module.RecoveryQueue, "push",
                            failing(seif_module.RecoveryQueue.push, call_through=True, on_call=2))  # fmt: skip
    with pytest.raises(InjectedFailure):
        filt.merge_landmarks(int(ids[2]), int(ids[7]))
    monkeypatch.undo()
    assert_same_state(before, state_of(filt))


def test_ekf_merge_failure_leaves_the_filter_bit_identical(filters_and_run, monkeypatch):
    import copy

    filt = copy.deepcopy(filters_and_run[0]["ekf"])
    before = (filt._state_mean.tobytes(), filt._state_cov.tobytes(), filt.landmark_ids.copy())
    monkeypatch.setattr(ekf_module.scipy.linalg, "solve", failing(ekf_module.scipy.linalg.solve, call_through=True))
    with pytest.raises(InjectedFailure):
        filt.merge_landmarks(int(filt.landmark_ids[2]), int(filt.landmark_ids[7]))
    monkeypatch.undo()
    assert (filt._state_mean.tobytes(), filt._state_cov.tobytes()) == before[:2]
    np.testing.assert_array_equal(filt.landmark_ids, before[2])


def test_rigid_submap_match_finds_a_planted_copy_within_the_drift_bounds():
    rng = np.random.default_rng(7)
    old = rng.uniform(-8, 8, size=(30, 2))
    picked = rng.choice(30, size=6, replace=False)
    angle = np.radians(4.0)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    # the copy: old landmarks displaced by a drift, plus two genuinely new landmarks
    copy = (old[picked] - np.array([1.0, -0.5])) @ rotation + rng.normal(scale=0.05, size=(6, 2))
    recent = np.vstack([copy, [[20.0, 20.0], [-20.0, 15.0]]])
    pairs, second = rigid_submap_match(recent, old, 0.3, np.radians(10), 3.0)
    assert sorted(pairs) == sorted(zip(range(6), picked.tolist()))
    assert second <= 3
    # the same copy beyond the drift bounds is not taken
    assert rigid_submap_match(recent, old, 0.3, np.radians(2), 3.0)[0] != sorted(pairs)
    assert len(rigid_submap_match(recent + 10.0, old, 0.3, np.radians(10), 3.0)[0]) < 4
    assert rigid_submap_match(recent[:1], old, 0.3, 1.0, 3.0) == ([], 0)
    with pytest.raises(ValueError, match="recent"):
        rigid_submap_match(recent[:, :1], old, 0.3, 1.0, 3.0)
    with pytest.raises(ValueError, match="old"):
        rigid_submap_match(recent, np.full((3, 2), np.nan), 0.3, 1.0, 3.0)
    with pytest.raises(TypeError, match="tolerance"):
        rigid_submap_match(recent, old, "0.3", 1.0, 3.0)
    with pytest.raises(ValueError, match="max_shift"):
        rigid_submap_match(recent, old, 0.3, 1.0, 0.0)


def test_audit_scores_merges_by_the_final_map():
    class Decisions:  # what AssociationAudit reads of an Associator
        def __init__(self):
            self.created, self.merges = {}, []

    decisions = Decisions()
    audit = AssociationAudit()
    decisions.created = {0: 0, 1: 1}
    audit.record(decisions, [0, 1], [10, 11])  # two new landmarks: both agree
    decisions.created = {2: 0, 3: 1}
    audit.record(decisions, [2, 3], [10, 11])  # two duplicates
    decisions.created = {}
    audit.record(decisions, [2, 3], [10, 11])  # measurements of the duplicates: agree with their attribution
    assert (audit.agree, audit.errors, audit.duplicates) == (4, 2, 2)
    decisions.merges = [(0, 2), (0, 3)]  # right, then wrong (3 is true landmark 11)
    audit.record(decisions, [], [])
    assert (audit.merges_right, audit.merges_wrong, audit.duplicates, audit.duplicates_started) == (1, 1, 0, 2)
    assert (audit.agree, audit.errors) == (4, 2)  # +1 (2's first measurement), -1 (3's agreeing one)
    assert audit.agree + audit.errors == audit.total


def test_associator_validates_the_merge_options():
    with pytest.raises(TypeError, match="loop_merge"):
        Associator(loop_merge=1)
    for name, value in (("merge_tolerance", 0.0), ("merge_shift", float("inf")), ("merge_rotation", -1.0)):
        with pytest.raises(ValueError, match=name):
            Associator(**{name: value})
    for name, value in (("merge_inliers", 1), ("merge_every", 0), ("merge_margin", -1)):
        with pytest.raises(ValueError, match=name):
            Associator(**{name: value})


def association_run(scenario: str, seed: int, loop_merge: bool) -> AssociationAudit:
    motion, sensor, run = make_loop_run(FIDELITY_SCENARIOS[scenario], seed)
    filt = SEIF(motion, sensor, run.initial_pose, max_active=8)
    associator = Associator(**{**ASSOCIATOR_PRESETS["joint"], "loop_merge": loop_merge})  # the joint preset's runs
    audit = AssociationAudit()
    for t in range(run.steps):
        filt.predict(run.controls[t], run.dt)
        audit.record(associator, associator.update(filt, run.ranges[t], run.bearings[t]), run.ids[t])
    return audit


@pytest.mark.slow
def test_loop_merge_takes_back_the_seifs_duplicates():
    """``rectangle-narrow`` seed 0, SEIF(k=8): the overconfident closure that duplicates part of the map.

    Measured (``python benchmarks/association.py --scenarios rectangle-narrow --seeds 1 --filters seif
    [--options loop_merge=true]``): without merges 22 duplicates; with them every merge right and few left.
    """
    plain, merged = association_run("rectangle-narrow", 0, False), association_run("rectangle-narrow", 0, True)
    assert plain.duplicates >= 15
    assert merged.merges_wrong == 0 and merged.merges_right >= 5
    assert merged.duplicates <= plain.duplicates // 3
    assert merged.agreement > plain.agreement


@pytest.mark.slow
@pytest.mark.parametrize("filter_name", ["EKF", "SEIF"])
def test_revisable_association_meets_the_targets_on_the_loop_runs(filter_name):
    """All eight ``FIDELITY_SCENARIOS``, seed 0 (no selection): the ``"revisable"`` preset (merges and tentative closures)
    and the ``"likelihood"`` preset (revisable, joint hypotheses ranked by likelihood).

    Measured (``python benchmarks/association.py --seeds 1 --preset revisable|likelihood``): EKF revisable 99.76%
    correct, 0.24% duplicates, no wrong merge (joint preset: 99.60%, 0.24%), likelihood 99.87%, 0.24%; SEIF(k=8)
    revisable 99.54%, 1.22%, one wrong merge (a tentative landmark of an unmapped tree next to an old one,
    ``rectangle-narrow``; joint preset: 98.78%, 6.20%), likelihood 99.73%, 0.85%. Asserted: the issue's targets
    (>= 99.5%, <= 2%), revisable no worse than joint and likelihood no worse than revisable.
    """
    from tests.slam.test_association import loop_audit

    audits = {preset: [loop_audit(name, 0, filter_name, preset) for name in FIDELITY_SCENARIOS]
              for preset in ("joint", "revisable", "likelihood")}  # fmt: skip
    figures = {}
    for preset, runs in audits.items():
        figures[preset] = (sum(a.agree for a in runs) / sum(a.total for a in runs),
                           sum(a.duplicates for a in runs) / sum(a.true_landmarks for a in runs))  # fmt: skip
    message = f"{filter_name}: " + "; ".join(f"{p} {c:.4f}, {d:.4f}" for p, (c, d) in figures.items())
    for better, worse in (("revisable", "joint"), ("likelihood", "revisable")):
        (correct, duplicates), (other_correct, other_duplicates) = figures[better], figures[worse]
        assert correct >= 0.995 and duplicates <= 0.02, message
        assert correct > other_correct and duplicates <= other_duplicates, message
        assert sum(a.merges_wrong for a in audits[better]) <= (0 if filter_name == "EKF" else 1), message
    # the deferred lone closures are no longer discarded: they started tentative landmarks, merged since
    assert sum(a.discarded for a in audits["revisable"]) < sum(a.discarded for a in audits["joint"])
    assert sum(a.associator.stats.merged for a in audits["revisable"]) > 0


@pytest.mark.slow
def test_likelihood_preset_refuses_the_false_closure_of_circle_large_seed_5():
    """``circle-large`` seed 5, EKF: at scan 420 two unmapped trees fall inside the gates of two old landmarks.

    Counting pairings, the branch and bound takes those two (d2 10.7 and 10.1) over the one old landmark really
    in view (d2 2.7), and the closure pulls the pose 2 m off (``revisable``: 258 wrong decisions, 1.1 m off at the
    end). Ranked by likelihood, the two unmapped trees are new landmarks and the closure waits
    (``likelihood``: 53 wrong decisions, 0.4 m off at the end).
    """
    from tests.slam.test_association import loop_audit

    revisable, likelihood = (loop_audit("circle-large", 5, "EKF", preset) for preset in ("revisable", "likelihood"))
    assert revisable.errors > 200
    assert likelihood.errors < 80 and likelihood.agreement >= 0.99


def test_a_tentative_landmark_is_no_candidate_and_expires():
    """While tentative, a landmark takes no measurement through the search; after ``closure_window`` it is let go."""
    motion, sensor, run = make_loop_run(FIDELITY_SCENARIOS["rectangle-narrow"], 0)
    filt = EKF(motion, sensor, run.initial_pose)
    # the revisable stage: tentative landmarks hidden from the search (the tentative preset opens them)
    associator = Associator(**{**ASSOCIATOR_PRESETS["joint"], "tentative_closures": True, "closure_window": 5})
    seen_tentative = False
    for t in range(run.steps):
        filt.predict(run.controls[t], run.dt)
        pending = set(associator.tentatives)
        meas, landmark, _, _ = associator.distances(filt, run.ranges[t], run.bearings[t])
        assert not pending & set(filt.landmark_ids[landmark].tolist())
        associator.update(filt, run.ranges[t], run.bearings[t])
        seen_tentative |= bool(associator.tentatives)
        for _, started in associator.tentatives.values():
            assert associator.stats.scans - started <= associator.closure_window + 1
    assert seen_tentative
