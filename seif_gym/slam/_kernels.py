"""Compiled kernels of the SEIF steps (numba).

The one home of the filters' compiled code. Each kernel here is the fast twin
of a reference function: gather and scatter of
:class:`~seif_gym.slam.information.InformationStore`;
:func:`~seif_gym.slam.seif.motion_update`, :func:`~seif_gym.slam.seif.measurement_update`,
:func:`~seif_gym.slam.seif.sparsify`, :func:`~seif_gym.slam.seif.recover_mean_amortized`,
:func:`~seif_gym.slam.seif.recover_mean_wavefront` and
:func:`~seif_gym.slam.seif.blanket_covariances` (run through
:class:`~seif_gym.slam.seif.CompiledSEIFBackend`); the ESEIF's
:func:`~seif_gym.slam.eseif.marginalize_robot`; and the batched steps of
:class:`~seif_gym.slam.batched.BatchedSEIF` built from the same kernels.
``tests/slam/test_kernels.py`` checks each against its reference. Why compiled: the blocks are small
(19 x 19 for eight active landmarks), so a numpy version spends most of its
time in call overhead, not arithmetic.

The kernels work on the store's arrays in place and assume the caller made
room (``reserve_landmarks`` / ``reserve_degree``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from seif_gym.type_aliases import FloatArray, IntArray

TWO_PI = 2.0 * np.pi


@njit(cache=True)
def _find(neighbour_index, neighbour_count, i, j):
    for slot in range(neighbour_count[i]):
        if neighbour_index[i, slot] == j:
            return slot
    return -1


@njit(cache=True)
def gather(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
           information_vector, mean, block_position, landmarks):  # fmt: skip
    """Dense ``Omega``, ``xi``, ``mu`` over the robot and ``landmarks`` (robot first)."""
    count = landmarks.shape[0]
    size = 3 + 2 * count
    omega = np.zeros((size, size))
    xi = np.empty(size)
    mu = np.empty(size)
    for a in range(3):
        xi[a] = information_vector[a]
        mu[a] = mean[a]
        for b in range(3):
            omega[a, b] = robot_info[a, b]
    for p in range(count):
        block_position[landmarks[p]] = p
    for p in range(count):
        i = landmarks[p]
        o = 3 + 2 * p
        for a in range(2):
            xi[o + a] = information_vector[3 + 2 * i + a]
            mu[o + a] = mean[3 + 2 * i + a]
            for b in range(3):
                omega[b, o + a] = robot_links[i, b, a]
                omega[o + a, b] = robot_links[i, b, a]
            for b in range(2):
                omega[o + a, o + b] = landmark_info[i, a, b]
        for slot in range(neighbour_count[i]):
            q = block_position[neighbour_index[i, slot]]
            if q >= 0:
                oq = 3 + 2 * q
                for a in range(2):
                    for b in range(2):
                        omega[o + a, oq + b] = neighbour_info[i, slot, a, b]
    for p in range(count):
        block_position[landmarks[p]] = -1
    return omega, xi, mu


@njit(cache=True)
def scatter(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
            information_vector, landmarks, omega, xi):  # fmt: skip
    """Write a dense block over the robot and ``landmarks`` back into the store."""
    count = landmarks.shape[0]
    for a in range(3):
        information_vector[a] = xi[a]
        for b in range(3):
            robot_info[a, b] = omega[a, b]
    for p in range(count):
        i = landmarks[p]
        o = 3 + 2 * p
        for a in range(2):
            information_vector[3 + 2 * i + a] = xi[o + a]
            for b in range(3):
                robot_links[i, b, a] = omega[b, o + a]
            for b in range(2):
                landmark_info[i, a, b] = omega[o + a, o + b]
        for q in range(count):
            if q == p:
                continue
            j = landmarks[q]
            oq = 3 + 2 * q
            slot = _find(neighbour_index, neighbour_count, i, j)
            if slot < 0:
                nonzero = False
                for a in range(2):
                    for b in range(2):
                        if omega[o + a, oq + b] != 0.0:
                            nonzero = True
                if not nonzero:
                    continue
                slot = neighbour_count[i]
                neighbour_index[i, slot] = j
                neighbour_count[i] += 1
            for a in range(2):
                for b in range(2):
                    neighbour_info[i, slot, a, b] = omega[o + a, oq + b]


@njit(cache=True)
def _inverse_3x3(m):
    inv = np.empty((3, 3))
    inv[0, 0] = m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]
    inv[0, 1] = m[0, 2] * m[2, 1] - m[0, 1] * m[2, 2]
    inv[0, 2] = m[0, 1] * m[1, 2] - m[0, 2] * m[1, 1]
    inv[1, 0] = m[1, 2] * m[2, 0] - m[1, 0] * m[2, 2]
    inv[1, 1] = m[0, 0] * m[2, 2] - m[0, 2] * m[2, 0]
    inv[1, 2] = m[0, 2] * m[1, 0] - m[0, 0] * m[1, 2]
    inv[2, 0] = m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]
    inv[2, 1] = m[0, 1] * m[2, 0] - m[0, 0] * m[2, 1]
    inv[2, 2] = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    det = m[0, 0] * inv[0, 0] + m[0, 1] * inv[1, 0] + m[0, 2] * inv[2, 0]
    return inv / det


@njit(cache=True)
def motion_update_block(omega, xi, mu, delta, jacobian, noise):
    """Fast :func:`seif_gym.slam.seif.motion_update`, in place on the block.

    Uses ``Phi = (I + Psi)^T Omega (I + Psi)`` with ``I + Psi = blockdiag(G^-1, I)``
    (the same matrix as ``Omega + lam``, without forming ``lam``), and
    ``xi_bar = xi + Omega_bar mu_bar - Omega mu``, which is
    ``xi + (lam - kappa) mu + Omega_bar F_x^T delta`` rearranged.
    """
    size = xi.shape[0]
    g_inv = _inverse_3x3(jacobian)
    omega_mu = omega @ mu
    # Phi: robot rows and columns transformed by G^-T ... G^-1
    phi = omega.copy()
    top = np.ascontiguousarray(g_inv.T) @ np.ascontiguousarray(omega[:3, :])
    for a in range(3):
        for c in range(size):
            phi[a, c] = top[a, c]
            phi[c, a] = top[a, c]
    corner = np.ascontiguousarray(top[:, :3]) @ g_inv
    phi[:3, :3] = corner
    # kappa = Phi_x (R^-1 + Phi_xx)^-1 Phi_x^T, symmetric rank 3
    inner = _inverse_3x3(_inverse_3x3(noise) + corner)
    inner = 0.5 * (inner + inner.T)
    phi_x = np.ascontiguousarray(phi[:, :3])
    left = phi_x @ inner
    kappa = left @ phi_x.T
    omega_bar = phi - kappa
    for a in range(size):
        for b in range(a + 1, size):
            value = 0.5 * (omega_bar[a, b] + omega_bar[b, a])
            omega_bar[a, b] = value
            omega_bar[b, a] = value
    mu_bar = mu.copy()
    for a in range(3):
        mu_bar[a] += delta[a]
    xi_bar = xi + omega_bar @ mu_bar - omega_mu
    return omega_bar, xi_bar, mu_bar


@njit(cache=True)
def predict(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
            information_vector, mean, block_position, active, delta, jacobian, noise):  # fmt: skip
    """Gather, motion update, scatter; ``mean[:3] += delta`` (heading not wrapped)."""
    omega, xi, mu = gather(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                           neighbour_count, information_vector, mean, block_position, active)  # fmt: skip
    omega_bar, xi_bar, mu_bar = motion_update_block(omega, xi, mu, delta, jacobian, noise)
    scatter(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
            information_vector, active, omega_bar, xi_bar)  # fmt: skip
    for a in range(3):
        mean[a] = mu_bar[a]


@njit(cache=True)
def _wrap(angle):
    return (angle + np.pi) % TWO_PI - np.pi


@njit(cache=True)
def range_bearing_jacobian(dx, dy, H):
    """Fill ``H`` (2, 5) of :class:`~seif_gym.slam.models.RangeBearingSensor` for ``d = m - (x, y)``; returns ``q``."""
    q = dx * dx + dy * dy
    sqrt_q = np.sqrt(q)
    H[0, 0] = -dx / sqrt_q
    H[0, 1] = -dy / sqrt_q
    H[0, 2] = 0.0
    H[0, 3] = dx / sqrt_q
    H[0, 4] = dy / sqrt_q
    H[1, 0] = dy / q
    H[1, 1] = -dx / q
    H[1, 2] = -1.0
    H[1, 3] = -dy / q
    H[1, 4] = dx / q
    return q


@njit(cache=True)
def measurement_update(robot_info, robot_links, landmark_info, information_vector, mean,
                       indices, ranges, bearings, noise_info):  # fmt: skip
    """Fast :func:`seif_gym.slam.seif.measurement_update`, straight into the store."""
    x = mean[0]
    y = mean[1]
    theta = mean[2]
    H = np.zeros((2, 5))
    state = np.empty(5)
    innovation = np.empty(2)
    for k in range(indices.shape[0]):
        i = indices[k]
        o = 3 + 2 * i
        dx = mean[o] - x
        dy = mean[o + 1] - y
        q = range_bearing_jacobian(dx, dy, H)
        innovation[0] = ranges[k] - np.sqrt(q)
        innovation[1] = _wrap(bearings[k] - (np.arctan2(dy, dx) - theta))
        state[0] = x
        state[1] = y
        state[2] = theta
        state[3] = mean[o]
        state[4] = mean[o + 1]
        HtQ = H.T @ noise_info
        info = HtQ @ H
        vec = HtQ @ (innovation + H @ state)
        for a in range(3):
            information_vector[a] += vec[a]
            for b in range(3):
                robot_info[a, b] += info[a, b]
            for b in range(2):
                robot_links[i, a, b] += info[a, 3 + b]
        for a in range(2):
            information_vector[o + a] += vec[3 + a]
            for b in range(2):
                landmark_info[i, a, b] += info[3 + a, 3 + b]


@njit(cache=True)
def _schur_term(omega, indices):
    """``Omega[:, idx] Omega[idx, idx]^-1 Omega[idx, :]``, exactly symmetric (Cholesky)."""
    k = indices.shape[0]
    size = omega.shape[0]
    sub = np.empty((k, k))
    rows = np.empty((k, size))
    for a in range(k):
        for c in range(size):
            rows[a, c] = omega[indices[a], c]
        for b in range(k):
            sub[a, b] = omega[indices[a], indices[b]]
    lower = np.linalg.cholesky(sub)
    # W = L^-1 rows by forward substitution; term = W^T W
    w = rows.copy()
    for a in range(k):
        for b in range(a):
            for c in range(size):
                w[a, c] -= lower[a, b] * w[b, c]
        for c in range(size):
            w[a, c] /= lower[a, a]
    return w.T @ w


@njit(cache=True)
def sparsify_block(omega, xi, mu, num_kept):
    """Fast :func:`seif_gym.slam.seif.sparsify` on the block (robot, m+, m0)."""
    size = xi.shape[0]
    start = 3 + 2 * num_kept
    m0 = np.arange(start, size)
    xm0 = np.concatenate((np.arange(3), m0))
    x = np.arange(3)
    omega_tilde = omega - _schur_term(omega, m0) + _schur_term(omega, xm0) - _schur_term(omega, x)
    for a in range(3):
        for c in range(start, size):
            omega_tilde[a, c] = 0.0
            omega_tilde[c, a] = 0.0
    for a in range(size):
        for b in range(a + 1, size):
            value = 0.5 * (omega_tilde[a, b] + omega_tilde[b, a])
            omega_tilde[a, b] = value
            omega_tilde[b, a] = value
    xi_tilde = xi + (omega_tilde - omega) @ mu
    return omega_tilde, xi_tilde


@njit(cache=True)
def sparsify(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
             information_vector, mean, block_position, block, num_kept):  # fmt: skip
    """Gather the (robot, m+, m0) block, sparsify, scatter back."""
    omega, xi, mu = gather(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                           neighbour_count, information_vector, mean, block_position, block)  # fmt: skip
    omega_tilde, xi_tilde = sparsify_block(omega, xi, mu, num_kept)
    scatter(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
            information_vector, block, omega_tilde, xi_tilde)  # fmt: skip


@njit(cache=True)
def _solve_2x2(m, r0, r1):
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    return (m[1, 1] * r0 - m[0, 1] * r1) / det, (m[0, 0] * r1 - m[1, 0] * r0) / det


@njit(cache=True)
def recover_mean(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                 information_vector, mean, landmarks, active):  # fmt: skip
    """Fast :func:`seif_gym.slam.seif.recover_mean_amortized`."""
    for k in range(landmarks.shape[0]):
        i = landmarks[k]
        mean[3 + 2 * i], mean[4 + 2 * i] = _landmark_target(
            robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count, information_vector, mean, i
        )
    relax_robot(robot_info, robot_links, information_vector, mean, active)


@njit(cache=True)
def _landmark_target(robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                     information_vector, mean, i):  # fmt: skip
    """``Omega_ii^-1 (xi_i - sum_{j != i} Omega_ij mu_j)``: where a block Gauss-Seidel step puts landmark ``i``."""
    o = 3 + 2 * i
    r0 = information_vector[o]
    r1 = information_vector[o + 1]
    for b in range(3):
        r0 -= robot_links[i, b, 0] * mean[b]
        r1 -= robot_links[i, b, 1] * mean[b]
    for slot in range(neighbour_count[i]):
        oj = 3 + 2 * neighbour_index[i, slot]
        r0 -= neighbour_info[i, slot, 0, 0] * mean[oj] + neighbour_info[i, slot, 0, 1] * mean[oj + 1]
        r1 -= neighbour_info[i, slot, 1, 0] * mean[oj] + neighbour_info[i, slot, 1, 1] * mean[oj + 1]
    return _solve_2x2(landmark_info[i], r0, r1)


@njit(cache=True)
def blanket_nodes(active, targets, block_position):
    """``active`` followed by the landmarks of ``targets`` not in it (each once)."""
    nodes = np.empty(active.shape[0] + targets.shape[0], dtype=np.int64)
    count = 0
    for i in active:
        nodes[count] = i
        block_position[i] = count
        count += 1
    for i in targets:
        if block_position[i] < 0:
            nodes[count] = i
            block_position[i] = count
            count += 1
    for p in range(count):
        block_position[nodes[p]] = -1
    return nodes[:count]


@njit(cache=True)
def blanket_covariances(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                        information_vector, mean, block_position, nodes, targets):  # fmt: skip
    """Fast :func:`seif_gym.slam.seif.blanket_covariances`: invert the block over ``nodes``."""
    omega, _, _ = gather(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                         neighbour_count, information_vector, mean, block_position, nodes)  # fmt: skip
    cov = np.linalg.inv(omega)
    for p in range(nodes.shape[0]):
        block_position[nodes[p]] = p
    landmark_covs = np.empty((targets.shape[0], 2, 2))
    for k in range(targets.shape[0]):
        o = 3 + 2 * block_position[targets[k]]
        for a in range(2):
            for b in range(2):
                landmark_covs[k, a, b] = 0.5 * (cov[o + a, o + b] + cov[o + b, o + a])
    for p in range(nodes.shape[0]):
        block_position[nodes[p]] = -1
    pose_cov = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            pose_cov[a, b] = 0.5 * (cov[a, b] + cov[b, a])
    return pose_cov, landmark_covs


@njit(cache=True)
def conditional_std(landmark_info, count):
    """``sqrt(trace(Omega_ii^-1))`` for the first ``count`` landmarks."""
    out = np.empty(count)
    for i in range(count):
        a = landmark_info[i, 0, 0]
        b = landmark_info[i, 0, 1]
        c = landmark_info[i, 1, 0]
        d = landmark_info[i, 1, 1]
        out[i] = np.sqrt((a + d) / (a * d - b * c))
    return out


@njit(cache=True)
def blanket_joint_covariance(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                             information_vector, mean, block_position, active, targets, neighbour_limit):  # fmt: skip
    """Joint covariance of the robot and ``targets`` from a Markov-blanket block.

    The block holds the robot, its ``active`` landmarks, the ``targets`` and
    the landmarks linked to a target in ``Omega`` (the targets' own Markov
    blankets, Probabilistic Robotics section 12.7): all of them for
    ``neighbour_limit < 0``, else the ``neighbour_limit`` most strongly linked
    of each target (largest Frobenius norm of ``Omega_ij``; 0 for none).
    It is factorised once (Cholesky) and solved for the ``3 + 2k`` columns of
    the robot and the targets only. Returns the ``(3 + 2k, 3 + 2k)``
    covariance, robot first, targets in the given order.
    """
    # collect the nodes: active, then targets, then the targets' neighbours (each once)
    capacity = active.shape[0] + targets.shape[0]
    with_neighbours = neighbour_limit != 0
    if with_neighbours:
        for i in targets:
            capacity += neighbour_count[i]
    nodes = np.empty(capacity, dtype=np.int64)
    count = 0
    for i in active:
        if block_position[i] < 0:
            block_position[i] = count
            nodes[count] = i
            count += 1
    for i in targets:
        if block_position[i] < 0:
            block_position[i] = count
            nodes[count] = i
            count += 1
    if with_neighbours:
        for i in targets:
            links = neighbour_count[i]
            order = np.arange(links)
            if 0 <= neighbour_limit < links:
                strength = np.empty(links)
                for slot in range(links):
                    total = 0.0
                    for a in range(2):
                        for b in range(2):
                            total += neighbour_info[i, slot, a, b] ** 2
                    strength[slot] = -total
                order = np.argsort(strength)[:neighbour_limit]
            for slot in order:
                j = neighbour_index[i, slot]
                if block_position[j] < 0:
                    block_position[j] = count
                    nodes[count] = j
                    count += 1
    nodes = nodes[:count]
    for p in range(count):
        block_position[nodes[p]] = -1
    omega, _, _ = gather(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                         neighbour_count, information_vector, mean, block_position, nodes)  # fmt: skip
    # rows of the robot and the targets in the block
    k = targets.shape[0]
    rows = np.empty(3 + 2 * k, dtype=np.int64)
    for a in range(3):
        rows[a] = a
    for p in range(count):
        block_position[nodes[p]] = p
    for t in range(k):
        o = 3 + 2 * block_position[targets[t]]
        rows[3 + 2 * t] = o
        rows[4 + 2 * t] = o + 1
    for p in range(count):
        block_position[nodes[p]] = -1
    return covariance_rows(omega, rows)


@njit(cache=True)
def covariance_rows(omega, rows):
    """``[omega^-1]`` over ``rows`` x ``rows``: one Cholesky factor, solved for those unit columns only."""
    size = omega.shape[0]
    lower = np.linalg.cholesky(omega)
    # W = L^-1 E for the unit columns E of ``rows``; covariance = W^T W
    w = np.zeros((size, rows.shape[0]))
    for c in range(rows.shape[0]):
        w[rows[c], c] = 1.0
    for a in range(size):
        for b in range(a):
            lab = lower[a, b]
            if lab != 0.0:
                for c in range(rows.shape[0]):
                    w[a, c] -= lab * w[b, c]
        inv = 1.0 / lower[a, a]
        for c in range(rows.shape[0]):
            w[a, c] *= inv
    return w.T @ w


@njit(cache=True)
def exact_marginal(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                   information_vector, mean, block_position, num_landmarks, rows):  # fmt: skip
    """Exact ``[Omega^-1]`` over the state rows ``rows``, from the dense ``Omega`` of the whole map (small maps)."""
    omega, _, _ = gather(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                         information_vector, mean, block_position, np.arange(num_landmarks))  # fmt: skip
    return covariance_rows(omega, rows)


# ---------------------------------------------------------------------------
# Wavefront mean recovery (the fast twin of seif.recover_mean_wavefront)
# ---------------------------------------------------------------------------
#: Kinds of entries in the wavefront's undo log.
UNDO_MEAN, UNDO_POP, UNDO_PUSH = 0, 1, 2


@njit(cache=True)
def _relax_landmark(robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                    information_vector, mean, i, relaxation):  # fmt: skip
    """One over-relaxed block Gauss-Seidel step on landmark ``i``; returns the squared move of its mean."""
    o = 3 + 2 * i
    new0, new1 = _landmark_target(robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                                  information_vector, mean, i)  # fmt: skip
    d0 = relaxation * (new0 - mean[o])
    d1 = relaxation * (new1 - mean[o + 1])
    mean[o] += d0
    mean[o + 1] += d1
    return d0 * d0 + d1 * d1


@njit(cache=True)
def relax_robot(robot_info, robot_links, information_vector, mean, active):
    """``mu_x = Omega_xx^-1 (xi_x - sum_active Omega_xi mu_i)`` (a Gauss-Seidel step on the robot)."""
    rhs = np.empty(3)
    for a in range(3):
        rhs[a] = information_vector[a]
    for k in range(active.shape[0]):
        i = active[k]
        o = 3 + 2 * i
        for a in range(3):
            rhs[a] -= robot_links[i, a, 0] * mean[o] + robot_links[i, a, 1] * mean[o + 1]
    pose = np.linalg.solve(robot_info, rhs)
    for a in range(3):
        mean[a] = pose[a]


@njit(cache=True)
def _log(undo_kind, undo_index, undo_value, undo_count, kind, index, v0, v1):
    n = undo_count[0]
    undo_kind[n] = kind
    undo_index[n] = index
    undo_value[n, 0] = v0
    undo_value[n, 1] = v1
    undo_count[0] = n + 1


@njit(cache=True)
def _relax_logged(robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count, information_vector,
                  mean, i, relaxation, tol2, queue, queued, queue_state, undo_kind, undo_index, undo_value,
                  undo_count):  # fmt: skip
    o = 3 + 2 * i
    _log(undo_kind, undo_index, undo_value, undo_count, UNDO_MEAN, i, mean[o], mean[o + 1])
    moved = _relax_landmark(robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                            information_vector, mean, i, relaxation)  # fmt: skip
    if moved > tol2:
        _push_neighbours(neighbour_index, neighbour_count, i, queue, queued, queue_state,
                         undo_kind, undo_index, undo_value, undo_count)  # fmt: skip


@njit(cache=True)
def _push_neighbours(neighbour_index, neighbour_count, i, queue, queued, queue_state,
                     undo_kind, undo_index, undo_value, undo_count):  # fmt: skip
    """Put the neighbours of landmark ``i`` that are not queued yet at the end of the queue (logged)."""
    capacity = queue.shape[0]
    for slot in range(neighbour_count[i]):
        j = neighbour_index[i, slot]
        if not queued[j] and queue_state[1] < capacity:
            queue[(queue_state[0] + queue_state[1]) % capacity] = j
            queue_state[1] += 1
            queued[j] = True
            _log(undo_kind, undo_index, undo_value, undo_count, UNDO_PUSH, j, 0.0, 0.0)


@njit(cache=True)
def relax_robot_block(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                      information_vector, mean, block_position, active):  # fmt: skip
    """Solve for the robot and ``active`` jointly, the rest of the map held at its mean.

    ``Omega_BB mu_B = xi_B - Omega_B,rest mu_rest`` over the block ``B`` of
    the robot and its active landmarks (a block Gauss-Seidel step with one
    big block). Returns the new block mean (robot first); writes nothing.
    """
    omega, xi, _ = gather(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                          neighbour_count, information_vector, mean, block_position, active)  # fmt: skip
    for p in range(active.shape[0]):
        block_position[active[p]] = p
    for p in range(active.shape[0]):
        i = active[p]
        o = 3 + 2 * p
        for slot in range(neighbour_count[i]):
            j = neighbour_index[i, slot]
            if block_position[j] < 0:
                oj = 3 + 2 * j
                for a in range(2):
                    xi[o + a] -= neighbour_info[i, slot, a, 0] * mean[oj] + neighbour_info[i, slot, a, 1] * mean[oj + 1]
    for p in range(active.shape[0]):
        block_position[active[p]] = -1
    return np.linalg.solve(omega, xi)


@njit(cache=True)
def recover_mean_wavefront(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                           information_vector, mean, block_position, active, seeds, queue, queued, queue_state,
                           budget, relaxation, tolerance, undo_kind, undo_index, undo_value, undo_count):  # fmt: skip
    """Fast :func:`seif_gym.slam.seif.recover_mean_wavefront`, with an undo log.

    Every change of a landmark mean, every pop and every push is appended to
    the undo log (``undo_count[0]`` entries) before it is made, so that
    :func:`undo_wavefront` can revert a call, also one that failed midway
    (the robot's mean is the caller's to save).
    """
    tol2 = tolerance * tolerance
    capacity = queue.shape[0]
    for k in range(seeds.shape[0]):
        _relax_logged(robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                      information_vector, mean, seeds[k], 1.0, tol2, queue, queued, queue_state,
                      undo_kind, undo_index, undo_value, undo_count)  # fmt: skip
    solution = relax_robot_block(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                                 neighbour_count, information_vector, mean, block_position, active)  # fmt: skip
    for a in range(3):
        mean[a] = solution[a]
    for p in range(active.shape[0]):
        i = active[p]
        o = 3 + 2 * i
        _log(undo_kind, undo_index, undo_value, undo_count, UNDO_MEAN, i, mean[o], mean[o + 1])
        d0 = solution[3 + 2 * p] - mean[o]
        d1 = solution[4 + 2 * p] - mean[o + 1]
        mean[o] += d0
        mean[o + 1] += d1
        if d0 * d0 + d1 * d1 > tol2:
            _push_neighbours(neighbour_index, neighbour_count, i, queue, queued, queue_state,
                             undo_kind, undo_index, undo_value, undo_count)  # fmt: skip
    for _ in range(budget):
        if queue_state[1] == 0:
            break
        i = queue[queue_state[0]]
        _log(undo_kind, undo_index, undo_value, undo_count, UNDO_POP, i, 0.0, 0.0)
        queue[queue_state[0]] = -1
        queue_state[0] = (queue_state[0] + 1) % capacity
        queue_state[1] -= 1
        queued[i] = False
        _relax_logged(robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                      information_vector, mean, i, relaxation, tol2, queue, queued, queue_state,
                      undo_kind, undo_index, undo_value, undo_count)  # fmt: skip
    relax_robot(robot_info, robot_links, information_vector, mean, active)


@njit(cache=True)
def undo_wavefront(mean, queue, queued, queue_state, undo_kind, undo_index, undo_value, count):
    """Revert the first ``count`` logged changes of :func:`recover_mean_wavefront`, newest first."""
    capacity = queue.shape[0]
    for n in range(count - 1, -1, -1):
        i = undo_index[n]
        kind = undo_kind[n]
        if kind == UNDO_MEAN:
            mean[3 + 2 * i] = undo_value[n, 0]
            mean[4 + 2 * i] = undo_value[n, 1]
        elif kind == UNDO_PUSH:
            queue_state[1] -= 1
            queue[(queue_state[0] + queue_state[1]) % capacity] = -1
            queued[i] = False
        else:
            queue_state[0] = (queue_state[0] - 1) % capacity
            queue[queue_state[0]] = i
            queue_state[1] += 1
            queued[i] = True


# ---------------------------------------------------------------------------
# Journal of a filter step (seif.UpdateJournal): save and restore landmark rows
# ---------------------------------------------------------------------------
@njit(cache=True)
def save_rows(rows, start, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
              information_vector, mean, is_active, last_observed,
              saved_rows, saved_links, saved_info, saved_index, saved_neighbours, saved_counts, saved_values,
              saved_flags, saved_observed):  # fmt: skip
    """Copy every per-landmark value of ``rows`` into the journal's buffers from entry ``start`` on.

    Rows beyond the arrays' capacity are skipped (they go with the arrays).
    Only the used neighbour slots are copied (beyond a landmark's count the
    slots hold -1 and 0). Returns the number of entries after the copy; the
    caller made the buffers large enough.
    """
    capacity = landmark_info.shape[0]
    n = start
    for i in rows:
        if i >= capacity:
            continue
        saved_rows[n] = i
        saved_links[n] = robot_links[i]
        saved_info[n] = landmark_info[i]
        # a row written before it was saved (only ever saved earlier too, whose copy wins) may count more
        # slots than these arrays hold: never read past them
        count = min(neighbour_count[i], neighbour_index.shape[1])
        saved_counts[n] = count
        for slot in range(count):
            saved_index[n, slot] = neighbour_index[i, slot]
            saved_neighbours[n, slot] = neighbour_info[i, slot]
        saved_values[n, 0] = information_vector[3 + 2 * i]
        saved_values[n, 1] = information_vector[4 + 2 * i]
        saved_values[n, 2] = mean[3 + 2 * i]
        saved_values[n, 3] = mean[4 + 2 * i]
        saved_flags[n] = is_active[i]
        saved_observed[n] = last_observed[i]
        n += 1
    return n


@njit(cache=True)
def restore_rows(count, saved_rows, saved_links, saved_info, saved_index, saved_neighbours, saved_counts,
                 saved_values, saved_flags, saved_observed,
                 robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                 information_vector, mean, is_active, last_observed, block_position):  # fmt: skip
    """Write the first ``count`` journal entries back; of several entries of a row the first (oldest) wins.

    ``block_position`` (all -1) marks the rows done and is left all -1.
    """
    for n in range(count):
        i = saved_rows[n]
        if block_position[i] >= 0:
            continue
        block_position[i] = 0
        robot_links[i] = saved_links[n]
        landmark_info[i] = saved_info[n]
        old = saved_counts[n]
        for slot in range(old, neighbour_count[i]):  # slots a failed step appended
            neighbour_index[i, slot] = -1
            neighbour_info[i, slot] = 0.0
        for slot in range(old):
            neighbour_index[i, slot] = saved_index[n, slot]
            neighbour_info[i, slot] = saved_neighbours[n, slot]
        neighbour_count[i] = old
        information_vector[3 + 2 * i] = saved_values[n, 0]
        information_vector[4 + 2 * i] = saved_values[n, 1]
        mean[3 + 2 * i] = saved_values[n, 2]
        mean[4 + 2 * i] = saved_values[n, 3]
        is_active[i] = saved_flags[n]
        last_observed[i] = saved_observed[n]
    for n in range(count):
        block_position[saved_rows[n]] = -1


# -- many SEIFs in one call (seif_gym.slam.batched) -------------------------------------------------
@njit(cache=True)
def velocity_linearization(theta, v, w, dt, alphas, floor, delta, jacobian, noise):
    """:meth:`VelocityMotionModel.linearize_trusted` into ``delta``, ``jacobian``, ``noise`` (same operations)."""
    half = 0.5 * w * dt
    if abs(half) < 1e-4:
        a2 = half * half
        sinc = 1.0 - a2 / 6.0 + a2 * a2 / 120.0
        dsinc = -half / 3.0 + half * a2 / 30.0
    else:
        s_half = np.sin(half)
        c_half = np.cos(half)
        sinc = s_half / half
        dsinc = (half * c_half - s_half) / (half * half)
    mid = theta + half
    c = np.cos(mid)
    s = np.sin(mid)
    dx = v * dt * c * sinc
    dy = v * dt * s * sinc
    delta[0] = dx
    delta[1] = dy
    delta[2] = w * dt
    jacobian[:, :] = 0.0
    jacobian[0, 0] = 1.0
    jacobian[1, 1] = 1.0
    jacobian[2, 2] = 1.0
    jacobian[0, 2] = -dy
    jacobian[1, 2] = dx
    v0 = dt * c * sinc
    v1 = v * dt * 0.5 * dt * (-s * sinc + c * dsinc)
    u0 = dt * s * sinc
    u1 = v * dt * 0.5 * dt * (c * sinc + s * dsinc)
    vv = v * v
    ww = w * w
    m_v = alphas[0] * vv + alphas[1] * ww
    m_w = alphas[2] * vv + alphas[3] * ww
    r01 = v0 * m_v * u0 + v1 * m_w * u1
    r02 = v1 * m_w * dt
    r12 = u1 * m_w * dt
    noise[0, 0] = v0 * m_v * v0 + v1 * m_w * v1 + floor
    noise[0, 1] = r01
    noise[0, 2] = r02
    noise[1, 0] = r01
    noise[1, 1] = u0 * m_v * u0 + u1 * m_w * u1 + floor
    noise[1, 2] = r12
    noise[2, 0] = r02
    noise[2, 1] = r12
    noise[2, 2] = dt * m_w * dt + (alphas[4] * vv + alphas[5] * ww) * dt * dt + floor


@njit(cache=True)
def _wrap_float(angle):
    """:func:`seif_gym.slam.models.wrap_angle` of a float (``[-pi, pi)``, the rounding fold included)."""
    wrapped = (angle + np.pi) % TWO_PI - np.pi
    if wrapped >= np.pi:
        wrapped -= TWO_PI
    return wrapped


@njit(cache=True)
def rewrap_heading(robot_info, robot_links, information_vector, mean, active):
    """:func:`seif_gym.slam.seif._rewrap_heading`: wrap ``mu_theta``, shift ``xi`` with it."""
    theta = mean[2]
    if -np.pi <= theta < np.pi:
        return
    shift = _wrap_float(theta) - theta
    mean[2] += shift
    for a in range(3):
        information_vector[a] += robot_info[a, 2] * shift
    for p in range(active.shape[0]):
        i = active[p]
        information_vector[3 + 2 * i] += robot_links[i, 2, 0] * shift
        information_vector[4 + 2 * i] += robot_links[i, 2, 1] * shift


@njit(cache=True)
def seif_predict_env(e, robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                     information_vector, mean, block_position, active, active_count, controls, dt, alphas, floor):  # fmt: skip
    """``SEIF.predict_trusted`` of filter ``e`` of a batch (arrays with a leading filter axis)."""
    delta = np.empty(3)
    jacobian = np.empty((3, 3))
    noise = np.empty((3, 3))
    velocity_linearization(mean[e, 2], controls[e, 0], controls[e, 1], dt, alphas, floor, delta, jacobian, noise)
    act = active[e, : active_count[e]]
    predict(robot_info[e], robot_links[e], landmark_info[e], neighbour_index[e], neighbour_info[e],
            neighbour_count[e], information_vector[e], mean[e], block_position[e], act, delta, jacobian, noise)  # fmt: skip
    rewrap_heading(robot_info[e], robot_links[e], information_vector[e], mean[e], act)


@njit(cache=True)
def seif_predict_many(*arguments):
    """:func:`seif_predict_env` of every filter of a batch, one after another.

    ``arguments``: those of :func:`seif_predict_env` after ``e`` (the first one has the env axis).
    """
    for e in range(arguments[0].shape[0]):
        seif_predict_env(e, *arguments)


@njit(cache=True)
def _map_ids(mean, counters, id_to_index, ids, ranges, bearings, measured):
    """State orders of the ``measured`` ids; a new landmark is appended at the inverse sensor model's position.

    ``SlamFilter._update_known`` and ``SEIF._add_landmarks``; ``counters[0]`` counts it.
    """
    m = measured.shape[0]
    n = counters[0]
    indices = np.empty(m, dtype=np.int64)
    x = mean[0]
    y = mean[1]
    theta = mean[2]
    for k in range(m):
        index = id_to_index[measured[k]]
        if index < 0:
            index = n
            n += 1
            id_to_index[measured[k]] = index
            ids[index] = measured[k]
            angle = bearings[k] + theta
            mean[3 + 2 * index] = x + ranges[k] * np.cos(angle)
            mean[4 + 2 * index] = y + ranges[k] * np.sin(angle)
        indices[k] = index
    counters[0] = n
    return indices


@njit(cache=True)
def _incorporate_one(robot_info, robot_links, landmark_info, information_vector, mean, active, counters, is_active,
                     last_observed, indices, ranges, bearings, noise_info):  # fmt: skip
    """``SEIF._incorporate``: the measurement update, then the landmarks observed join the active set."""
    if indices.shape[0] == 0:
        return
    measurement_update(robot_info, robot_links, landmark_info, information_vector, mean, indices, ranges, bearings,
                       noise_info)  # fmt: skip
    count = counters[1]
    for k in range(indices.shape[0]):
        i = indices[k]
        last_observed[i] = counters[2]
        if not is_active[i]:
            active[count] = i
            count += 1
            is_active[i] = True
    counters[1] = count


@njit(cache=True)
def _recovery_seeds(counters, is_active, recovery_landmarks):
    """The wavefront recovery's seeds: the passive landmarks among the next ``recovery_landmarks`` in round robin.

    ``counters = [num_landmarks, active_count, update_count, round_robin]``; the round-robin position
    ``counters[3]`` advances by the landmarks looked at (in place).
    """
    n = counters[0]
    batch = min(recovery_landmarks, n)
    seeds = np.empty(batch, dtype=np.int64)
    s = 0
    for k in range(batch):
        j = (counters[3] + k) % n
        if not is_active[j]:
            seeds[s] = j
            s += 1
    if batch > 0:
        counters[3] = (counters[3] + batch) % n
    return seeds[:s]


@njit(cache=True)
def _recover_one(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                 information_vector, mean, block_position, active, counters, is_active, queue, queued, queue_state,
                 recovery_landmarks, budget, relaxation, tolerance):  # fmt: skip
    """``SEIF._recover_mean`` (wavefront): the next passive landmarks in round robin, the robot block, the queue."""
    seeds = _recovery_seeds(counters, is_active, recovery_landmarks)
    act = active[: counters[1]]
    log_size = (seeds.shape[0] + act.shape[0] + budget) * (2 + neighbour_index.shape[1]) + 1
    recover_mean_wavefront(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                           information_vector, mean, block_position, act, seeds, queue, queued, queue_state,
                           budget, relaxation, tolerance, np.empty(log_size, np.int8), np.empty(log_size, np.int64),
                           np.empty((log_size, 2)), np.zeros(1, np.int64))  # fmt: skip
    rewrap_heading(robot_info, robot_links, information_vector, mean, act)


@njit(cache=True)
def _sparsify_stalest(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                      information_vector, mean, block_position, active, counters, is_active, last_observed,
                      update_count, max_active):  # fmt: skip
    """The SEIF's sparsification after an update: the active landmarks observed longest ago leave.

    Never one observed in update ``update_count``; at most ``max_active`` stay active (``< 0``: all).
    ``counters[1]`` (the active count) and ``active`` / ``is_active`` are updated in place.
    """
    count = counters[1]
    act = active[:count]
    if max_active < 0 or count <= max_active:
        return
    candidates = np.empty(count, dtype=np.int64)
    c = 0
    for p in range(count):
        if last_observed[active[p]] != update_count:
            candidates[c] = p
            c += 1
    remove_count = min(count - max_active, c)
    if remove_count == 0:
        return
    order = np.argsort(last_observed[act[candidates[:c]]], kind="mergesort")
    remove = np.zeros(count, dtype=np.bool_)
    for r in range(remove_count):
        remove[candidates[order[r]]] = True
    block = np.empty(count, dtype=np.int64)
    kept = 0
    for p in range(count):
        if not remove[p]:
            block[kept] = active[p]
            kept += 1
    q = kept
    for p in range(count):
        if remove[p]:
            block[q] = active[p]
            q += 1
    sparsify(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
             information_vector, mean, block_position, block, kept)  # fmt: skip
    for p in range(kept, count):
        is_active[block[p]] = False
    for p in range(kept):
        active[p] = block[p]
    counters[1] = kept


@njit(cache=True)
def seif_update_one(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                    information_vector, mean, block_position, active, counters, is_active, last_observed,
                    id_to_index, ids, queue, queued, queue_state, ranges, bearings, measured, noise_info,
                    max_active, recovery_landmarks, budget, relaxation, tolerance):  # fmt: skip
    """``SEIF.update_trusted`` (known ids, wavefront recovery) of one filter of a batch.

    ``counters = [num_landmarks, active_count, update_count, round_robin]`` (updated in place);
    ``id_to_index[id]`` is the state order of landmark ``id`` (-1: unmapped), ``ids`` the inverse.
    """
    indices = _map_ids(mean, counters, id_to_index, ids, ranges, bearings, measured)
    counters[2] += 1
    update_count = counters[2]
    _incorporate_one(robot_info, robot_links, landmark_info, information_vector, mean, active, counters, is_active,
                     last_observed, indices, ranges, bearings, noise_info)  # fmt: skip
    # wavefront recovery: the next passive landmarks in round robin, then the robot block and the queue
    _recover_one(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                 information_vector, mean, block_position, active, counters, is_active, queue, queued, queue_state,
                 recovery_landmarks, budget, relaxation, tolerance)  # fmt: skip
    # sparsification: the landmarks observed longest ago leave, never one observed in this update
    _sparsify_stalest(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                      information_vector, mean, block_position, active, counters, is_active, last_observed,
                      update_count, max_active)  # fmt: skip


@njit(cache=True)
def seif_update_env(e, robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                    information_vector, mean, block_position, active, counters, is_active, last_observed,
                    id_to_index, ids, queue, queued, queue_state, ranges, bearings, measured, measured_count,
                    noise_info, max_active, recovery_landmarks, budget, relaxation, tolerance):  # fmt: skip
    """:func:`seif_update_one` of filter ``e`` of a batch, with its first ``measured_count[e]`` measurements."""
    m = measured_count[e]
    seif_update_one(robot_info[e], robot_links[e], landmark_info[e], neighbour_index[e], neighbour_info[e],
                    neighbour_count[e], information_vector[e], mean[e], block_position[e], active[e],
                    counters[e], is_active[e], last_observed[e], id_to_index[e], ids[e], queue[e], queued[e],
                    queue_state[e], ranges[e, :m], bearings[e, :m], measured[e, :m], noise_info, max_active,
                    recovery_landmarks, budget, relaxation, tolerance)  # fmt: skip


@njit(cache=True)
def seif_update_many(*arguments):
    """:func:`seif_update_env` of every filter of a batch, one after another.

    ``arguments``: those of :func:`seif_update_env` after ``e`` (the first one has the env axis).
    """
    for e in range(arguments[0].shape[0]):
        seif_update_env(e, *arguments)


# -- the ESEIF's relocalization (seif_gym.slam.eseif) --------------------------------------------------------
@njit(cache=True)
def marginalize_robot_block(omega: FloatArray, xi: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Fast :func:`marginalize_robot` (Cholesky of ``Omega_xx``, exactly symmetric result)."""
    size = xi.shape[0]
    lower = np.linalg.cholesky(np.ascontiguousarray(omega[:3, :3]))
    # W = L^-1 Omega_x,: and w = L^-1 xi_x by forward substitution; the Schur term is W^T W, W^T w
    w = np.ascontiguousarray(omega[:3, :]).copy()
    wx = xi[:3].copy()
    for a in range(3):
        for b in range(a):
            for c in range(size):
                w[a, c] -= lower[a, b] * w[b, c]
            wx[a] -= lower[a, b] * wx[b]
        for c in range(size):
            w[a, c] /= lower[a, a]
        wx[a] /= lower[a, a]
    omega_marg = np.zeros((size, size))
    xi_marg = np.zeros(size)
    for r in range(3, size):
        value = xi[r]
        for a in range(3):
            value -= w[a, r] * wx[a]
        xi_marg[r] = value
        for c in range(r, size):
            value = omega[r, c]
            for a in range(3):
                value -= w[a, r] * w[a, c]
            omega_marg[r, c] = value
            omega_marg[c, r] = value
    return omega_marg, xi_marg


