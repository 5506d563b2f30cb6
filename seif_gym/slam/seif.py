"""The Sparse Extended Information Filter (Thrun et al., *Probabilistic Robotics*, ch. 12).

Each of the four SEIF steps has one function here, written as
plainly as the equations, over a dense *block* of the information matrix:
the robot and the landmarks the step touches (its active landmarks, or the
ones it observes). The block is gathered from and scattered back to an
:class:`~seif_gym.slam.information.InformationStore`, so every step costs time
in the size of the active set, never in the size of the map:

1. :func:`motion_update`          (Probabilistic Robotics, Table 12.2)
2. :func:`measurement_update`     (Table 12.3)
3. :func:`sparsify`               (Table 12.4)
4. :func:`recover_mean_wavefront` (the block step of Table 12.5), the default
   amortized recovery (and Thrun's round robin :func:`recover_mean_amortized`,
   and :func:`recover_mean_exact`)

With no sparsification (``max_active=None``) and exact mean recovery the SEIF
is the exact extended information filter, and both equal EKF SLAM to
round-off after any number of steps; sparsification keeps the mean at the step
where it is applied.

An update either completes or leaves the filter bit-identical: each stage
saves what it is about to change in a :class:`UpdateJournal` first, and a
failure anywhere (a block that is not positive definite, say) restores it.

These functions are the *reference path*. A :class:`SEIF` runs its steps
through one backend, chosen once from its ``implementation`` option:
:class:`CompiledSEIFBackend` (the default: the compiled twins of these
functions, all in :mod:`seif_gym.slam._kernels`) or
:class:`ReferenceSEIFBackend` (these functions on gathered blocks); the tests
check the two equal (``tests/slam/test_kernels.py``, ``tests/slam/test_seif.py``).
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg
from numpy.typing import ArrayLike, NDArray

from seif_gym.slam import _kernels
from seif_gym.slam.base import SlamFilter, SparseInformationForm
from seif_gym.slam.information import InformationStore
from seif_gym.slam.models import wrap_angle
from seif_gym.type_aliases import FloatArray, IntArray
from seif_gym.validation import as_count, as_nonnegative_scalar, as_scalar_between

__all__ = [
    "SEIF",
    "SEIFBackend",
    "CompiledSEIFBackend",
    "ReferenceSEIFBackend",
    "DENSE_MARGINALS_UP_TO",
    "exact_marginal_covariance",
    "motion_update",
    "measurement_update",
    "sparsify",
    "recover_mean_amortized",
    "recover_mean_wavefront",
    "recover_mean_exact",
    "RecoveryQueue",
    "JournalBuffer",
    "UpdateJournal",
    "blanket_covariances",
]


# ---------------------------------------------------------------------------
# The four steps, reference path (dense blocks, literal equations)
# ---------------------------------------------------------------------------
def motion_update(
    omega: FloatArray, xi: FloatArray, mu: FloatArray, delta: FloatArray, jacobian: FloatArray, noise: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """SEIF motion update on the block of the robot and its active landmarks.

    Parameters
    ----------
    omega, xi, mu : ndarray
        Information matrix (s, s), vector (s,) and mean (s,) of the block,
        robot first.
    delta : ndarray, shape (3,)
        Pose increment of the motion model.
    jacobian : ndarray, shape (3, 3)
        ``G = I + Delta``, the motion Jacobian with respect to the pose.
    noise : ndarray, shape (3, 3)
        State-space motion noise ``R``.

    Returns
    -------
    omega_bar, xi_bar, mu_bar : ndarray
        The predicted block. ``mu_bar``'s heading is *not* wrapped here.

    Notes
    -----
    Thrun, Burgard & Fox, *Probabilistic Robotics*, Table 12.2::

        Psi   = F_x^T [(I + Delta)^-1 - I] F_x
        lam   = Psi^T Omega + Omega Psi + Psi^T Omega Psi
        Phi   = Omega + lam
        kappa = Phi F_x^T (R^-1 + F_x Phi F_x^T)^-1 F_x Phi
        Omega_bar = Phi - kappa
        xi_bar    = xi + (lam - kappa) mu + Omega_bar F_x^T delta
        mu_bar    = mu + F_x^T delta

    All of ``lam`` and ``kappa`` lies in the rows and columns of the robot
    and its active landmarks, which is why the block is enough.
    """
    size = len(xi)
    F_x = np.zeros((3, size))
    F_x[:, :3] = np.eye(3)
    psi = F_x.T @ (np.linalg.inv(jacobian) - np.eye(3)) @ F_x
    lam = psi.T @ omega + omega @ psi + psi.T @ omega @ psi
    phi = omega + lam
    kappa = phi @ F_x.T @ np.linalg.inv(np.linalg.inv(noise) + F_x @ phi @ F_x.T) @ F_x @ phi
    omega_bar = phi - kappa
    omega_bar = 0.5 * (omega_bar + omega_bar.T)
    xi_bar = xi + (lam - kappa) @ mu + omega_bar @ F_x.T @ delta
    mu_bar = mu + F_x.T @ delta
    return omega_bar, xi_bar, mu_bar


def measurement_update(
    omega: FloatArray,
    xi: FloatArray,
    mu: FloatArray,
    ranges: FloatArray,
    bearings: FloatArray,
    noise_info: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Add range-bearing measurements to the block of the robot and the observed landmarks.

    The p-th measurement is of the p-th landmark of the block (block rows
    ``3 + 2p, 4 + 2p``); ``noise_info`` is ``Q^-1``.

    Notes
    -----
    Probabilistic Robotics, Table 12.3, linearised at ``mu``::

        Omega = Omega_bar + sum_i H_i^T Q^-1 H_i
        xi    = xi_bar    + sum_i H_i^T Q^-1 [wrap(z_i - z_hat_i) + H_i mu_bar]

    The bearing innovation is wrapped; ``xi`` itself never is.
    """
    omega = omega.copy()
    xi = xi.copy()
    x, y, theta = mu[:3]
    for p, (r, phi) in enumerate(zip(ranges, bearings)):
        j = slice(3 + 2 * p, 5 + 2 * p)
        d = mu[j] - (x, y)
        q = float(d @ d)
        sqrt_q = np.sqrt(q)
        z_hat = np.array([sqrt_q, np.arctan2(d[1], d[0]) - theta])
        H_small = (
            np.array(
                [
                    [-sqrt_q * d[0], -sqrt_q * d[1], 0.0, sqrt_q * d[0], sqrt_q * d[1]],
                    [d[1], -d[0], -q, -d[1], d[0]],
                ]
            )
            / q
        )
        H = np.zeros((2, len(xi)))
        H[:, :3] = H_small[:, :3]
        H[:, j] = H_small[:, 3:]
        innovation = np.array([r - z_hat[0], wrap_angle(float(phi - z_hat[1]))])
        omega += H.T @ noise_info @ H
        xi += H.T @ noise_info @ (innovation + H @ mu)
    return 0.5 * (omega + omega.T), xi


