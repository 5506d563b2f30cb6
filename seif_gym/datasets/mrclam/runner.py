"""Run a SLAM filter of :mod:`seif_gym.slam` on MRCLAM logs and score it against Vicon and the survey.

``python -m seif_gym.datasets.mrclam [--data DIR] --robot N|all --filter ekf|eif|seif|eseif|cseif --out OUT.npz
[--association known|ml] [--calibration FILE]``

For each robot (:func:`run_robot`):

* the models come from a :class:`~seif_gym.datasets.mrclam.calibration.Calibration`
  (``--calibration FILE``; without it, the dataset's own ground truth is
  calibrated first, :func:`~seif_gym.datasets.mrclam.calibration.calibrate`):
  per-second motion noise, command correction and latency, range-dependent
  range noise, bearing and range biases, sensor latency, heading offset;
* the filter starts at the ground-truth pose at the first odometry time
  (heading plus the robot's heading offset), with a tiny covariance: the map
  frame is anchored there;
* it predicts on a regular schedule (at most ``predict_step`` seconds, and at
  every camera frame) with the mean of the corrected commands over each
  interval (commands take effect ``command_latency`` after their stamps and
  are held across gaps); a camera frame, dated ``sensor_latency`` before its
  stamp, updates the filter with known correspondences (the barcodes'
  subjects) or with the :class:`~seif_gym.slam.association.Associator`;
* an innovation gate rejects misreads; because the sensor errors of one
  landmark are strongly correlated in time (the calibration measures
  ~0.9 at 1 s and ~0.7 at 5 s for the range, and persistent per-landmark
  biases of up to ~0.15 m), a landmark is used at most once every
  ``min_interval`` seconds (with data association: a frame at most once
  every ``min_interval`` seconds, since the barcodes are not used) and ``Q``
  is inflated by ``noise_inflation``. The defaults (2 s, 12) were chosen on
  Dataset 6 with the EKF (``docs/data/mrclam.md``): they are tuned, not derived.

Scores (:func:`score`): pose RMSE against Vicon *anchored* (the filter's
frame is the ground truth's, through the initial pose) and after the rigid
alignment of the map to the survey, the map RMSE against the survey (both),
the ANEES of the pose (3 degrees of freedom) with the 95 % band of a
chi-square mean, and the time.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time as clock
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.stats

from seif_gym.datasets._files import DataNotFoundError, npz_path, output_file, run_cli, save_figure, save_npz
from seif_gym.datasets._geometry import rigid_alignment
from seif_gym.datasets.mrclam import loader as mrclam
from seif_gym.datasets.mrclam.calibration import Calibration, calibrate
from seif_gym.progress import Progress
from seif_gym.slam.models import wrap_angle
from seif_gym.slam.noise_models import RangeDependentSensor
from seif_gym.type_aliases import FloatArray, IntArray

if TYPE_CHECKING:
    from seif_gym.slam.association import Associator
    from seif_gym.slam.base import SlamFilter

__all__ = ["MrclamRun", "RunnerConfig", "chi2_band", "main", "plot_runs", "run_robot", "save_runs", "score", "table"]


FILTER_NAMES = ("ekf", "eif", "seif", "eseif", "cseif")


@dataclass(frozen=True)
class RunnerConfig:
    """How the runner feeds a filter (see the module docstring).

    Attributes
    ----------
    predict_step : float
        Longest prediction, s.
    innovation_gate : float or None
        The filters' ``innovation_gate`` (squared Mahalanobis distance, 2 dof).
    min_interval : float
        A landmark is used at most once per this many seconds.
    noise_inflation : float
        Factor on the sensor's ``Q``.
    max_active : dict
        ``max_active`` per filter name (SEIF and ConservativeSEIF ``k = 8``, ESEIF ``k = 4``).
    initial_std : float
        Standard deviation of each initial pose component (m, rad).
    subtract_range_bias : bool
        Subtract the calibrated per-robot range bias from the ranges.
    max_range : float
        Readings beyond this range are left out, m.
    """

    predict_step: float = 0.25
    innovation_gate: float | None = 13.8
    min_interval: float = 2.0
    noise_inflation: float = 12.0
    max_active: dict[str, int] = field(default_factory=lambda: {"seif": 8, "eseif": 4, "cseif": 8})
    initial_std: float = 1e-3
    subtract_range_bias: bool = True
    max_range: float = 10.0


@dataclass
class MrclamRun:
    """One filter's run over one robot's log.

    Attributes
    ----------
    robot : int
    filter_name : str
    time : float64 (k,)
        Times of the estimates (UNIX s), one per prediction step.
    pose : float64 (k, 3)
        Estimated poses.
    pose_covariance : float64 (k, 3, 3)
        Their marginal covariances.
    truth : float64 (k, 3)
        Vicon poses at those times (heading plus the heading offset); NaN
        where the ground truth has no sample.
    landmarks : float64 (m, 2)
        Final map.
    landmark_ids : int64 (m,)
        Survey subject numbers of the map's landmarks (-1: no survey landmark,
        with data association).
    seconds : float
        Wall time of the filter loop (models and data preparation excluded).
    readings, used, gated, thinned : int
        Landmark readings in the log, used by the filter, rejected by the
        gate, left out by the thinning.
    scores : dict
        :func:`score`'s figures.
    """

    robot: int
    filter_name: str
    time: FloatArray
    pose: FloatArray
    pose_covariance: FloatArray
    truth: FloatArray
    landmarks: FloatArray
    landmark_ids: IntArray
    seconds: float
    readings: int = 0
    used: int = 0
    gated: int = 0
    thinned: int = 0
    scores: dict[str, float] = field(default_factory=dict)


def _sensor(calibration: Calibration, config: RunnerConfig) -> RangeDependentSensor:
    root = math.sqrt(config.noise_inflation)
    lo, hi = calibration.range_bounds
    return RangeDependentSensor(calibration.range_slope * root, (lo * root, hi * root),
                                calibration.sigma_bearing * root, max_range=config.max_range)  # fmt: skip


def _make_filter(filter_name: str, calibration: Calibration, config: RunnerConfig, pose: FloatArray) -> SlamFilter:
    from seif_gym.slam import FILTERS

    if filter_name not in FILTER_NAMES:
        raise ValueError(f"filter must be one of {FILTER_NAMES}, got {filter_name!r}")
    options: dict[str, Any] = {"innovation_gate": config.innovation_gate}
    if filter_name in config.max_active:
        options["max_active"] = config.max_active[filter_name]
    cov = np.eye(3) * config.initial_std**2
    return FILTERS[filter_name](calibration.motion_model(corrected=False), _sensor(calibration, config), pose, cov,
                                **options)  # fmt: skip


def thin_frame(
    rows: IntArray, subjects: IntArray, now: float, last_used: dict[int, float], min_interval: float
) -> tuple[IntArray, int]:
    """The readings of one frame to use: each landmark at most once per ``min_interval`` s, one per frame.

    ``rows`` index ``subjects``; ``last_used`` (landmark -> time) is updated
    for the readings kept. Returns the kept rows (in their order) and how many
    were left out by the interval.
    """
    thinned = 0
    if min_interval > 0.0:
        fresh = np.array([now - last_used.get(int(s), -np.inf) >= min_interval for s in subjects[rows].tolist()],
                         dtype=bool)  # fmt: skip
        thinned = int(len(rows) - np.count_nonzero(fresh))
        rows = rows[fresh]
    _, first = np.unique(subjects[rows], return_index=True)
    rows = rows[np.sort(first)]
    for s in subjects[rows].tolist():
        last_used[s] = now
    return rows, thinned


def mean_controls(log: mrclam.MrclamLog, calibration: Calibration, edges: FloatArray) -> FloatArray:
    """Mean corrected control over each interval ``[edges[i], edges[i + 1]]`` (commands held, latency applied)."""
    odo = log.odometry
    corrected = calibration.correction.apply(odo.controls)
    start = odo.time + calibration.command_latency
    # the integral of the piecewise-constant corrected controls, zero before the first command
    cumulative = np.vstack([np.zeros(2), np.cumsum(corrected[:-1] * np.diff(start)[:, None], axis=0)])

    def integral(t: FloatArray) -> FloatArray:
        k = np.searchsorted(start, t, side="right") - 1
        before = k < 0
        k = np.maximum(k, 0)
        value = cumulative[k] + corrected[k] * (t - start[k])[:, None]
        value[before] = 0.0
        return value

    totals = integral(edges)
    return np.diff(totals, axis=0) / np.diff(edges)[:, None]


def ground_truth(log: mrclam.MrclamLog, times: FloatArray, heading_offset: float, max_gap: float = 0.25) -> FloatArray:
    gt = log.ground_truth
    truth = np.full((len(times), 3), np.nan)
    inside = (times >= gt.time[0]) & (times <= gt.time[-1])
    after = np.clip(np.searchsorted(gt.time, times), 1, len(gt.time) - 1)
    inside &= (gt.time[after] - gt.time[after - 1]) <= max_gap
    t = times[inside]
    truth[inside, 0] = np.interp(t, gt.time, gt.x)
    truth[inside, 1] = np.interp(t, gt.time, gt.y)
    truth[inside, 2] = wrap_angle(np.interp(t, gt.time, np.unwrap(gt.theta)) + heading_offset)
    return truth


def run_robot(
    log: mrclam.MrclamLog,
    filter_name: str,
    calibration: Calibration,
    config: RunnerConfig = RunnerConfig(),
    association: str = "known",
    progress: bool = False,
) -> MrclamRun:
    """Run ``filter_name`` over one robot's log (module docstring) and score it (:func:`score`).

    Parameters
    ----------
    log : MrclamLog
        From :func:`seif_gym.datasets.mrclam.load`.
    filter_name : {"ekf", "eif", "seif", "eseif", "cseif"}
    calibration : Calibration
    config : RunnerConfig
    association : {"known", "ml"}
        Known correspondences (barcodes) or maximum-likelihood data association.
    progress : bool
        Show a progress bar on stderr.
    """
    if not isinstance(log, mrclam.MrclamLog):
        raise TypeError(f"log must be an MrclamLog, got {type(log).__name__}")
    if association not in ("known", "ml"):
        raise ValueError(f"association must be 'known' or 'ml', got {association!r}")
    if not isinstance(calibration, Calibration):
        raise TypeError(f"calibration must be a Calibration, got {type(calibration).__name__}")
    offsets = calibration.robot(log.robot)
    odo, meas = log.odometry, log.measurements
    start, end = float(odo.time[0]), float(odo.time[-1])
    # camera frames, dated sensor_latency before their stamps, inside the odometry's span
    frame_stamps, frame_start = meas.frames()
    frame_times = frame_stamps - calibration.sensor_latency
    keep_frames = np.flatnonzero((frame_times > start) & (frame_times <= end))
    # the schedule: every frame, and enough steps between for predict_step
    grid = np.arange(start, end, config.predict_step)[1:]
    edges = np.union1d(np.concatenate([[start], grid, [end]]), frame_times[keep_frames])
    is_frame = np.zeros(len(edges), dtype=bool)
    frame_at = np.full(len(edges), -1, dtype=np.int64)
    positions = np.searchsorted(edges, frame_times[keep_frames])
    is_frame[positions] = True
    frame_at[positions] = keep_frames
    controls = mean_controls(log, calibration, edges)
    dts = np.diff(edges)
    initial = ground_truth(log, np.array([start]), offsets.heading_offset)[0]
    if not np.all(np.isfinite(initial)):
        raise ValueError(f"robot {log.robot}: no ground truth at the first odometry time")
    filt = _make_filter(filter_name, calibration, config, initial)
    associator = None
    if association == "ml":
        from seif_gym.slam.association import make_associator

        associator = make_associator("joint")  # the preset these runs were measured with
    ranges_all = meas.range - (offsets.range_bias if config.subtract_range_bias else 0.0)
    bearings_all = wrap_angle(meas.bearing - offsets.bearing_bias)
    subjects_all = meas.subject
    last_used: dict[int, float] = {}
    last_frame = -np.inf
    steps = len(dts)
    poses = np.empty((steps, 3))
    covariances = np.empty((steps, 3, 3))
    used = thinned = 0
    bar = Progress(max(steps, 1), f"{filter_name} robot {log.robot}", enabled=progress, unit="step")
    predict, update = filt.predict_trusted, filt.update_trusted
    started = clock.perf_counter()
    for k in range(steps):
        dt = float(dts[k])
        if dt > 1e-9:
            predict(controls[k], dt)
        j = k + 1
        if is_frame[j]:
            frame = int(frame_at[j])
            rows = np.arange(frame_start[frame], frame_start[frame + 1])
            rows = rows[ranges_all[rows] <= config.max_range]
            now = float(edges[j])
            if associator is None:  # each landmark at most once per min_interval, one reading per frame
                rows, left_out = thin_frame(rows, subjects_all, now, last_used, config.min_interval)
                thinned += left_out
            elif (
                now - last_frame < config.min_interval
            ):  # unknown landmarks: whole frames at most once per min_interval
                thinned += len(rows)
                rows = rows[:0]
            if len(rows):
                ranges = np.ascontiguousarray(ranges_all[rows])
                bearings = np.ascontiguousarray(bearings_all[rows])
                if associator is None:
                    update(ranges, bearings, np.ascontiguousarray(subjects_all[rows]))
                else:
                    associator.update(filt, ranges, bearings)
                used += len(rows)
                last_frame = now
                for s in subjects_all[rows].tolist():
                    last_used[s] = now
        poses[k] = filt.pose
        covariances[k] = filt.pose_covariance
        if progress and (k + 1) % 500 == 0:
            bar.update(500, f"landmarks {filt.num_landmarks}")
    seconds = clock.perf_counter() - started
    bar.update(steps - bar.done)
    bar.close()
    times = edges[1:]
    landmark_ids = np.array(filt.landmark_ids, dtype=np.int64)
    if associator is not None:  # name each landmark by the subject whose readings created it
        landmark_ids = _subjects_of(filt, log, associator, landmark_ids)
    result = MrclamRun(
        robot=log.robot, filter_name=filter_name, time=times, pose=poses, pose_covariance=covariances,
        truth=ground_truth(log, times, offsets.heading_offset), landmarks=np.array(filt.landmarks),
        landmark_ids=landmark_ids, seconds=seconds, readings=len(meas), used=used - filt.gated_measurements,
        gated=filt.gated_measurements, thinned=thinned,
    )  # fmt: skip
    result.scores = score(result, log.landmarks)
    return result


def _subjects_of(filt: SlamFilter, log: mrclam.MrclamLog, associator: Associator | None, ids: IntArray) -> IntArray:
    """Survey subject of each associator landmark: the nearest surveyed landmark after a rigid alignment."""
    survey = log.landmarks.positions
    estimate = np.asarray(filt.landmarks)
    if len(estimate) == 0:
        return ids
    nearest = np.argmin(np.linalg.norm(estimate[:, None] - survey[None], axis=2), axis=1)
    if len(estimate) >= 2:
        rotation, translation = rigid_alignment(estimate, survey[nearest])
        aligned = estimate @ rotation.T + translation
        nearest = np.argmin(np.linalg.norm(aligned[:, None] - survey[None], axis=2), axis=1)
    return log.landmarks.subject[nearest].astype(np.int64)


def chi2_band(dof: int, samples: int, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided ``probability`` band of the mean of ``samples`` independent ``chi2(dof)`` values."""
    low = scipy.stats.chi2.ppf(0.5 * (1.0 - probability), dof * samples) / samples
    high = scipy.stats.chi2.ppf(0.5 * (1.0 + probability), dof * samples) / samples
    return float(low), float(high)