@njit(cache=True)
def relocalization_pose_information(
    mean: FloatArray, landmark_info: FloatArray, indices: IntArray, noise_cov: FloatArray
) -> FloatArray:
    """Pose information ``J_i = H_x^T S_i^-1 H_x`` each measured landmark would give, shape (m, 3, 3).

    ``S_i = Q + H_m P_i H_m^T`` counts the landmark's own uncertainty, with
    ``P_i = Omega_ii^-1`` its conditional covariance (the constant-time proxy
    the SEIF also uses; a lower bound of the marginal). ``H_x``, ``H_m`` are the
    pose and landmark columns of ``H`` (:class:`~seif_gym.slam.models.RangeBearingSensor`) at
    the current mean.
    """
    offsets = np.empty((indices.shape[0], 2))
    covariances = np.empty((indices.shape[0], 2, 2))
    for k in range(indices.shape[0]):
        i = indices[k]
        offsets[k, 0] = mean[3 + 2 * i] - mean[0]
        offsets[k, 1] = mean[4 + 2 * i] - mean[1]
        a, b, c, d = landmark_info[i, 0, 0], landmark_info[i, 0, 1], landmark_info[i, 1, 0], landmark_info[i, 1, 1]
        det = a * d - b * c
        covariances[k, 0, 0], covariances[k, 1, 1] = d / det, a / det
        covariances[k, 0, 1] = covariances[k, 1, 0] = -0.5 * (b + c) / det
    return _pose_information(offsets, covariances, noise_cov)