def sparsify(omega: FloatArray, xi: FloatArray, mu: FloatArray, num_kept: int) -> tuple[FloatArray, FloatArray]:
    """Remove the robot's links to the last active landmarks of the block.

    The block holds the robot, then ``num_kept`` landmarks that stay active
    (``m+``), then the landmarks to deactivate (``m0``). Passive landmarks
    (``m-``) are not in the block: every term below is zero outside it.

    Notes
    -----
    Probabilistic Robotics, Table 12.4, with ``Omega^0`` the block
    itself (conditioning on ``m- = 0`` removes only rows outside it)::

        Omega~ = Omega - Omega0 F_m0 (F_m0^T Omega0 F_m0)^-1 F_m0^T Omega0
                       + Omega0 F_xm0 (F_xm0^T Omega0 F_xm0)^-1 F_xm0^T Omega0
                       - Omega F_x (F_x^T Omega F_x)^-1 F_x^T Omega
        xi~    = xi + (Omega~ - Omega) mu

    The robot-``m0`` blocks of ``Omega~`` are zero in exact arithmetic; they
    are set to exact zeros before ``xi~`` is formed, so the mean is kept to
    round-off.
    """
    size = len(xi)
    start_m0 = 3 + 2 * num_kept
    x = np.arange(3)
    m0 = np.arange(start_m0, size)
    xm0 = np.concatenate([x, m0])

    def project(indices: IntArray, matrix: FloatArray) -> FloatArray:
        F = np.zeros((size, len(indices)))
        F[indices, np.arange(len(indices))] = 1.0
        return matrix @ F @ np.linalg.solve(F.T @ matrix @ F, F.T @ matrix)

    omega_tilde = omega - project(m0, omega) + project(xm0, omega) - project(x, omega)
    omega_tilde[np.ix_(x, m0)] = 0.0
    omega_tilde[np.ix_(m0, x)] = 0.0
    omega_tilde = 0.5 * (omega_tilde + omega_tilde.T)
    xi_tilde = xi + (omega_tilde - omega) @ mu
    return omega_tilde, xi_tilde


def recover_mean_amortized(store: InformationStore, landmarks: IntArray, active: IntArray) -> None:
    """Coordinate descent on ``1/2 mu^T Omega mu - xi^T mu`` for some landmarks, then the robot.

    Updates ``store.mean`` in place: each landmark of ``landmarks`` in turn,
    then the robot (whose neighbours are the ``active`` landmarks).

    Notes
    -----
    Probabilistic Robotics, Table 12.5::

        mu_i = Omega_ii^-1 (xi_i - sum_{j != i} Omega_ij mu_j)
    """
    mean, xi = store.mean, store.information_vector
    for i in landmarks:
        rows = slice(3 + 2 * i, 5 + 2 * i)
        rhs = xi[rows] - store.robot_links[i].T @ mean[:3]
        for slot in range(store.neighbour_count[i]):
            j = store.neighbour_index[i, slot]
            rhs = rhs - store.neighbour_info[i, slot] @ mean[3 + 2 * j : 5 + 2 * j]
        mean[rows] = np.linalg.solve(store.landmark_info[i], rhs)
    rhs = xi[:3].copy()
    for i in active:
        rhs -= store.robot_links[i] @ mean[3 + 2 * i : 5 + 2 * i]
    mean[:3] = np.linalg.solve(store.robot_info, rhs)


#: Up to this many landmarks, exact marginals factorise the dense ``Omega`` (a sparse LU's fixed overhead dominates there).
DENSE_MARGINALS_UP_TO = 60


def exact_marginal_covariance(store: InformationStore, state_indices: IntArray,
                              dense_up_to: int = DENSE_MARGINALS_UP_TO) -> FloatArray:  # fmt: skip
    """Exact marginal covariance ``[Omega^-1]`` over ``state_indices``: a global solve, never constant time.

    Up to ``dense_up_to`` landmarks, a dense Cholesky of ``Omega`` gathered
    by a compiled kernel (O(n^3), at most a ``(3 + 2 dense_up_to)``-square
    matrix); above, a sparse LU (O(n) to O(n^1.5)).
    Per-step callers (the env's ``info["pose_nees"]``, single or batched) pay
    this; the filter's own steps never call it. ``tests/slam/test_seif.py`` checks
    both paths against the inverse of the dense matrix.
    """
    if store.num_landmarks <= dense_up_to:
        cov = _kernels.exact_marginal(*store.kernel_arrays(), store.num_landmarks,
                                      np.asarray(state_indices, dtype=np.int64))  # fmt: skip
    else:
        unit = np.zeros((store.state_dim, len(state_indices)))
        unit[state_indices, np.arange(len(state_indices))] = 1.0
        solver = scipy.sparse.linalg.splu(store.to_sparse().tocsc(), permc_spec="MMD_AT_PLUS_A")
        cov = solver.solve(unit)[state_indices]
    return 0.5 * (cov + cov.T)


class RecoveryQueue:
    """The FIFO of landmarks waiting for relaxation in :func:`recover_mean_wavefront`.

    A ring buffer (``items``, free slots hold -1), a flag per landmark
    (``queued``) and ``state = [head, size]``; arrays so that the compiled
    kernel can work on them in place. Memory linear in the map.
    """

    def __init__(self, capacity: int = 64) -> None:
        self.items: IntArray = np.full(capacity, -1, dtype=np.int64)
        self.queued: NDArray[np.bool_] = np.zeros(capacity, dtype=bool)
        self.state: IntArray = np.zeros(2, dtype=np.int64)

    def __len__(self) -> int:
        return int(self.state[1])

    def ordered(self) -> IntArray:
        """The queued landmarks, first to be relaxed first."""
        head, size = int(self.state[0]), int(self.state[1])
        return self.items[(head + np.arange(size)) % len(self.items)]

    def grow(self, capacity: int) -> None:
        """Make room for ``capacity`` landmarks (new arrays; the queue's order is kept)."""
        if capacity <= len(self.items):
            return
        ordered = self.ordered()
        items = np.full(capacity, -1, dtype=np.int64)
        items[: len(ordered)] = ordered
        queued = np.zeros(capacity, dtype=bool)
        queued[: len(self.queued)] = self.queued
        self.items, self.queued = items, queued
        self.state = np.array([0, len(ordered)], dtype=np.int64)

    def push(self, landmark: int) -> None:
        if not self.queued[landmark]:
            self.items[(self.state[0] + self.state[1]) % len(self.items)] = landmark
            self.state[1] += 1
            self.queued[landmark] = True

    def pop(self) -> int:
        head = int(self.state[0])
        landmark = int(self.items[head])
        self.items[head] = -1
        self.state[0] = (head + 1) % len(self.items)
        self.state[1] -= 1
        self.queued[landmark] = False
        return landmark


