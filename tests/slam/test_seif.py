"""The SEIF's own guarantees: sparsification, the active bound, mean recovery,
constant-time steps, linear memory, and the compiled kernels equal to the
reference functions of ``seif_gym.slam.seif``."""

from __future__ import annotations

import numpy as np
import pytest

from seif_gym.slam import RangeBearingSensor, VelocityMotionModel, _kernels
from seif_gym.slam.information import InformationStore
from seif_gym.slam.seif import (
    SEIF,
    RecoveryQueue,
    measurement_update,
    motion_update,
    recover_mean_amortized,
    recover_mean_wavefront,
    sparsify,
)

DT = 0.1


def feed(filt, run, steps=None):
    for t in range(run.steps if steps is None else steps):
        filt.predict(run.controls[t], run.dt)
        filt.update(run.ranges[t], run.bearings[t], run.ids[t])
    return filt


def dense(filt) -> np.ndarray:
    return filt.information_matrix.toarray()


# ---------------------------------------------------------------------------
# compiled kernels == reference functions
# ---------------------------------------------------------------------------
def store_arrays(store: InformationStore):
    return (
        store.robot_info, store.robot_links, store.landmark_info,
        store.neighbour_index, store.neighbour_info, store.neighbour_count,
        store.information_vector,
    )  # fmt: skip


def assert_stores_equal(a: InformationStore, b: InformationStore, rtol=1e-12) -> None:
    np.testing.assert_allclose(a.to_sparse().toarray(), b.to_sparse().toarray(), rtol=rtol, atol=1e-9)
    np.testing.assert_allclose(a.information_vector_view(), b.information_vector_view(), rtol=rtol, atol=1e-9)
    np.testing.assert_allclose(a.mean_view(), b.mean_view(), rtol=rtol, atol=1e-12)


@pytest.fixture(scope="module")
def busy_seif(ring_loop_run):
    """A SEIF whose store has robot links, landmark links and many landmarks."""
    motion, sensor, run = ring_loop_run
    return feed(SEIF(motion, sensor, run.initial_pose, max_active=6), run, steps=120)


def test_gather_equals_reference(busy_seif):
    store = busy_seif._store
    landmarks = np.concatenate([busy_seif._active, [0, 3]]).astype(np.int64)
    expected = store.gather(landmarks)
    got = _kernels.gather(*store_arrays(store), store.mean, store.block_position, landmarks)
    for e, g in zip(expected, got):
        np.testing.assert_array_equal(e, g)
    assert np.all(store.block_position == -1)


def test_scatter_equals_reference(busy_seif):
    rng = np.random.default_rng(1)
    landmarks = np.concatenate([busy_seif._active, [0, 3]]).astype(np.int64)
    size = 3 + 2 * len(landmarks)
    block = rng.standard_normal((size, size))
    block = block @ block.T
    xi = rng.standard_normal(size)
    reference, compiled = busy_seif._store.copy(), busy_seif._store.copy()
    reference.scatter(landmarks, block, xi)
    compiled.reserve_degree(landmarks, len(landmarks))
    _kernels.scatter(*store_arrays(compiled), landmarks, block, xi)
    assert_stores_equal(reference, compiled, rtol=0)


def random_block(rng, landmarks: int):
    size = 3 + 2 * landmarks
    a = rng.standard_normal((size, size))
    omega = a @ a.T + size * np.eye(size)
    mu = rng.standard_normal(size) * 5
    xi = omega @ mu + 1e-3 * rng.standard_normal(size)
    return omega, xi, mu


@pytest.mark.parametrize("landmarks", [0, 1, 8, 12])
@pytest.mark.parametrize("control", [(1.0, 0.5), (0.7, 0.0), (0.0, 0.0)])
def test_motion_kernel_equals_reference(landmarks, control):
    rng = np.random.default_rng(landmarks)
    omega, xi, mu = random_block(rng, landmarks)
    delta, jacobian, noise = VelocityMotionModel().linearize(mu[:3], control, DT)
    expected = motion_update(omega, xi, mu, delta, jacobian, noise)
    got = _kernels.motion_update_block(omega, xi, mu, delta, jacobian, noise)
    for e, g in zip(expected, got):
        np.testing.assert_allclose(g, e, rtol=1e-9, atol=1e-9 * np.abs(e).max())


