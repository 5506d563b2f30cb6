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


@pytest.mark.parametrize("filter_class", [SEIF, EKF])
def test_association_agrees_with_the_truth_on_99_percent(filter_class):
    audits = [agreement(filter_class, seed) for seed in range(5)]
    agree, total = sum(a.agree for a in audits), sum(a.total for a in audits)
    discarded = sum(a.discarded for a in audits)
    assert agree / total >= 0.99, f"{filter_class.__name__}: {agree}/{total} agree, {discarded} discarded"


def test_audit_counts_each_kind_of_decision():
    class Fake:
        created: dict = {}

    audit, fake = AssociationAudit(), Fake()
    fake.created = {0: 0, 1: 1}
    assert audit.record(fake, [0, 1], [7, 8]) == 0  # two new landmarks
    fake.created = {2: 2}
    assert audit.record(fake, [1, 0, 2, -1], [8, 9, 7, 3]) == 3  # right, wrong, duplicate of 7, discarded
    assert (audit.agree, audit.errors, audit.discarded, audit.total) == (3, 3, 1, 6)
    np.testing.assert_array_equal(audit.true_ids([1, 0, 2, 5]), [8, 7, 7, -1])


def test_decisions_on_a_hand_made_scan():
    """Known landmark, new landmark, ambiguous measurement and mutual exclusion in one scan."""
    motion = VelocityMotionModel()
    sensor = RangeBearingSensor(sigma_range=0.1, sigma_bearing=math.radians(2.0), max_range=10.0)
    filt = EKF(motion, sensor, np.zeros(3))
    associator = Associator(first_id=100)
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
