"""Tests of ``seif_gym.slam.association``: maximum-likelihood data association.

The main check runs the associator on simulated data whose true ids are
known, with the default noise of the models (the env's defaults), and counts
the measurements whose decision agrees with the truth: a measurement agrees
when it is associated with the landmark that holds its true id, or starts a
new landmark for a true landmark not mapped yet. A discarded measurement
counts as a disagreement. The simulated landmarks are at least 1 m apart
(uniform otherwise): closer pairs cannot be told apart by a sensor with a
2 degree bearing noise at 5 m, and every association rule then merges them.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from seif_gym.slam import EKF, SEIF, RangeBearingSensor, VelocityMotionModel
from seif_gym.slam.association import AssociationAudit, Associator
from seif_gym.slam.simulation import loop_controls, loop_start_pose, simulate_run


def separated_landmarks(n: int, half: float, separation: float, rng: np.random.Generator) -> np.ndarray:
    points: list[np.ndarray] = []
    while len(points) < n:
        p = rng.uniform(-half, half, 2)
        if all(np.hypot(*(p - q)) >= separation for q in points):
            points.append(p)
    return np.array(points)


def simulated_run(seed: int):
    """Env defaults: 30 landmarks in a 20 m arena, 5 m range, 180 degree field of view, dt 0.25 s."""
    rng = np.random.default_rng(seed)
    motion = VelocityMotionModel()
    sensor = RangeBearingSensor(max_range=5.0, fov=math.pi)
    landmarks = separated_landmarks(30, 9.0, 1.0, rng)
    controls = loop_controls(400, 0.25, 5.0, turns=2.0)
    run = simulate_run(motion, sensor, landmarks, controls, 0.25, loop_start_pose(5.0), rng)
    return motion, sensor, run


def agreement(filter_class, seed: int, associator: Associator | None = None) -> AssociationAudit:
    """The audit of one simulated run."""
    motion, sensor, run = simulated_run(seed)
    filt = filter_class(motion, sensor, run.initial_pose)
    associator = associator or Associator()
    audit = AssociationAudit()
    for t in range(run.steps):
        filt.predict(run.controls[t], run.dt)
        ids = associator.update(filt, run.ranges[t], run.bearings[t])
        audit.record(associator, ids, run.ids[t])
    return audit


@pytest.mark.slow
@pytest.mark.parametrize("filter_class", [SEIF, EKF])
def test_association_agrees_with_the_truth_on_99_percent(filter_class):
    audits = [agreement(filter_class, seed) for seed in range(5)]
    agree, total = sum(a.agree for a in audits), sum(a.total for a in audits)
    discarded = sum(a.discarded for a in audits)
    assert agree / total >= 0.99, f"{filter_class.__name__}: {agree}/{total} agree, {discarded} discarded"


def test_audit_counts_each_kind_of_decision():
    class Fake:  # what AssociationAudit reads of an Associator
        created: dict = {}
        merges: list = []

    audit, fake = AssociationAudit(), Fake()
    fake.created = {0: 0, 1: 1}
    assert audit.record(fake, [0, 1], [7, 8]) == 0  # two new landmarks
    fake.created = {2: 2}
    assert audit.record(fake, [1, 0, 2, -1], [8, 9, 7, 3]) == 3  # right, wrong, duplicate of 7, discarded
    assert (audit.agree, audit.errors, audit.discarded, audit.total) == (3, 3, 1, 6)
    np.testing.assert_array_equal(audit.true_ids([1, 0, 2, 5]), [8, 7, 7, -1])


def test_decisions_on_a_hand_made_scan():
    """Known landmark, new landmark, ambiguous measurement and mutual exclusion in one scan.

    The ``"joint"`` preset (the defaults up to 1.0) discards ambiguous measurements; the defaults (``"tentative"``)
    start tentative landmarks for them (``tests/slam/test_association_family_a.py``).
    """
    from seif_gym.slam.association import make_associator

    motion = VelocityMotionModel()
    sensor = RangeBearingSensor(sigma_range=0.1, sigma_bearing=math.radians(2.0), max_range=10.0)
    filt = EKF(motion, sensor, np.zeros(3))
    associator = make_associator("joint", first_id=100)
    # map two landmarks: at (4, 0) and (0, 4)
    ids = associator.update(filt, np.array([4.0, 4.0]), np.array([0.0, math.pi / 2]))
    np.testing.assert_array_equal(ids, [100, 101])
    assert associator.created == {100: 0, 101: 1}
    ranges = np.array([4.02, 4.0, 4.55, 8.0])
    bearings = np.array([0.0, 0.005, math.pi / 2, -math.pi / 2])
    ids = associator.associate(filt, ranges, bearings)
    # measurements 0 and 1 both fit landmark 100: exclusion gives it to one, the other is ambiguous
    assert sorted(ids[:2].tolist()) == [-1, 100]
    assert ids[2] == -1  # 0.55 m from landmark 101 (d2 = 15): beyond the gate, short of a new landmark
    assert ids[3] == 102  # nothing near: a new landmark
    assert associator.next_id == 103
    assert associator.stats.associated == 1 and associator.stats.new == 3 and associator.stats.discarded == 2


def test_mutual_exclusion_picks_the_most_likely_assignment():
    motion = VelocityMotionModel()
    sensor = RangeBearingSensor(sigma_range=0.2, sigma_bearing=math.radians(3.0), max_range=10.0)
    filt = EKF(motion, sensor, np.zeros(3))
    associator = Associator()
    associator.update(filt, np.array([5.0, 5.0]), np.array([0.0, 0.1]))  # two landmarks 0.5 m apart
    # measurement 0 fits both, measurement 1 only the second: exclusion must give 0 to the first
    ids = associator.associate(filt, np.array([5.0, 5.0]), np.array([0.06, 0.1]))
    np.testing.assert_array_equal(ids, [0, 1])


def test_min_separation_blocks_new_landmarks_next_to_mapped_ones():
    motion = VelocityMotionModel()
    sensor = RangeBearingSensor(sigma_range=0.05, sigma_bearing=math.radians(0.5), max_range=10.0)
    filt = EKF(motion, sensor, np.zeros(3))
    associator = Associator(min_separation=1.5)
    associator.update(filt, np.array([5.0]), np.array([0.0]))
    ids = associator.associate(filt, np.array([6.0]), np.array([0.0]))  # 1 m behind: far in d2, near in metres
    assert ids[0] == -1
    ids = Associator().associate(filt, np.array([6.0]), np.array([0.0]))
    assert ids[0] >= 0  # without the prior it is a new landmark


def test_signatures_separate_landmarks_the_geometry_cannot():
    motion = VelocityMotionModel()
    sensor = RangeBearingSensor(sigma_range=0.2, sigma_bearing=math.radians(3.0), max_range=10.0)
    filt = EKF(motion, sensor, np.zeros(3))
    associator = Associator(signature_sigma=0.05)
    associator.update(filt, np.array([5.0, 5.0]), np.array([0.0, 0.12]), signatures=np.array([0.2, 0.8]))
    # geometrically in between, but the signature says the second one
    ids = associator.associate(filt, np.array([5.0]), np.array([0.065]), signatures=np.array([0.78]))
    np.testing.assert_array_equal(ids, [1])
    ids = associator.associate(filt, np.array([5.0]), np.array([0.055]), signatures=np.array([0.21]))
    np.testing.assert_array_equal(ids, [0])


def test_seif_joint_covariance_is_the_exact_one_without_sparsification():
    """With no sparsification the Markov-blanket block holds the whole map: exact covariances."""
    motion, sensor, run = simulated_run(0)
    seif = SEIF(motion, sensor, run.initial_pose, max_active=None, mean_recovery="exact")
    ekf = EKF(motion, sensor, run.initial_pose)
    for t in range(60):
        for filt in (seif, ekf):
            filt.predict(run.controls[t], run.dt)
            filt.update(run.ranges[t], run.bearings[t], run.ids[t])
    indices = np.array([0, seif.num_landmarks - 1, 1])
    np.testing.assert_allclose(seif.local_joint_covariance(indices), ekf.local_joint_covariance(indices), atol=1e-10)
    pose_cov, landmark_covs = seif.local_marginals(indices)
    joint = seif.local_joint_covariance(indices, neighbours=False)
    np.testing.assert_allclose(joint[:3, :3], pose_cov, atol=1e-12)
    np.testing.assert_allclose(joint[5:7, 5:7], landmark_covs[1], atol=1e-12)


def test_seif_joint_covariance_with_sparsification_is_a_valid_covariance():
    motion, sensor, run = simulated_run(1)
    seif = SEIF(motion, sensor, run.initial_pose, max_active=2)
    for t in range(120):
        seif.predict(run.controls[t], run.dt)
        seif.update(run.ranges[t], run.bearings[t], run.ids[t])
    indices = np.arange(seif.num_landmarks)[::3]
    joint = seif.local_joint_covariance(indices)
    assert joint.shape == (3 + 2 * len(indices),) * 2
    np.testing.assert_allclose(joint, joint.T, atol=1e-12)
    assert np.linalg.eigvalsh(joint).min() > 0
    # a larger block conditions on fewer landmarks: all neighbours >= the 2 strongest >= none
    limited = seif.local_joint_covariance(indices, neighbours=2)
    small = seif.local_joint_covariance(indices, neighbours=False)
    assert np.linalg.eigvalsh(joint - limited).min() > -1e-10
    assert np.linalg.eigvalsh(limited - small).min() > -1e-10
    with pytest.raises(ValueError):
        seif.local_joint_covariance(indices, neighbours=-1)


def test_empty_inputs_and_validation():
    motion = VelocityMotionModel()
    sensor = RangeBearingSensor()
    filt = SEIF(motion, sensor, np.zeros(3))
    associator = Associator()
    assert associator.update(filt, np.empty(0), np.empty(0)).shape == (0,)
    with pytest.raises(ValueError):
        Associator(gate=1.5)
    with pytest.raises(ValueError):
        Associator(gate=0.99, new_landmark=0.9)
    with pytest.raises(ValueError):
        Associator(candidate_radius=2.0, min_separation=3.0)


# -- joint compatibility branch and bound ---------------------------------------------------------------
def joint_hypotheses(nu, cov, pair_meas, pair_landmark, gate):
    """Every hypothesis (each landmark at most once) that passes the joint gate: ``(sorted pairs, d2, ln det S)``."""
    import itertools

    import scipy.stats

    measurements = sorted(set(pair_meas.tolist()))
    options = [[None] + np.flatnonzero(pair_meas == i).tolist() for i in measurements]
    for choice in itertools.product(*options):
        pairs = sorted(k for k in choice if k is not None)
        landmarks = [int(pair_landmark[k]) for k in pairs]
        if len(set(landmarks)) < len(landmarks):
            continue
        if not pairs:
            yield pairs, 0.0, 0.0
            continue
        idx = np.array([2 * k + a for k in pairs for a in (0, 1)])
        S = cov[np.ix_(idx, idx)]
        v = nu[pairs].reshape(-1)
        d2 = float(v @ np.linalg.solve(S, v))
        if d2 <= scipy.stats.chi2.ppf(gate, 2 * len(pairs)):
            yield pairs, d2, float(np.linalg.slogdet(S)[1])


def brute_force_jcbb(nu, cov, pair_meas, pair_landmark, gate):
    """Every joint hypothesis enumerated: the most pairings passing the joint gate, then the smallest d2 + ln det S."""
    best = (0, 0.0, [])
    for pairs, d2, logdet in joint_hypotheses(nu, cov, pair_meas, pair_landmark, gate):
        cost = d2 + logdet
        if len(pairs) > best[0] or (len(pairs) == best[0] and cost < best[1] - 1e-9):
            best = (len(pairs), cost, pairs)
    return best


def random_association_problem(rng: np.random.Generator):
    """A few measurements, each with 1-3 candidate landmarks, correlated through a shared pose block."""
    m, n = int(rng.integers(2, 6)), int(rng.integers(2, 6))
    pair_meas, pair_landmark = [], []
    for i in range(m):
        for j in rng.choice(n, size=int(rng.integers(1, min(n, 3) + 1)), replace=False):
            pair_meas.append(i)
            pair_landmark.append(int(j))
    K = len(pair_meas)
    A = rng.normal(size=(2 * K, 3)) * 0.5
    cov = A @ A.T + np.kron(np.eye(K), np.diag([0.05, 0.02]))
    nu = rng.normal(size=(K, 2)) * rng.uniform(0.1, 1.0)
    return nu, cov, np.array(pair_meas), np.array(pair_landmark)


@pytest.mark.parametrize("seed", range(40))
def test_jcbb_equals_brute_force_enumeration(seed):
    from seif_gym.slam.association import jcbb

    rng = np.random.default_rng(seed)
    nu, cov, pair_meas, pair_landmark = random_association_problem(rng)
    gate = float(rng.choice([0.9, 0.99, 0.999]))
    count, cost, pairs = brute_force_jcbb(nu, cov, pair_meas, pair_landmark, gate)
    found = jcbb(nu, cov, pair_meas, pair_landmark, gate=gate, max_nodes=10**6)
    assert len(found) == count
    if count:
        idx = np.array([2 * k + a for k in found for a in (0, 1)])
        S = cov[np.ix_(idx, idx)]
        v = nu[found].reshape(-1)
        assert float(v @ np.linalg.solve(S, v)) + np.linalg.slogdet(S)[1] == pytest.approx(cost, abs=1e-8)
        assert len(set(pair_meas[found].tolist())) == count and len(set(pair_landmark[found].tolist())) == count


@pytest.mark.parametrize("seed", range(60))
def test_compiled_jcbb_returns_the_reference_hypothesis(seed):
    """The compiled search and the plain-Python ``_JointSearch``: same hypothesis, budgets and starts included."""
    from seif_gym.slam.association import jcbb

    rng = np.random.default_rng(1000 + seed)
    nu, cov, pair_meas, pair_landmark = random_association_problem(rng)
    gate = float(rng.choice([0.9, 0.99, 0.999]))
    max_nodes = int(rng.choice([3, 12, 10**6]))
    first = np.flatnonzero(pair_meas == pair_meas[0])
    initial = [int(rng.choice(first))] if seed % 2 else None
    reference = jcbb(nu, cov, pair_meas, pair_landmark, gate, max_nodes, initial=initial, compiled=False)
    compiled = jcbb(nu, cov, pair_meas, pair_landmark, gate, max_nodes, initial=initial)
    np.testing.assert_array_equal(compiled, reference)
    # ranked by likelihood: the same again (a loose noise bound on half the seeds: a search that cuts less)
    gains, noise_logdet = random_gains(rng, pair_meas), float(np.log(0.05 * 0.02)) - (seed % 2) * 3.0
    reference = jcbb(nu, cov, pair_meas, pair_landmark, gate, max_nodes, initial=initial, compiled=False,
                     gains=gains, noise_logdet=noise_logdet)  # fmt: skip
    compiled = jcbb(nu, cov, pair_meas, pair_landmark, gate, max_nodes, initial=initial, gains=gains,
                    noise_logdet=noise_logdet)  # fmt: skip
    np.testing.assert_array_equal(compiled, reference)


def brute_force_likelihood_jcbb(nu, cov, pair_meas, pair_landmark, gate, gains):
    """Every joint hypothesis enumerated: the largest ``sum(gains) - (d2 + ln det S) / 2`` passing the joint gate."""
    best = (0.0, [])  # the empty hypothesis scores 0
    for pairs, d2, logdet in joint_hypotheses(nu, cov, pair_meas, pair_landmark, gate):
        score = float(gains[pairs].sum()) - 0.5 * (d2 + logdet)
        if pairs and score > best[0] + 1e-9:
            best = (score, pairs)
    return best


def random_gains(rng: np.random.Generator, pair_meas: np.ndarray) -> np.ndarray:
    """Per-pair gains around the break-even of a pairing against a new landmark (some negative)."""
    return rng.normal(loc=1.0, scale=2.0, size=len(pair_meas))


@pytest.mark.parametrize("seed", range(40))
def test_likelihood_jcbb_equals_brute_force_enumeration(seed):
    """With ``gains``, the search returns the hypothesis of largest likelihood ratio, not the most pairings."""
    from seif_gym.slam.association import jcbb

    rng = np.random.default_rng(2000 + seed)
    nu, cov, pair_meas, pair_landmark = random_association_problem(rng)
    gains = random_gains(rng, pair_meas)
    gate = float(rng.choice([0.9, 0.99, 0.999]))
    # the sensor-noise bound of the search: random_association_problem adds diag(0.05, 0.02) to every block
    noise_logdet = float(np.log(0.05 * 0.02))
    score, pairs = brute_force_likelihood_jcbb(nu, cov, pair_meas, pair_landmark, gate, gains)
    for compiled in (True, False):
        found = jcbb(nu, cov, pair_meas, pair_landmark, gate=gate, max_nodes=10**6, compiled=compiled,
                     gains=gains, noise_logdet=noise_logdet)  # fmt: skip
        assert found.tolist() == pairs, (compiled, score)


def test_likelihood_jcbb_prefers_one_good_pairing_to_two_poor_ones():
    """The case of the loop runs: two poor pairings pass the joint gate where one good one explains the scan.

    Counting pairings takes the two; the likelihood ratio against new landmarks takes the good one, unless
    new landmarks are unlikely where the two measurements lie.
    """
    from seif_gym.slam.association import jcbb

    # pairs: 0 = measurement 0 -> landmark 0 (d2 1); 1 = measurement 1 -> landmark 0 and 2 = measurement 2 ->
    # landmark 1 (d2 6.25 each); pairs 0 and 2 are strongly correlated (a shared pose) and jointly incompatible
    nu = np.array([[1.0, 0.0], [2.5, 0.0], [2.5, 0.0]])
    cov = np.eye(6)
    cov[0, 4] = cov[4, 0] = -0.95
    pair_meas, pair_landmark = np.array([0, 1, 2]), np.array([0, 0, 1])
    assert jcbb(nu, cov, pair_meas, pair_landmark, gate=0.999).tolist() == [1, 2]
    # measurements 1 and 2 about as likely new landmarks as not: 5 - 1/2 beats 3 + 3 - 12.5/2
    gains = np.array([5.0, 3.0, 3.0])
    assert jcbb(nu, cov, pair_meas, pair_landmark, gate=0.999, gains=gains, noise_logdet=0.0).tolist() == [0]
    # where a new landmark is unlikely (a well-covered place), the two pairings win again: 6 + 6 - 6.25 > 4.5
    gains = np.array([5.0, 6.0, 6.0])
    assert jcbb(nu, cov, pair_meas, pair_landmark, gate=0.999, gains=gains, noise_logdet=0.0).tolist() == [1, 2]
    with pytest.raises(ValueError, match="gains"):
        jcbb(nu, cov, pair_meas, pair_landmark, gains=np.zeros(2))
    with pytest.raises(ValueError, match="gains"):
        jcbb(nu, cov, pair_meas, pair_landmark, gains=np.array([5.0, np.nan, 3.0]))
    for bad in (float("nan"), float("inf"), "0"):
        with pytest.raises(ValueError, match="noise_logdet"):
            jcbb(nu, cov, pair_meas, pair_landmark, gains=np.ones(3), noise_logdet=bad)


def test_conditional_loglik_is_the_chain_rule():
    from seif_gym.slam.association import conditional_loglik

    rng = np.random.default_rng(3)
    nu, cov, _, _ = random_association_problem(rng)
    pairs = np.array([0, len(nu) - 1]) if len(nu) > 1 else np.array([0])
    idx = np.array([2 * k + a for k in pairs for a in (0, 1)])
    S = cov[np.ix_(idx, idx)]

    def logpdf(v, C):
        return -0.5 * (v @ np.linalg.solve(C, v) + np.linalg.slogdet(2 * np.pi * C)[1])

    joint = logpdf(nu[pairs].reshape(-1), S)
    rest = logpdf(nu[pairs[1:]].reshape(-1), S[2:, 2:]) if len(pairs) > 1 else 0.0
    assert conditional_loglik(nu, cov, pairs)[0] == pytest.approx(joint - rest, abs=1e-9)


def test_associator_validates_its_new_options():
    for kwargs in ({"landmark_density": -1.0}, {"detection": 1.0}, {"joint_gate": 0.0}, {"max_nodes": 0},
                   {"blanket_size": -1}, {"landmark_separation": -0.5}):  # fmt: skip
        with pytest.raises(ValueError, match=next(iter(kwargs))):
            Associator(**kwargs)


# -- presets, and the seif_gym 0.1 associator they must reproduce -----------------------------------------------------
def legacy_ids(associator: Associator, filt, ranges, bearings) -> np.ndarray:
    """seif_gym 0.1's decision, written out: chi-square gate, best assignment of ``d2 + ln det S``, new landmarks."""
    import scipy.optimize

    m = len(ranges)
    ids = np.full(m, -1, dtype=np.int64)
    gate, new_threshold = associator.thresholds()
    pair_meas, pair_landmark, d2, logdet = associator.distances(filt, ranges, bearings)
    gated = np.flatnonzero(d2 <= gate)
    if len(gated):
        rows, row_of = np.unique(pair_meas[gated], return_inverse=True)
        cols, col_of = np.unique(pair_landmark[gated], return_inverse=True)
        cost = np.full((len(rows), len(cols)), 1e9)
        cost[row_of, col_of] = d2[gated] + logdet[gated]
        r_idx, c_idx = scipy.optimize.linear_sum_assignment(cost)
        ok = cost[r_idx, c_idx] < 1e9
        ids[rows[r_idx[ok]]] = filt.landmark_ids[cols[c_idx[ok]]]
    best = np.full(m, np.inf)
    np.minimum.at(best, pair_meas, d2)
    new = (ids < 0) & (best > new_threshold)
    ids[new] = associator.next_id + np.arange(int(new.sum()))
    return ids