@njit(cache=True)
def _pose_information(offsets: FloatArray, covariances: FloatArray, noise_cov: FloatArray) -> FloatArray:
    """``J_i = H_x^T (Q + H_m P_i H_m^T)^-1 H_x`` for landmarks at ``offsets`` (m, 2) from the robot.

    ``covariances`` (m, 2, 2) are the landmarks' ``P_i``; zero for a landmark
    first seen in this scan, whose only position information is the scan's.
    """
    count = offsets.shape[0]
    out = np.empty((count, 3, 3))
    q00, q01, q11 = noise_cov[0, 0], noise_cov[0, 1], noise_cov[1, 1]
    H_x = np.empty((2, 3))
    for k in range(count):
        dx, dy = offsets[k, 0], offsets[k, 1]
        q = dx * dx + dy * dy
        r = np.sqrt(q)
        # H = [H_x | H_m] with H_m = -H_x[:, :2]
        H_x[0, 0], H_x[0, 1], H_x[0, 2] = -dx / r, -dy / r, 0.0
        H_x[1, 0], H_x[1, 1], H_x[1, 2] = dy / q, -dx / q, -1.0
        h00, h01, h10, h11 = dx / r, dy / r, -dy / q, dx / q
        p00, p01, p11 = covariances[k, 0, 0], covariances[k, 0, 1], covariances[k, 1, 1]
        # S = Q + H_m P H_m^T (symmetric 2 x 2), then S^-1
        t00, t01 = h00 * p00 + h01 * p01, h00 * p01 + h01 * p11
        t10, t11 = h10 * p00 + h11 * p01, h10 * p01 + h11 * p11
        s00 = q00 + t00 * h00 + t01 * h01
        s01 = q01 + t00 * h10 + t01 * h11
        s11 = q11 + t10 * h10 + t11 * h11
        det = s00 * s11 - s01 * s01
        i00, i01, i11 = s11 / det, -s01 / det, s00 / det
        for u in range(3):
            for v in range(3):
                out[k, u, v] = H_x[0, u] * (i00 * H_x[0, v] + i01 * H_x[1, v]) + H_x[1, u] * (
                    i01 * H_x[0, v] + i11 * H_x[1, v]
                )
    return out