def recover_mean_wavefront(
    store: InformationStore,
    queue: RecoveryQueue,
    active: IntArray,
    seeds: IntArray,
    budget: int,
    relaxation: float,
    tolerance: float,
) -> None:
    """Block coordinate descent that follows the correction outwards from the robot.

    Relax each landmark of ``seeds`` (passive ones in round robin); solve for
    the robot and its ``active`` landmarks jointly, the rest of the map held
    at its mean; then pop up to ``budget`` landmarks from ``queue`` and relax
    each with over-relaxation ``relaxation``. A landmark whose mean moves by
    more than ``tolerance`` puts its neighbours in ``Omega`` on the queue.
    Finally relax the robot again. Updates ``store.mean`` and ``queue`` in place.

    Notes
    -----
    The same block step as Thrun's amortized recovery (Table 12.5),
    over-relaxed (block SOR, ``0 < relaxation < 2``)::

        mu_i <- mu_i + w [ Omega_ii^-1 (xi_i - sum_{j != i} Omega_ij mu_j) - mu_i ]

    Every block step lowers ``1/2 mu^T Omega mu - xi^T mu`` for ``0 < w < 2``
    (``Omega`` is positive definite), so with the round robin of passive
    landmarks among the seeds the mean converges to ``Omega^-1 xi`` whatever
    the order. The order is what matters for speed: a loop closure moves the
    robot and the landmarks it sees, and the correction must travel along the
    chain of links back through the map; the FIFO relaxes the landmarks in the
    order the wave reaches them, a bounded number per update, and carries the
    rest over to the next update. The robot and its active landmarks are
    coupled by the strongest links of ``Omega``; one joint solve of their
    ``(3 + 2k)`` block (the block step of a bigger block) moves them together,
    where single-block steps would creep. The cost per update is
    ``O(k^3 + (|seeds| + budget) * degree)``, whatever the size of the map.
    """
    mean, xi = store.mean, store.information_vector

    def relax(i: int, weight: float) -> None:
        rows = slice(3 + 2 * i, 5 + 2 * i)
        rhs = xi[rows] - store.robot_links[i].T @ mean[:3]
        for slot in range(store.neighbour_count[i]):
            j = store.neighbour_index[i, slot]
            rhs = rhs - store.neighbour_info[i, slot] @ mean[3 + 2 * j : 5 + 2 * j]
        move = weight * (np.linalg.solve(store.landmark_info[i], rhs) - mean[rows])
        mean[rows] += move
        if float(move @ move) > tolerance * tolerance:
            for j in store.neighbour_index[i, : store.neighbour_count[i]]:
                queue.push(int(j))

    def relax_robot() -> None:
        rhs = xi[:3].copy()
        for i in active:
            rhs -= store.robot_links[i] @ mean[3 + 2 * i : 5 + 2 * i]
        mean[:3] = np.linalg.solve(store.robot_info, rhs)

    for i in seeds:
        relax(int(i), 1.0)
    # the robot and its active landmarks in one block, the rest of the map held at its mean
    omega, rhs, _ = store.gather(active)
    inside = set(active.tolist())
    for p, i in enumerate(active.tolist()):
        for slot in range(store.neighbour_count[i]):
            j = int(store.neighbour_index[i, slot])
            if j not in inside:
                rhs[3 + 2 * p : 5 + 2 * p] -= store.neighbour_info[i, slot] @ mean[3 + 2 * j : 5 + 2 * j]
    solution = np.linalg.solve(omega, rhs)
    mean[:3] = solution[:3]
    for p, i in enumerate(active.tolist()):
        move = solution[3 + 2 * p : 5 + 2 * p] - mean[3 + 2 * i : 5 + 2 * i]
        mean[3 + 2 * i : 5 + 2 * i] += move
        if float(move @ move) > tolerance * tolerance:
            for j in store.neighbour_index[i, : store.neighbour_count[i]]:
                queue.push(int(j))
    for _ in range(budget):
        if len(queue) == 0:
            break
        relax(queue.pop(), relaxation)
    relax_robot()


class JournalBuffer:
    """Reusable buffers for the landmark rows an :class:`UpdateJournal` saves (one per filter).

    Grown (doubling) when a step saves more rows, or wider rows, than they
    hold; their size follows the active set and the scan, never the map.
    """

    def __init__(self, rows: int = 32, width: int = 16) -> None:
        self.rows: IntArray = np.zeros(rows, dtype=np.int64)
        self.links: FloatArray = np.zeros((rows, 3, 2))
        self.info: FloatArray = np.zeros((rows, 2, 2))
        self.index: IntArray = np.zeros((rows, width), dtype=np.int64)
        self.neighbours: FloatArray = np.zeros((rows, width, 2, 2))
        self.counts: IntArray = np.zeros(rows, dtype=np.int64)
        self.values: FloatArray = np.zeros((rows, 4))
        self.flags: NDArray[np.bool_] = np.zeros(rows, dtype=bool)
        self.observed: IntArray = np.zeros(rows, dtype=np.int64)

    def reserve(self, rows: int, width: int, keep: int) -> None:
        """Room for ``rows`` entries of ``width`` neighbour slots, keeping the first ``keep`` entries."""
        if rows <= len(self.rows) and width <= self.index.shape[1]:
            return
        grown = JournalBuffer(max(rows, 2 * len(self.rows)), max(width, self.index.shape[1]))
        for name in ("rows", "links", "info", "counts", "values", "flags", "observed"):
            getattr(grown, name)[:keep] = getattr(self, name)[:keep]
        grown.index[:keep, : self.index.shape[1]] = self.index[:keep]
        grown.neighbours[:keep, : self.index.shape[1]] = self.neighbours[:keep]
        vars(self).update(vars(grown))

    def arrays(self) -> tuple[NDArray, ...]:
        return (self.rows, self.links, self.info, self.index, self.neighbours, self.counts, self.values,
                self.flags, self.observed)  # fmt: skip


