"""Calibration of the MRCLAM robots' motion and sensor noise from the Vicon ground truth.

``python -m seif_gym.datasets.mrclam calibrate [--data DIR] [--robots 1 2 ...] [--out FILE]``
estimates, from the logs of an MRCLAM dataset (:mod:`seif_gym.datasets.mrclam`)
and their ground truth, what a filter needs to run on them
(:mod:`seif_gym.slam.noise_models`), and writes it to a JSON file that the
runner and the env read back with :meth:`Calibration.load`:

* the **command correction** ``v' = s_v v max(0, 1 - c|omega|) + b_v``,
  ``omega' = s_w omega + b_w`` (:class:`~seif_gym.slam.noise_models.CommandCorrection`)
  and the **command latency** (commands take effect some time after their stamps);
* the **per-second motion noise** densities of
  :class:`~seif_gym.slam.noise_models.PerSecondVelocityMotionModel`
  (forward, turn, lateral, each ``(constant, per v^2, per omega^2)``), fitted
  at a chosen horizon (see below);
* the **sensor noise** of :class:`~seif_gym.slam.noise_models.RangeDependentSensor`
  (``sigma_r = clip(a r, lo, hi)``, ``sigma_phi``) and the **sensor latency**
  (camera frames are older than their stamps);
* per robot, the **heading offset** of its Vicon heading from its direction of
  travel and the **bearing bias** of its camera;
* diagnostics: the noise rates at several horizons, outlier fractions and the
  time correlation of the sensor errors.

Every estimate is robust (:mod:`seif_gym.datasets.robust`): Huber regression
for the correction, a trimmed Huber scale fit for the noise, Huber locations
for the offsets. :func:`simulate_logs` draws logs with known parameters
(commands, motion, Vicon, camera, outliers) to test that the calibration
recovers them; :func:`write_dataset` writes logs in the MRCLAM text format.

Why a horizon: after correction, the forward error of the robots is partly
bias-like (the speed error persists over seconds, so its variance grows
faster than linearly in time), while a dt-linear model has variance ``q T``.
The densities are fitted to windows of ``horizon`` seconds, i.e. they match
the real spread at that horizon (shorter: overestimated, longer:
underestimated); the diagnostics give the rates at 0.5 to 20 s. Choose about
the time between a filter's landmark sightings.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from seif_gym._atomic import atomic_write_text
from seif_gym.datasets._arrays import frozen
from seif_gym.datasets._files import DataFormatError, DataNotFoundError, output_file, run_cli
from seif_gym.datasets.mrclam import loader as mrclam
from seif_gym.datasets.robust import (
    fit_scale_model,
    fit_variance_regression,
    huber_location,
    huber_regression,
    mad_scale,
    robust_correlation,
    scale_objective,
)
from seif_gym.slam.models import wrap_angle
from seif_gym.slam.noise_models import (
    CommandCorrection,
    CorrectedMotionModel,
    PerSecondVelocityMotionModel,
    RangeDependentSensor,
)
from seif_gym.type_aliases import FloatArray, IntArray

__all__ = [
    "FORMAT",
    "Calibration",
    "RobotCalibration",
    "calibrate",
    "describe_world",
    "DATASET6",
    "main",
    "simulate_logs",
    "summary",
    "write_dataset",
]


#: The ``format`` field of a calibration file.
FORMAT = "seif_gym.mrclam.calibration/1"
#: Integration step of the calibration, s (the odometry's rate).
STEP = 0.01
#: Horizons (s) at which the diagnostics report the motion-noise rates.
DIAGNOSTIC_HORIZONS = (0.5, 1.0, 2.0, 5.0, 10.0, 20.0)
#: Lags (s) at which the diagnostics report the time correlation of sensor errors.
CORRELATION_LAGS = (0.25, 1.0, 5.0)


# ---------------------------------------------------------------------------
# The calibration
# ---------------------------------------------------------------------------
#: The calibration of MRCLAM Dataset 6 shipped with the package (``python -m seif_gym.datasets.mrclam calibrate``
#: on the five robots): read by ``SeifExploreMRCLAM`` and the MRCLAM commands' examples.
DATASET6 = Path(__file__).with_name("mrclam6_calibration.json")


@dataclass(frozen=True)
class RobotCalibration:
    """What differs between robots.

    Attributes
    ----------
    heading_offset : float
        ``delta``, rad: direction of travel minus Vicon heading (add it to the
        ground-truth heading to get the heading the motion model moves along).
    bearing_bias : float
        ``b``, rad: mean of measured minus true bearing (subtract it from the
        measured bearings).
    range_bias : float
        Mean of measured minus true range, m (robust; reported, a runner may subtract it).
    """

    heading_offset: float = 0.0
    bearing_bias: float = 0.0
    range_bias: float = 0.0


@dataclass(frozen=True)
class Calibration:
    """Calibrated models of the MRCLAM robots; see the module docstring.

    Attributes
    ----------
    correction : CommandCorrection
        Commanded to executed velocities.
    command_latency : float
        Seconds between a command's stamp and its effect.
    forward, turn, lateral : tuple of 3 floats
        Densities of :class:`~seif_gym.slam.noise_models.PerSecondVelocityMotionModel`.
    horizon : float
        Window length (s) the densities were fitted at.
    range_slope : float
        ``a`` of ``sigma_r = clip(a r, lo, hi)``.
    range_bounds : (float, float)
        ``(lo, hi)``, m.
    sigma_bearing : float
        Bearing noise, rad.
    sensor_latency : float
        Seconds by which a camera frame is older than its stamp.
    robots : dict of int to RobotCalibration
        Per-robot offsets (robots not calibrated are absent).
    diagnostics : dict
        JSON-ready figures (rates per horizon, outlier fractions, correlations, counts).
    source : dict
    world : dict
        What a simulator of the logs needs (:func:`describe_world`): the
        surveyed landmarks, the area the robots drove in, their speed and
        turn-rate limits, the camera's field of view and range, the frame
        period. Empty for a calibration without logs.
        How it was made (dataset folder, robots, options).
    """

    correction: CommandCorrection = field(default_factory=CommandCorrection)
    command_latency: float = 0.0
    forward: tuple[float, float, float] = (0.0, 0.0, 0.0)
    turn: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lateral: tuple[float, float, float] = (0.0, 0.0, 0.0)
    horizon: float = 20.0
    range_slope: float = 0.05
    range_bounds: tuple[float, float] = (0.02, 0.5)
    sigma_bearing: float = 0.01
    sensor_latency: float = 0.0
    robots: dict[int, RobotCalibration] = field(default_factory=dict)
    diagnostics: dict[str, Any] = field(default_factory=dict)
    source: dict[str, Any] = field(default_factory=dict)
    world: dict[str, Any] = field(default_factory=dict)

    # -- models -----------------------------------------------------------------
    def motion_model(
        self, noise_floor: float = 1e-9, corrected: bool = True
    ) -> CorrectedMotionModel | PerSecondVelocityMotionModel:
        """The calibrated motion model: per-second noise behind the command correction.

        With ``corrected=False``, the bare
        :class:`~seif_gym.slam.noise_models.PerSecondVelocityMotionModel` (for
        controls already corrected).
        """
        model = PerSecondVelocityMotionModel(self.forward, self.turn, self.lateral, noise_floor=noise_floor)
        return CorrectedMotionModel(model, self.correction) if corrected else model

    def sensor(self, max_range: float = 10.0, fov: float = 2.0 * math.pi) -> RangeDependentSensor:
        """The calibrated :class:`~seif_gym.slam.noise_models.RangeDependentSensor`."""
        return RangeDependentSensor(self.range_slope, self.range_bounds, self.sigma_bearing, max_range, fov)

    def env_kwargs(self) -> dict[str, Any]:
        """``gym.make`` keyword arguments of a ``SeifExplore`` env with the calibrated noise.

        The per-second motion noise (``motion_model="per_second"``), the
        range-dependent range noise and the bearing noise; the simulated robot
        executes its commands as commanded (the command correction and the
        offsets are properties of the real robots' logs, not of the noise).

        Examples
        --------
        >>> import gymnasium as gym, seif_gym
        >>> from seif_gym.datasets.mrclam.calibration import DATASET6, Calibration
        >>> kwargs = Calibration.load(DATASET6).env_kwargs()  # doctest: +SKIP
        >>> env = gym.make("SeifExplore-v2", **kwargs)  # doctest: +SKIP
        """
        return {
            "motion_model": "per_second",
            "motion_noise": (*self.forward, *self.turn, *self.lateral),
            "range_noise": (self.range_slope, *self.range_bounds),
            "sigma_bearing": self.sigma_bearing,
        }

    def robot(self, robot: int) -> RobotCalibration:
        """The offsets of ``robot`` (zeros for a robot not calibrated)."""
        return self.robots.get(int(robot), RobotCalibration())

    # -- files --------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready contents (the file's layout)."""
        return {
            "format": FORMAT,
            "command_correction": self.correction.to_dict(),
            "command_latency": self.command_latency,
            "motion_noise": {
                "model": "PerSecondVelocityMotionModel",
                "forward": list(self.forward),
                "turn": list(self.turn),
                "lateral": list(self.lateral),
                "horizon": self.horizon,
                "units": "densities (constant, per v^2, per omega^2): forward and lateral m^2/s, turn rad^2/s",
            },
            "sensor_noise": {
                "model": "RangeDependentSensor",
                "range_slope": self.range_slope,
                "range_bounds": list(self.range_bounds),
                "sigma_bearing": self.sigma_bearing,
            },
            "sensor_latency": self.sensor_latency,
            "robots": {str(r): vars(c).copy() for r, c in sorted(self.robots.items())},
            "diagnostics": self.diagnostics,
            "source": self.source,
            "world": self.world,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Calibration:
        """Read :meth:`to_dict`'s layout.

        Raises
        ------
        TypeError
            ``data`` is not a mapping.
        ValueError
            A field is missing or malformed (the message names it).
        """
        if not isinstance(data, Mapping):
            raise TypeError(f"data must be a mapping, got {type(data).__name__}")
        if data.get("format") != FORMAT:
            raise ValueError(f"format must be {FORMAT!r}, got {data.get('format')!r}")
        try:
            motion, sensor = data["motion_noise"], data["sensor_noise"]
            return cls(
                correction=CommandCorrection(**data["command_correction"]),
                command_latency=float(data["command_latency"]),
                forward=_triple(motion["forward"], "motion_noise.forward"),
                turn=_triple(motion["turn"], "motion_noise.turn"),
                lateral=_triple(motion["lateral"], "motion_noise.lateral"),
                horizon=float(motion["horizon"]),
                range_slope=float(sensor["range_slope"]),
                range_bounds=tuple(float(b) for b in sensor["range_bounds"]),  # type: ignore[arg-type]
                sigma_bearing=float(sensor["sigma_bearing"]),
                sensor_latency=float(data["sensor_latency"]),
                robots={
                    int(r): RobotCalibration(**{k: float(v) for k, v in c.items()})
                    for r, c in data.get("robots", {}).items()
                },  # fmt: skip
                diagnostics=dict(data.get("diagnostics", {})),
                source=dict(data.get("source", {})),
                world=dict(data.get("world", {})),
            )
        except KeyError as error:
            raise ValueError(f"calibration data lacks the field {error.args[0]!r}") from error
        except (TypeError, ValueError, AttributeError) as error:
            raise ValueError(f"calibration data has a malformed field: {error}") from error

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the calibration as JSON to ``path``, whole or not at all; returns the path."""
        return atomic_write_text(path, json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Calibration:
        """Read a file written by :meth:`save`.

        Raises
        ------
        DataNotFoundError
            No file at ``path`` (a ``FileNotFoundError``).
        DataFormatError
            A ``ValueError`` naming the file (and the line, for invalid JSON):
            not JSON, not an object, or a field missing or malformed.
        """
        path = Path(path)
        if not path.is_file():
            raise DataNotFoundError(f"calibration file not found: {path} "
                                    "(python -m seif_gym.datasets.mrclam calibrate writes one)")  # fmt: skip
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as error:
            raise DataFormatError(f"{path}, line {error.lineno}: not valid JSON ({error.msg})") from None
        except UnicodeDecodeError:
            raise DataFormatError(f"{path}: not a text file") from None
        if not isinstance(data, dict):
            raise DataFormatError(f"{path}: a calibration file holds a JSON object, found {type(data).__name__}")
        try:
            return cls.from_dict(data)
        except ValueError as error:
            raise DataFormatError(f"{path}: {error}") from None


def _triple(values: ArrayLike, name: str) -> tuple[float, float, float]:
    values = [float(v) for v in np.asarray(values, dtype=np.float64).ravel()]
    if len(values) != 3:
        raise ValueError(f"{name} must have 3 entries, got {len(values)}")
    return values[0], values[1], values[2]


# ---------------------------------------------------------------------------
# Tracks: a robot's log on a regular grid
# ---------------------------------------------------------------------------
@dataclass
class _Track:
    """One robot's ground truth and commands on a grid of ``STEP`` seconds."""

    robot: int
    time: FloatArray  # (n,) grid
    x: FloatArray
    y: FloatArray
    theta: FloatArray  # unwrapped
    valid: NDArray[np.bool_]  # (n - 1,) step k -> k + 1 has ground truth on both ends (no gap)
    log: mrclam.MrclamLog

    def commands(self, latency: float) -> tuple[FloatArray, FloatArray]:
        """Raw commands in effect on each step (held; zero before the first), with ``latency``."""
        odo = self.log.odometry
        k = np.searchsorted(odo.time + latency, self.time[:-1], side="right") - 1
        started = k >= 0
        k = np.maximum(k, 0)
        return np.where(started, odo.v[k], 0.0), np.where(started, odo.omega[k], 0.0)

    def steps_along(self, heading_offset: float) -> tuple[FloatArray, FloatArray]:
        """Ground-truth displacement of each step along and across the direction of travel."""
        dx, dy = np.diff(self.x), np.diff(self.y)
        mid = 0.5 * (self.theta[:-1] + self.theta[1:]) + heading_offset
        c, s = np.cos(mid), np.sin(mid)
        return c * dx + s * dy, -s * dx + c * dy


def _track(log: mrclam.MrclamLog, max_gap: float = 0.25) -> _Track:
    gt, odo = log.ground_truth, log.odometry
    start, end = max(gt.time[0], odo.time[0]), min(gt.time[-1], odo.time[-1])
    if end - start < 10.0:
        raise ValueError(f"robot {log.robot}: ground truth and odometry overlap for {end - start:.1f} s only")
    time = start + STEP * np.arange(int((end - start) / STEP))
    theta = np.interp(time, gt.time, np.unwrap(gt.theta))
    # a step is valid when the ground-truth samples around both of its ends are close together
    after = np.clip(np.searchsorted(gt.time, time), 1, len(gt.time) - 1)
    gap_ok = (gt.time[after] - gt.time[after - 1]) <= max_gap
    valid = gap_ok[:-1] & gap_ok[1:]
    return _Track(log.robot, time, np.interp(time, gt.time, gt.x), np.interp(time, gt.time, gt.y), theta, valid, log)


def _windows(track: _Track, length: float, stride: float | None = None) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Start and end grid indices of windows of ``length`` s (every ``stride`` s) with valid steps only."""
    n = max(round(length / STEP), 1)
    every = max(round((stride if stride is not None else length) / STEP), 1)
    starts = np.arange(0, len(track.time) - 1 - n, every)
    bad = np.concatenate([[0], np.cumsum(~track.valid)])
    ok = bad[starts + n] == bad[starts]
    return starts[ok], starts[ok] + n


def _window_sums(values: FloatArray, starts: IntArray, ends: IntArray) -> FloatArray:
    cumulative = np.concatenate([[0.0], np.cumsum(values)])
    return cumulative[ends] - cumulative[starts]


# ---------------------------------------------------------------------------
# Motion: latency, heading offsets, correction, noise
# ---------------------------------------------------------------------------
def _correction_design(
    track: _Track, latency: float, offset: float, starts: IntArray, ends: IntArray, fit_offsets: bool
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Per window: the ground-truth distance and turn, and the regressors of the correction."""
    v, w = track.commands(latency)
    along, _ = track.steps_along(offset)
    distance = _window_sums(along, starts, ends)
    turn = track.theta[ends] - track.theta[starts]
    duration = (ends - starts) * STEP
    speed_columns: list[NDArray[np.floating]] = [
        _window_sums(v * STEP, starts, ends),
        -_window_sums(v * np.abs(w) * STEP, starts, ends),
    ]
    turn_columns: list[NDArray[np.floating]] = [_window_sums(w * STEP, starts, ends)]
    if fit_offsets:
        speed_columns.append(duration)
        turn_columns.append(duration)
    return distance, turn, np.column_stack(speed_columns), np.column_stack(turn_columns)


def _fit_correction(
    tracks: Sequence[_Track],
    latency: float,
    offsets: Mapping[int, float],
    windows: Mapping[int, tuple[IntArray, IntArray]],
    fit_offsets: bool,
) -> tuple[CommandCorrection, float, float]:
    """Huber regressions of distance and turn per window; returns the correction and the two residual scales."""
    parts = [_correction_design(t, latency, offsets[t.robot], windows[t.robot][0], windows[t.robot][1], fit_offsets)
             for t in tracks]  # fmt: skip
    distance = np.concatenate([p[0] for p in parts])
    turn = np.concatenate([p[1] for p in parts])
    speed_design = np.vstack([p[2] for p in parts])
    turn_design = np.vstack([p[3] for p in parts])
    moving = np.abs(speed_design[:, 0]) > 1e-6
    speed_coef, speed_scale = huber_regression(speed_design[moving], distance[moving])
    turn_coef, turn_scale = huber_regression(turn_design, turn)
    s_v = max(float(speed_coef[0]), 1e-6)
    correction = CommandCorrection(
        speed_scale=s_v,
        turn_slowdown=max(float(speed_coef[1]) / s_v, 0.0),
        speed_offset=float(speed_coef[2]) if fit_offsets else 0.0,
        turn_scale=max(float(turn_coef[0]), 1e-6),
        turn_offset=float(turn_coef[1]) if fit_offsets else 0.0,
    )
    return correction, speed_scale, turn_scale


def _heading_offset(track: _Track, latency: float, starts: IntArray, ends: IntArray) -> float:
    """Robust mean angle between the ground-truth displacement and the Vicon heading, over moving windows."""
    along, across = track.steps_along(0.0)
    forward, lateral = _window_sums(along, starts, ends), _window_sums(across, starts, ends)
    moving = forward > 0.01
    if np.count_nonzero(moving) < 10:
        return 0.0
    # lateral = tan(delta) forward + noise of about constant spread: a Huber regression through the origin
    slope, _ = huber_regression(forward[moving, None], lateral[moving])
    return float(math.atan(slope[0]))


def _refine_minimum(grid: FloatArray, values: FloatArray) -> float:
    """The minimum of a parabola through the best grid point and its neighbours."""
    i = int(np.argmin(values))
    if 0 < i < len(grid) - 1:
        a, b, c = values[i - 1], values[i], values[i + 1]
        denominator = a - 2.0 * b + c
        if denominator > 0:
            return float(grid[i] + 0.5 * (grid[1] - grid[0]) * (a - c) / denominator)
    return float(grid[i])


def _motion_residuals(
    track: _Track, correction: CommandCorrection, latency: float, offset: float, starts: IntArray, ends: IntArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Forward, lateral and heading errors of dead reckoning per window, and the noise features."""
    v, w = track.commands(latency)
    corrected = correction.apply(np.column_stack([v, w]))
    along, across = track.steps_along(offset)
    forward = _window_sums(along - corrected[:, 0] * STEP, starts, ends)
    lateral = _window_sums(across, starts, ends)
    heading = track.theta[ends] - track.theta[starts] - _window_sums(corrected[:, 1] * STEP, starts, ends)
    features = np.column_stack([
        (ends - starts) * STEP,
        _window_sums(corrected[:, 0] ** 2 * STEP, starts, ends),
        _window_sums(corrected[:, 1] ** 2 * STEP, starts, ends),
    ])  # fmt: skip
    return forward, lateral, heading, features


# ---------------------------------------------------------------------------
# Sensor
# ---------------------------------------------------------------------------
def _sensor_residuals(
    log: mrclam.MrclamLog, latency: float, heading_offset: float, max_gap: float = 0.25
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, IntArray]:
    """Range and bearing residuals of the landmark readings (true pose at stamp - latency), and their ranges."""
    m, gt = log.measurements, log.ground_truth
    t = m.time - latency
    inside = (t >= gt.time[0]) & (t <= gt.time[-1])
    after = np.clip(np.searchsorted(gt.time, t), 1, len(gt.time) - 1)
    inside &= (gt.time[after] - gt.time[after - 1]) <= max_gap
    t = t[inside]
    x, y = np.interp(t, gt.time, gt.x), np.interp(t, gt.time, gt.y)
    theta = np.interp(t, gt.time, np.unwrap(gt.theta)) + heading_offset
    landmarks = log.landmarks.positions[log.landmarks.index(m.subject[inside])]
    dx, dy = landmarks[:, 0] - x, landmarks[:, 1] - y
    range_error = m.range[inside] - np.hypot(dx, dy)
    bearing_error = wrap_angle(m.bearing[inside] - (np.arctan2(dy, dx) - theta))
    return range_error, bearing_error, m.range[inside], m.time[inside], m.subject[inside]


def _range_noise(errors: FloatArray, ranges: FloatArray) -> tuple[float, tuple[float, float]]:
    """``(a, (lo, hi))`` of ``clip(a r, lo, hi)``: robust fits from several starts, the best kept.

    The starts come from robust scales of range bins: the slope from the
    middle bins with and without the floor and ceiling of the end bins, and
    no clip at all. The clip's corners make local minima (a steeper slope can
    stand in for the floor), so each start is fitted
    (:func:`~seif_gym.datasets.robust.fit_scale_model`) and the fit with the
    lowest Huber objective is kept.
    """
    edges = np.unique(np.quantile(ranges, np.linspace(0.0, 1.0, 9)))
    centres, scales = [], []
    for low, high in itertools.pairwise(edges):
        inside = (ranges >= low) & (ranges <= high)
        if np.count_nonzero(inside) >= 20:
            centres.append(float(np.median(ranges[inside])))
            scales.append(mad_scale(errors[inside]))
    centres_arr, scales_arr = np.array(centres), np.array(scales)
    ratios = scales_arr / centres_arr
    middle = float(np.median(ratios[len(ratios) // 4 : max(len(ratios) - len(ratios) // 4, len(ratios) // 4 + 1)]))
    r_min, r_max = float(ranges.min()), float(ranges.max())
    starts = [
        (float(np.median(ratios)), float(scales_arr.min()), float(scales_arr.max())),
        (middle, float(scales_arr[0]), float(scales_arr[-1])),
        (middle, 0.5 * middle * r_min, 2.0 * middle * r_max),
    ]

    def log_sigma(theta: FloatArray) -> FloatArray:
        a, lo, hi = np.exp(theta)
        return np.log(np.clip(a * ranges, min(lo, hi), max(lo, hi)))

    fits = [fit_scale_model(errors, log_sigma, np.log(np.maximum(start, 1e-9))) for start in starts]
    best = min(fits, key=lambda theta: scale_objective(errors, log_sigma(theta)))
    a, lo, hi = np.exp(best)
    lo, hi = min(lo, hi), max(lo, hi)
    # a bound no range reaches is not identified: put it where the data end
    lo = max(lo, a * r_min)  # a floor no range reaches: where the data end
    hi = min(hi, a * r_max)  # likewise a ceiling
    return float(a), (float(lo), float(max(hi, lo)))


def _error_correlations(
    times: FloatArray,
    subjects: IntArray,
    errors: FloatArray,
    scale: float | FloatArray,
    lags: Sequence[float] = CORRELATION_LAGS,
    tolerance: float = 0.1,
) -> dict[str, float]:
    """Robust correlation of two errors of the same landmark ``lag`` seconds apart (within ``tolerance``)."""
    out: dict[str, float] = {}
    order = np.lexsort((times, subjects))
    t, s, e = times[order], subjects[order], errors[order] / scale
    for lag in lags:
        first, second = [], []
        for subject in np.unique(s):
            rows = np.flatnonzero(s == subject)
            tt = t[rows]
            j = np.searchsorted(tt, tt + lag)
            for i, jj in enumerate(j):
                for candidate in (jj - 1, jj):
                    if i < candidate < len(rows) and abs(tt[candidate] - tt[i] - lag) <= tolerance:
                        first.append(e[rows[i]])
                        second.append(e[rows[candidate]])
                        break
        out[f"{lag:g}s"] = robust_correlation(first, second) if len(first) >= 20 else math.nan
    return out


# ---------------------------------------------------------------------------
# calibrate
# ---------------------------------------------------------------------------
def calibrate(
    logs: Sequence[mrclam.MrclamLog] | Mapping[int, mrclam.MrclamLog],
    *,
    horizon: float = 20.0,
    fit_offsets: bool = False,
    latency_grid: Sequence[float] | None = None,
    sensor_latency_grid: Sequence[float] | None = None,
    progress: Any = None,
) -> Calibration:
    """Estimate a :class:`Calibration` from MRCLAM logs and their ground truth.

    Parameters
    ----------
    logs : mapping of int to MrclamLog, or sequence of MrclamLog
        One log per robot (:func:`seif_gym.datasets.mrclam.load`), all of one
        dataset (one survey).
    horizon : float, default 20
        Window length (s) the motion-noise densities are fitted at: the
        MRCLAM robots go 30-80 s between landmark sightings, where the
        variance of their dead reckoning grows faster than linearly.
    fit_offsets : bool, default False
        Fit the offsets ``b_v``, ``b_w`` of the correction too (they move a
        robot that is commanded to stand still, so they are off by default).
    latency_grid, sensor_latency_grid : sequence of float, optional
        Candidate latencies (s); defaults 0-0.6 s and 0-0.15 s, every 10 ms,
        refined between grid points.
    progress : callable, optional
        Called with a short message at each stage.

    Returns
    -------
    Calibration

    Notes
    -----
    1. *Tracks*: each robot's ground truth interpolated on a 10 ms grid over
       the span it shares with the odometry; steps within 0.25 s of a
       ground-truth gap are left out.
    2. *Heading offsets* ``delta``: ``atan`` of the slope of a Huber
       regression (through the origin) of the lateral on the forward
       displacement of 1 s windows driven forward, in the frame of the Vicon
       heading.
    3. *Command latency and correction*: for each candidate latency ``tau``,
       1 s windows; the distance driven along the direction of travel is
       regressed on ``(sum v dt, -sum v|omega| dt[, T])`` and the heading change
       on ``(sum omega dt[, T])`` by Huber regressions (so
       ``s_v``, ``s_v c``, ``s_w``); ``tau`` minimises the heading fit's
       robust residual scale.
    4. *Motion noise*: windows of ``horizon`` s every ``horizon / 2`` s; the
       forward and lateral errors of the corrected commands along the true
       path (ground-truth displacement projected on the direction of travel
       minus ``sum v' dt``, and across it) and the heading error
       (``Delta theta - sum omega' dt``) have variances
       ``sum q(v', omega') dt = q0 T + q1 sum v'^2 dt + q2 sum omega'^2 dt``;
       each triple is fitted by :func:`~seif_gym.datasets.robust.fit_variance_regression`.
    5. *Sensor*: for each candidate sensor latency ``lambda``, the residuals of
       every landmark reading against the ground-truth pose at ``stamp -
       lambda`` (heading plus ``delta``) and the surveyed landmark; ``lambda``
       minimises the pooled bearing residuals' MAD (each robot's median
       removed). Per robot, the bearing and range biases are Huber locations;
       ``sigma_phi`` is a robust scale of the pooled bearing residuals
       (:func:`~seif_gym.datasets.robust.fit_scale_model`, constant model) and
       ``clip(a r, lo, hi)`` is fitted to the range residuals the same way.
    """
    items = list(logs.values()) if isinstance(logs, Mapping) else list(logs)
    if not items or not all(isinstance(log, mrclam.MrclamLog) for log in items):
        raise TypeError("logs must be a non-empty mapping or sequence of MrclamLog")
    if len({log.robot for log in items}) != len(items):
        raise ValueError("logs must hold each robot once")
    if isinstance(horizon, bool) or not isinstance(horizon, (int, float)) or not 0.1 <= horizon <= 120.0:
        raise ValueError(f"horizon must be a number of seconds in [0.1, 120], got {horizon!r}")
    latencies = np.arange(0.0, 0.6001, 0.01) if latency_grid is None else np.asarray(latency_grid, dtype=np.float64)
    sensor_latencies = (np.arange(0.0, 0.1501, 0.01) if sensor_latency_grid is None
                        else np.asarray(sensor_latency_grid, dtype=np.float64))  # fmt: skip
    say = progress if callable(progress) else (lambda message: None)

    say("tracks")
    tracks = [_track(log) for log in sorted(items, key=lambda log: log.robot)]
    second = {t.robot: _windows(t, 1.0) for t in tracks}

    say("heading offsets")
    offsets = {t.robot: _heading_offset(t, 0.0, *second[t.robot]) for t in tracks}

    say("command latency and correction")
    scores = []
    for latency in latencies:
        scores.append(_fit_correction(tracks, float(latency), offsets, second, fit_offsets)[2])
    command_latency = _refine_minimum(latencies, np.array(scores))
    correction, speed_scale, turn_scale = _fit_correction(tracks, command_latency, offsets, second, fit_offsets)

    say("motion noise")
    windows = {t.robot: _windows(t, horizon, horizon / 2.0) for t in tracks}
    parts = [_motion_residuals(t, correction, command_latency, offsets[t.robot], *windows[t.robot]) for t in tracks]
    forward_e, lateral_e, heading_e = (np.concatenate([p[k] for p in parts]) for k in range(3))
    features = np.vstack([p[3] for p in parts])
    if len(features) < 20:
        raise ValueError(f"too few {horizon} s windows of ground truth ({len(features)}) to fit the motion noise")
    forward = tuple(float(c) for c in fit_variance_regression(forward_e - np.median(forward_e), features))
    turn = tuple(float(c) for c in fit_variance_regression(heading_e - np.median(heading_e), features))
    lateral = tuple(float(c) for c in fit_variance_regression(lateral_e - np.median(lateral_e), features))

    say("motion noise per horizon (diagnostics)")
    rates: dict[str, dict[str, float]] = {}
    for length in DIAGNOSTIC_HORIZONS:
        spans = {t.robot: _windows(t, length, length / 2.0) for t in tracks}
        parts_h = [_motion_residuals(t, correction, command_latency, offsets[t.robot], *spans[t.robot]) for t in tracks]
        if sum(len(p[0]) for p in parts_h) < 20:
            continue
        duration = np.concatenate([p[3][:, 0] for p in parts_h])[:, None]
        rates[f"{length:g}s"] = {
            name: float(fit_variance_regression(e - np.median(e), duration)[0])
            for name, e in zip(
                ("forward", "lateral", "turn"), (np.concatenate([p[k] for p in parts_h]) for k in range(3))
            )
        }

    say("sensor latency")
    sensor_scores = []
    for latency in sensor_latencies:
        bearing = [_sensor_residuals(t.log, float(latency), offsets[t.robot])[1] for t in tracks]
        sensor_scores.append(mad_scale(np.concatenate([b - np.median(b) for b in bearing])))
    sensor_latency = max(_refine_minimum(sensor_latencies, np.array(sensor_scores)), 0.0)

    say("sensor noise")
    robots: dict[int, RobotCalibration] = {}
    range_parts, bearing_parts, range_values, per_robot = [], [], [], {}
    for t in tracks:
        range_error, bearing_error, ranges, times, subjects = _sensor_residuals(t.log, sensor_latency, offsets[t.robot])
        if len(ranges) < 10:
            robots[t.robot] = RobotCalibration(heading_offset=offsets[t.robot])
            continue
        bearing_bias = huber_location(bearing_error)
        range_bias = huber_location(range_error)
        robots[t.robot] = RobotCalibration(offsets[t.robot], bearing_bias, range_bias)
        range_parts.append(range_error - range_bias)
        bearing_parts.append(wrap_angle(bearing_error - bearing_bias))
        range_values.append(ranges)
        per_robot[t.robot] = (
            range_error - range_bias,
            wrap_angle(bearing_error - bearing_bias),
            ranges,
            times,
            subjects,
        )
    if not range_parts:
        raise ValueError("no landmark readings with ground truth: cannot calibrate the sensor")
    range_errors, bearing_errors = np.concatenate(range_parts), np.concatenate(bearing_parts)
    all_ranges = np.concatenate(range_values)
    sigma_bearing = float(np.exp(fit_scale_model(bearing_errors, lambda th: np.full(len(bearing_errors), th[0]),
                                                 [math.log(max(mad_scale(bearing_errors), 1e-6))])[0]))  # fmt: skip
    range_slope, range_bounds = _range_noise(range_errors, all_ranges)

    say("diagnostics")
    sensor_model = RangeDependentSensor(range_slope, range_bounds, sigma_bearing)
    outliers, correlations = {}, {}
    for robot, (r_err, b_err, ranges, times, subjects) in per_robot.items():
        r_scale = sensor_model.range_sigma(ranges)
        outliers[str(robot)] = {
            "range_beyond_3_sigma": float(np.mean(np.abs(r_err) > 3.0 * r_scale)),
            "bearing_beyond_3_sigma": float(np.mean(np.abs(b_err) > 3.0 * sigma_bearing)),
            "readings": len(ranges),
        }
        correlations[str(robot)] = {
            "range": _error_correlations(times, subjects, r_err, r_scale),
            "bearing": _error_correlations(times, subjects, b_err, sigma_bearing),
        }
    diagnostics = {
        "motion_rates_per_horizon": rates,
        "command_fit_scales": {"distance_per_1s_window": speed_scale, "turn_per_1s_window": turn_scale},
        "latency_scores": {"command": dict(zip((f"{x:.2f}" for x in latencies), map(float, scores))),
                           "sensor": dict(zip((f"{x:.2f}" for x in sensor_latencies), map(float, sensor_scores)))},
        "sensor_outliers": outliers,
        "sensor_error_correlation": correlations,
        "windows": {"correction_1s": int(sum(len(w[0]) for w in second.values())),
                    "noise": len(features)},
        "seconds_of_ground_truth": {str(t.robot): float(np.count_nonzero(t.valid) * STEP) for t in tracks},
    }  # fmt: skip
    return Calibration(
        correction=correction,
        command_latency=command_latency,
        forward=forward,  # type: ignore[arg-type]
        turn=turn,  # type: ignore[arg-type]
        lateral=lateral,  # type: ignore[arg-type]
        horizon=float(horizon),
        range_slope=range_slope,
        range_bounds=range_bounds,
        sigma_bearing=sigma_bearing,
        sensor_latency=sensor_latency,
        robots=robots,
        diagnostics=diagnostics,
        source={
            "robots": [t.robot for t in tracks],
            "fit_offsets": bool(fit_offsets),
            "dataset": items[0].path.name,  # the folder's name: where it lay is the user's, not the file's
        },  # fmt: skip
        world=describe_world(items),
    )


def describe_world(logs: Sequence[mrclam.MrclamLog]) -> dict[str, Any]:
    """What a simulator of these logs needs, measured on them (``Calibration.world``).

    Returns
    -------
    dict
        ``landmarks``: the survey, ``[[x, y], ...]`` m, and ``subjects``;
        ``bounds``: ``[x_min, x_max, y_min, y_max]`` of the robots' Vicon
        positions, m; ``max_speed``, ``max_turn_rate``: the largest
        commanded ``|v|`` (m/s) and ``|omega|`` (rad/s); ``fov``: twice the
        99.9th percentile of ``|bearing|`` (the camera's opening, rad);
        ``max_range``: the 99th percentile of the ranges read, m (beyond it
        mostly misreads); ``frame_period``: the median time between camera
        frames, s.
    """
    logs = list(logs)
    if not logs:
        raise ValueError("describe_world needs at least one log")
    x = np.concatenate([log.ground_truth.x for log in logs])
    y = np.concatenate([log.ground_truth.y for log in logs])
    controls = np.concatenate([log.odometry.controls for log in logs])
    bearings = np.concatenate([log.measurements.bearing for log in logs])
    ranges = np.concatenate([log.measurements.range for log in logs])
    periods = np.concatenate([np.diff(log.measurements.frames()[0]) for log in logs])
    survey = logs[0].landmarks
    return {
        "landmarks": survey.positions.tolist(),
        "subjects": survey.subject.tolist(),
        "bounds": [float(x.min()), float(x.max()), float(y.min()), float(y.max())],
        "max_speed": float(np.max(np.abs(controls[:, 0]))),
        "max_turn_rate": float(np.max(np.abs(controls[:, 1]))),
        "fov": float(2.0 * np.quantile(np.abs(bearings), 0.999)),
        "max_range": float(np.quantile(ranges, 0.99)),
        "frame_period": float(np.median(periods)) if len(periods) else math.nan,
    }


# ---------------------------------------------------------------------------
# Simulated logs with known parameters
# ---------------------------------------------------------------------------
def simulate_logs(
    truth: Calibration,
    rng: np.random.Generator,
    robots: Sequence[int] = (1, 2),
    duration: float = 300.0,
    landmarks: mrclam.Landmarks | None = None,
    outlier_fraction: float = 0.02,
    fov: float = 1.15,
    max_range: float = 8.0,
    frame_period: float = 0.24,
) -> dict[int, mrclam.MrclamLog]:
    """Draw MRCLAM-like logs whose true parameters are ``truth``.

    Parameters
    ----------
    truth : Calibration
        The parameters to draw from: correction, command latency, per-second
        motion noise, range and bearing noise, sensor latency, and per robot
        (``truth.robot(r)``) the Vicon heading offset and the bearing bias.
    rng : numpy.random.Generator
        The only source of randomness.
    robots : sequence of int
        Robot numbers (1..5).
    duration : float
        Seconds of odometry per robot.
    landmarks : Landmarks, optional
        The map; defaults to 15 landmarks in three clusters in a 5 m x 10 m arena.
    outlier_fraction : float
        Share of readings replaced by gross errors (bearing off by up to pi,
        range scaled by 0.5-1.5).
    fov, max_range, frame_period : float
        Camera field of view (rad), range (m) and time between frames (s).

    Returns
    -------
    dict of int to MrclamLog

    Notes
    -----
    Commands are piecewise constant (0.5-4 s segments; 15 % stops;
    ``v`` in 0.02-0.09 m/s, ``|omega| <= 0.57`` rad/s, steering back when the
    robot leaves the arena), logged every 10 ms (+-1 ms jitter) with a few
    dropped stretches. The robot executes ``truth.correction`` of the command
    stamped ``truth.command_latency`` earlier through
    ``truth.motion_model(corrected=False).sample`` every 10 ms. Vicon samples
    the path every 15 ms with 1 mm / 1 mrad noise and heading
    ``theta - delta``. A frame at ``t`` sees the landmarks in range and view of
    the pose at ``t - sensor_latency``, with ``sigma_r(r)`` at the true range,
    ``sigma_phi``, plus the robot's bearing bias.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if landmarks is None:
        centres = np.array([[1.0, -4.0], [3.0, -2.0], [2.5, 4.0]])
        points = np.vstack([c + rng.normal(0.0, 0.15, (5, 2)) for c in centres])
        landmarks = mrclam.Landmarks(frozen(np.arange(6, 21), np.int64), frozen(points[:, 0], np.float64),
                                     frozen(points[:, 1], np.float64), None, None)  # fmt: skip
    barcodes = frozen(np.column_stack([np.arange(1, 21), 10 * np.arange(1, 21) + 3]), np.int64)
    motion = truth.motion_model(corrected=False)
    sensor = truth.sensor(max_range=max_range)
    positions = landmarks.positions
    centre = positions.mean(axis=0)
    logs = {}
    for robot in robots:
        robot = mrclam._check_robot(robot)
        offsets = truth.robot(robot)
        steps = int(duration / STEP)
        # commands: piecewise constant, stamped every 10 ms
        commands = np.zeros((steps, 2))
        pose = np.array([centre[0], centre[1], rng.uniform(-math.pi, math.pi)])
        k = 0
        path = np.empty((steps + 1, 3))
        path[0] = pose
        stamp_time = STEP * np.arange(steps)
        latency_steps = round(truth.command_latency / STEP)
        while k < steps:
            length = int(rng.uniform(0.5, 4.0) / STEP)
            away = path[k, :2] - centre
            if np.hypot(*away) > 4.0:  # outside the arena: turn back towards its centre
                bearing = wrap_angle(math.atan2(-away[1], -away[0]) - path[k, 2])
                command = np.array([0.05, 0.5 * math.copysign(1.0, bearing)])
            elif rng.random() < 0.15:
                command = np.zeros(2)
            else:
                command = np.array([rng.uniform(0.02, 0.09), rng.uniform(-0.57, 0.57)])
            end = min(k + length, steps)
            commands[k:end] = command
            for j in range(k, end):  # the robot executes the command stamped latency earlier
                executed = commands[j - latency_steps] if j >= latency_steps else np.zeros(2)
                path[j + 1] = motion.sample_trusted(path[j], truth.correction.apply_trusted(executed), STEP, rng)
            k = end
        start_time = 1.2e9 + 1000.0 * robot
        times = start_time + STEP * np.arange(steps + 1)
        # odometry rows: every 10 ms with jitter, a few dropped stretches (the command held meanwhile)
        keep = np.ones(steps, dtype=bool)
        for _ in range(int(duration / 60.0)):
            first = int(rng.integers(0, steps))
            keep[first : first + int(rng.uniform(0.2, 1.0) / STEP)] = False
        keep[0] = True
        odo_time = start_time + stamp_time[keep] + rng.uniform(-0.001, 0.001, np.count_nonzero(keep))
        odometry = mrclam.Odometry(frozen(np.round(odo_time, 3), np.float64), frozen(commands[keep, 0], np.float64),
                                   frozen(commands[keep, 1], np.float64))  # fmt: skip
        # Vicon: from 5 s before the odometry, every 15 ms, heading theta - delta, small noise
        gt_time = np.arange(start_time - 5.0, times[-1], 0.015)
        unwrapped = np.unwrap(path[:, 2])
        before = gt_time < times[0]
        gx = np.where(before, path[0, 0], np.interp(gt_time, times, path[:, 0])) + rng.normal(0, 1e-3, len(gt_time))
        gy = np.where(before, path[0, 1], np.interp(gt_time, times, path[:, 1])) + rng.normal(0, 1e-3, len(gt_time))
        gth = np.where(before, unwrapped[0], np.interp(gt_time, times, unwrapped)) - offsets.heading_offset
        gth = wrap_angle(gth + rng.normal(0, 1e-3, len(gt_time)))
        ground_truth = mrclam.GroundTruth(*(frozen(np.round(a, 6), np.float64) for a in (gt_time, gx, gy, gth)))
        # camera frames: the pose at stamp - sensor latency
        frame_times = np.arange(times[0] + 1.0, times[-1] - 0.5, frame_period)
        rows = []
        for stamp in frame_times:
            seen_at = stamp - truth.sensor_latency
            pose_then = np.array([np.interp(seen_at, times, path[:, 0]), np.interp(seen_at, times, path[:, 1]),
                                  wrap_angle(float(np.interp(seen_at, times, unwrapped)))])  # fmt: skip
            z = sensor.predict_trusted(pose_then, positions)
            visible = np.flatnonzero((z[:, 0] <= max_range) & (np.abs(z[:, 1]) <= 0.5 * fov))
            for i in visible:
                r = z[i, 0] + sensor.range_sigma(z[i, 0])[0] * rng.standard_normal()
                phi = z[i, 1] + truth.sigma_bearing * rng.standard_normal() + offsets.bearing_bias
                if rng.random() < outlier_fraction:
                    phi += rng.uniform(-math.pi, math.pi)
                    r *= rng.uniform(0.5, 1.5)
                rows.append((stamp, landmarks.subject[i], abs(r), wrap_angle(float(phi))))
        table = np.array(rows) if rows else np.empty((0, 4))
        subject = table[:, 1].astype(np.int64)
        measurements = mrclam.Measurements(
            time=frozen(np.round(table[:, 0], 3), np.float64), subject=frozen(subject, np.int64),
            barcode=frozen(10 * subject + 3, np.int64), range=frozen(table[:, 2], np.float64),
            bearing=frozen(table[:, 3], np.float64),
        )  # fmt: skip
        empty = mrclam.Measurements(*(frozen(np.empty(0), d) for d in (np.float64, np.int64, np.int64, np.float64,
                                                                        np.float64)))  # fmt: skip
        logs[robot] = mrclam.MrclamLog(robot, odometry, measurements, empty, ground_truth, landmarks, barcodes,
                                       frozen(np.empty(0), np.int64), Path("simulated"))  # fmt: skip
    return logs


def write_dataset(folder: str | os.PathLike[str], logs: Mapping[int, mrclam.MrclamLog]) -> Path:
    """Write ``logs`` (one dataset) in the MRCLAM text format to ``folder``; returns the folder.

    ``Barcodes.dat`` and ``Landmark_Groundtruth.dat`` come from the first log;
    :func:`seif_gym.datasets.mrclam.load` reads the folder back.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if not logs:
        raise ValueError("logs must not be empty")
    first = next(iter(logs.values()))
    np.savetxt(folder / mrclam.BARCODES_FILE, first.barcodes, fmt="%d", header="Subject #    Barcode #")
    lm = first.landmarks
    columns: list[NDArray] = [lm.subject, lm.x, lm.y]
    if lm.std_x is not None and lm.std_y is not None:
        columns += [lm.std_x, lm.std_y]
    np.savetxt(folder / mrclam.LANDMARKS_FILE, np.column_stack(columns), fmt=["%d"] + ["%.9f"] * (len(columns) - 1),
               header="Subject #    x [m]    y [m]    x std-dev [m]    y std-dev [m]")  # fmt: skip
    for robot, log in logs.items():
        odo, gt, m = log.odometry, log.ground_truth, log.measurements
        np.savetxt(
            folder / f"Robot{robot}_Odometry.dat",
            np.column_stack([odo.time, odo.v, odo.omega]),
            fmt=["%.3f", "%.6f", "%.6f"],
            header="Time [s]    Forward velocity [m/s]    Angular velocity[rad/s]",
        )
        np.savetxt(
            folder / f"Robot{robot}_Groundtruth.dat",
            np.column_stack([gt.time, gt.x, gt.y, gt.theta]),
            fmt=["%.3f", "%.7f", "%.7f", "%.7f"],
            header="Time [s]    x [m]    y [m]    Orientation [rad]",
        )
        readings = np.column_stack([m.time, m.barcode, m.range, m.bearing])
        sightings = np.column_stack([log.robot_sightings.time, log.robot_sightings.barcode,
                                     log.robot_sightings.range, log.robot_sightings.bearing])  # fmt: skip
        table = np.vstack([readings, sightings])
        table = table[np.argsort(table[:, 0], kind="stable")]
        np.savetxt(folder / f"Robot{robot}_Measurement.dat", table, fmt=["%.3f", "%d", "%.7f", "%.7f"],
                   header="Time [s]    Subject #    range [m]    bearing [rad]")  # fmt: skip
    return folder


# ---------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------
def summary(calibration: Calibration) -> str:
    """A short human-readable table of a calibration."""
    c = calibration.correction
    lines = [
        (
            f"command correction  v' = {c.speed_scale:.4f} v max(0, 1 - {c.turn_slowdown:.3f}|w|) + {c.speed_offset:+.4f}, "
            f"w' = {c.turn_scale:.4f} w + {c.turn_offset:+.5f}"
        ),
        f"command latency     {calibration.command_latency:.3f} s",
        f"motion noise (per second, fitted at {calibration.horizon:g} s; constant, per v^2, per w^2)",
        f"  forward [m^2/s]   {calibration.forward[0]:.3e}  {calibration.forward[1]:.3e}  {calibration.forward[2]:.3e}",
        f"  turn  [rad^2/s]   {calibration.turn[0]:.3e}  {calibration.turn[1]:.3e}  {calibration.turn[2]:.3e}",
        f"  lateral [m^2/s]   {calibration.lateral[0]:.3e}  {calibration.lateral[1]:.3e}  {calibration.lateral[2]:.3e}",
        (
            f"range noise         sigma_r = clip({calibration.range_slope:.4f} r, {calibration.range_bounds[0]:.4f}, "
            f"{calibration.range_bounds[1]:.4f}) m"
        ),
        f"bearing noise       sigma_phi = {calibration.sigma_bearing:.4f} rad",
        f"sensor latency      {calibration.sensor_latency:.3f} s",
        "robot  heading offset [mrad]  bearing bias [mrad]  range bias [m]",
    ]
    for robot, r in sorted(calibration.robots.items()):
        lines.append(f"{robot:5d}  {1e3 * r.heading_offset:21.1f}  {1e3 * r.bearing_bias:19.1f}  {r.range_bias:14.4f}")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m seif_gym.datasets.mrclam calibrate",
        description="Calibrate the command correction, per-second motion noise and sensor noise of MRCLAM robots "
        "from their Vicon ground truth; writes a JSON file that the runner and the env read.",
    )
    parser.add_argument("--data", default=None,
                        help="an MRCLAM dataset folder (default: $SEIF_GYM_DATA/mrclam/MRCLAM_Dataset6)")  # fmt: skip
    parser.add_argument("--robots", type=int, nargs="+", default=list(mrclam.ROBOTS), help="robots (default: all)")
    parser.add_argument("--out", default="mrclam_calibration.json", help="output JSON file")
    parser.add_argument("--horizon", type=float, default=20.0, help="window (s) the motion noise is fitted at")
    parser.add_argument("--fit-offsets", action="store_true", help="also fit the command offsets b_v, b_w")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m seif_gym.datasets.mrclam calibrate ...``; returns the exit status.

    2 for bad arguments, and for data not found or malformed (one line on
    stderr naming the file and the line).
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    robots = sorted(set(args.robots))
    unknown = sorted(set(robots) - set(mrclam.ROBOTS))
    if unknown:
        parser.error(f"--robots: unknown robot(s) {unknown}; the datasets have {list(mrclam.ROBOTS)}")

    def command() -> int:
        output_file(args.out, "--out")  # before any work: an --out that cannot be written fails at once
        logs = [mrclam.load(args.data, robot) for robot in robots]

        def progress(message: str) -> None:
            if not args.quiet:
                print(f"  {message} ...", file=sys.stderr, flush=True)

        calibration = calibrate(logs, horizon=args.horizon, fit_offsets=args.fit_offsets, progress=progress)
        path = calibration.save(args.out)
        if not args.quiet:
            print(summary(calibration))
            print(f"wrote {path}")
        return 0

    return run_cli(parser.prog, command)


if __name__ == "__main__":  # ``python -m seif_gym.datasets.mrclam.calibration``: the module's own main (imported once)
    from seif_gym.datasets.mrclam import calibration as _command_module

    sys.exit(_command_module.main())