@njit(cache=True)
def _det3(m: FloatArray) -> float:
    return (
        m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
        - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
        + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0])
    )


@njit(cache=True)
def select_relocalization_landmarks(pose_information: FloatArray, count: int, rcond: float) -> IntArray:
    """Pick ``count`` measurements whose summed pose information has the largest determinant.

    Parameters
    ----------
    pose_information : ndarray, shape (m, 3, 3)
        ``J_i`` of each candidate (:func:`relocalization_pose_information`).
    count : int
        Measurements to withhold, at least 2 (one range-bearing measurement
        leaves the rotation about its landmark unobserved).
    rcond : float
        Refuse (return an empty array) when the chosen ``J = sum J_i`` has
        ``lambda_min(J) < rcond lambda_max(J)``.

    Returns
    -------
    ndarray of int64
        Positions in ``pose_information`` of the chosen measurements (best
        pair first, then greedy additions), or empty.

    Notes
    -----
    ``det J`` is the D-optimal criterion: it rewards landmarks that are close,
    well mapped and spread in bearing (the relocalized pose is well
    conditioned). The best pair is found exhaustively (``O(m^2)`` for a scan
    of ``m`` measurements), further ones greedily.
    """
    m = pose_information.shape[0]
    chosen = np.empty(0, dtype=np.int64)
    if m < 2 or count < 2:
        return chosen
    best, first, second = -np.inf, -1, -1
    for i in range(m):
        for j in range(i + 1, m):
            value = _det3(pose_information[i] + pose_information[j])
            if value > best:
                best, first, second = value, i, j
    taken = np.zeros(m, dtype=np.bool_)
    taken[first] = True
    taken[second] = True
    total = pose_information[first] + pose_information[second]
    chosen = np.empty(min(count, m), dtype=np.int64)
    chosen[0], chosen[1] = first, second
    for n in range(2, chosen.shape[0]):
        best, pick = -np.inf, -1
        for k in range(m):
            if not taken[k]:
                value = _det3(total + pose_information[k])
                if value > best:
                    best, pick = value, k
        taken[pick] = True
        total = total + pose_information[pick]
        chosen[n] = pick
    eigenvalues = np.linalg.eigvalsh(0.5 * (total + total.T))
    if not eigenvalues[0] > rcond * eigenvalues[2]:
        return np.empty(0, dtype=np.int64)
    return chosen