class UpdateJournal:
    """What a filter step is about to change, saved so that a failed step can be undone.

    Opened with the landmarks whose rows the step may change (information
    rows, links, ``xi``, ``mu``, flags): they are saved at once, with the
    robot's block and references to every array (a stage that grows the
    store replaces them). Recovery adds what it touches beyond them: the
    wavefront's undo log, or copies for the exact and the plain paths.
    :meth:`restore` puts it all back, so that the filter is bit-identical to
    before the step. It costs time in the number of landmarks the step
    touches, never in the size of the map.
    """

    _STORE_ARRAYS = (
        "robot_links", "landmark_info", "neighbour_index", "neighbour_info",
        "neighbour_count", "information_vector", "mean", "block_position",
    )  # fmt: skip
    _FILTER_ARRAYS = ("_active", "_is_active", "_last_observed")

    def __init__(self, filt: SEIF, landmarks: IntArray | None = None) -> None:
        store, queue = filt._store, filt._queue
        self._filter = filt
        # in the order of _STORE_ARRAYS and _FILTER_ARRAYS (spelled out: this runs twice per filter step)
        self._store_arrays = (
            store.robot_links, store.landmark_info, store.neighbour_index, store.neighbour_info,
            store.neighbour_count, store.information_vector, store.mean, store.block_position,
        )  # fmt: skip
        self._filter_arrays = (filt._active, filt._is_active, filt._last_observed)
        counters = tuple(getattr(filt, name) for name in filt._COUNTERS) if filt._COUNTERS else ()
        self._scalars = (store.num_landmarks, filt._update_count, filt._round_robin, counters)
        self._robot = (store.robot_info.copy(), store.information_vector[:3].copy(), store.mean[:3].copy())
        self._queue = (queue.items, queue.queued, queue.state, queue.state.copy())
        self._saved = 0  # entries of filt._journal_buffer
        self._full_mean: FloatArray | None = None
        self._queue_copy: tuple[IntArray, NDArray[np.bool_]] | None = None
        self._wavefront_logs: list[tuple] = []
        if landmarks is not None:
            self.save_landmarks(landmarks)

    def save_landmarks(self, landmarks: IntArray) -> None:
        """Save the rows of ``landmarks`` (state orders) before a stage writes them.

        A row saved twice keeps its first (untouched) copy. Rows beyond the
        capacity at the start go with the old arrays.
        """
        rows = np.asarray(landmarks, dtype=np.int64)
        links, info, index, neighbours, counts, vector, mean, _ = self._store_arrays
        buffer = self._filter._journal_buffer
        buffer.reserve(self._saved + len(rows), index.shape[1], self._saved)
        self._saved = _kernels.save_rows(rows, self._saved, links, info, index, neighbours, counts, vector, mean,
                                         self._filter_arrays[1], self._filter_arrays[2], *buffer.arrays())  # fmt: skip

    def save_mean(self) -> None:
        """Save the whole mean (for exact recovery, which costs O(n^1.5) anyway)."""
        if self._full_mean is None:
            self._full_mean = self._store_arrays[6].copy()

    def save_queue(self) -> None:
        """Save copies of the recovery queue's arrays (the plain recovery's way; O(n))."""
        if self._queue_copy is None:
            self._queue_copy = (self._queue[0].copy(), self._queue[1].copy())

    def log_wavefront(self, queue: RecoveryQueue, undo: tuple) -> None:
        """Keep the undo log of one compiled wavefront recovery on ``queue``'s arrays."""
        self._wavefront_logs.append((queue.items, queue.queued, queue.state, undo))

    def restore(self) -> None:
        """Put the filter back as it was when the journal was opened."""
        filt, store = self._filter, self._filter._store
        for items, queued, state, (kind, index, value, count) in reversed(self._wavefront_logs):
            _kernels.undo_wavefront(store.mean, items, queued, state, kind, index, value, int(count[0]))
        for name, array in zip(self._STORE_ARRAYS, self._store_arrays):
            setattr(store, name, array)
        for name, filter_array in zip(self._FILTER_ARRAYS, self._filter_arrays):
            setattr(filt, name, filter_array)
        store.num_landmarks, filt._update_count, filt._round_robin, counters = self._scalars
        for name, value in zip(filt._COUNTERS, counters):
            setattr(filt, name, value)
        store.robot_info[:], store.information_vector[:3], store.mean[:3] = self._robot
        if self._full_mean is not None:
            store.mean[:] = self._full_mean
        links, info, index, neighbours, counts, vector, mean, block_position = self._store_arrays
        _kernels.restore_rows(self._saved, *filt._journal_buffer.arrays(), links, info, index, neighbours, counts,
                              vector, mean, self._filter_arrays[1], self._filter_arrays[2], block_position)  # fmt: skip
        queue = filt._queue
        queue.items, queue.queued, queue.state = self._queue[:3]
        queue.state[:] = self._queue[3]
        if self._queue_copy is not None:
            queue.items[:], queue.queued[:] = self._queue_copy


def recover_mean_exact(store: InformationStore) -> None:
    """``mu = Omega^-1 xi`` by a sparse factorisation (exact recovery).

    Costs O(n) to O(n^1.5) for the graphs of SLAM; the evaluation and the tests
    use it as ground truth, and ``mean_recovery="exact"`` runs it every step.
    """
    omega = store.to_sparse().tocsc()
    solver = scipy.sparse.linalg.splu(omega, permc_spec="MMD_AT_PLUS_A")
    store.mean[: store.state_dim] = solver.solve(store.information_vector_view())


def blanket_covariances(store: InformationStore, nodes: IntArray, targets: IntArray) -> tuple[FloatArray, FloatArray]:
    """Covariances of the robot and of ``targets`` from the block over the robot and ``nodes``.

    ``nodes`` must contain every landmark of ``targets``. The block's inverse
    is the covariance *conditioned on the landmarks outside the block*: the
    constant-time approximation of marginals that Probabilistic Robotics
    (section 12.7) uses for data association. It is tighter than the true
    marginal, the more so the more of the map the block leaves out.
    """
    omega, _, _ = store.gather(nodes)
    cov = np.linalg.inv(omega)
    position = {int(i): p for p, i in enumerate(nodes)}
    rows = [slice(3 + 2 * position[int(i)], 5 + 2 * position[int(i)]) for i in targets]
    landmark_covs = np.array([cov[r, r] for r in rows]).reshape(-1, 2, 2)
    return 0.5 * (cov[:3, :3] + cov[:3, :3].T), 0.5 * (landmark_covs + landmark_covs.transpose(0, 2, 1))


def _rewrap_heading(store: InformationStore, active: IntArray) -> None:
    """Wrap the heading of ``mu`` into ``[-pi, pi)`` and shift ``xi`` with it.

    Moving ``mu_theta`` by ``c`` moves ``Omega mu`` by ``c`` times the heading
    column of ``Omega``; ``xi`` is moved by the same amount so that the
    residual ``xi - Omega mu`` (zero for an exact mean) is unchanged. The
    heading column is non-zero only in the robot row and the active landmarks.
    """
    theta = float(store.mean[2])
    if -np.pi <= theta < np.pi:
        return
    shift = wrap_angle(theta) - theta
    store.mean[2] += shift
    store.information_vector[:3] += store.robot_info[:, 2] * shift
    for i in active:
        store.information_vector[3 + 2 * i : 5 + 2 * i] += store.robot_links[i][2] * shift


