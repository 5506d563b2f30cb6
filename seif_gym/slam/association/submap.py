"""Map geometry for revising the association: rigid sub-map matches and the sensor's coverage.

:func:`rigid_submap_match` finds the duplicates that step 8 of :mod:`seif_gym.slam.association` merges;
:class:`CoverageGrid` counts the scans that had a place well inside their footprint (step 5).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from seif_gym.type_aliases import FloatArray
from seif_gym.validation import as_finite_array, as_positive_scalar

if TYPE_CHECKING:  # for annotations only
    from seif_gym.slam.models import RangeBearingSensor

__all__ = ["CoverageGrid", "rigid_submap_match"]


def rigid_submap_match(
    recent: FloatArray, old: FloatArray, tolerance: float, max_rotation: float, max_shift: float
) -> tuple[list[tuple[int, int]], int]:
    """The rigid motion that lays most of ``recent`` onto ``old``, within the drift bounds.

    Every pair of ``recent`` points (more than 1 m apart) is matched with
    every pair of ``old`` points at the same distance (within ``tolerance``),
    both ways round; each such match fixes a rotation and a translation. One
    is kept when its rotation is within ``max_rotation`` (radians) and it
    moves the centroid of ``recent`` by at most ``max_shift`` (metres): a
    loop's drift, not an arbitrary motion. Its inliers are the ``recent``
    points that land within ``tolerance`` of an ``old`` one, one to one.

    Parameters
    ----------
    recent, old : ndarray, shape (a, 2), (b, 2)
        Estimated positions: landmarks started lately, and landmarks mapped
        long ago, near the robot.
    tolerance, max_rotation, max_shift : float
        As above.

    Returns
    -------
    pairs : list of (int, int)
        ``(row of recent, row of old)`` of the best hypothesis's inliers.
    second : int
        Inliers of the best hypothesis that shares no pair with it (how
        distinctive the match is).

    Raises
    ------
    TypeError, ValueError
        Naming the argument: points that are not finite ``(n, 2)`` arrays,
        bounds that are not positive finite numbers.
    """
    recent, old = as_finite_array(recent, "recent", (None, 2)), as_finite_array(old, "old", (None, 2))
    tolerance = as_positive_scalar(tolerance, "tolerance")
    max_rotation = as_positive_scalar(max_rotation, "max_rotation")
    max_shift = as_positive_scalar(max_shift, "max_shift")
    if len(recent) < 2 or len(old) < 2:
        return [], 0
    ri, rj = np.triu_indices(len(recent), 1)
    oi, oj = np.triu_indices(len(old), 1)
    recent_gap = np.linalg.norm(recent[ri] - recent[rj], axis=1)
    old_gap = np.linalg.norm(old[oi] - old[oj], axis=1)
    wide = recent_gap > 1.0
    ri, rj, recent_gap = ri[wide], rj[wide], recent_gap[wide]
    a, b = np.nonzero(np.abs(recent_gap[:, None] - old_gap[None, :]) < tolerance)
    if len(a) == 0:
        return [], 0
    # both orientations of each old pair
    start = np.concatenate([recent[ri[a]], recent[ri[a]]])
    end = np.concatenate([recent[rj[a]], recent[rj[a]]])
    to_start = np.concatenate([old[oi[b]], old[oj[b]]])
    to_end = np.concatenate([old[oj[b]], old[oi[b]]])
    u, v = end - start, to_end - to_start
    rotation = np.arctan2(v[:, 1], v[:, 0]) - np.arctan2(u[:, 1], u[:, 0])
    rotation = (rotation + np.pi) % (2.0 * np.pi) - np.pi
    cos, sin = np.cos(rotation), np.sin(rotation)
    shift = to_start - np.column_stack([cos * start[:, 0] - sin * start[:, 1], sin * start[:, 0] + cos * start[:, 1]])
    centre = recent.mean(axis=0)
    moved_centre = np.column_stack([cos * centre[0] - sin * centre[1], sin * centre[0] + cos * centre[1]]) + shift
    plausible = (np.abs(rotation) <= max_rotation) & (np.hypot(*(moved_centre - centre).T) <= max_shift)
    hypotheses: list[tuple[int, frozenset[tuple[int, int]]]] = []
    for h in np.flatnonzero(plausible).tolist():
        moved = recent @ np.array([[cos[h], sin[h]], [-sin[h], cos[h]]]) + shift[h]
        distance = np.linalg.norm(moved[:, None, :] - old[None, :, :], axis=2)
        nearest = distance.argmin(axis=1)
        close = np.flatnonzero(distance[np.arange(len(recent)), nearest] < tolerance)
        if len(np.unique(nearest[close])) < len(close):
            continue  # two recent landmarks on one old one: not a rigid copy
        hypotheses.append((len(close), frozenset(zip(close.tolist(), nearest[close].tolist()))))
    if not hypotheses:
        return [], 0
    hypotheses.sort(key=lambda item: -item[0])
    best = hypotheses[0][1]
    second = max((count for count, pairs in hypotheses if not pairs & best), default=0)
    return sorted(best), second


class CoverageGrid:
    """How often each cell of a uniform grid lay well inside the sensor's footprint (a dict of cells).

    A cell counts once per scan when its centre is within ``max_range - margin`` of the estimated
    pose and ``fov / 2`` of the heading (``margin`` the larger of 1 m and 20% of the range, so that
    the pose error does not count cells at the footprint's edge). A landmark in a cell seen ``c``
    times that is still not in the map is unlikely: each of those scans would have detected it.
    Cost per scan: the cells of one footprint (bounded), whatever the size of the map.
    """

    def __init__(self) -> None:
        self.cells: dict[tuple[int, int], int] = {}
        self.cell = 0.0

    def _setup(self, sensor: RangeBearingSensor) -> None:
        self.cell = max(1.0, float(sensor.max_range) / 10.0)

    def add_scan(self, pose: FloatArray, sensor: RangeBearingSensor) -> None:
        """Count the cells well inside the footprint of a scan from ``pose``."""
        if not self.cell:
            self._setup(sensor)
        reach = float(sensor.max_range) - max(1.0, 0.2 * float(sensor.max_range))
        if reach <= 0.0:
            return
        c = self.cell
        low = np.floor((pose[:2] - reach) / c).astype(np.int64)
        high = np.floor((pose[:2] + reach) / c).astype(np.int64)
        ix, iy = np.meshgrid(np.arange(low[0], high[0] + 1), np.arange(low[1], high[1] + 1), indexing="ij")
        dx = (ix + 0.5) * c - pose[0]
        dy = (iy + 0.5) * c - pose[1]
        inside = dx * dx + dy * dy <= reach * reach
        half_fov = 0.5 * float(getattr(sensor, "fov", 2.0 * math.pi))
        if half_fov < math.pi:
            inside &= np.abs((np.arctan2(dy, dx) - pose[2] + np.pi) % (2.0 * np.pi) - np.pi) <= half_fov
        cells = self.cells
        for key in zip(ix[inside].tolist(), iy[inside].tolist()):
            cells[key] = cells.get(key, 0) + 1

    def counts(self, points: FloatArray) -> FloatArray:
        """How many scans covered the cell of each point (0 before any scan)."""
        if not self.cell:
            return np.zeros(len(points))
        keys = np.floor(np.asarray(points) / self.cell).astype(np.int64).tolist()
        return np.array([self.cells.get((a, b), 0) for a, b in keys], dtype=np.float64)