# -- many ESEIFs in one call (seif_gym.slam.batched.BatchedESEIF) ---------------------------------------------------
@njit(cache=True)
def _eseif_plan(mean, landmark_info, active_count, is_active, id_to_index, ranges, bearings, measured, noise_cov,
                max_active, relocalization_landmarks, rcond):  # fmt: skip
    """``ESEIF._plan_update`` as ``(withheld, split, kept)``.

    ``withheld``: positions of ``z_beta`` (empty: an ordinary update); ``split``: whether the
    relocalization is a split one; ``kept``: the measurements kept (all but those a full bound discards).
    """
    m = measured.shape[0]
    kept = np.ones(m, dtype=np.bool_)
    none = np.empty(0, dtype=np.int64)
    if max_active < 0 or m == 0:
        return none, False, kept
    indices = np.empty(m, dtype=np.int64)
    mapped = np.zeros(m, dtype=np.bool_)
    active = np.zeros(m, dtype=np.bool_)
    joining = 0
    for k in range(m):
        indices[k] = id_to_index[measured[k]]
        mapped[k] = indices[k] >= 0
        if mapped[k]:
            active[k] = is_active[indices[k]]
        if not active[k]:
            joining += 1
    if active_count + joining <= max_active:
        return none, False, kept
    candidates = np.flatnonzero(mapped)
    information = np.empty((m, 3, 3))
    mapped_information = relocalization_pose_information(mean, landmark_info, indices[candidates], noise_cov)
    for c in range(candidates.shape[0]):
        information[candidates[c]] = mapped_information[c]
    new = np.flatnonzero(~mapped)
    offsets = np.empty((new.shape[0], 2))
    for c in range(new.shape[0]):
        heading = mean[2] + bearings[new[c]]
        offsets[c, 0] = ranges[new[c]] * np.cos(heading)
        offsets[c, 1] = ranges[new[c]] * np.sin(heading)
    new_information = _pose_information(offsets, np.zeros((new.shape[0], 2, 2)), noise_cov)
    for c in range(new.shape[0]):
        information[new[c]] = new_information[c]
    if candidates.shape[0] >= 2:  # Walter et al.'s relocalization
        chosen = select_relocalization_landmarks(information[candidates], relocalization_landmarks, rcond)
        if chosen.shape[0] > 0:
            return candidates[chosen], False, kept
    chosen = select_relocalization_landmarks(information, relocalization_landmarks, rcond)
    if chosen.shape[0] > 0:  # split relocalization
        return np.sort(chosen), True, kept
    # no relocalization possible: keep what fits in the bound, mapped landmarks first, then the nearest
    return none, False, _keep_within_bound(active, mapped, ranges, max_active - active_count)


@njit(cache=True)
def _keep_within_bound(active, mapped, ranges, room):  # fmt: skip
    """The measurements an update keeps when the active bound leaves ``room`` places for the others.

    Every measurement of an active landmark, then, of the others, the first ``room`` by (new after
    mapped, nearest first): a stable insertion sort with ``np.lexsort``'s order.
    """
    kept = active.copy()
    others = np.flatnonzero(~active)
    order = np.empty(others.shape[0], dtype=np.int64)
    for c in range(others.shape[0]):  # a stable insertion sort on (not mapped, range), as np.lexsort
        pos = c
        key_new, key_range = not mapped[others[c]], ranges[others[c]]
        while pos > 0:
            prev = others[order[pos - 1]]
            prev_new = not mapped[prev]
            if prev_new > key_new or (prev_new == key_new and ranges[prev] > key_range):
                order[pos] = order[pos - 1]
                pos -= 1
            else:
                break
        order[pos] = c
    for c in range(min(max(room, 0), others.shape[0])):
        kept[others[order[c]]] = True
    return kept