# ---------------------------------------------------------------------------
# Backends: the steps above run on a store, compiled or plain (chosen once per filter)
# ---------------------------------------------------------------------------
class SEIFBackend(abc.ABC):
    """How a SEIF's steps run on its :class:`InformationStore`: one instance per kind, chosen once per filter.

    :class:`CompiledSEIFBackend` calls the kernels of :mod:`seif_gym.slam._kernels` on the store's
    arrays; :class:`ReferenceSEIFBackend` gathers a dense block, applies this module's reference
    function and scatters it back. The tests check the two equal (``tests/slam/test_seif.py``).
    """

    #: The motion update writes the store only after its last computation: a failed one leaves the
    #: landmark rows untouched, so a step's journal needs only the robot's block.
    motion_update_writes_last: ClassVar[bool]

    @abc.abstractmethod
    def motion_update(self, store: InformationStore, active: IntArray, delta: FloatArray, jacobian: FloatArray,
                      noise: FloatArray) -> None:  # fmt: skip
        """:func:`motion_update` on the block of the robot and ``active``; ``mean[:3] += delta``."""

    @abc.abstractmethod
    def measurement_update(self, store: InformationStore, indices: IntArray, ranges: FloatArray,
                           bearings: FloatArray, measurement_info: FloatArray) -> None:  # fmt: skip
        """:func:`measurement_update` of these measurements of the landmarks ``indices`` (one ``Q^-1``)."""

    @abc.abstractmethod
    def sparsify(self, store: InformationStore, block: IntArray, num_kept: int) -> None:
        """:func:`sparsify` on the block of the robot and ``block`` (the kept landmarks first)."""

    @abc.abstractmethod
    def recover_mean_wavefront(self, store: InformationStore, queue: RecoveryQueue, active: IntArray,
                               seeds: IntArray, budget: int, relaxation: float, tolerance: float,
                               journal: UpdateJournal | None) -> None:  # fmt: skip
        """:func:`recover_mean_wavefront`, recording in ``journal`` what it changes."""

    @abc.abstractmethod
    def recover_mean_amortized(self, store: InformationStore, landmarks: IntArray, active: IntArray) -> None:
        """:func:`recover_mean_amortized` (the caller's journal saved ``landmarks`` already)."""

    @abc.abstractmethod
    def blanket_covariances(self, store: InformationStore, active: IntArray, is_active: NDArray[np.bool_],
                            targets: IntArray) -> tuple[FloatArray, FloatArray]:  # fmt: skip
        """:func:`blanket_covariances` over the robot, ``active`` and ``targets``."""


class CompiledSEIFBackend(SEIFBackend):
    """The SEIF's steps by the compiled kernels of :mod:`seif_gym.slam._kernels` (the default)."""

    motion_update_writes_last = True

    def motion_update(self, store: InformationStore, active: IntArray, delta: FloatArray, jacobian: FloatArray,
                      noise: FloatArray) -> None:  # fmt: skip
        store.reserve_degree(active, len(active))
        _kernels.predict(*store.kernel_arrays(), active, delta, jacobian, noise)

    def measurement_update(self, store: InformationStore, indices: IntArray, ranges: FloatArray,
                           bearings: FloatArray, measurement_info: FloatArray) -> None:  # fmt: skip
        _kernels.measurement_update(store.robot_info, store.robot_links, store.landmark_info,
                                    store.information_vector, store.mean, indices, ranges, bearings,
                                    measurement_info)  # fmt: skip

    def sparsify(self, store: InformationStore, block: IntArray, num_kept: int) -> None:
        store.reserve_degree(block, len(block))
        _kernels.sparsify(*store.kernel_arrays(), block, num_kept)

    def recover_mean_wavefront(self, store: InformationStore, queue: RecoveryQueue, active: IntArray,
                               seeds: IntArray, budget: int, relaxation: float, tolerance: float,
                               journal: UpdateJournal | None) -> None:  # fmt: skip
        # an undo log of every change, sized for the worst case of this call
        log_size = (len(seeds) + len(active) + budget) * (2 + store.degree) + 1
        undo = (np.empty(log_size, np.int8), np.empty(log_size, np.int64), np.empty((log_size, 2)),
                np.zeros(1, np.int64))  # fmt: skip
        if journal is not None:
            journal.log_wavefront(queue, undo)
        _kernels.recover_mean_wavefront(*store.kernel_arrays(), active, seeds, queue.items, queue.queued,
                                        queue.state, budget, relaxation, tolerance, *undo)  # fmt: skip

    def recover_mean_amortized(self, store: InformationStore, landmarks: IntArray, active: IntArray) -> None:
        _kernels.recover_mean(*store.kernel_arrays()[:8], landmarks, active)

    def blanket_covariances(self, store: InformationStore, active: IntArray, is_active: NDArray[np.bool_],
                            targets: IntArray) -> tuple[FloatArray, FloatArray]:  # fmt: skip
        nodes = _kernels.blanket_nodes(active, targets, store.block_position)
        return _kernels.blanket_covariances(*store.kernel_arrays(), nodes, targets)


class ReferenceSEIFBackend(SEIFBackend):
    """The SEIF's steps by this module's plain functions on gathered dense blocks (slow; for checking)."""

    motion_update_writes_last = False

    def motion_update(self, store: InformationStore, active: IntArray, delta: FloatArray, jacobian: FloatArray,
                      noise: FloatArray) -> None:  # fmt: skip
        omega, xi, mu = store.gather(active)
        omega, xi, mu = motion_update(omega, xi, mu, delta, jacobian, noise)
        store.scatter(active, omega, xi)
        store.mean[:3] = mu[:3]

    def measurement_update(self, store: InformationStore, indices: IntArray, ranges: FloatArray,
                           bearings: FloatArray, measurement_info: FloatArray) -> None:  # fmt: skip
        omega, xi, mu = store.gather(indices)
        omega, xi = measurement_update(omega, xi, mu, ranges, bearings, measurement_info)
        store.scatter(indices, omega, xi)

    def sparsify(self, store: InformationStore, block: IntArray, num_kept: int) -> None:
        omega, xi, mu = store.gather(block)
        omega, xi = sparsify(omega, xi, mu, num_kept)
        store.scatter(block, omega, xi)

    def recover_mean_wavefront(self, store: InformationStore, queue: RecoveryQueue, active: IntArray,
                               seeds: IntArray, budget: int, relaxation: float, tolerance: float,
                               journal: UpdateJournal | None) -> None:  # fmt: skip
        if journal is not None:  # copies instead of an undo log: this path is for checking, not speed
            journal.save_mean()
            journal.save_queue()
        recover_mean_wavefront(store, queue, active, seeds, budget, relaxation, tolerance)

    def recover_mean_amortized(self, store: InformationStore, landmarks: IntArray, active: IntArray) -> None:
        recover_mean_amortized(store, landmarks, active)

    def blanket_covariances(self, store: InformationStore, active: IntArray, is_active: NDArray[np.bool_],
                            targets: IntArray) -> tuple[FloatArray, FloatArray]:  # fmt: skip
        outside = [i for i in dict.fromkeys(targets.tolist()) if not is_active[i]]
        nodes = np.concatenate([active, np.array(outside, dtype=np.int64)])
        return blanket_covariances(store, nodes, targets)