@pytest.mark.parametrize("filter_class", [EKF, SEIF])
def test_individual_preset_reproduces_the_original_associator(filter_class):
    from seif_gym.slam.association import make_associator

    motion, sensor, run = simulated_run(7)
    filt = filter_class(motion, sensor, run.initial_pose)
    associator = make_associator("individual")
    for t in range(run.steps):
        filt.predict(run.controls[t], run.dt)
        expected = legacy_ids(associator, filt, run.ranges[t], run.bearings[t])
        ids = associator.associate(filt, run.ranges[t], run.bearings[t])
        np.testing.assert_array_equal(ids, expected, err_msg=f"step {t}")
        keep = ids >= 0
        filt.update(run.ranges[t][keep], run.bearings[t][keep], ids[keep])
    assert associator.stats.deferred == 0


def test_make_associator_presets_and_overrides():
    from seif_gym.slam.association import ASSOCIATOR_PRESETS, make_associator

    assert set(ASSOCIATOR_PRESETS) == {"individual", "joint", "revisable", "likelihood", "tentative"}
    revisable = make_associator("revisable")
    assert revisable.joint and revisable.loop_merge and revisable.tentative_closures
    assert revisable.joint_objective == "pairings" and revisable.exclusion_margin is None
    likelihood = make_associator("likelihood")
    assert likelihood.loop_merge and likelihood.tentative_closures and likelihood.joint_objective == "likelihood"
    assert likelihood.gate == 0.9999 and likelihood.exclusion_margin == pytest.approx(9.21, abs=0.01)
    individual = make_associator("individual")
    assert not individual.joint and individual.landmark_density == 0.0 and individual.blanket_size == 0
    assert individual.detection == 0.0
    joint = make_associator()
    assert joint.joint and joint.landmark_density == Associator().landmark_density
    assert make_associator("joint", gate=0.99).gate == 0.99
    with pytest.raises(ValueError, match="preset"):
        make_associator("nearest")
    with pytest.raises(ValueError, match="preset"):
        make_associator(3)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="closure_window"):
        make_associator(closure_window=-1)