@pytest.mark.parametrize("num_kept,num_removed", [(0, 1), (3, 1), (8, 2), (4, 5)])
def test_sparsify_kernel_equals_reference(num_kept, num_removed):
    rng = np.random.default_rng(num_kept * 10 + num_removed)
    omega, xi, mu = random_block(rng, num_kept + num_removed)
    expected = sparsify(omega, xi, mu, num_kept)
    got = _kernels.sparsify_block(omega, xi, mu, num_kept)
    for e, g in zip(expected, got):
        np.testing.assert_allclose(g, e, rtol=1e-10, atol=1e-10 * np.abs(e).max())


def test_measurement_kernel_equals_reference(busy_seif):
    sensor = busy_seif.sensor
    indices = np.array([0, 2, 5, 9], dtype=np.int64)
    store = busy_seif._store
    z = sensor.predict(store.mean[:3], store.mean[3:].reshape(-1, 2)[indices]) + 0.05
    reference, compiled = store.copy(), store.copy()
    omega, xi, mu = reference.gather(indices)
    omega, xi = measurement_update(omega, xi, mu, z[:, 0], z[:, 1], busy_seif._measurement_info)
    reference.scatter(indices, omega, xi)
    _kernels.measurement_update(
        compiled.robot_info, compiled.robot_links, compiled.landmark_info, compiled.information_vector,
        compiled.mean, indices, z[:, 0].copy(), z[:, 1].copy(), busy_seif._measurement_info,
    )  # fmt: skip
    assert_stores_equal(reference, compiled)


def test_recovery_kernel_equals_reference(busy_seif):
    landmarks = np.arange(busy_seif.num_landmarks, dtype=np.int64)
    reference, compiled = busy_seif._store.copy(), busy_seif._store.copy()
    recover_mean_amortized(reference, landmarks, busy_seif._active)
    _kernels.recover_mean(*store_arrays(compiled), compiled.mean, landmarks, busy_seif._active)
    np.testing.assert_allclose(compiled.mean_view(), reference.mean_view(), rtol=1e-12, atol=1e-12)