def score(run: MrclamRun, landmarks: mrclam.Landmarks) -> dict[str, float]:
    """Pose and map errors of a run against Vicon and the survey.

    Returns
    -------
    dict
        ``pose_rmse_anchored``, ``pose_rmse_aligned`` (m: position RMSE over
        the estimates with ground truth, in the filter's frame and after the
        rigid alignment of the map to the survey), ``map_rmse_anchored``,
        ``map_rmse_aligned`` (m, over the mapped surveyed landmarks),
        ``heading_rmse`` (rad), ``anees`` (mean pose NEES, 3 dof),
        ``anees_low``, ``anees_high`` (its 95 % chi-square band for that many
        independent samples), ``nees_in_95`` (share of steps whose NEES is
        inside the 95 % two-sided interval of ``chi2(3)``), ``seconds``.

    Notes
    -----
    The alignment ``(R, t)`` minimises ``sum |R m_i + t - s_i|^2`` over the
    mapped landmarks ``m_i`` and their surveyed positions ``s_i``
    (:func:`~seif_gym.datasets.victoria_park.rigid_alignment`); the
    trajectory is moved by the same ``(R, t)``. NEES uses the anchored poses.
    """
    from seif_gym.metrics import pose_nees

    have = np.all(np.isfinite(run.truth), axis=1)
    error = run.pose[have, :2] - run.truth[have, :2]
    scores: dict[str, float] = {"seconds": float(run.seconds), "steps_with_truth": float(np.count_nonzero(have))}
    scores["pose_rmse_anchored"] = float(np.sqrt(np.mean(np.sum(error**2, axis=1)))) if have.any() else math.nan
    scores["heading_rmse"] = (float(np.sqrt(np.mean(wrap_angle(run.pose[have, 2] - run.truth[have, 2]) ** 2)))
                              if have.any() else math.nan)  # fmt: skip
    known = np.isin(run.landmark_ids, landmarks.subject)
    mapped, ids = run.landmarks[known], run.landmark_ids[known]
    survey = landmarks.positions[landmarks.index(ids)] if len(ids) else np.empty((0, 2))
    scores["landmarks_mapped"] = float(len(np.unique(ids)))
    scores["map_rmse_anchored"] = (
        float(np.sqrt(np.mean(np.sum((mapped - survey) ** 2, axis=1)))) if len(ids) else math.nan
    )
    if len(np.unique(ids)) >= 2:
        rotation, translation = rigid_alignment(mapped, survey)
        aligned_map = mapped @ rotation.T + translation
        scores["map_rmse_aligned"] = float(np.sqrt(np.mean(np.sum((aligned_map - survey) ** 2, axis=1))))
        aligned = run.pose[have, :2] @ rotation.T + translation
        scores["pose_rmse_aligned"] = float(np.sqrt(np.mean(np.sum((aligned - run.truth[have, :2]) ** 2, axis=1))))
        scores["alignment_rotation"] = float(math.atan2(rotation[1, 0], rotation[0, 0]))
    else:
        scores["map_rmse_aligned"] = scores["pose_rmse_aligned"] = scores["alignment_rotation"] = math.nan
    if have.any():
        nees = np.asarray(pose_nees(run.truth[have], run.pose[have], run.pose_covariance[have]))
        scores["anees"] = float(np.mean(nees))
        scores["anees_low"], scores["anees_high"] = chi2_band(3, len(nees))
        low, high = scipy.stats.chi2.ppf([0.025, 0.975], 3)
        scores["nees_in_95"] = float(np.mean((nees >= low) & (nees <= high)))
    else:
        scores["anees"] = scores["anees_low"] = scores["anees_high"] = scores["nees_in_95"] = math.nan
    return scores