# -- loop closure: the scenarios of seif_gym.slam.scenarios (full figures: benchmarks/association.py) -----------
def loop_audit(scenario: str, seed: int, filter_name: str, preset: str) -> AssociationAudit:
    """One loop-closing run of ``FIDELITY_SCENARIOS`` with hidden ids; its audit (and the associator as ``.associator``)."""
    from seif_gym.slam.association import make_associator
    from seif_gym.slam.scenarios import FIDELITY_SCENARIOS, make_loop_run

    motion, sensor, run = make_loop_run(FIDELITY_SCENARIOS[scenario], seed)
    filt = EKF(motion, sensor, run.initial_pose) if filter_name == "EKF" else SEIF(
        motion, sensor, run.initial_pose, max_active=8)  # fmt: skip
    associator, audit = make_associator(preset), AssociationAudit()
    for t in range(run.steps):
        filt.predict(run.controls[t], run.dt)
        audit.record(associator, associator.update(filt, run.ranges[t], run.bearings[t]), run.ids[t])
    audit.associator = associator
    return audit


@pytest.mark.slow
@pytest.mark.parametrize("filter_name", ["EKF", "SEIF"])
def test_loop_closing_runs_beat_the_individual_associator(filter_name):
    """All eight ``FIDELITY_SCENARIOS``, seed 0 (no selection), default ("joint") against "individual".

    Measured (``python benchmarks/association.py --seeds 1``, and with the individual preset's options):

    * EKF: joint 99.60% correct, duplicates 0.24% of the true landmarks; individual 99.48%, 1.70%.
      The issue's targets (>= 99.5%, <= 2%) are met and both figures beat the individual associator:
      that is what is asserted.
    * SEIF(max_active=8): joint 98.78%, 6.20%; individual 99.32%, 4.86%. The targets are NOT met and
      the joint preset does NOT beat the individual one on these runs (``circle-large`` and
      ``rectangle-narrow``: loop closures the SEIF's overconfident covariance gets wrong, which the
      deferral of lone closures makes worse here; over seeds 0-2 the duplicates are lower, 4.20% vs
      4.82%, the correct fraction still lower, 98.98% vs 99.27%). Asserted: regression bounds only,
      98.5% correct and 7% duplicates for the joint preset.
    """
    from seif_gym.slam.scenarios import FIDELITY_SCENARIOS

    totals = {}
    for preset in ("joint", "individual"):
        audits = [loop_audit(name, 0, filter_name, preset) for name in FIDELITY_SCENARIOS]
        totals[preset] = (sum(a.agree for a in audits) / sum(a.total for a in audits),
                          sum(a.duplicates for a in audits) / sum(a.true_landmarks for a in audits))  # fmt: skip
    (correct, duplicates), (legacy_correct, legacy_duplicates) = totals["joint"], totals["individual"]
    message = f"{filter_name}: joint {correct:.4f} correct, {duplicates:.4f} dup; individual {legacy_correct:.4f}, " \
              f"{legacy_duplicates:.4f}"  # fmt: skip
    if filter_name == "EKF":
        assert correct >= 0.995 and duplicates <= 0.02, message
        assert correct > legacy_correct and duplicates < legacy_duplicates, message
    else:
        assert correct >= 0.985 and duplicates <= 0.07, message


