"""``SeifExploreMRCLAM``: the SeifExplore env matched to the robots of the UTIAS MRCLAM dataset.

## Description

`SeifExploreEnv` with the world, robot and sensor of MRCLAM Dataset 6
(Leung et al., IJRR 2011), as measured by `python -m seif_gym.datasets.mrclam
calibrate` and shipped in `seif_gym/datasets/mrclam/mrclam6_calibration.json`
(`Calibration.world`, `describe_world`):

| | simulated | from the logs |
|---|---|---|
| landmarks | the 15 surveyed positions (`layout="fixed"`) | `Landmark_Groundtruth.dat` |
| walls | a rectangle around the robots' Vicon positions and the landmarks, 0.25 m margin (about 5.2 × 10.5 m) | `bounds` and the survey |
| speed, turn rate | `max_speed` 0.086 m/s, `max_turn_rate` 0.57 rad/s | the largest commands |
| camera | `fov` 1.18 rad, `sensor_range` 7.05 m | 99.9 % of the bearings, 99 % of the ranges |
| motion noise | per second (`motion_model="per_second"`): forward, turn, lateral densities | calibrated on 20 s windows |
| range / bearing noise | `clip(0.048 r, 0.070, 0.204)` m, 0.0081 rad | calibrated |
| range errors in time | drifting, correlation time 16.1 s (`range_error_time`) | their correlation after 5 s |
| step | `dt` 0.25 s (the camera's frame period is 0.24 s) | |

Coordinates are the dataset's shifted so that the walls are centred on the
origin (`MRCLAM_ORIGIN` is the dataset point at the origin). Everything else
(spaces, rewards, episode end, info) is `SeifExploreEnv`'s; the default
filter is the SEIF with `k = 8`.

What the simulator leaves out (the docs' MRCLAM page measures them on the logs): the
real errors are heavy-tailed (the bearings' too are correlated in time), barcodes are misread, the
commands are biased (the logs need `CommandCorrection`; the simulated robot
executes its commands with the calibrated noise only), and the camera sees
other robots. The filter here uses the calibrated `Q` without the runner's
inflation and treats the errors as white: like on the logs, the drifting range
errors make it overconfident.

## Version History

Every version of `SeifExploreMRCLAM`, and what changed in each, is listed in
`CHANGELOG.md`, section "Environment versions".
"""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path
from typing import Any

from seif_gym.datasets.mrclam.calibration import DATASET6, Calibration

__all__ = ["MRCLAM_CALIBRATION", "MRCLAM_ORIGIN", "mrclam_kwargs"]

#: The calibration of Dataset 6 the variant is built from.
MRCLAM_CALIBRATION = DATASET6
#: Margin between the walls and the outermost robot position or landmark, m.
WALL_MARGIN = 0.25


@functools.cache
def _world(calibration: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """The calibration file's data and its world description, read once per file (callers only read them)."""
    data = json.loads(Path(calibration).read_text())
    world = data.get("world") or {}
    missing = [
        key for key in ("landmarks", "bounds", "max_speed", "max_turn_rate", "fov", "max_range") if key not in world
    ]
    if missing:
        raise ValueError(f"{calibration}: the calibration has no world description ({', '.join(missing)}); "
                         "recalibrate with python -m seif_gym.datasets.mrclam calibrate")  # fmt: skip
    return data, world


def _origin(world: dict[str, Any]) -> tuple[float, float, float, float]:
    """``(x0, y0, width, height)``: the centre of the walls (dataset frame) and their size."""
    x_min, x_max, y_min, y_max = (float(v) for v in world["bounds"])
    for x, y in world["landmarks"]:
        x_min, x_max, y_min, y_max = min(x_min, x), max(x_max, x), min(y_min, y), max(y_max, y)
    width, height = x_max - x_min + 2 * WALL_MARGIN, y_max - y_min + 2 * WALL_MARGIN
    return 0.5 * (x_min + x_max), 0.5 * (y_min + y_max), width, height


def range_error_time(data: dict[str, Any]) -> float | None:
    """Correlation time of the range errors, s: the median over robots of ``-5 s / ln rho(5 s)``.

    ``rho(5 s)`` is the correlation of a landmark's range errors 5 s apart
    (``diagnostics.sensor_error_correlation`` of the calibration); an
    Ornstein-Uhlenbeck process with this time has that correlation at 5 s
    (and 0.98 / 0.94 at 0.25 / 1 s, where the logs give 0.95-0.98 / 0.85-0.97).
    ``None`` when the calibration has no such figures.
    """
    correlations = data.get("diagnostics", {}).get("sensor_error_correlation", {})
    times = [
        -5.0 / math.log(float(lags["range"]["5s"]))
        for lags in correlations.values()
        if 0.0 < float(lags.get("range", {}).get("5s", 0.0)) < 1.0
    ]
    return float(sorted(times)[len(times) // 2]) if times else None


def mrclam_kwargs(calibration: str | Path | None = None) -> dict[str, Any]:
    """``SeifExploreEnv`` keyword arguments of the MRCLAM-matched env (module docstring).

    Parameters
    ----------
    calibration : path, optional
        A calibration file with a world description (default
        :data:`MRCLAM_CALIBRATION`, Dataset 6).
    """
    data, world = _world(Path(calibration) if calibration is not None else MRCLAM_CALIBRATION)
    x0, y0, width, height = _origin(world)
    noise = Calibration.from_dict(data).env_kwargs()  # the calibrated models, as for any SeifExplore env
    return {
        "arena_size": float(math.ceil(max(width, height))),
        "arena_extent": (round(width, 3), round(height, 3)),
        "layout": "fixed",
        "num_landmarks": len(world["landmarks"]),
        "landmark_positions": tuple((round(x - x0, 6), round(y - y0, 6)) for x, y in world["landmarks"]),
        "max_speed": float(world["max_speed"]),
        "max_turn_rate": float(world["max_turn_rate"]),
        "dt": 0.25,
        "sensor_range": round(float(world["max_range"]), 3),
        "fov": round(float(world["fov"]), 4),
        **noise,
        "range_error_time": None if (tau := range_error_time(data)) is None else round(tau, 2),
        "sigma_range": noise["range_noise"][2],  # unused with range_noise; the largest, as the sensor reports
    }


def mrclam_origin(calibration: str | Path | None = None) -> tuple[float, float]:
    """The dataset point at the env's origin (add it to env coordinates to get the dataset's)."""
    _, world = _world(Path(calibration) if calibration is not None else MRCLAM_CALIBRATION)
    x0, y0, _, _ = _origin(world)
    return x0, y0


#: The dataset point at the env's origin, for Dataset 6.
MRCLAM_ORIGIN: tuple[float, float] = mrclam_origin()