# ---------------------------------------------------------------------------
# Files
# ---------------------------------------------------------------------------
def save_runs(runs: Sequence[MrclamRun], path: str | os.PathLike[str]) -> Path:
    """Write runs to one ``.npz``, whole or not at all: per run ``r{robot}_{name}`` arrays (``time``, ``pose``, ...).

    Returns the file written (``.npz`` appended to ``path`` when missing).

    With one run the arrays are also stored under their plain names
    (``time``, ``pose`` (N x 3), ``pose_covariance`` (N x 3 x 3), ``truth``,
    ``landmarks`` (M x 2), ``landmark_ids`` (survey subjects)).
    """
    arrays: dict[str, Any] = {}
    for run in runs:
        prefix = f"r{run.robot}_"
        for name in ("time", "pose", "pose_covariance", "truth", "landmarks", "landmark_ids"):
            arrays[prefix + name] = getattr(run, name)
        arrays[prefix + "scores"] = np.array(sorted(run.scores.items()), dtype=object).astype(str)
    if len(runs) == 1:
        for name in ("time", "pose", "pose_covariance", "truth", "landmarks", "landmark_ids"):
            arrays[name] = getattr(runs[0], name)
    arrays["robots"] = np.array([run.robot for run in runs], dtype=np.int64)
    arrays["filter"] = np.str_(runs[0].filter_name if runs else "")
    return save_npz(path, arrays)