@njit(cache=True)
def eseif_update_one(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                     information_vector, mean, block_position, active, counters, is_active, last_observed,
                     id_to_index, ids, queue, queued, queue_state, ranges, bearings, measured, noise_info, noise_cov,
                     max_active, relocalization_landmarks, split_weight, rcond, recovery_landmarks, budget, relaxation,
                     tolerance, eseif_counters):  # fmt: skip
    """``ESEIF.update_trusted`` (known ids, wavefront recovery) of one filter of a batch.

    ``counters`` as for :func:`seif_update_one`; ``eseif_counters = [relocalizations, split relocalizations,
    discarded measurements]`` (updated in place). The same kernels in the same order as the ESEIF's
    compiled backend.
    """
    withheld, split, kept = _eseif_plan(mean, landmark_info, counters[1], is_active, id_to_index, ranges, bearings,
                                        measured, noise_cov, max_active, relocalization_landmarks, rcond)  # fmt: skip
    use = np.flatnonzero(kept)
    m = use.shape[0]
    eseif_counters[2] += kept.shape[0] - m
    z_range = ranges[use]
    z_bearing = bearings[use]
    z_id = measured[use]
    indices = _map_ids(mean, counters, id_to_index, ids, z_range, z_bearing, z_id)
    counters[2] += 1
    if withheld.shape[0] == 0:
        _incorporate_one(robot_info, robot_links, landmark_info, information_vector, mean, active, counters,
                         is_active, last_observed, indices, z_range, z_bearing, noise_info)  # fmt: skip
        _recover_one(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                     information_vector, mean, block_position, active, counters, is_active, queue, queued,
                     queue_state, recovery_landmarks, budget, relaxation, tolerance)  # fmt: skip
        return
    alpha = np.ones(m, dtype=np.bool_)
    alpha[withheld] = False
    rest = np.flatnonzero(alpha)
    _incorporate_one(robot_info, robot_links, landmark_info, information_vector, mean, active, counters, is_active,
                     last_observed, indices[rest], z_range[rest], z_bearing[rest], noise_info)  # (b)  # fmt: skip
    if split:
        _incorporate_one(robot_info, robot_links, landmark_info, information_vector, mean, active, counters,
                         is_active, last_observed, indices[withheld], z_range[withheld], z_bearing[withheld],
                         split_weight * noise_info)  # fmt: skip
    _recover_one(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                 information_vector, mean, block_position, active, counters, is_active, queue, queued, queue_state,
                 recovery_landmarks, budget, relaxation, tolerance)  # fmt: skip
    # (c) the robot marginalized out of the block of the robot and its active landmarks
    block = active[: counters[1]].copy()
    omega, xi, _ = gather(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                          information_vector, mean, block_position, block)  # fmt: skip
    omega, xi = marginalize_robot_block(omega, xi)
    scatter(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
            information_vector, block, omega, xi)  # fmt: skip
    for p in range(block.shape[0]):
        is_active[block[p]] = False
    counters[1] = 0
    # (d) relocalized by z_beta
    weight = 1.0 - split_weight if split else 1.0
    relocalization_info = noise_info if weight == 1.0 else weight * noise_info
    _incorporate_one(robot_info, robot_links, landmark_info, information_vector, mean, active, counters, is_active,
                     last_observed, indices[withheld], z_range[withheld], z_bearing[withheld],
                     relocalization_info)  # fmt: skip
    _recover_one(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                 information_vector, mean, block_position, active, counters, is_active, queue, queued, queue_state,
                 recovery_landmarks, budget, relaxation, tolerance)  # fmt: skip
    eseif_counters[0] += 1
    if split:
        eseif_counters[1] += 1


@njit(cache=True)
def eseif_update_env(e, robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                     information_vector, mean, block_position, active, counters, is_active, last_observed,
                     id_to_index, ids, queue, queued, queue_state, ranges, bearings, measured, measured_count,
                     noise_info, noise_cov, max_active, relocalization_landmarks, split_weight, rcond,
                     recovery_landmarks, budget, relaxation, tolerance, eseif_counters):  # fmt: skip
    """:func:`eseif_update_one` of filter ``e`` of a batch, with its first ``measured_count[e]`` measurements."""
    m = measured_count[e]
    eseif_update_one(robot_info[e], robot_links[e], landmark_info[e], neighbour_index[e], neighbour_info[e],
                     neighbour_count[e], information_vector[e], mean[e], block_position[e], active[e], counters[e],
                     is_active[e], last_observed[e], id_to_index[e], ids[e], queue[e], queued[e], queue_state[e],
                     ranges[e, :m], bearings[e, :m], measured[e, :m], noise_info, noise_cov, max_active,
                     relocalization_landmarks, split_weight, rcond, recovery_landmarks, budget, relaxation, tolerance,
                     eseif_counters[e])  # fmt: skip


@njit(cache=True)
def eseif_update_many(*arguments):
    """:func:`eseif_update_env` of every filter of a batch, one after another.

    ``arguments``: those of :func:`eseif_update_env` after ``e`` (the first one has the env axis).
    """
    for e in range(arguments[0].shape[0]):
        eseif_update_env(e, *arguments)


# -- a planner's look-ahead (seif_gym.slam.rollout): scratch copies that are never restored ---------------------------
@njit(cache=True, inline="always")
def _push_unlogged(neighbour_index, neighbour_count, i, queue, queued, queue_state):
    """:func:`_push_neighbours` without the undo log."""
    capacity = queue.shape[0]
    for slot in range(neighbour_count[i]):
        j = neighbour_index[i, slot]
        if not queued[j] and queue_state[1] < capacity:
            queue[(queue_state[0] + queue_state[1]) % capacity] = j
            queue_state[1] += 1
            queued[j] = True


@njit(cache=True, inline="always")
def _relax_unlogged(robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count, information_vector,
                    mean, i, relaxation, tol2, queue, queued, queue_state):  # fmt: skip
    """:func:`_relax_logged` without the undo log, in one body (the operations of its callees, in their order)."""
    o = 3 + 2 * i
    r0 = information_vector[o]
    r1 = information_vector[o + 1]
    for b in range(3):
        r0 -= robot_links[i, b, 0] * mean[b]
        r1 -= robot_links[i, b, 1] * mean[b]
    for slot in range(neighbour_count[i]):
        oj = 3 + 2 * neighbour_index[i, slot]
        r0 -= neighbour_info[i, slot, 0, 0] * mean[oj] + neighbour_info[i, slot, 0, 1] * mean[oj + 1]
        r1 -= neighbour_info[i, slot, 1, 0] * mean[oj] + neighbour_info[i, slot, 1, 1] * mean[oj + 1]
    det = landmark_info[i, 0, 0] * landmark_info[i, 1, 1] - landmark_info[i, 0, 1] * landmark_info[i, 1, 0]
    new0 = (landmark_info[i, 1, 1] * r0 - landmark_info[i, 0, 1] * r1) / det
    new1 = (landmark_info[i, 0, 0] * r1 - landmark_info[i, 1, 0] * r0) / det
    d0 = relaxation * (new0 - mean[o])
    d1 = relaxation * (new1 - mean[o + 1])
    mean[o] += d0
    mean[o + 1] += d1
    if d0 * d0 + d1 * d1 > tol2:
        _push_unlogged(neighbour_index, neighbour_count, i, queue, queued, queue_state)


@njit(cache=True)
def recover_mean_wavefront_unlogged(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                                    neighbour_count, information_vector, mean, block_position, active, seeds, queue,
                                    queued, queue_state, budget, relaxation, tolerance):  # fmt: skip
    """:func:`recover_mean_wavefront` without the undo log: the same operations in the same order.

    For a copy that is thrown away after use (nothing to restore); the nested calls of the logged
    version are one body here, which is most of its speed.
    """
    tol2 = tolerance * tolerance
    capacity = queue.shape[0]
    for k in range(seeds.shape[0]):
        _relax_unlogged(robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                        information_vector, mean, seeds[k], 1.0, tol2, queue, queued, queue_state)  # fmt: skip
    solution = relax_robot_block(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                                 neighbour_count, information_vector, mean, block_position, active)  # fmt: skip
    for a in range(3):
        mean[a] = solution[a]
    for p in range(active.shape[0]):
        i = active[p]
        o = 3 + 2 * i
        d0 = solution[3 + 2 * p] - mean[o]
        d1 = solution[4 + 2 * p] - mean[o + 1]
        mean[o] += d0
        mean[o + 1] += d1
        if d0 * d0 + d1 * d1 > tol2:
            _push_unlogged(neighbour_index, neighbour_count, i, queue, queued, queue_state)
    for _ in range(budget):
        if queue_state[1] == 0:
            break
        i = queue[queue_state[0]]
        queue[queue_state[0]] = -1
        queue_state[0] = (queue_state[0] + 1) % capacity
        queue_state[1] -= 1
        queued[i] = False
        _relax_unlogged(robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                        information_vector, mean, i, relaxation, tol2, queue, queued, queue_state)  # fmt: skip
    relax_robot(robot_info, robot_links, information_vector, mean, active)


@njit(cache=True)
def seif_update_mapped(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                       information_vector, mean, block_position, active, counters, is_active, last_observed, queue,
                       queued, queue_state, ranges, bearings, indices, noise_info, max_active, recovery_landmarks,
                       budget, relaxation, tolerance):  # fmt: skip
    """:func:`seif_update_one` of landmarks already in the map (state orders ``indices``), unlogged.

    The same steps in the same order: measurement update, wavefront recovery (by
    :func:`recover_mean_wavefront_unlogged`), heading rewrap, sparsification.
    """
    counters[2] += 1
    update_count = counters[2]
    _incorporate_one(robot_info, robot_links, landmark_info, information_vector, mean, active, counters, is_active,
                     last_observed, indices, ranges, bearings, noise_info)  # fmt: skip
    seeds = _recovery_seeds(counters, is_active, recovery_landmarks)
    act = active[: counters[1]]
    recover_mean_wavefront_unlogged(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                                    neighbour_count, information_vector, mean, block_position, act, seeds, queue,
                                    queued, queue_state, budget, relaxation, tolerance)  # fmt: skip
    rewrap_heading(robot_info, robot_links, information_vector, mean, act)
    # sparsification, as in seif_update_one
    _sparsify_stalest(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                      information_vector, mean, block_position, active, counters, is_active, last_observed,
                      update_count, max_active)  # fmt: skip


