"""Tests of ``seif_gym.slam.marginals``: the breadth-first covariance block of a SEIF."""

from __future__ import annotations

import numpy as np
import pytest

from seif_gym.slam import EKF, SEIF
from seif_gym.slam.marginals import breadth_first_joint_covariance, breadth_first_nodes
from seif_gym.slam.scenarios import FIDELITY_SCENARIOS, make_loop_run


def seif_after(steps: int, max_active: int | None = 4):
    motion, sensor, run = make_loop_run(FIDELITY_SCENARIOS["circle"], 0)
    seif = SEIF(motion, sensor, run.initial_pose, max_active=max_active)
    for t in range(steps):
        seif.predict(run.controls[t], run.dt)
        seif.update(run.ranges[t], run.bearings[t], run.ids[t])
    return seif


def test_a_block_holding_the_whole_map_is_exact():
    seif = seif_after(120)
    indices = np.array([0, seif.num_landmarks // 2, seif.num_landmarks - 1])
    cov = breadth_first_joint_covariance(seif, indices, max_landmarks=10**6)
    state = np.concatenate([np.arange(3)] + [3 + 2 * i + np.arange(2) for i in indices])
    exact = np.linalg.inv(seif.information_matrix.toarray())[np.ix_(state, state)]
    np.testing.assert_allclose(cov, exact, rtol=1e-8, atol=1e-10)


def test_block_is_bounded_and_wider_than_the_markov_blanket():
    seif = seif_after(200)
    old = np.array([0, 1])
    nodes = breadth_first_nodes(seif._store, seif._active, old, 40)
    assert len(nodes) == 40 and len(set(nodes.tolist())) == 40
    assert set(old.tolist()) <= set(nodes.tolist()) and set(seif._active.tolist()) <= set(nodes.tolist())
    wide = breadth_first_joint_covariance(seif, old, 40)
    narrow = seif.local_joint_covariance(old, neighbours=False)  # robot, active and targets: inside the BFS block
    # a larger block conditions on less: a larger (or equal) covariance
    assert np.linalg.eigvalsh(wide - narrow).min() > -1e-10
    assert np.trace(wide) > np.trace(narrow)


def test_validation():
    seif = seif_after(10)
    with pytest.raises(TypeError):
        breadth_first_joint_covariance(EKF(seif.motion, seif.sensor, np.zeros(3)), np.array([0]))
    with pytest.raises(ValueError):
        breadth_first_joint_covariance(seif, np.array([seif.num_landmarks]))
    with pytest.raises(ValueError):
        breadth_first_joint_covariance(seif, np.array([0]), max_landmarks=-1)
    with pytest.raises(TypeError):
        breadth_first_joint_covariance(seif, np.array([0.5]))