def plot_runs(
    runs: Sequence[MrclamRun], landmarks: mrclam.Landmarks, path: str | os.PathLike[str], title: str | None = None
) -> Path:
    """Trajectories against Vicon and maps against the survey, one panel per robot (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    count = max(len(runs), 1)
    figure, axes = plt.subplots(1, count, figsize=(3.2 * count, 5.2), squeeze=False)
    for axis, run in zip(axes[0], runs):
        have = np.all(np.isfinite(run.truth), axis=1)
        axis.plot(run.truth[have, 0], run.truth[have, 1], color="0.6", lw=0.8, label="Vicon")
        axis.plot(run.pose[:, 0], run.pose[:, 1], color="tab:blue", lw=0.8, label=run.filter_name.upper())
        axis.scatter(landmarks.x, landmarks.y, marker="x", color="k", s=25, label="survey")
        axis.scatter(run.landmarks[:, 0], run.landmarks[:, 1], facecolors="none", edgecolors="tab:red", s=25,
                     label="map")  # fmt: skip
        s = run.scores
        axis.set_title(f"robot {run.robot}: {s.get('pose_rmse_anchored', math.nan):.2f} m, "
                       f"ANEES {s.get('anees', math.nan):.1f}", fontsize=9)  # fmt: skip
        axis.set_aspect("equal")
        axis.tick_params(labelsize=7)
    axes[0][0].legend(fontsize=7, loc="lower left")
    if title:
        figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    path = save_figure(figure, path, dpi=110)
    plt.close(figure)
    return path


def table(runs: Sequence[MrclamRun]) -> str:
    """The scores of runs as a text table (one row per robot, then the mean)."""
    head = (f"{'robot':>5} {'filter':>6} {'anchored':>9} {'aligned':>8} {'map':>6} {'map al.':>7} "
            f"{'ANEES':>7} {'95% band':>13} {'gated':>5} {'time':>6}")  # fmt: skip
    lines = [head, "-" * len(head)]
    for run in runs:
        s = run.scores
        lines.append(
            f"{run.robot:>5} {run.filter_name:>6} {s['pose_rmse_anchored']:9.3f} {s['pose_rmse_aligned']:8.3f} "
            f"{s['map_rmse_anchored']:6.3f} {s['map_rmse_aligned']:7.3f} {s['anees']:7.2f} "
            f"[{s['anees_low']:.2f}, {s['anees_high']:.2f}] {run.gated:5d} {run.seconds:5.2f}s"
        )
    if len(runs) > 1:
        mean = {key: float(np.mean([r.scores[key] for r in runs]))
                for key in ("pose_rmse_anchored", "pose_rmse_aligned", "map_rmse_anchored", "map_rmse_aligned", "anees")}  # fmt: skip
        lines.append(
            f"{'mean':>5} {runs[0].filter_name:>6} {mean['pose_rmse_anchored']:9.3f} {mean['pose_rmse_aligned']:8.3f} "
            f"{mean['map_rmse_anchored']:6.3f} {mean['map_rmse_aligned']:7.3f} {mean['anees']:7.2f} {'':>13} "
            f"{sum(r.gated for r in runs):5d} {sum(r.seconds for r in runs):5.2f}s"
        )
    return "\n".join(lines)


# ---------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m seif_gym.datasets.mrclam",
        description="Run a SLAM filter on MRCLAM logs; score it against Vicon and the survey. "
        "(Subcommands: 'calibrate' and 'episodes', see python -m seif_gym.datasets.mrclam calibrate --help.)",
    )
    parser.add_argument("--data", default=None,
                        help="an MRCLAM dataset folder (default: $SEIF_GYM_DATA/mrclam/MRCLAM_Dataset6)")  # fmt: skip
    parser.add_argument("--robot", default="all", help="robot 1..5, or 'all' (default: every robot in the folder)")
    parser.add_argument("--filter", default="ekf", choices=FILTER_NAMES, help="the filter (default ekf)")
    parser.add_argument("--out", default="mrclam_run.npz", help="output .npz (a .png plot is written beside it)")
    parser.add_argument("--association", default="known", choices=("known", "ml"), help="data association")
    parser.add_argument("--calibration", default=None,
                        help="calibration JSON (python -m seif_gym.datasets.mrclam calibrate); "
                        "default: calibrate the dataset's ground truth first")  # fmt: skip
    parser.add_argument(
        "--max-active", type=int, default=None, help="k of the SEIF (8), ESEIF (4) or ConservativeSEIF (8)"
    )
    parser.add_argument("--gate", type=float, default=RunnerConfig.innovation_gate,
                        help="innovation gate, squared Mahalanobis distance (default 13.8; 0 = none)")  # fmt: skip
    parser.add_argument("--min-interval", type=float, default=RunnerConfig.min_interval,
                        help="use a landmark at most once per this many seconds")  # fmt: skip
    parser.add_argument("--inflation", type=float, default=RunnerConfig.noise_inflation, help="factor on Q")
    parser.add_argument("--predict-step", type=float, default=RunnerConfig.predict_step, help="longest prediction, s")
    parser.add_argument("--no-plot", action="store_true", help="do not write the plot")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def _robots(text: str, folder: str | os.PathLike[str] | None = None) -> list[int]:
    """The robots of ``--robot``: one, or ``all`` the robots whose odometry file ``folder`` holds."""
    if text == "all":
        if folder is None:
            return list(mrclam.ROBOTS)
        present = [r for r in mrclam.ROBOTS if (Path(folder) / f"Robot{r}_Odometry.dat").is_file()]
        if not present:
            raise DataNotFoundError(f"MRCLAM data not found: no RobotN_Odometry.dat in {folder}")
        return present
    try:
        return [mrclam._check_robot(int(text))]
    except ValueError as error:
        raise ValueError(f"--robot must be 1..5 or 'all', got {text!r}") from error


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m seif_gym.datasets.mrclam ...`` (the runner); returns the exit status.

    2 for bad arguments, and for data or a calibration file not found or
    malformed (one line on stderr naming the file and the line).
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.robot != "all":
        try:
            _robots(args.robot)
        except ValueError as error:
            parser.error(str(error))
    return run_cli(parser.prog, lambda: _command(args))


def _command(args: argparse.Namespace) -> int:
    """The runner's work, after its arguments are parsed."""
    output_file(npz_path(args.out), "--out")  # before any work: an --out that cannot be written fails at once
    given = None if args.calibration is None else Calibration.load(args.calibration)  # a bad file fails first
    folder = mrclam.locate(args.data)
    robots = _robots(args.robot, folder)
    logs = {robot: mrclam.load(folder, robot) for robot in robots}
    if given is None:
        if not args.quiet:
            print("no --calibration: calibrating the dataset's ground truth first", file=sys.stderr)
        calibration = calibrate(logs)
    else:
        calibration = given
    max_active = dict(RunnerConfig().max_active)
    if args.max_active is not None:
        max_active[args.filter] = args.max_active
    config = replace(RunnerConfig(), innovation_gate=args.gate if args.gate > 0 else None,
                     min_interval=args.min_interval, noise_inflation=args.inflation, predict_step=args.predict_step,
                     max_active=max_active)  # fmt: skip
    runs = [run_robot(logs[r], args.filter, calibration, config, args.association, progress=not args.quiet)
            for r in robots]  # fmt: skip
    out = save_runs(runs, args.out)
    print(table(runs))
    if not args.no_plot:
        plot = plot_runs(runs, logs[robots[0]].landmarks, out.with_suffix(".png"),
                         title=f"{args.filter.upper()} on {folder.name}")  # fmt: skip
        print(f"wrote {out} and {plot}")
    else:
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":  # ``python -m seif_gym.datasets.mrclam.runner``: the module's own main (imported once)
    from seif_gym.datasets.mrclam import runner as _command_module

    sys.exit(_command_module.main())