def test_lone_loop_closures_are_deferred_until_backed():
    """A closing pair alone is deferred (discarded); with ``closure_pairings=1`` nothing ever is."""
    from seif_gym.slam.association import make_associator

    audit = loop_audit("rectangle-narrow", 0, "EKF", "joint")
    assert audit.associator.stats.deferred > 0
    assert audit.associator.stats.deferred <= audit.discarded
    motion, sensor, run = simulated_run(1)
    filt = EKF(motion, sensor, run.initial_pose)
    associator = make_associator(closure_pairings=1)
    for t in range(run.steps):
        filt.predict(run.controls[t], run.dt)
        associator.update(filt, run.ranges[t], run.bearings[t])
    assert associator.stats.deferred == 0


def test_exclusion_margin_lets_a_landmark_start_next_to_one_measured_in_the_same_scan():
    """A tree 0.6 m beside a mapped one, both measured at 3 m: its d2 to the mapped tree is 16 (between the gate, 13.8,
    and the new-landmark threshold, 23). The other measurement takes the mapped tree with d2 0, so by mutual exclusion
    the first is a new landmark; without ``exclusion_margin`` it is discarded as ambiguous.
    """
    from seif_gym.slam.association import make_associator

    sensor = RangeBearingSensor(max_range=5.0, fov=math.pi)
    ranges, bearings = np.array([3.0, math.hypot(3.0, 0.6)]), np.array([0.0, math.atan2(0.6, 3.0)])
    decisions = {}
    for margin in (None, 9.2, 20.0):
        filt = EKF(VelocityMotionModel(), sensor, np.zeros(3))
        associator = make_associator("joint", exclusion_margin=margin)  # the 0.999 gate of 1.0's defaults
        assert associator.update(filt, ranges[:1], bearings[:1]).tolist() == [0]
        filt.predict(np.zeros(2), 0.25)
        d2 = associator.distances(filt, ranges, bearings)[2]
        assert d2[0] < 1e-9 and associator.thresholds()[0] < d2[1] < associator.thresholds()[1]
        decisions[margin] = associator.update(filt, ranges, bearings).tolist()
    assert decisions == {None: [0, -1], 9.2: [0, 1], 20.0: [0, -1]}  # 16 - 0 < 20: still too close to call
    for bad in (-1.0, float("nan"), "9"):
        with pytest.raises((ValueError, TypeError), match="exclusion_margin"):
            Associator(exclusion_margin=bad)
    with pytest.raises(ValueError, match="joint_objective"):
        Associator(joint_objective="most")