# ---------------------------------------------------------------------------
# The filter
# ---------------------------------------------------------------------------
class SEIF(SlamFilter, SparseInformationForm):
    """Sparse Extended Information Filter SLAM with known correspondences.

    Parameters
    ----------
    motion, sensor, initial_pose, initial_pose_cov
        See :class:`~seif_gym.slam.base.SlamFilter`.
    max_active : int or None, default 8
        Bound ``k`` on the active landmarks (those linked to the robot) after
        each update; ``None`` never sparsifies (the SEIF is then the exact
        EIF). More than ``k`` stay active only when more than ``k`` landmarks
        were observed in the same update.
    mean_recovery : {"wavefront", "amortized", "exact"}, default "wavefront"
        ``"wavefront"``: constant-time block coordinate descent that follows
        the correction through the map (:func:`recover_mean_wavefront`):
        the landmarks the update touched, ``recovery_landmarks`` passive ones
        in round robin and the robot, then up to ``recovery_budget`` landmarks
        from the queue of those whose neighbours moved. ``"amortized"``:
        Thrun's recovery (:func:`recover_mean_amortized`), the active
        landmarks, ``recovery_landmarks`` passive ones in round robin and the
        robot; it lags behind loop closures (``SeifExplore-v0`` runs it).
        ``"exact"``: a sparse solve of ``Omega mu = xi`` every update.
    recovery_landmarks : int, default 8
        Passive landmarks refined per update in round robin.
    recovery_budget : int, default 64
        Queued landmarks relaxed per update by the wavefront recovery. More
        keeps up better after large corrections but costs time in every update
        of a long map (a small correction travels far along a chain of
        landmarks); ``docs/filters/fidelity.md`` measures the trade-off.
    recovery_relaxation : float, default 1.8
        Over-relaxation ``w`` in ``(0, 2)`` of the queued landmarks' steps.
    recovery_tolerance : float, default 1e-4
        A landmark whose mean moves more than this (metres) queues its neighbours.
    implementation : {"compiled", "reference"}, default "compiled"
        Compiled kernels, or the plain numpy functions of this module
        (slow; for checking and reading).

    Notes
    -----
    One ``predict`` is the motion update; one ``update`` is the measurement
    update, then mean recovery, then sparsification (which keeps the
    mean). The module functions give the equation of each step
    (Probabilistic Robotics, Tables 12.2-12.5). A step that fails at any
    stage (for example a block that is not positive definite) raises and
    leaves the filter bit-identical (:class:`UpdateJournal`). A checked
    ``predict`` also refuses, so, a step whose pose information lost its
    digits in ``Phi - kappa``
    (:func:`~seif_gym.slam.base.prediction_error`; constant time).
    """

    OPTIONS: ClassVar[dict[str, Any]] = {
        "max_active": 8,
        "mean_recovery": "wavefront",
        "recovery_landmarks": 8,
        "recovery_budget": 64,
        "recovery_relaxation": 1.8,
        "recovery_tolerance": 1e-4,
        "implementation": "compiled",
    }
    #: Recovery methods (``mean_recovery``).
    MEAN_RECOVERIES: ClassVar[tuple[str, ...]] = ("wavefront", "amortized", "exact")
    #: Counters of subclasses that a failed step restores with the rest.
    _COUNTERS: ClassVar[tuple[str, ...]] = ()
    #: The backend of each ``implementation``.
    BACKENDS: ClassVar[dict[str, SEIFBackend]] = {"compiled": CompiledSEIFBackend(),
                                                  "reference": ReferenceSEIFBackend()}  # fmt: skip

    def _check_options(self, options: dict[str, Any]) -> None:
        if options["max_active"] is not None:
            as_count(options["max_active"], "max_active", minimum=1)
        if options["mean_recovery"] not in self.MEAN_RECOVERIES:
            raise ValueError(f"mean_recovery must be one of {self.MEAN_RECOVERIES}, got {options['mean_recovery']!r}")
        as_count(options["recovery_landmarks"], "recovery_landmarks")
        as_count(options["recovery_budget"], "recovery_budget")
        as_scalar_between(options["recovery_relaxation"], "recovery_relaxation", 0.0, 2.0)  # over-relaxation's range
        as_nonnegative_scalar(options["recovery_tolerance"], "recovery_tolerance")
        if options["implementation"] not in ("compiled", "reference"):
            raise ValueError(f"implementation must be 'compiled' or 'reference', got {options['implementation']!r}")

    def _initialize(self, pose: FloatArray, pose_cov: FloatArray) -> None:
        self.max_active: int | None = None if self.options["max_active"] is None else int(self.options["max_active"])
        self.mean_recovery: str = self.options["mean_recovery"]
        self.recovery_landmarks = int(self.options["recovery_landmarks"])
        self.recovery_budget = int(self.options["recovery_budget"])
        self.recovery_relaxation = float(self.options["recovery_relaxation"])
        self.recovery_tolerance = float(self.options["recovery_tolerance"])
        self._backend = self.BACKENDS[self.options["implementation"]]
        self._store = InformationStore()
        self._store.robot_info[:] = scipy.linalg.cho_solve(scipy.linalg.cho_factor(pose_cov), np.eye(3))
        self._store.robot_info[:] = 0.5 * (self._store.robot_info + self._store.robot_info.T)
        self._store.mean[:3] = pose
        self._store.information_vector[:3] = self._store.robot_info @ pose
        self._active: IntArray = np.empty(0, dtype=np.int64)
        # per landmark: is it active, and the update count when it was last observed
        self._is_active: NDArray[np.bool_] = np.zeros(self._store.capacity, dtype=bool)
        self._last_observed: IntArray = np.zeros(self._store.capacity, dtype=np.int64)
        self._update_count = 0
        self._round_robin = 0
        self._queue = RecoveryQueue(self._store.capacity)
        self._journal: UpdateJournal | None = None
        self._journal_buffer = JournalBuffer()

    # -- step 1 ------------------------------------------------------------------
    def _predict(self, control: FloatArray, dt: float, verify: bool = False) -> None:
        # a motion update that writes the robot's and its active landmarks' rows only after its last
        # computation needs only the robot's block and the arrays (which may grow) saved; others save the
        # rows, and so does a verified one (its check comes after the writes)
        saved = None if self._backend.motion_update_writes_last and not verify else self._active
        journal = UpdateJournal(self, saved)
        try:
            self._motion_update(control, dt, verify)
        except BaseException:
            journal.restore()
            raise

    def _motion_update(self, control: FloatArray, dt: float, verify: bool = False) -> None:
        """:func:`motion_update` on the robot and its active landmarks; ``verify``: then check the pose block.

        The check (:func:`~seif_gym.slam.base.prediction_error`) is constant time: the robot's 3 x 3 block.
        """
        store = self._store
        delta, jacobian, noise = self._linearize(store.mean[:3], control, dt)
        if verify:
            self._check_motion(control, dt, delta, jacobian, noise)
            before = store.robot_info.copy()
        self._backend.motion_update(store, self._active, delta, jacobian, noise)
        if verify:
            self._check_pose_information(control, dt, before, store.robot_info, jacobian, noise)
        _rewrap_heading(store, self._active)

    # -- merging two landmarks (data association's revision) --------------------------
    def _merge(self, keep: int, remove: int) -> None:
        """``InformationStore.merge`` plus the active set, the recovery queue and the bookkeeping.

        At most ``k`` robot links stay: the merged landmark is active when
        either was (one active landmark fewer when both were). ``keep``'s mean
        is relaxed once against its neighbours and their neighbourhood is
        queued, so that the wavefront carries the correction out. Time in the
        neighbour counts and the recovery queue's length (the queue is rebuilt
        in fresh arrays, so that the journal can put the old ones back); a
        failure leaves the filter as it was (the update's journal).
        """
        store = self._store
        last = self.num_landmarks - 1
        touched = [keep, remove, last]
        for landmark in (keep, remove, last):
            touched.extend(store.neighbour_index[landmark, : store.neighbour_count[landmark]].tolist())
        journal = self._journal = UpdateJournal(self, np.unique(np.array(touched, dtype=np.int64)))
        try:
            self._merge_step(keep, remove)
        except BaseException:
            journal.restore()
            raise
        finally:
            self._journal = None

    def _merge_step(self, keep: int, remove: int) -> None:
        store = self._store
        last = self.num_landmarks - 1
        queued = self._queue.ordered()
        was_active = bool(self._is_active[keep] or self._is_active[remove])
        observed = max(self._last_observed[keep], self._last_observed[remove])
        store.merge(keep, remove)
        moved = keep if keep != last else remove  # where ``keep`` is now

        def renamed(indices: IntArray) -> IntArray:  # state orders after the swap-remove; ``remove`` dropped
            kept = indices[indices != remove]
            return np.where(kept == last, remove, kept)

        self._is_active[remove] = self._is_active[last]
        self._last_observed[remove] = self._last_observed[last]
        self._is_active[last] = False
        self._last_observed[last] = 0
        active = renamed(self._active)
        if was_active and moved not in active:
            active = np.append(active, moved)
        self._active = active.astype(np.int64)
        self._is_active[moved] = was_active
        self._last_observed[moved] = observed
        self._round_robin = self._round_robin % max(last, 1)
        # keep's mean from its own row of Omega mu = xi, the rest held (one block Gauss-Seidel step)
        count = int(store.neighbour_count[moved])
        neighbours = store.neighbour_index[moved, :count].copy()
        rhs = store.information_vector[3 + 2 * moved : 5 + 2 * moved] - store.robot_links[moved].T @ store.mean[:3]
        for k, block in zip(neighbours.tolist(), store.neighbour_info[moved, :count]):
            rhs = rhs - block @ store.mean[3 + 2 * k : 5 + 2 * k]
        store.mean[3 + 2 * moved : 5 + 2 * moved] = np.linalg.solve(store.landmark_info[moved], rhs)
        queue = RecoveryQueue(store.capacity)
        for landmark in [*renamed(queued).tolist(), moved, *neighbours.tolist()]:
            queue.push(int(landmark))
        self._queue = queue
        if self.mean_recovery == "exact":
            if self._journal is not None:
                self._journal.save_mean()
            recover_mean_exact(store)

    # -- steps 2-4 ---------------------------------------------------------------
    def _update(self, ranges: FloatArray, bearings: FloatArray, indices: IntArray, is_new: NDArray[np.bool_]) -> None:
        # every stage writes into the rows of the robot, the active and the observed landmarks, or logs
        rows = [self._active, indices]
        if self.mean_recovery == "amortized":  # the round robin's next batches (an ESEIF update recovers twice)
            rows.append((self._round_robin + np.arange(min(2 * self.recovery_landmarks, self.num_landmarks)))
                        % max(self.num_landmarks, 1))  # fmt: skip
        journal = self._journal = UpdateJournal(self, np.concatenate(rows))
        try:
            self._measurement_step(ranges, bearings, indices, is_new)
        except BaseException:
            journal.restore()
            raise
        finally:
            self._journal = None

    def _measurement_step(
        self, ranges: FloatArray, bearings: FloatArray, indices: IntArray, is_new: NDArray[np.bool_]
    ) -> None:
        """Steps 2-4 (inside a transaction): measurement update, mean recovery, sparsification."""
        if is_new.any():
            self._add_landmarks(ranges[is_new], bearings[is_new])
        self._update_count += 1
        self._incorporate(ranges, bearings, indices)
        self._recover_mean()
        self._sparsify()

    def _add_landmarks(self, ranges: FloatArray, bearings: FloatArray) -> None:
        """Append new landmarks at the inverse sensor model's positions, with zero information.

        The measurement that follows supplies their information (:meth:`~seif_gym.slam.models.RangeBearingSensor.inverse`).
        """
        store = self._store
        inverse = getattr(self.sensor, "inverse_trusted", self.sensor.inverse)
        store.add_landmarks(inverse(store.mean[:3], ranges, bearings))
        grow = store.capacity - len(self._last_observed)
        if grow > 0:
            self._last_observed = np.concatenate([self._last_observed, np.zeros(grow, dtype=np.int64)])
            self._is_active = np.concatenate([self._is_active, np.zeros(grow, dtype=bool)])
        self._queue.grow(store.capacity)

    def _incorporate(self, ranges: FloatArray, bearings: FloatArray, indices: IntArray, weight: float = 1.0) -> None:
        """:func:`measurement_update` with these measurements; their landmarks become active.

        ``weight`` scales the measurement information ``Q^-1`` (the ESEIF's
        split relocalization uses one measurement twice, with weights that sum to 1).
        """
        if len(indices) == 0:
            return
        store = self._store
        noise_infos = self._noise_informations(ranges)
        if noise_infos is None:
            measurement_info = self._measurement_info if weight == 1.0 else weight * self._measurement_info
            groups = [(indices, ranges, bearings, measurement_info)]
        else:  # a range-dependent sensor: one Q_i^-1 per measurement (all linearised at the same mean)
            groups = [(indices[k : k + 1], ranges[k : k + 1], bearings[k : k + 1], weight * noise_infos[k])
                      for k in range(len(indices))]  # fmt: skip
        for group, group_ranges, group_bearings, measurement_info in groups:
            self._backend.measurement_update(store, group, group_ranges, group_bearings, measurement_info)
        self._last_observed[indices] = self._update_count
        newly_active = indices[~self._is_active[indices]]
        if len(newly_active):
            self._active = np.concatenate([self._active, newly_active])
            self._is_active[newly_active] = True

    def _recover_mean(self) -> None:
        store = self._store
        journal = self._journal
        if self.mean_recovery == "exact":
            if journal is not None:
                journal.save_mean()
            recover_mean_exact(store)
        elif self.mean_recovery == "wavefront":
            self._backend.recover_mean_wavefront(store, self._queue, self._active, self._passive_batch(),
                                                 self.recovery_budget, self.recovery_relaxation,
                                                 self.recovery_tolerance, journal)  # fmt: skip
        else:
            landmarks = np.concatenate([self._passive_batch(), self._active])  # saved when the journal opened
            self._backend.recover_mean_amortized(store, landmarks, self._active)
        _rewrap_heading(store, self._active)

    def _passive_batch(self) -> IntArray:
        """The next ``recovery_landmarks`` landmarks in round robin (active ones skipped later)."""
        n = self.num_landmarks
        count = min(self.recovery_landmarks, n)
        if count == 0:
            return np.empty(0, dtype=np.int64)
        batch = (self._round_robin + np.arange(count)) % n
        self._round_robin = (self._round_robin + count) % n
        return batch[~self._is_active[batch]]

    def _sparsify(self) -> None:
        """:func:`sparsify`: deactivate the landmarks observed longest ago until ``k`` remain."""
        if self.max_active is None or len(self._active) <= self.max_active:
            return
        # the landmarks observed longest ago go first, never one observed in this update
        last_observed = self._last_observed[self._active]
        candidates = np.flatnonzero(last_observed != self._update_count)  # positions in the active set
        remove_count = min(len(self._active) - self.max_active, len(candidates))
        if remove_count == 0:
            return
        order = np.argsort(last_observed[candidates], kind="stable")
        remove = np.zeros(len(self._active), dtype=bool)
        remove[candidates[order[:remove_count]]] = True
        deactivated = self._active[remove]
        kept = self._active[~remove]
        block = np.concatenate([kept, deactivated])
        self._backend.sparsify(self._store, block, len(kept))
        self._active = kept
        self._is_active[deactivated] = False

    # -- read-only state -------------------------------------------------------------
    @property
    def active_landmarks(self) -> NDArray[np.int64]:
        """Ids of the landmarks linked to the robot, shape (a,)."""
        ids = self._ids[self._active]
        ids.setflags(write=False)
        return ids

    @property
    def information_matrix(self) -> scipy.sparse.csr_array:
        """``Omega`` in state order (robot, then landmarks), as a ``scipy.sparse.csr_array``."""
        return self._store.to_sparse()

    @property
    def information_vector(self) -> FloatArray:
        """``xi`` in state order, shape (3 + 2n,)."""
        xi = self._store.information_vector_view().copy()
        xi.setflags(write=False)
        return xi

    def exact_mean(self) -> FloatArray:
        """``Omega^-1 xi`` by a sparse solve, without changing the filter (O(n^1.5))."""
        omega = self._store.to_sparse().tocsc()
        return scipy.sparse.linalg.splu(omega, permc_spec="MMD_AT_PLUS_A").solve(self._store.information_vector_view())

    def refine_mean(self, sweeps: int = 1) -> None:
        """Run ``sweeps`` full coordinate-descent sweeps over all landmarks and the robot.

        Costs O(n) per sweep; repeated, amortized recovery converges to
        :meth:`exact_mean` (the tests check it).
        """
        as_count(sweeps, "sweeps")
        everything = np.arange(self.num_landmarks, dtype=np.int64)
        store = self._store
        for _ in range(int(sweeps)):
            self._backend.recover_mean_amortized(store, everything, self._active)
            _rewrap_heading(store, self._active)

    def local_marginals(self, landmark_indices: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Pose and landmark covariances from the Markov blanket, in constant time.

        Inverts the information block over the robot, its active landmarks
        and the requested landmarks (:func:`blanket_covariances`): the
        covariance conditioned on the rest of the map, which is tighter than
        the exact marginal (``pose_covariance``, ``landmark_covariance``).
        """
        return self.local_marginals_trusted(self._check_landmark_indices(landmark_indices))

    def local_marginals_trusted(self, indices: IntArray) -> tuple[FloatArray, FloatArray]:
        """:meth:`local_marginals` without input checks (valid int64 state orders)."""
        return self._backend.blanket_covariances(self._store, self._active, self._is_active, indices)

    def local_joint_covariance(self, landmark_indices: ArrayLike, neighbours: bool | int = True) -> FloatArray:
        """Joint covariance of the pose and the landmarks at ``landmark_indices``, in constant time.

        Returns the ``(3 + 2k, 3 + 2k)`` covariance over ``(x, y, theta,
        m_i1, m_i2, ...)`` (the pose-landmark cross-covariances included, which
        an innovation covariance ``H Sigma H^T + Q`` needs) from the Markov
        blanket: the information block over the robot, its active landmarks,
        the requested landmarks and the landmarks linked to them
        (Probabilistic Robotics section 12.7), conditioned on the rest of the
        map. ``neighbours``: ``True`` all linked landmarks, ``False`` none, an
        int ``n`` the ``n`` most strongly linked of each requested landmark
        (a block of bounded size however many links accumulate). Never a
        dense inverse of ``Omega``: one Cholesky factor of the block, solved
        for the requested columns only.
        """
        indices = self._check_landmark_indices(landmark_indices)
        if isinstance(neighbours, (bool, np.bool_)):
            limit = -1 if neighbours else 0
        elif isinstance(neighbours, (int, np.integer)) and neighbours >= 0:
            limit = int(neighbours)
        else:
            raise ValueError(f"neighbours must be a bool or a non-negative int, got {neighbours!r}")
        return _kernels.blanket_joint_covariance(*self._store.kernel_arrays(), self._active, indices, limit)

    def landmark_std(self) -> FloatArray:
        """``sqrt(trace(Omega_ii^-1))`` per landmark: the conditional uncertainty, in O(n) without a solve."""
        return _kernels.conditional_std(self._store.landmark_info, self.num_landmarks)

    # -- SlamFilter hooks ------------------------------------------------------------
    def _mean_vector(self) -> FloatArray:
        return self._store.mean_view()

    #: Up to this many landmarks, exact marginals factorise the dense ``Omega`` (:func:`exact_marginal_covariance`).
    DENSE_MARGINALS_UP_TO: ClassVar[int] = DENSE_MARGINALS_UP_TO

    def _marginal_covariance(self, state_indices: IntArray) -> FloatArray:
        """Exact marginal covariance ``[Omega^-1]`` over ``state_indices`` (:func:`exact_marginal_covariance`)."""
        return exact_marginal_covariance(self._store, state_indices, self.DENSE_MARGINALS_UP_TO)

    def _full_covariance(self) -> FloatArray:
        omega = self._store.to_sparse().toarray()
        return scipy.linalg.cho_solve(scipy.linalg.cho_factor(omega), np.eye(len(omega)))

    def _state_nbytes(self) -> int:
        return self._store.nbytes() + self._active.nbytes + self._last_observed.nbytes + self._is_active.nbytes
