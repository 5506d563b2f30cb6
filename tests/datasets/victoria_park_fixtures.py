"""A small synthetic Victoria Park log in the layout of ``victoria_park.npz``, written by the tests themselves.

The car drives one loop of about 200 m (the car model of
:class:`~seif_gym.slam.car_model.AckermannLaserModel`, 40 Hz odometry with a
little noise) among ~40 trees; the laser (every 200 ms, 180 degrees, 40 m)
reports each tree's range, bearing (laser frame, 0 ... pi from the right) and
diameter with small noise, and the GPS (5 Hz) the true laser position with
5 cm noise. Same array names, dtypes, units and clock as the real file.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from seif_gym.slam.car_model import AckermannLaserModel

#: Where the synthetic loop starts (the runner starts at the first GPS fix, heading 36 degrees).
START = (100.0, 50.0, math.radians(36.0))


def synthetic_arrays(seconds: float = 52.0, seed: int = 0) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """``(arrays, trees)``: the arrays of a ``victoria_park.npz`` and the true tree positions (k, 2)."""
    rng = np.random.default_rng(seed)
    model = AckermannLaserModel()
    steps = int(seconds / 0.025)
    odo_time_ms = 20_000 + 25 * np.arange(steps, dtype=np.int64)
    speed, steering = np.full(steps, 4.0), np.full(steps, 0.09)  # a circle of about 31 m radius
    poses = np.empty((steps, 3))
    poses[0] = START
    for i in range(1, steps):
        poses[i] = model.predict(poses[i - 1], np.array([speed[i - 1], steering[i - 1]]), 0.025)
    # trees 6-14 m beside the path, at least 5 m apart
    trees: list[np.ndarray] = []
    for i in range(0, steps, 40):
        x, y, heading = poses[i]
        side = rng.choice([-1.0, 1.0]) * rng.uniform(6.0, 14.0)
        tree = np.array([x - side * math.sin(heading), y + side * math.cos(heading)])
        if all(np.hypot(*(tree - other)) >= 5.0 for other in trees):
            trees.append(tree)
    tree_xy = np.array(trees)
    # scans every 200 ms, the first one just before the first odometry sample (as in the real log)
    laser_time_ms = np.arange(19_990, int(odo_time_ms[-1]) + 1, 200, dtype=np.int64)
    det_scan, det_range, det_bearing = [], [], []
    for k, t in enumerate(laser_time_ms):
        i = max(int(np.searchsorted(odo_time_ms, t, side="right")) - 1, 0)
        pose = poses[i]
        if t > odo_time_ms[i]:
            pose = model.predict(pose, np.array([speed[i], steering[i]]), (t - odo_time_ms[i]) / 1000.0)
        offset = tree_xy - pose[:2]
        ranges = np.hypot(offset[:, 0], offset[:, 1])
        bearings = np.arctan2(offset[:, 1], offset[:, 0]) - pose[2]
        bearings = (bearings + math.pi) % (2 * math.pi) - math.pi
        seen = np.flatnonzero((ranges > 1.0) & (ranges < 40.0) & (np.abs(bearings) < math.pi / 2 - 0.05))
        det_scan += [k] * len(seen)
        det_range += list(ranges[seen] + rng.normal(0.0, 0.05, len(seen)))
        det_bearing += list(bearings[seen] + math.pi / 2 + rng.normal(0.0, math.radians(0.3), len(seen)))
    gps = np.arange(0, steps, 8)  # 5 Hz
    arrays = {
        "odo_time_ms": odo_time_ms,
        "odo_speed": speed + rng.normal(0.0, 0.02, steps),
        "odo_steering": steering + rng.normal(0.0, 0.002, steps),
        "laser_time_ms": laser_time_ms,
        "det_scan": np.array(det_scan, dtype=np.int32),
        "det_range": np.array(det_range),
        "det_bearing": np.array(det_bearing),
        "det_diameter": rng.uniform(0.2, 0.6, len(det_scan)),
        "gps_time_ms": odo_time_ms[gps],
        "gps_x": poses[gps, 0] + rng.normal(0.0, 0.05, len(gps)),
        "gps_y": poses[gps, 1] + rng.normal(0.0, 0.05, len(gps)),
    }
    return arrays, tree_xy


def write_victoria_park(folder: Path, arrays: dict[str, np.ndarray] | None = None) -> Path:
    """Write ``arrays`` (default :func:`synthetic_arrays`) as ``folder/victoria_park.npz``; returns the file."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "victoria_park.npz"
    np.savez_compressed(path, **(synthetic_arrays()[0] if arrays is None else arrays))
    return path
