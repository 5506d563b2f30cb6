"""Each filter step runs the same on both backends, and each compiled kernel equals its reference.

``tests/slam/test_seif.py`` compares the block kernels (gather, scatter, motion, measurement, sparsification,
amortized and wavefront recovery) with the reference functions; ``tests/slam/test_eseif.py`` the ESEIF's.
Here: every method of the two SEIF (and ESEIF) backends on copies of one busy store, and the kernels
that have no reference function against the mathematics they compute (inverses, traces, the motion
model's linearization, the heading wrap).
"""

from __future__ import annotations

import numpy as np
import pytest

from seif_gym.slam import ESEIF, SEIF, VelocityMotionModel, _kernels
from seif_gym.slam.eseif import CompiledESEIFBackend, ReferenceESEIFBackend
from seif_gym.slam.information import InformationStore
from seif_gym.slam.seif import CompiledSEIFBackend, RecoveryQueue, ReferenceSEIFBackend, _rewrap_heading

DT = 0.1


def feed(filt, run, steps):
    for t in range(steps):
        filt.predict(run.controls[t], run.dt)
        filt.update(run.ranges[t], run.bearings[t], run.ids[t])
    return filt


def assert_stores_close(a: InformationStore, b: InformationStore) -> None:
    omega_a, omega_b = a.to_sparse().toarray(), b.to_sparse().toarray()
    scale = np.abs(omega_a).max()
    np.testing.assert_allclose(omega_a, omega_b, rtol=1e-10, atol=1e-10 * scale)
    np.testing.assert_allclose(a.information_vector_view(), b.information_vector_view(), rtol=1e-10, atol=1e-8)
    np.testing.assert_allclose(a.mean_view(), b.mean_view(), rtol=1e-10, atol=1e-10)


@pytest.fixture(scope="module")
def busy(ring_loop_run):
    """A SEIF after 120 steps of the ring loop: robot links, landmark links, passive landmarks."""
    motion, sensor, run = ring_loop_run
    return feed(SEIF(motion, sensor, run.initial_pose, max_active=6), run, 120)


def both(busy):
    """(compiled store, reference store): two copies of the busy filter's store."""
    return busy._store.copy(), busy._store.copy()


def test_backends_run_the_motion_update_alike(busy):
    compiled, reference = both(busy)
    delta, jacobian, noise = VelocityMotionModel().linearize(compiled.mean[:3], (0.8, 0.3), DT)
    CompiledSEIFBackend().motion_update(compiled, busy._active, delta, jacobian, noise)
    ReferenceSEIFBackend().motion_update(reference, busy._active, delta, jacobian, noise)
    assert_stores_close(compiled, reference)
    assert not np.array_equal(compiled.robot_info, busy._store.robot_info)  # it did move


def test_backends_run_the_measurement_update_alike(busy):
    compiled, reference = both(busy)
    indices = np.array([0, 2, 5], dtype=np.int64)
    z = busy.sensor.predict(compiled.mean[:3], compiled.mean[3:].reshape(-1, 2)[indices]) + 0.03
    for backend, store in ((CompiledSEIFBackend(), compiled), (ReferenceSEIFBackend(), reference)):
        backend.measurement_update(store, indices, z[:, 0].copy(), z[:, 1].copy(), busy._measurement_info)
    assert_stores_close(compiled, reference)


def test_backends_sparsify_alike(busy):
    compiled, reference = both(busy)
    block = np.asarray(busy._active, dtype=np.int64)
    assert len(block) >= 3
    CompiledSEIFBackend().sparsify(compiled, block, len(block) - 2)
    ReferenceSEIFBackend().sparsify(reference, block, len(block) - 2)
    assert_stores_close(compiled, reference)
    assert not np.any(compiled.robot_links[block[-2:]])  # the two left the robot's links


def test_backends_recover_the_mean_alike(busy):
    compiled, reference = both(busy)
    for store in (compiled, reference):
        store.mean[3 : store.state_dim] += 0.05  # stale, as after a loop closure
    landmarks = np.arange(busy.num_landmarks, dtype=np.int64)
    CompiledSEIFBackend().recover_mean_amortized(compiled, landmarks, busy._active)
    ReferenceSEIFBackend().recover_mean_amortized(reference, landmarks, busy._active)
    assert_stores_close(compiled, reference)
    stores = both(busy)
    queues = RecoveryQueue(stores[0].capacity), RecoveryQueue(stores[1].capacity)
    seeds = np.array([1, 7], dtype=np.int64)
    for backend, store, queue in zip((CompiledSEIFBackend(), ReferenceSEIFBackend()), stores, queues):
        store.mean[3 : store.state_dim] += 0.05
        for _ in range(3):
            backend.recover_mean_wavefront(store, queue, busy._active, seeds, 16, 1.5, 1e-4, None)
    assert_stores_close(*stores)
    assert len(queues[0]) > 0  # the budget binds: the wave is still travelling
    np.testing.assert_array_equal(queues[0].ordered(), queues[1].ordered())