def test_wavefront_kernel_equals_reference(ring_loop_run):
    """The compiled wavefront (with its undo log) equals the plain one: means and queue, step by step."""
    motion, sensor, run = ring_loop_run
    filt = feed(SEIF(motion, sensor, run.initial_pose, max_active=6, mean_recovery="amortized"), run, steps=200)
    # a stale mean everywhere (as after a loop closure) so that the wave spreads and the budget binds
    filt._store.mean[3 : filt.state_dim] += 0.05
    reference_store, compiled_store = filt._store.copy(), filt._store.copy()
    reference_queue, compiled_queue = RecoveryQueue(filt._store.capacity), RecoveryQueue(filt._store.capacity)
    seeds = np.array([0, 5, 9], dtype=np.int64)
    for _ in range(6):
        recover_mean_wavefront(reference_store, reference_queue, filt._active, seeds, 16, 1.5, 1e-4)
        log_size = (len(seeds) + len(filt._active) + 16) * (2 + compiled_store.degree) + 1
        undo = (
            np.empty(log_size, np.int8),
            np.empty(log_size, np.int64),
            np.empty((log_size, 2)),
            np.zeros(1, np.int64),
        )
        _kernels.recover_mean_wavefront(
            *store_arrays(compiled_store), compiled_store.mean, compiled_store.block_position, filt._active, seeds,
            compiled_queue.items, compiled_queue.queued, compiled_queue.state, 16, 1.5, 1e-4, *undo,
        )  # fmt: skip
        np.testing.assert_allclose(compiled_store.mean_view(), reference_store.mean_view(), rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(compiled_queue.ordered(), reference_queue.ordered())
        np.testing.assert_array_equal(compiled_queue.queued, reference_queue.queued)
        assert len(reference_queue) > 0  # the budget binds: work is carried over
    # the undo log of the last call takes the mean and the queue back to before it
    before_mean, before_items = compiled_store.mean.copy(), compiled_queue.items.copy()
    undo = (np.empty(log_size, np.int8), np.empty(log_size, np.int64), np.empty((log_size, 2)), np.zeros(1, np.int64))
    state_before = compiled_queue.state.copy()
    queued_before = compiled_queue.queued.copy()
    _kernels.recover_mean_wavefront(
        *store_arrays(compiled_store), compiled_store.mean, compiled_store.block_position, filt._active, seeds,
        compiled_queue.items, compiled_queue.queued, compiled_queue.state, 16, 1.5, 1e-4, *undo,
    )  # fmt: skip
    assert not np.array_equal(compiled_store.mean, before_mean)
    _kernels.undo_wavefront(compiled_store.mean, compiled_queue.items, compiled_queue.queued, compiled_queue.state,
                            *undo[:3], int(undo[3][0]))  # fmt: skip
    mean_after = compiled_store.mean.copy()
    mean_after[:3] = before_mean[:3]  # the robot is the journal's to restore
    np.testing.assert_array_equal(mean_after, before_mean)
    np.testing.assert_array_equal(compiled_queue.items, before_items)
    np.testing.assert_array_equal(compiled_queue.state, state_before)
    np.testing.assert_array_equal(compiled_queue.queued, queued_before)


def test_wavefront_descends_and_converges(ring_loop_run):
    """Each recovery lowers 1/2 mu^T Omega mu - xi^T mu (block SOR on an SPD matrix) and the mean approaches Omega^-1 xi."""
    motion, sensor, run = ring_loop_run
    filt = feed(SEIF(motion, sensor, run.initial_pose, max_active=6), run, steps=300)
    omega = filt.information_matrix
    exact = filt.exact_mean()
    filt._store.mean[3 : filt.state_dim] += np.random.default_rng(0).normal(0.0, 0.3, filt.state_dim - 3)

    def energy() -> float:
        mu = filt.mean - exact  # relative to the minimum: no cancellation in the comparison
        return 0.5 * float(mu @ (omega @ mu))

    start_error, last = np.abs(filt.mean - exact).max(), energy()
    for _ in range(1000):
        filt._recover_mean()
        now = energy()
        assert now <= last * (1 + 1e-12)
        last = now
    assert np.abs(filt.mean - exact).max() < 0.02 * start_error


def test_wavefront_keeps_up_where_round_robin_lags(ring_loop_run):
    """After the loop closes, the default recovery is far closer to Omega^-1 xi than Thrun's round robin."""
    motion, sensor, run = ring_loop_run
    lags = {}
    for recovery in ("wavefront", "amortized"):
        filt = feed(SEIF(motion, sensor, run.initial_pose, max_active=6, mean_recovery=recovery), run, steps=300)
        lags[recovery] = np.abs(filt.mean - filt.exact_mean()).max()
    assert lags["wavefront"] < 0.2 * lags["amortized"]


@pytest.mark.parametrize("max_active", [None, 2, 6])
@pytest.mark.parametrize("mean_recovery", ["wavefront", "amortized", "exact"])
def test_compiled_filter_equals_reference_filter(ring_loop_run, max_active, mean_recovery):
    motion, sensor, run = ring_loop_run
    options = dict(max_active=max_active, mean_recovery=mean_recovery)
    compiled = feed(SEIF(motion, sensor, run.initial_pose, **options), run, steps=150)
    reference = feed(SEIF(motion, sensor, run.initial_pose, implementation="reference", **options), run, steps=150)
    np.testing.assert_allclose(compiled.mean, reference.mean, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(dense(compiled), dense(reference), rtol=1e-9, atol=1e-6)
    np.testing.assert_array_equal(compiled.active_landmarks, reference.active_landmarks)


# ---------------------------------------------------------------------------
# sparsification, one step, against the full-matrix equations of docs/filters/math.md
# ---------------------------------------------------------------------------
def sparsify_full_matrix(omega, xi, mu, x, m0, m_minus):
    """docs/filters/math.md, "Sparsification", on the whole matrix, Omega^0 with the m- rows and columns zeroed."""
    omega0 = omega.copy()
    omega0[m_minus, :] = 0.0
    omega0[:, m_minus] = 0.0

    def term(matrix, idx):
        return matrix[:, idx] @ np.linalg.solve(matrix[np.ix_(idx, idx)], matrix[idx, :])

    xm0 = np.concatenate([x, m0])
    omega_tilde = omega - term(omega0, m0) + term(omega0, xm0) - term(omega, x)
    return omega_tilde, xi + (omega_tilde - omega) @ mu


@pytest.mark.parametrize("implementation", ["compiled", "reference"])
def test_one_sparsification_step(ring_loop_run, implementation):
    motion, sensor, run = ring_loop_run
    filt = feed(
        SEIF(motion, sensor, run.initial_pose, max_active=8, mean_recovery="exact", implementation=implementation),
        run,
        steps=80,
    )
    before_active = set(filt.active_landmarks.tolist())
    assert len(before_active) > 6, "the scenario must have more active landmarks than the bound"
    assert filt.num_landmarks > len(before_active), "and passive landmarks"
    omega, xi, mu = dense(filt), filt.information_vector.copy(), filt.mean.copy()
    filt.max_active = 3
    filt.update([], [], np.array([], dtype=np.int64))  # no measurement: only sparsification acts
    after_active = set(filt.active_landmarks.tolist())
    assert len(after_active) == 3 and after_active < before_active

    omega_tilde, xi_tilde = dense(filt), filt.information_vector

    def rows(ids):
        return np.concatenate([[3 + 2 * filt.landmark_index(i), 4 + 2 * filt.landmark_index(i)] for i in ids])

    x = np.arange(3)
    m0 = rows(sorted(before_active - after_active))
    m_minus = rows(sorted(set(filt.landmark_ids.tolist()) - before_active))
    # robot-m0 links are exactly zero; m- rows and columns untouched bit for bit
    assert np.all(omega_tilde[np.ix_(x, m0)] == 0.0) and np.all(omega_tilde[np.ix_(m0, x)] == 0.0)
    np.testing.assert_array_equal(omega_tilde[m_minus, :], omega[m_minus, :])
    np.testing.assert_array_equal(omega_tilde[:, m_minus], omega[:, m_minus])
    np.testing.assert_array_equal(xi_tilde[m_minus], xi[m_minus])
    # symmetric positive definite, and the mean is kept
    np.testing.assert_array_equal(omega_tilde, omega_tilde.T)
    assert np.linalg.eigvalsh(omega_tilde).min() > 0.0
    np.testing.assert_allclose(np.linalg.solve(omega_tilde, xi_tilde), mu, rtol=1e-9, atol=1e-9)
    # and it is the full-matrix formula of docs/filters/math.md restricted to the active block
    expected_omega, expected_xi = sparsify_full_matrix(omega, xi, mu, x, m0, m_minus)
    scale = np.abs(omega).max()
    np.testing.assert_allclose(omega_tilde, expected_omega, rtol=1e-9, atol=1e-9 * scale)
    np.testing.assert_allclose(xi_tilde, expected_xi, rtol=1e-9, atol=1e-9 * np.abs(xi).max())


@pytest.mark.parametrize("max_active", [1, 3, 8])
def test_active_bound_holds_after_every_update(ring_loop_run, max_active):
    motion, sensor, run = ring_loop_run
    filt = SEIF(motion, sensor, run.initial_pose, max_active=max_active)
    exceeded = 0
    for t in range(run.steps):
        filt.predict(run.controls[t], run.dt)
        filt.update(run.ranges[t], run.bearings[t], run.ids[t])
        active = filt.active_landmarks
        observed = len(run.ids[t])
        assert len(active) <= max(max_active, observed)
        if len(active) > max_active:
            # only when more than k were seen, and then exactly the ones seen stay
            assert set(active.tolist()) == set(run.ids[t].tolist())
            exceeded += 1
        # the robot's links are exactly its active landmarks
        robot_row = dense(filt)[:3, 3:].reshape(3, -1, 2)
        linked = filt.landmark_ids[np.flatnonzero(np.any(robot_row != 0.0, axis=(0, 2)))]
        assert set(linked.tolist()) <= set(active.tolist())
    assert max_active > 1 or exceeded > 0, "the run should also exercise the many-observations case"


# ---------------------------------------------------------------------------
# mean recovery
# ---------------------------------------------------------------------------
def test_amortized_recovery_converges_to_exact_mean(ring_loop_run):
    motion, sensor, run = ring_loop_run
    filt = feed(SEIF(motion, sensor, run.initial_pose, max_active=4), run)
    exact = filt.exact_mean()
    errors = [np.abs(filt.mean - exact).max()]
    for _ in range(10):
        filt.refine_mean(1000)
        errors.append(np.abs(filt.mean - exact).max())
    assert errors[0] > 1e-3, "amortized recovery alone should not already be exact"
    assert all(b < a for a, b in zip(errors, errors[1:])), errors
    assert errors[-1] < 1e-8 * max(1.0, np.abs(exact).max()), errors
    # refining never changes the information form
    np.testing.assert_allclose(filt.exact_mean(), exact, rtol=1e-12, atol=1e-12)


def test_exact_recovery_mean_solves_information_form(ring_loop_run):
    motion, sensor, run = ring_loop_run
    filt = feed(SEIF(motion, sensor, run.initial_pose, max_active=4, mean_recovery="exact"), run, steps=100)
    np.testing.assert_allclose(dense(filt) @ filt.mean, filt.information_vector, rtol=1e-9, atol=1e-9)


# ---------------------------------------------------------------------------
# constant time and linear memory (structural checks; timings are in benchmarks/)
# ---------------------------------------------------------------------------
def test_amortized_steps_never_touch_the_whole_map(ring_loop_run, monkeypatch):
    motion, sensor, run = ring_loop_run
    filt = feed(SEIF(motion, sensor, run.initial_pose, max_active=6), run, steps=30)

    def forbidden(*args, **kwargs):
        raise AssertionError("a per-step path built a whole-map matrix")

    monkeypatch.setattr(InformationStore, "to_sparse", forbidden)
    monkeypatch.setattr("scipy.sparse.linalg.splu", forbidden)
    monkeypatch.setattr(_kernels, "recover_mean", _guard_recovery(_kernels.recover_mean, limit=6 + 8 + 1))
    for t in range(30, run.steps):
        filt.predict(run.controls[t], run.dt)
        filt.update(run.ranges[t], run.bearings[t], run.ids[t])


def _guard_recovery(kernel, limit):
    def guarded(*args):
        landmarks = args[-2]
        assert len(landmarks) <= limit + 20, f"amortized recovery touched {len(landmarks)} landmarks"
        return kernel(*args)

    return guarded


def corridor_seif(num_landmarks: int) -> SEIF:
    """Drive along a corridor of ``num_landmarks`` landmarks until all are mapped."""
    rng = np.random.default_rng(3)
    spacing = 0.5
    landmarks = np.column_stack([spacing * np.arange(num_landmarks), rng.uniform(-2.0, 2.0, num_landmarks)])
    motion = VelocityMotionModel()
    sensor = RangeBearingSensor(max_range=3.0)
    filt = SEIF(motion, sensor, [-1.0, 0.0, 0.0], max_active=8)
    pose = np.array([-1.0, 0.0, 0.0])
    speed = 2.0
    for _ in range(int(spacing * num_landmarks / (speed * DT)) + 20):
        pose = motion.predict(pose, (speed, 0.0), DT)
        visible = sensor.visible(pose, landmarks)
        z = sensor.predict(pose, landmarks[visible])
        filt.predict((speed, 0.0), DT)
        filt.update(z[:, 0], z[:, 1], np.flatnonzero(visible))
    assert filt.num_landmarks == num_landmarks
    return filt


@pytest.mark.slow
def test_memory_is_linear_in_the_map():
    small, large = corridor_seif(250), corridor_seif(1000)
    per_landmark_small = small.memory_bytes / small.num_landmarks
    per_landmark_large = large.memory_bytes / large.num_landmarks
    # capacity doubles, so allow a factor two either way, but no growth with n
    assert 0.5 < per_landmark_large / per_landmark_small < 2.0
    # and the information matrix stays sparse: bounded links per landmark
    nnz = large.information_matrix.nnz
    assert nnz < 200 * large.num_landmarks


@pytest.mark.parametrize("dense_up_to", [0, 10_000], ids=["sparse-lu", "dense-cholesky"])
def test_marginal_covariances_are_exact(busy_seif, monkeypatch, dense_up_to):
    """Both paths of the exact marginals equal the inverse of the dense information matrix."""
    monkeypatch.setattr(SEIF, "DENSE_MARGINALS_UP_TO", dense_up_to)
    inverse = np.linalg.inv(dense(busy_seif))
    np.testing.assert_allclose(busy_seif.pose_covariance, inverse[:3, :3], rtol=1e-9, atol=1e-12)
    landmark = int(busy_seif.landmark_ids[5])
    rows = slice(3 + 2 * 5, 5 + 2 * 5)
    np.testing.assert_allclose(busy_seif.landmark_covariance(landmark), inverse[rows, rows], rtol=1e-9, atol=1e-12)


def _held(obj, seen: set | None = None) -> object:
    """Every array and plain value ``obj`` holds, recursively, as comparable values (the models left out)."""
    seen = set() if seen is None else seen
    if isinstance(obj, np.ndarray):
        return (obj.dtype.str, obj.shape, obj.tobytes())
    if isinstance(obj, (int, float, bool, str, type(None), np.generic)):
        return obj
    if isinstance(obj, dict):
        return {key: _held(value, seen) for key, value in obj.items()}
    if isinstance(obj, (tuple, list)):
        return tuple(_held(value, seen) for value in obj)
    if not hasattr(obj, "__dict__") or id(obj) in seen:
        return type(obj).__name__
    seen.add(id(obj))
    return {name: _held(value, seen) for name, value in vars(obj).items() if name not in ("motion", "sensor")}


@pytest.mark.parametrize("name", ["ekf", "eif", "seif", "eseif"])
def test_a_deep_copy_runs_on_as_the_original_and_apart_from_it(ring_loop_run, name):
    """``SlamFilter.__deepcopy__`` (the planner's copies): the same filter, sharing no state with the original."""
    import copy

    from seif_gym.slam import EIF, EKF, ESEIF, SEIF

    motion, sensor, run = ring_loop_run
    make = {"ekf": EKF, "eif": EIF, "seif": SEIF, "eseif": ESEIF}[name]
    original = feed(make(motion, sensor, run.initial_pose), run, 150)
    before = _held(original)
    copied = copy.deepcopy(original)
    assert _held(copied) == before and copied._id_to_index is not original._id_to_index
    # the copy runs on (closing the loop, mapping new landmarks) and the original is left as it was
    for t in range(150, run.steps):
        copied.predict(run.controls[t], run.dt)
        copied.update(run.ranges[t], run.bearings[t], run.ids[t])
    assert copied.num_landmarks > original.num_landmarks
    assert _held(original) == before
    # the original, run on the same way, ends where the copy did, bit for bit
    for t in range(150, run.steps):
        original.predict(run.controls[t], run.dt)
        original.update(run.ranges[t], run.bearings[t], run.ids[t])
    assert _held(original) == _held(copied)