@njit(cache=True)
def rollout_step(t, start, horizon, robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                 neighbour_count, information_vector, mean, block_position, active, counters, is_active,
                 last_observed, id_to_index, ids, queue, queued, queue_state, eseif_counters, controls, dt, alphas,
                 floor, noise_info, noise_cov, eseif, max_active, relocalization_landmarks, split_weight, rcond,
                 recovery_landmarks, budget, relaxation, tolerance, landmark_x, landmark_y, max_range, half_fov,
                 dx, dy, angle, poses, pose_covariances, landmark_std):  # fmt: skip
    """Step ``t`` (``0 <= t <= horizon``) of copies ``start, start + 1, ...`` of a SEIF (or ESEIF).

    The copies are rows of batch arrays (:class:`~seif_gym.slam.batched.BatchedSEIF`'s layout, landmark
    ``i``'s id ``i``). Copy ``e`` first takes the measurement update (when ``t > 0``) with what it
    expects from its pose of step ``t - 1``: ``r = sqrt(dx^2 + dy^2)`` and ``wrap(angle - theta)`` of
    each landmark's offsets ``dx[e]``, ``dy[e]`` from that pose (``angle`` their ``atan2``, from the
    caller), for ``0 < r <= max_range`` and, when ``half_fov < pi``, ``|bearing| <= half_fov``; then
    the motion update of step ``t`` with ``controls[e]`` (when ``t < horizon``: its pose goes to
    ``poses[e, t]``, the landmarks' offsets from it to ``dx[e]``, ``dy[e]``), or, at ``t == horizon``,
    gives its pose covariance (:func:`blanket_covariances` over its active landmarks) and
    :func:`conditional_std`. The same kernels in the same order as ``SEIF.predict_trusted`` and
    ``update_trusted``; the SEIF's update unlogged (:func:`seif_update_mapped`), the ESEIF's by
    :func:`eseif_update_one`.

    Returns ``(-1, 0)`` when every copy is done. Before a copy moves, its neighbour lists must have room
    for what the two updates may add (at most ``2 (a + m)`` new neighbours for ``a`` active landmarks
    and ``m`` measurements; a SEIF reserves room as it goes): a copy without it is returned untouched
    with the degree it needs, ``(e, degree)``, for the caller to grow the arrays and call again from ``e``.
    """
    n = landmark_x.shape[0]
    degree = neighbour_index.shape[2]
    limited = half_fov < np.pi
    ranges = np.empty(n)
    bearings = np.empty(n)
    measured = np.empty(n, dtype=np.int64)
    delta = np.empty(3)
    jacobian = np.empty((3, 3))
    noise = np.empty((3, 3))
    no_targets = np.empty(0, dtype=np.int64)
    for e in range(start, robot_info.shape[0]):
        m = 0
        if t > 0:  # RangeBearingSensor.predict_trusted's operations, in its order
            for i in range(n):
                r = np.sqrt(dx[e, i] * dx[e, i] + dy[e, i] * dy[e, i])
                if not (r > 0.0 and r <= max_range):
                    continue
                bearing = (angle[e, i] - poses[e, t - 1, 2] + np.pi) % TWO_PI - np.pi
                if limited and not abs(bearing) <= half_fov:
                    continue
                ranges[m] = r
                bearings[m] = bearing
                measured[m] = i
                m += 1
        if degree < n - 1:  # a landmark never has more than n - 1 neighbours
            most = 0
            for i in range(n):
                most = max(most, neighbour_count[e, i])
            needed = most + 2 * (counters[e, 1] + m)
            if needed > degree:
                return e, min(needed, n - 1)
        if t > 0:
            if eseif:
                eseif_update_one(robot_info[e], robot_links[e], landmark_info[e], neighbour_index[e], neighbour_info[e],
                                 neighbour_count[e], information_vector[e], mean[e], block_position[e], active[e],
                                 counters[e], is_active[e], last_observed[e], id_to_index[e], ids[e], queue[e],
                                 queued[e], queue_state[e], ranges[:m], bearings[:m], measured[:m], noise_info,
                                 noise_cov, max_active, relocalization_landmarks, split_weight, rcond,
                                 recovery_landmarks, budget, relaxation, tolerance, eseif_counters[e])  # fmt: skip
            else:
                seif_update_mapped(robot_info[e], robot_links[e], landmark_info[e], neighbour_index[e],
                                   neighbour_info[e], neighbour_count[e], information_vector[e], mean[e],
                                   block_position[e], active[e], counters[e], is_active[e], last_observed[e],
                                   queue[e], queued[e], queue_state[e], ranges[:m], bearings[:m], measured[:m],
                                   noise_info, max_active, recovery_landmarks, budget, relaxation,
                                   tolerance)  # fmt: skip
        act = active[e, : counters[e, 1]]
        if t < horizon:  # seif_predict_env
            velocity_linearization(mean[e, 2], controls[e, 0], controls[e, 1], dt, alphas, floor, delta, jacobian,
                                   noise)  # fmt: skip
            predict(robot_info[e], robot_links[e], landmark_info[e], neighbour_index[e], neighbour_info[e],
                    neighbour_count[e], information_vector[e], mean[e], block_position[e], act, delta, jacobian,
                    noise)  # fmt: skip
            rewrap_heading(robot_info[e], robot_links[e], information_vector[e], mean[e], act)
            for a in range(3):
                poses[e, t, a] = mean[e, a]
            for i in range(n):
                dx[e, i] = landmark_x[i] - mean[e, 0]
                dy[e, i] = landmark_y[i] - mean[e, 1]
        else:  # SEIF.local_marginals with no landmark, SEIF.landmark_std
            nodes = blanket_nodes(act, no_targets, block_position[e])
            pose_cov, _ = blanket_covariances(robot_info[e], robot_links[e], landmark_info[e], neighbour_index[e],
                                              neighbour_info[e], neighbour_count[e], information_vector[e], mean[e],
                                              block_position[e], nodes, no_targets)  # fmt: skip
            pose_covariances[e] = pose_cov
            landmark_std[e] = conditional_std(landmark_info[e], n)
    return -1, 0


# -- the ConservativeSEIF's certified cut (seif_gym.slam.cseif) ---------------------------------------------------
@njit(cache=True)
def _sqrtm_2x2(a):
    """Symmetric square root of a 2 x 2 positive semidefinite matrix: ``(A + sqrt(det A) I) / sqrt(tr A + 2 sqrt(det A))``."""
    det = max(a[0, 0] * a[1, 1] - 0.5 * (a[0, 1] + a[1, 0]) * 0.5 * (a[0, 1] + a[1, 0]), 0.0)
    s = np.sqrt(det)
    t = np.sqrt(max(a[0, 0] + a[1, 1] + 2.0 * s, 0.0))
    out = np.zeros((2, 2))
    if t == 0.0:
        return out
    out[0, 0] = (a[0, 0] + s) / t
    out[1, 1] = (a[1, 1] + s) / t
    out[0, 1] = out[1, 0] = 0.5 * (a[0, 1] + a[1, 0]) / t
    return out


@njit(cache=True)
def _inverse_2x2(a):
    det = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    out = np.empty((2, 2))
    out[0, 0], out[1, 1] = a[1, 1] / det, a[0, 0] / det
    out[0, 1], out[1, 0] = -a[0, 1] / det, -a[1, 0] / det
    return out


@njit(cache=True)
def cut_cost(omega, local, position):
    """The certified cost ``c`` and the 5 x 2 factor ``u`` on (robot, landmark) of :func:`~seif_gym.slam.cseif.cut_direction`.

    Returns ``(c, u, weights)`` with ``weights = [Omega_B]_bb^-1 u``; ``c = inf`` when ``[Omega_B]_bb`` is not
    positive definite, ``c = 0`` (and ``u = 0``) when the link is already zero.
    """
    o = 3 + 2 * position
    rows = np.array([0, 1, 2, o, o + 1])
    u = np.zeros((5, 2))
    weights = np.zeros((5, 2))
    nonzero = False
    for a in range(3):
        for b in range(2):
            if omega[a, o + b] != 0.0:
                nonzero = True
    if not nonzero:
        return 0.0, u, weights
    block = np.empty((5, 5))
    for a in range(5):
        for b in range(5):
            block[a, b] = 0.5 * (local[rows[a], rows[b]] + local[rows[b], rows[a]])
    # Cholesky by hand (numba's raises a generic error): refuse a block that is not positive definite
    lower = np.zeros((5, 5))
    for j in range(5):
        d = block[j, j]
        for k in range(j):
            d -= lower[j, k] * lower[j, k]
        if not d > 0.0:
            return np.inf, u, weights
        lower[j, j] = np.sqrt(d)
        for i in range(j + 1, 5):
            v = block[i, j]
            for k in range(j):
                v -= lower[i, k] * lower[j, k]
            lower[i, j] = v / lower[j, j]
    inverse_lower = np.linalg.inv(lower)
    cov = np.ascontiguousarray(inverse_lower.T) @ inverse_lower
    link = np.empty((3, 2))
    for a in range(3):
        for b in range(2):
            link[a, b] = omega[a, o + b]
    m = np.ascontiguousarray(link.T) @ np.ascontiguousarray(cov[:3, :3]) @ link
    eps = 1e-12 * (m[0, 0] + m[1, 1])
    m[0, 0] += eps
    m[1, 1] += eps
    root_n = _sqrtm_2x2(np.ascontiguousarray(cov[3:, 3:]))
    if root_n[0, 0] * root_n[1, 1] - root_n[0, 1] * root_n[1, 0] <= 0.0:
        return np.inf, u, weights
    inverse_root_n = _inverse_2x2(root_n)
    d = inverse_root_n @ _sqrtm_2x2(root_n @ m @ root_n) @ inverse_root_n
    root_d = _sqrtm_2x2(0.5 * (d + d.T))
    if not root_d[0, 0] * root_d[1, 1] - root_d[0, 1] * root_d[1, 0] > 0.0:
        return np.inf, u, weights
    u[:3] = link @ _inverse_2x2(root_d)
    u[3:] = root_d
    weights = cov @ u
    g = np.ascontiguousarray(u.T) @ weights
    half_trace = 0.5 * (g[0, 0] + g[1, 1])
    off = 0.5 * (g[0, 1] + g[1, 0])
    cost = half_trace + np.sqrt(max(0.25 * (g[0, 0] - g[1, 1]) ** 2 + off * off, 0.0))
    if not np.isfinite(cost):
        return np.inf, u, weights
    return cost, u, weights