def test_backends_give_the_same_blanket_covariances(busy):
    store = busy._store
    targets = np.array([0, 3, int(busy._active[0])], dtype=np.int64)
    compiled = CompiledSEIFBackend().blanket_covariances(store, busy._active, busy._is_active, targets)
    reference = ReferenceSEIFBackend().blanket_covariances(store, busy._active, busy._is_active, targets)
    for c, r in zip(compiled, reference):
        np.testing.assert_allclose(c, r, rtol=1e-9, atol=1e-12)
    assert np.all(store.block_position == -1)  # the kernels' scratch is left clean


def test_eseif_backends_marginalize_the_robot_alike(ring_loop_run):
    motion, sensor, run = ring_loop_run
    filt = feed(ESEIF(motion, sensor, run.initial_pose, max_active=6), run, 60)
    compiled, reference = filt._store.copy(), filt._store.copy()
    block = np.asarray(filt._active, dtype=np.int64)
    CompiledESEIFBackend().marginalize_robot(compiled, block)
    ReferenceESEIFBackend().marginalize_robot(reference, block)
    np.testing.assert_allclose(compiled.to_sparse().toarray(), reference.to_sparse().toarray(), rtol=1e-9, atol=1e-6)
    assert not np.any(compiled.robot_info) and not np.any(compiled.robot_links)


def test_blanket_joint_covariance_is_the_inverse_of_its_block(busy):
    store = busy._store
    targets = np.array([0, 4], dtype=np.int64)
    cov = _kernels.blanket_joint_covariance(*store.kernel_arrays(), busy._active, targets, -1)
    # the block: the robot, the active landmarks, the targets and every landmark linked to a target
    nodes = list(dict.fromkeys(busy._active.tolist() + targets.tolist()))
    for i in targets.tolist():
        nodes += [int(j) for j in store.neighbour_index[i, : store.neighbour_count[i]] if int(j) not in nodes]
    omega, _, _ = store.gather(np.array(nodes, dtype=np.int64))
    full = np.linalg.inv(omega)
    rows = np.concatenate([np.arange(3)] + [3 + 2 * nodes.index(int(i)) + np.arange(2) for i in targets])
    np.testing.assert_allclose(cov, full[np.ix_(rows, rows)], rtol=1e-8, atol=1e-12)


def test_exact_marginal_is_the_dense_inverse(busy):
    store = busy._store
    indices = np.array([0, 1, 2, 3 + 2 * 5, 4 + 2 * 5], dtype=np.int64)
    cov = _kernels.exact_marginal(*store.kernel_arrays(), store.num_landmarks, indices)
    full = np.linalg.inv(store.to_sparse().toarray())
    np.testing.assert_allclose(cov, full[np.ix_(indices, indices)], rtol=1e-8, atol=1e-12)


def test_conditional_std_is_the_root_trace_of_each_landmarks_inverse_block(busy):
    store = busy._store
    std = _kernels.conditional_std(store.landmark_info, store.num_landmarks)
    expected = [np.sqrt(np.trace(np.linalg.inv(store.landmark_info[i]))) for i in range(store.num_landmarks)]
    np.testing.assert_allclose(std, expected, rtol=1e-12)


@pytest.mark.parametrize("control", [(0.8, 0.3), (0.5, 0.0), (0.0, 0.0), (1.0, 1e-6)])
def test_velocity_linearization_is_the_motion_models(control):
    model = VelocityMotionModel()
    theta = 2.9
    expected = model.linearize_trusted(np.array([1.0, -2.0, theta]), np.asarray(control, dtype=float), DT)
    delta, jacobian, noise = np.empty(3), np.empty((3, 3)), np.empty((3, 3))
    alphas = np.array(model.alphas, dtype=np.float64)
    _kernels.velocity_linearization(theta, control[0], control[1], DT, alphas, float(model.noise_floor), delta,
                                    jacobian, noise)  # fmt: skip
    for e, g in zip(expected, (delta, jacobian, noise)):
        np.testing.assert_array_equal(g, e)  # the same operations: the same bits (the batch depends on it)


def test_rewrap_heading_kernel_equals_reference(busy):
    compiled, reference = both(busy)
    for store in (compiled, reference):
        store.mean[2] += 2.0 * np.pi + 0.3  # out of [-pi, pi)
    _kernels.rewrap_heading(compiled.robot_info, compiled.robot_links, compiled.information_vector, compiled.mean,
                            busy._active)  # fmt: skip
    _rewrap_heading(reference, busy._active)
    assert -np.pi <= compiled.mean[2] < np.pi
    np.testing.assert_array_equal(compiled.mean_view(), reference.mean_view())
    np.testing.assert_allclose(compiled.information_vector_view(), reference.information_vector_view(), rtol=1e-14)
