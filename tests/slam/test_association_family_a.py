"""Association on family-A loops (``ASSOCIATION_SCENARIOS["family-a"]``) and the open tentative landmarks.

Family A: Thrun's velocity model, a circle of radius 8 m at 1.2 m/s, 0.1 s steps, about 60 landmarks at least
1 m apart, a 3.5 m / 180 degree sensor. At the loop closure an unmapped landmark about a metre from a landmark
mapped a loop ago falls inside its gate; the ``"likelihood"`` preset discards its measurements as ambiguous
(or gives them to the old landmark's tentative double), the ``"tentative"`` preset starts a tentative landmark
for it, which later scans confirm as a landmark of its own.

The fast test runs 450 steps (the loop closes near step 420) of design seed 3 with the EKF; the figures on the
held-out seeds 100..111, for the EKF and the SEIF, come from ``python benchmarks/association.py --family-a``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from seif_gym.slam import EKF, SEIF, RangeBearingSensor, VelocityMotionModel
from seif_gym.slam.association import ASSOCIATOR_PRESETS, AssociationAudit, Associator, make_associator
from seif_gym.slam.scenarios import ASSOCIATION_SCENARIOS, make_loop_run


def family_a_audit(seed: int, preset: str, steps: int | None = None, filter_name: str = "ekf") -> AssociationAudit:
    """The audit of one family-A run (its first ``steps`` steps) with the associator of ``preset``."""
    motion, sensor, run = make_loop_run(ASSOCIATION_SCENARIOS["family-a"], seed)
    if filter_name == "ekf":
        filt = EKF(motion, sensor, run.initial_pose)
    else:
        filt = SEIF(motion, sensor, run.initial_pose, max_active=8)
    associator, audit = make_associator(preset), AssociationAudit()
    for t in range(run.steps if steps is None else steps):
        filt.predict(run.controls[t], run.dt)
        audit.record(associator, associator.update(filt, run.ranges[t], run.bearings[t]), run.ids[t])
    return audit


def test_family_a_scenario_is_the_issue_s_loop():
    motion, sensor, run = make_loop_run(ASSOCIATION_SCENARIOS["family-a"], 0)
    assert run.steps == 700 and run.dt == 0.1
    assert 55 <= len(run.landmarks) <= 65
    gaps = np.hypot(*(run.landmarks[:, None, :] - run.landmarks[None, :, :]).transpose(2, 0, 1))
    assert gaps[~np.eye(len(gaps), dtype=bool)].min() >= 1.0
    assert tuple(motion.alphas) == (0.01, 0.001, 0.001, 0.01, 1e-4, 1e-4)
    assert sensor.max_range == 3.5 and sensor.fov == pytest.approx(math.pi)
    assert np.allclose(run.controls, [1.2, 0.15])


def test_tentative_preset_holds_the_loop_closure_the_likelihood_preset_discards():
    """Measured (design seed 3, 450 steps, EKF): likelihood 97.37% (39 discarded), tentative 100.00%, 0 duplicates."""
    before = family_a_audit(3, "likelihood", steps=450)
    after = family_a_audit(3, "tentative", steps=450)
    assert after.duplicates == 0 and after.discarded == 0
    assert after.agreement >= 0.995
    assert before.agreement < 0.98 and before.discarded > 20  # the failure the preset removes


def test_default_associator_is_the_tentative_preset():
    default = Associator()
    for name, value in ASSOCIATOR_PRESETS["tentative"].items():
        assert getattr(default, name) == value, name
    # the presets of 1.0 pin what they changed from the defaults: they compute what they did
    joint = make_associator("joint")
    assert not joint.open_tentatives and not joint.loop_merge and joint.gate == 0.999
    assert joint.joint_objective == "pairings" and joint.exclusion_margin is None


def test_ambiguous_measurement_starts_a_tentative_landmark_confirmed_when_seen_with_its_neighbour():
    """A tree 0.68 m beside a mapped one, at 3 m: outside the mapped one's gate, too close to be a new landmark.

    Alone, it is a tentative landmark (the double of the mapped tree) rather than a discarded measurement;
    seen in one scan with the mapped tree it is confirmed a landmark of its own (never merged into it).
    """
    sensor = RangeBearingSensor(max_range=5.0, fov=math.pi)
    r, b = math.hypot(3.0, 0.68), math.atan2(0.68, 3.0)
    decisions = {}
    for preset in ("likelihood", "tentative"):
        filt = EKF(VelocityMotionModel(), sensor, np.zeros(3))
        associator = make_associator(preset)
        assert associator.update(filt, np.array([3.0]), np.array([0.0])).tolist() == [0]
        filt.predict(np.zeros(2), 0.25)
        d2 = associator.distances(filt, np.array([r]), np.array([b]))[2]
        gate, new_landmark = associator.thresholds()
        assert gate < d2[0] < new_landmark  # ambiguous
        decisions[preset] = associator.update(filt, np.array([r]), np.array([b])).tolist()
    assert decisions == {"likelihood": [-1], "tentative": [1]}
    assert associator.tentatives[1][0] == 0
    # both trees in one scan: two landmarks; the tentative one is confirmed, never merged
    for _ in range(2):
        filt.predict(np.zeros(2), 0.25)
        assert associator.update(filt, np.array([3.0, r]), np.array([0.0, b])).tolist() == [0, 1]
    assert 1 not in associator.tentatives and filt.num_landmarks == 2


def test_open_tentatives_validation():
    assert not Associator(open_tentatives=True, tentative_closures=False).open_tentatives  # nothing to open
    with pytest.raises(TypeError, match="open_tentatives"):
        Associator(open_tentatives=1)  # type: ignore[arg-type]
    with pytest.raises((TypeError, ValueError), match="tentative_scans"):
        Associator(tentative_scans=0)


@pytest.mark.slow
@pytest.mark.parametrize("filter_name", ["ekf", "seif"])
def test_family_a_held_out_seeds_meet_the_targets(filter_name):
    """Held-out seeds 100..103 (never run while designing): >= 99.5% correct, <= 2% duplicates on the final map.

    The full table (seeds 100..111, three presets) is ``python benchmarks/association.py --family-a``.
    """
    audits = [family_a_audit(seed, "tentative", filter_name=filter_name) for seed in range(100, 104)]
    correct = sum(a.agree for a in audits) / sum(a.total for a in audits)
    duplicates = sum(a.duplicates for a in audits) / sum(a.true_landmarks for a in audits)
    assert correct >= 0.995 and duplicates <= 0.02, (correct, duplicates)