@njit(cache=True)
def cheapest_cut(omega, local, candidates):
    """The cheapest certified cut among the block positions ``candidates``: ``(position, factor, cost)``.

    ``factor`` is ``U`` of :func:`~seif_gym.slam.cseif.cut_direction` (``[Omega_B]_{:b} weights``, ``u`` on
    ``b``); ties keep the first candidate.
    """
    size = omega.shape[0]
    best, best_cost = -1, np.inf
    best_u = np.zeros((5, 2))
    best_weights = np.zeros((5, 2))
    for p in candidates:
        cost, u, weights = cut_cost(omega, local, p)
        if best < 0 or cost < best_cost:
            best, best_cost, best_u, best_weights = p, cost, u, weights
    factor = np.zeros((size, 2))
    if best < 0 or not np.isfinite(best_cost):
        return best, factor, best_cost
    o = 3 + 2 * best
    rows = np.array([0, 1, 2, o, o + 1])
    for r in range(size):
        for c in range(2):
            v = 0.0
            for a in range(5):
                v += local[r, rows[a]] * best_weights[a, c]
            factor[r, c] = v
    for a in range(5):
        for c in range(2):
            factor[rows[a], c] = best_u[a, c]
    return best, factor, best_cost


@njit(cache=True)
def apply_cut_block(omega, xi, mu, map_info, position, factor):
    """Compiled :func:`~seif_gym.slam.cseif.apply_cut`: ``(omega, xi, map_info)`` after the cut of ``position``.

    The same operations in the same order: ``S = U U^T``, ``Omega - S`` with the robot-``m0`` blocks
    set to zero and symmetrised, ``xi - S mu``, then ``A~ = A_kk + C E^-1 C^T`` (symmetrised) over the
    landmarks kept. The products and the 2 x 2 solve are numba's (BLAS and LAPACK calls).
    """
    size = xi.shape[0]
    o = 3 + 2 * position
    u = np.ascontiguousarray(factor)
    cut = u @ np.ascontiguousarray(u.T)
    cut_omega = omega - cut
    for a in range(3):
        for b in range(2):
            cut_omega[a, o + b] = 0.0
            cut_omega[o + b, a] = 0.0
    new_omega = np.empty((size, size))
    for a in range(size):
        for b in range(size):
            new_omega[a, b] = 0.5 * (cut_omega[a, b] + cut_omega[b, a])
    new_xi = xi - cut @ np.ascontiguousarray(mu)
    kept = np.empty(size - 5, dtype=np.int64)
    r = 0
    for a in range(3, size):
        if a != o and a != o + 1:
            kept[r] = a
            r += 1
    # Omega_B~ = Omega~ - (0 (+) A): its coupling C of the landmarks kept to m0, and E
    coupling = np.empty((size - 5, 2))
    for a in range(size - 5):
        for b in range(2):
            coupling[a, b] = new_omega[kept[a], o + b] - map_info[kept[a] - 3, o - 3 + b]
    own = np.empty((2, 2))
    for a in range(2):
        for b in range(2):
            own[a, b] = new_omega[o + a, o + b] - map_info[o - 3 + a, o - 3 + b]
    moved = coupling @ np.linalg.solve(own, np.ascontiguousarray(coupling.T))
    grown = np.empty((size - 5, size - 5))
    for a in range(size - 5):
        for b in range(size - 5):
            grown[a, b] = map_info[kept[a] - 3, kept[b] - 3] + moved[a, b]
    new_map_info = np.empty((size - 5, size - 5))
    for a in range(size - 5):
        for b in range(size - 5):
            new_map_info[a, b] = 0.5 * (grown[a, b] + grown[b, a])
    return new_omega, new_xi, new_map_info


# -- many ConservativeSEIFs in one call (seif_gym.slam.batched.BatchedConservativeSEIF) ------------------------------
@njit(cache=True)
def _cseif_kept(is_active, active_count, id_to_index, ranges, measured, max_active_hard):
    """``ConservativeSEIF._within_hard_bound`` as a mask (all ``True``: every measurement kept).

    The active landmarks' measurements stay; of the others, mapped ones first, then the nearest, as
    many as keep at most ``max(max_active_hard, m)`` landmarks active (``max_active_hard < 0``: no bound).
    """
    m = measured.shape[0]
    kept = np.ones(m, dtype=np.bool_)
    if max_active_hard < 0 or m == 0:
        return kept
    mapped = np.zeros(m, dtype=np.bool_)
    active = np.zeros(m, dtype=np.bool_)
    joining = 0
    for k in range(m):
        index = id_to_index[measured[k]]
        mapped[k] = index >= 0
        if mapped[k]:
            active[k] = is_active[index]
        if not active[k]:
            joining += 1
    room = max(max_active_hard, m) - active_count  # the ids of one update are distinct
    if joining <= room:
        return kept
    return _keep_within_bound(active, mapped, ranges, room)


@njit(cache=True)
def _cseif_sparsify(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                    information_vector, mean, block_position, active, counters, is_active, last_observed, max_active,
                    cut_budget, map_info, cseif_counters):  # fmt: skip
    """``ConservativeSEIF._sparsify`` (compiled): the cheapest certified cuts until ``max_active`` remain.

    ``map_info[:2a, :2a]`` is ``A`` over the ``a`` active landmarks; ``cseif_counters[0]`` counts the
    cuts, ``cseif_counters[1]`` the updates whose cuts were deferred (all updated in place).
    """
    if max_active < 0:
        return
    update_count = counters[2]
    deferred = False
    while counters[1] > max_active:
        count = counters[1]
        act = active[:count].copy()
        candidates = np.empty(count, dtype=np.int64)
        c = 0
        for p in range(count):
            if last_observed[act[p]] != update_count:
                candidates[c] = p
                c += 1
        if c == 0:
            break
        omega, xi, mu = gather(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                               neighbour_count, information_vector, mean, block_position, act)  # fmt: skip
        dim = 2 * count
        current = np.ascontiguousarray(map_info[:dim, :dim])
        local = omega.copy()
        for a in range(dim):
            for b in range(dim):
                local[3 + a, 3 + b] -= current[a, b]
        position, factor, cost = cheapest_cut(omega, local, candidates[:c].copy())
        if not cost <= cut_budget:
            deferred = True
            break
        omega, xi, new_map_info = apply_cut_block(omega, xi, mu, current, position, factor)
        scatter(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                information_vector, act, omega, xi)  # fmt: skip
        for p in range(position, count - 1):
            active[p] = active[p + 1]
        is_active[act[position]] = False
        counters[1] = count - 1
        map_info[: dim - 2, : dim - 2] = new_map_info
        cseif_counters[0] += 1
    if deferred:
        cseif_counters[1] += 1


@njit(cache=True)
def cseif_update_one(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                     information_vector, mean, block_position, active, counters, is_active, last_observed,
                     id_to_index, ids, queue, queued, queue_state, ranges, bearings, measured, noise_info,
                     max_active, max_active_hard, cut_budget, recovery_landmarks, budget, relaxation, tolerance,
                     map_info, cseif_counters):  # fmt: skip
    """``ConservativeSEIF.update_trusted`` (known ids, wavefront recovery, compiled) of one filter of a batch.

    ``counters`` as for :func:`seif_update_one`; ``map_info[:2a, :2a]`` is ``A`` over the ``a`` active
    landmarks; ``cseif_counters = [cuts, deferred cuts, discarded measurements]`` (all updated in place).
    The filter's steps in its order: the hard bound's mask, the new landmarks, the measurement update
    (a landmark that becomes active brings its rows of ``Omega`` into ``A``), the wavefront recovery,
    the certified cuts.
    """
    kept = _cseif_kept(is_active, counters[1], id_to_index, ranges, measured, max_active_hard)
    use = np.flatnonzero(kept)
    z_range = ranges[use]
    z_bearing = bearings[use]
    z_id = measured[use]
    indices = _map_ids(mean, counters, id_to_index, ids, z_range, z_bearing, z_id)
    counters[2] += 1
    old = counters[1]
    joining = 0
    dim = 0
    grown = np.empty((0, 0))
    if indices.shape[0] > 0 and max_active >= 0:
        for k in range(indices.shape[0]):
            if not is_active[indices[k]]:
                joining += 1
    if joining > 0:
        # A grows by the joining landmarks' rows of Omega before the update (all of them in Omega_A)
        block = np.empty(old + joining, dtype=np.int64)
        block[:old] = active[:old]
        q = old
        for k in range(indices.shape[0]):
            if not is_active[indices[k]]:
                block[q] = indices[k]
                q += 1
        omega, _, _ = gather(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                             neighbour_count, information_vector, mean, block_position, block)  # fmt: skip
        dim = 2 * (old + joining)
        grown = omega[3:, 3:].copy()
        grown[: 2 * old, : 2 * old] = map_info[: 2 * old, : 2 * old]
    _incorporate_one(robot_info, robot_links, landmark_info, information_vector, mean, active, counters, is_active,
                     last_observed, indices, z_range, z_bearing, noise_info)  # fmt: skip
    if joining > 0:
        map_info[:dim, :dim] = grown
    _recover_one(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                 information_vector, mean, block_position, active, counters, is_active, queue, queued, queue_state,
                 recovery_landmarks, budget, relaxation, tolerance)  # fmt: skip
    _cseif_sparsify(robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                    information_vector, mean, block_position, active, counters, is_active, last_observed, max_active,
                    cut_budget, map_info, cseif_counters)  # fmt: skip
    cseif_counters[2] += kept.shape[0] - use.shape[0]


@njit(cache=True)
def cseif_update_env(e, robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
                     information_vector, mean, block_position, active, counters, is_active, last_observed,
                     id_to_index, ids, queue, queued, queue_state, ranges, bearings, measured, measured_count,
                     noise_info, max_active, max_active_hard, cut_budget, recovery_landmarks, budget, relaxation,
                     tolerance, map_info, cseif_counters):  # fmt: skip
    """:func:`cseif_update_one` of filter ``e`` of a batch, with its first ``measured_count[e]`` measurements."""
    m = measured_count[e]
    cseif_update_one(robot_info[e], robot_links[e], landmark_info[e], neighbour_index[e], neighbour_info[e],
                     neighbour_count[e], information_vector[e], mean[e], block_position[e], active[e], counters[e],
                     is_active[e], last_observed[e], id_to_index[e], ids[e], queue[e], queued[e], queue_state[e],
                     ranges[e, :m], bearings[e, :m], measured[e, :m], noise_info, max_active, max_active_hard,
                     cut_budget, recovery_landmarks, budget, relaxation, tolerance, map_info[e],
                     cseif_counters[e])  # fmt: skip


@njit(cache=True)
def cseif_update_many(*arguments):
    """:func:`cseif_update_env` of every filter of a batch, one after another.

    ``arguments``: those of :func:`cseif_update_env` after ``e`` (the first one has the env axis).
    """
    for e in range(arguments[0].shape[0]):
        cseif_update_env(e, *arguments)
