"""Covariances for data association in a SEIF that reach across the map: a breadth-first block.

The SEIF's own :meth:`~seif_gym.slam.seif.SEIF.local_joint_covariance` inverts
the information block over the robot, its active landmarks, the candidates
and their direct neighbours: the covariance *conditioned on the rest of the
map*. For a landmark mapped a loop ago that conditioning removes most of the
uncertainty between it and the robot (the chain of landmarks along the loop
that carries it is held fixed), the innovation covariance is far too tight,
and the landmark's own measurements look like new landmarks (duplicates).

:func:`breadth_first_joint_covariance` grows the block instead by a
breadth-first search through ``Omega``'s links, from the robot's active
landmarks and from the candidates at once (one ring of each in turn), until
the block holds ``max_landmarks`` landmarks or both searches are exhausted:
the links that connect old landmarks to the robot are in the block, and what
is conditioned on are the landmarks farthest (in links) from both. The block
is bounded (``max_landmarks``), so is the cost (one dense Cholesky factor of
at most ``3 + 2 max_landmarks`` rows), whatever the size of the map; with a
block holding the whole map the covariance is exact.

This module reads the SEIF's private state (``filt._store``, an
:class:`~seif_gym.slam.information.InformationStore`, and ``filt._active``,
the state orders of the active landmarks) and never writes it (the store's
``block_position`` scratch array is restored to all -1 by the compiled
gather it calls).
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING, Protocol, TypeGuard

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

from seif_gym.slam import _kernels
from seif_gym.type_aliases import FloatArray, IntArray
from seif_gym.validation import as_count

if TYPE_CHECKING:  # for annotations only
    from seif_gym.slam.information import InformationStore

__all__ = ["breadth_first_nodes", "breadth_first_joint_covariance", "supports_breadth_first"]


class _StoreFilter(Protocol):
    """What :func:`breadth_first_joint_covariance` reads of a SEIF-type filter."""

    _store: InformationStore
    _active: IntArray


def supports_breadth_first(filt: object) -> TypeGuard[_StoreFilter]:
    """Whether ``filt`` keeps a SEIF-type information store (``_store`` and ``_active``)."""
    return hasattr(filt, "_store") and hasattr(filt, "_active")


def breadth_first_nodes(store: InformationStore, active: IntArray, targets: IntArray, max_landmarks: int) -> IntArray:
    """Landmarks of the block: ``active`` and ``targets`` first, then breadth-first rings through ``Omega``.

    The two searches (from the active landmarks, from the targets) advance one
    ring each in turn; a ring is cut short when the block is full. Returns
    state orders, each once, at most ``max(max_landmarks, len(active ∪ targets))``.
    """
    as_count(max_landmarks, "max_landmarks")
    chosen: dict[int, None] = dict.fromkeys(int(i) for i in np.concatenate([active, targets]).tolist())
    fronts = [deque(int(i) for i in active.tolist()), deque(int(i) for i in targets.tolist())]
    index, count = store.neighbour_index, store.neighbour_count
    while len(chosen) < max_landmarks and any(fronts):
        for side, front in enumerate(fronts):
            ring: deque[int] = deque()
            while front and len(chosen) < max_landmarks:
                i = front.popleft()
                for j in index[i, : count[i]].tolist():
                    if j not in chosen:
                        chosen[j] = None
                        ring.append(j)
                        if len(chosen) >= max_landmarks:
                            break
            fronts[side] = ring
    return np.fromiter(chosen, dtype=np.int64, count=len(chosen))


def breadth_first_joint_covariance(
    filt: _StoreFilter, landmark_indices: ArrayLike, max_landmarks: int = 128
) -> FloatArray:
    """Joint covariance of the pose and ``landmark_indices`` from a breadth-first block of ``filt``'s ``Omega``.

    Parameters
    ----------
    filt : SEIF or ESEIF
        A filter with an information store (:func:`supports_breadth_first`).
    landmark_indices : array_like of int
        State orders (0-based) of the landmarks.
    max_landmarks : int
        Size bound of the block (:func:`breadth_first_nodes`).

    Returns
    -------
    ndarray, shape (3 + 2k, 3 + 2k)
        Covariance over ``(x, y, theta, m_i1, m_i2, ...)``, conditioned on the
        landmarks outside the block (exact when the block holds the whole map).
    """
    if not supports_breadth_first(filt):
        raise TypeError(f"filt must be a SEIF-type filter with an information store, got {type(filt).__name__}")
    targets = np.asarray(landmark_indices)
    if targets.ndim != 1 or (targets.size and not np.issubdtype(targets.dtype, np.integer)):
        raise TypeError("landmark_indices must be a one-dimensional array of ints")
    targets = targets.astype(np.int64)
    store = filt._store
    if targets.size and (targets.min() < 0 or targets.max() >= store.num_landmarks):
        raise ValueError(f"landmark_indices must lie in [0, {store.num_landmarks}), got {targets.tolist()}")
    nodes = breadth_first_nodes(store, np.asarray(filt._active, dtype=np.int64), targets, max_landmarks)
    omega, _, _ = _kernels.gather(*store.kernel_arrays(), nodes)
    position = {int(i): p for p, i in enumerate(nodes.tolist())}
    rows = np.concatenate([np.arange(3)] + [3 + 2 * position[int(i)] + np.arange(2) for i in targets.tolist()])
    unit = np.zeros((omega.shape[0], len(rows)))
    unit[rows, np.arange(len(rows))] = 1.0
    factor = scipy.linalg.cho_factor(omega, lower=True)
    cov = scipy.linalg.cho_solve(factor, unit)[rows]
    return 0.5 * (cov + cov.T)
