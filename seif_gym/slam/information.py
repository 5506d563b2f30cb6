"""Sparse storage of the SEIF's information matrix and vector.

The information matrix ``Omega`` of a SEIF is sparse by construction: the
robot is linked only to its *active* landmarks, and a landmark only to the
landmarks it was once active together with. :class:`InformationStore` keeps
exactly those blocks, in flat arrays that compiled kernels can read, so that a
step costs time in the size of the active set and memory is linear in the map:

==========================  =====================  ==============================================
array                       shape                  holds
==========================  =====================  ==============================================
``robot_info``              (3, 3)                 ``Omega_xx``
``robot_links``             (capacity, 3, 2)       ``Omega_{x, m_i}`` (zero unless ``i`` active)
``landmark_info``           (capacity, 2, 2)       ``Omega_{m_i, m_i}``
``neighbour_index``         (capacity, degree)     ``j`` of each stored ``Omega_{m_i, m_j}``, -1 empty
``neighbour_info``          (capacity, degree,     ``Omega_{m_i, m_j}`` (both ``(i, j)`` and
                            2, 2)                  ``(j, i)`` are stored)
``neighbour_count``         (capacity,)            number of stored neighbours of ``m_i``
``information_vector``      (3 + 2 capacity,)      ``xi``
``mean``                    (3 + 2 capacity,)      ``mu`` (the filter's current estimate)
==========================  =====================  ==============================================

Landmarks are numbered ``0 .. n-1`` in the order they entered the state; the
state vector is ``(x, y, theta, m_0x, m_0y, m_1x, ...)``. ``degree`` (the most
neighbours any landmark has) and ``capacity`` grow by doubling when needed.

``gather`` and ``scatter`` below are the plain reference versions of moving a
dense block over the robot and some landmarks out of and back into the store;
:mod:`seif_gym.slam._kernels` holds compiled versions tested equal to them.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse

from seif_gym.type_aliases import FloatArray, IntArray

__all__ = ["InformationStore", "block_slices"]


def block_slices(count: int) -> list[slice]:
    """Slices of the robot and ``count`` landmarks in a gathered dense block."""
    return [slice(0, 3)] + [slice(3 + 2 * p, 5 + 2 * p) for p in range(count)]


class InformationStore:
    """Block-sparse ``Omega``, ``xi`` and ``mu`` of a SLAM information filter."""

    def __init__(self, capacity: int = 64, degree: int = 16) -> None:
        self.num_landmarks = 0
        self.robot_info: FloatArray = np.zeros((3, 3))
        self.robot_links: FloatArray = np.zeros((capacity, 3, 2))
        self.landmark_info: FloatArray = np.zeros((capacity, 2, 2))
        self.neighbour_index: IntArray = np.full((capacity, degree), -1, dtype=np.int64)
        self.neighbour_info: FloatArray = np.zeros((capacity, degree, 2, 2))
        self.neighbour_count: IntArray = np.zeros(capacity, dtype=np.int64)
        self.information_vector: FloatArray = np.zeros(3 + 2 * capacity)
        self.mean: FloatArray = np.zeros(3 + 2 * capacity)
        # scratch for the kernels: position of a landmark in the current block, -1 if absent
        self.block_position: IntArray = np.full(capacity, -1, dtype=np.int64)

    # -- capacity ------------------------------------------------------------
    @property
    def capacity(self) -> int:
        return self.landmark_info.shape[0]

    @property
    def degree(self) -> int:
        return self.neighbour_index.shape[1]

    def reserve_landmarks(self, count: int) -> None:
        """Make room for ``count`` landmarks in total (doubling growth)."""
        if count <= self.capacity:
            return
        capacity = max(count, 2 * self.capacity)
        n = self.num_landmarks

        def grow(array: np.ndarray, fill: int = 0) -> np.ndarray:
            grown = np.full((capacity,) + array.shape[1:], fill, dtype=array.dtype)
            grown[:n] = array[:n]
            return grown

        self.robot_links = grow(self.robot_links)
        self.landmark_info = grow(self.landmark_info)
        self.neighbour_index = grow(self.neighbour_index, -1)
        self.neighbour_info = grow(self.neighbour_info)
        self.neighbour_count = grow(self.neighbour_count)
        self.block_position = np.full(capacity, -1, dtype=np.int64)
        for name in ("information_vector", "mean"):
            old = getattr(self, name)
            new = np.zeros(3 + 2 * capacity)
            new[: 3 + 2 * n] = old[: 3 + 2 * n]
            setattr(self, name, new)

    def reserve_degree(self, landmarks: IntArray, extra: int) -> None:
        """Make sure each of ``landmarks`` can take ``extra`` more neighbours."""
        if len(landmarks) == 0:
            return
        needed = int(self.neighbour_count[landmarks].max()) + extra
        if needed <= self.degree:
            return
        degree = max(needed, 2 * self.degree)
        index = np.full((self.capacity, degree), -1, dtype=np.int64)
        info = np.zeros((self.capacity, degree, 2, 2))
        index[:, : self.degree] = self.neighbour_index
        info[:, : self.degree] = self.neighbour_info
        self.neighbour_index, self.neighbour_info = index, info

    def add_landmarks(self, positions: FloatArray) -> None:
        """Append landmarks with zero information at ``positions`` (m, 2)."""
        count = len(positions)
        self.reserve_landmarks(self.num_landmarks + count)
        n = self.num_landmarks
        self.mean[3 + 2 * n : 3 + 2 * (n + count)] = positions.reshape(-1)
        self.num_landmarks = n + count

    # -- views ---------------------------------------------------------------
    @property
    def state_dim(self) -> int:
        return 3 + 2 * self.num_landmarks

    def mean_view(self) -> FloatArray:
        return self.mean[: self.state_dim]

    def information_vector_view(self) -> FloatArray:
        return self.information_vector[: self.state_dim]

    def nbytes(self) -> int:
        arrays = (
            self.robot_info,
            self.robot_links,
            self.landmark_info,
            self.neighbour_index,
            self.neighbour_info,
            self.neighbour_count,
            self.information_vector,
            self.mean,
            self.block_position,
        )
        return int(sum(a.nbytes for a in arrays))

    def copy(self) -> InformationStore:
        clone = InformationStore.__new__(InformationStore)
        for name, value in vars(self).items():
            setattr(clone, name, value.copy() if isinstance(value, np.ndarray) else value)
        return clone

    # -- reference gather / scatter ------------------------------------------
    def kernel_arrays(self) -> tuple[FloatArray, FloatArray, FloatArray, IntArray, FloatArray, IntArray, FloatArray,
                                     FloatArray, IntArray]:  # fmt: skip
        """The arrays the compiled kernels of :mod:`seif_gym.slam._kernels` take first, in their order.

        ``robot_info, robot_links, landmark_info, neighbour_index, neighbour_info, neighbour_count,
        information_vector, mean, block_position`` (the current arrays: growth replaces them).
        """
        return (self.robot_info, self.robot_links, self.landmark_info, self.neighbour_index, self.neighbour_info,
                self.neighbour_count, self.information_vector, self.mean, self.block_position)  # fmt: skip

    def find_neighbour(self, i: int, j: int) -> int:
        """Slot of ``j`` in ``i``'s neighbour list, or -1."""
        slots = np.flatnonzero(self.neighbour_index[i, : self.neighbour_count[i]] == j)
        return int(slots[0]) if len(slots) else -1

    def gather(self, landmarks: IntArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Dense ``Omega``, ``xi`` and ``mu`` over the robot and ``landmarks``.

        The block is ordered robot first, then ``landmarks`` in the given order.
        """
        slices = block_slices(len(landmarks))
        size = 3 + 2 * len(landmarks)
        omega = np.zeros((size, size))
        omega[slices[0], slices[0]] = self.robot_info
        xi = np.empty(size)
        mu = np.empty(size)
        xi[:3], mu[:3] = self.information_vector[:3], self.mean[:3]
        for p, i in enumerate(landmarks, start=1):
            omega[slices[0], slices[p]] = self.robot_links[i]
            omega[slices[p], slices[0]] = self.robot_links[i].T
            omega[slices[p], slices[p]] = self.landmark_info[i]
            xi[slices[p]] = self.information_vector[3 + 2 * i : 5 + 2 * i]
            mu[slices[p]] = self.mean[3 + 2 * i : 5 + 2 * i]
            for q, j in enumerate(landmarks, start=1):
                if q != p:
                    slot = self.find_neighbour(i, j)
                    if slot >= 0:
                        omega[slices[p], slices[q]] = self.neighbour_info[i, slot]
        return omega, xi, mu

    def scatter(self, landmarks: IntArray, omega: FloatArray, xi: FloatArray) -> None:
        """Write a dense block over the robot and ``landmarks`` back.

        Landmark-landmark links that are exactly zero and not stored yet stay
        unstored; stored links keep their slot even when they become zero.
        """
        self.reserve_degree(np.asarray(landmarks, dtype=np.int64), len(landmarks))
        slices = block_slices(len(landmarks))
        self.robot_info[:] = omega[slices[0], slices[0]]
        self.information_vector[:3] = xi[:3]
        for p, i in enumerate(landmarks, start=1):
            self.robot_links[i] = omega[slices[0], slices[p]]
            self.landmark_info[i] = omega[slices[p], slices[p]]
            self.information_vector[3 + 2 * i : 5 + 2 * i] = xi[slices[p]]
            for q, j in enumerate(landmarks, start=1):
                if q == p:
                    continue
                block = omega[slices[p], slices[q]]
                slot = self.find_neighbour(i, j)
                if slot < 0:
                    if not np.any(block):
                        continue
                    slot = int(self.neighbour_count[i])
                    self.neighbour_index[i, slot] = j
                    self.neighbour_count[i] += 1
                self.neighbour_info[i, slot] = block

    # -- merging two landmarks ------------------------------------------------------
    def _unlink(self, owner: int, other: int) -> None:
        """Drop ``other`` from ``owner``'s neighbour list (the last entry takes its slot)."""
        slot = self.find_neighbour(owner, other)
        if slot < 0:
            return
        last = int(self.neighbour_count[owner]) - 1
        self.neighbour_index[owner, slot] = self.neighbour_index[owner, last]
        self.neighbour_info[owner, slot] = self.neighbour_info[owner, last]
        self.neighbour_index[owner, last] = -1
        self.neighbour_info[owner, last] = 0.0
        self.neighbour_count[owner] = last

    def _add_link(self, owner: int, other: int, block: FloatArray) -> None:
        """``Omega_{owner, other} += block`` (stored in ``owner``'s list; room reserved by the caller)."""
        slot = self.find_neighbour(owner, other)
        if slot < 0:
            slot = int(self.neighbour_count[owner])
            self.neighbour_index[owner, slot] = other
            self.neighbour_count[owner] += 1
        self.neighbour_info[owner, slot] += block

    def merge(self, keep: int, remove: int) -> None:
        """``Omega <- P^T Omega P``, ``xi <- P^T xi`` for ``m_keep = m_remove``, then swap-remove ``remove``.

        ``remove``'s robot link, diagonal block, links and information vector
        are added to ``keep``'s (``keep``'s diagonal also takes the link between
        the two, both ways); the last landmark then moves into ``remove``'s
        place. Time in the neighbour counts of the two landmarks and of the
        last one; ``keep``'s mean is left as it was (the filter's recovery
        moves it).
        """
        i, j = keep, remove
        count = int(self.neighbour_count[j])
        neighbours = self.neighbour_index[j, :count].copy()
        blocks = self.neighbour_info[j, :count].copy()  # Omega_{j, k}
        # room first (growth keeps the contents), so that nothing below can fail half-way
        self.reserve_degree(np.array([i], dtype=np.int64), count)
        self.reserve_degree(neighbours, 1)
        diagonal = self.landmark_info[i] + self.landmark_info[j]
        for k, block in zip(neighbours.tolist(), blocks):
            if k == i:
                diagonal = diagonal + block + block.T  # Omega_{j,i} + Omega_{i,j}
                continue
            self._add_link(i, k, block)
            self._add_link(k, i, block.T)
            self._unlink(k, j)
        self._unlink(i, j)
        self.landmark_info[i] = 0.5 * (diagonal + diagonal.T)
        self.robot_links[i] += self.robot_links[j]
        self.information_vector[3 + 2 * i : 5 + 2 * i] += self.information_vector[3 + 2 * j : 5 + 2 * j]
        self.neighbour_count[j] = 0
        self.neighbour_index[j] = -1
        self.swap_remove(j)

    def swap_remove(self, remove: int) -> None:
        """Delete landmark ``remove``, which must have no links left; the last landmark takes its index."""
        last = self.num_landmarks - 1
        if remove != last:
            for k in self.neighbour_index[last, : self.neighbour_count[last]].tolist():
                self.neighbour_index[k, self.find_neighbour(k, last)] = remove
            for array in (self.robot_links, self.landmark_info, self.neighbour_index, self.neighbour_info,
                          self.neighbour_count):  # fmt: skip
                array[remove] = array[last]
            for vector in (self.information_vector, self.mean):
                vector[3 + 2 * remove : 5 + 2 * remove] = vector[3 + 2 * last : 5 + 2 * last]
        self.robot_links[last] = 0.0
        self.landmark_info[last] = 0.0
        self.neighbour_index[last] = -1
        self.neighbour_info[last] = 0.0
        self.neighbour_count[last] = 0
        self.information_vector[3 + 2 * last : 5 + 2 * last] = 0.0
        self.mean[3 + 2 * last : 5 + 2 * last] = 0.0
        self.num_landmarks = last

    # -- export ----------------------------------------------------------------
    def to_sparse(self) -> scipy.sparse.csr_array:
        """``Omega`` as a ``scipy.sparse.csr_array`` in state order (O(nnz), vectorised)."""
        n = self.num_landmarks
        size = self.state_dim
        two = np.arange(2)
        rows, cols, vals = [], [], []

        def add(r: np.ndarray, c: np.ndarray, v: np.ndarray) -> None:
            keep = v != 0.0
            rows.append(r[keep])
            cols.append(c[keep])
            vals.append(v[keep])

        # robot block
        add(np.repeat(np.arange(3), 3), np.tile(np.arange(3), 3), self.robot_info.ravel())
        if n:
            offsets = 3 + 2 * np.arange(n)
            # robot-landmark links (3 x 2 per landmark) and their transposes
            link_rows = np.broadcast_to(np.arange(3)[None, :, None], (n, 3, 2))
            link_cols = np.broadcast_to(offsets[:, None, None] + two[None, None, :], (n, 3, 2))
            links = self.robot_links[:n]
            add(link_rows.ravel(), link_cols.ravel(), links.ravel())
            add(link_cols.ravel(), link_rows.ravel(), links.ravel())
            # landmark diagonal blocks
            diag_rows = np.broadcast_to(offsets[:, None, None] + two[None, :, None], (n, 2, 2))
            diag_cols = np.broadcast_to(offsets[:, None, None] + two[None, None, :], (n, 2, 2))
            add(diag_rows.ravel(), diag_cols.ravel(), self.landmark_info[:n].ravel())
            # landmark-landmark links
            counts = self.neighbour_count[:n]
            owner, slot = np.nonzero(np.arange(self.degree)[None, :] < counts[:, None])
            other = self.neighbour_index[owner, slot]
            r = 3 + 2 * owner[:, None, None] + two[None, :, None]
            c = 3 + 2 * other[:, None, None] + two[None, None, :]
            add(np.broadcast_to(r, (len(owner), 2, 2)).ravel(), np.broadcast_to(c, (len(owner), 2, 2)).ravel(),
                self.neighbour_info[owner, slot].ravel())  # fmt: skip
        matrix = scipy.sparse.coo_array(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(size, size)
        )
        return matrix.tocsr()
