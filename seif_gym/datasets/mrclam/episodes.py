r"""Real MRCLAM logs as :class:`~seif_gym.episodes.Episode`\ s: every filter of the harness on real data.

.. code-block:: bash

    python -m seif_gym.datasets.mrclam episodes [--data DIR] --out mrclam_episodes \
        [--calibration FILE] [--robots 1 2] [--dt 0.05]
    python -m seif_gym.harness --episodes-dir mrclam_episodes --filters ekf,eif,seif-k8,eseif-k4 --out eval/mrclam

:func:`log_to_episode` turns one robot's log into an episode of
``SeifExplore`` whose configuration holds the calibrated models
(``motion_model="per_second"``, ``range_noise``, the runner's noise
inflation and innovation gate; :meth:`Calibration.env_kwargs`), so that
:func:`seif_gym.episodes.replay`, :func:`seif_gym.harness.score_episode` and
``python -m seif_gym.harness --episodes-dir`` run every filter on the real
readings exactly as on simulated episodes. What the conversion does, and
where it differs from the runner (:mod:`seif_gym.datasets.mrclam.runner`):

* **Time grid.** An episode has a fixed step ``dt`` (default 0.05 s, five
  odometry commands). The controls of a step are the mean *corrected*
  commands over it (the calibrated command correction and latency, as the
  runner predicts). A camera frame, dated ``sensor_latency`` before its stamp,
  is measured at the end of the step it falls in: up to ``dt`` late (at the
  robots' 0.57 rad/s at most, 0.03 rad of bearing; the runner predicts to
  each frame's time exactly).
* **Readings.** As the runner's: ranges beyond ``max_range`` left out, one
  reading per landmark and frame, each landmark at most once per
  ``min_interval`` seconds (the errors are correlated in time), the
  calibrated per-robot range and bearing biases subtracted. Landmark ids are
  the rows of the survey (subject ``s`` is row ``s − 6`` in Dataset 6).
* **Truth.** Vicon poses interpolated at the step times (heading plus the
  calibrated heading offset, linearly across Vicon's dropouts); the episode
  ends at the last odometry command or the last Vicon sample, whichever comes
  first. The landmarks are the survey's.
* **Recorded estimate.** ``estimated_poses`` and ``map_errors`` are those of
  the configuration's own filter (``filter``, ``max_active``) replayed over the
  episode, so that replaying it reproduces them bit for bit, as for a
  recorded episode; ``rewards`` are the decreases of the map error.

The episode's ``seed`` is ``None`` and its ``layout`` the env's default (the
world is the survey's, not a generated one).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from seif_gym.datasets._files import output_folder, run_cli
from seif_gym.datasets.mrclam import loader as mrclam
from seif_gym.datasets.mrclam.calibration import DATASET6, Calibration
from seif_gym.datasets.mrclam.runner import ground_truth, mean_controls, thin_frame
from seif_gym.envs.explore import SeifExploreEnv
from seif_gym.episodes import Episode, replay
from seif_gym.progress import Progress
from seif_gym.slam.models import wrap_angle

__all__ = ["EpisodeConversion", "log_to_episode", "main"]


@dataclass(frozen=True)
class EpisodeConversion:
    """How a log becomes an episode (module docstring); the defaults are the runner's settings.

    Attributes
    ----------
    dt : float
        Seconds per step.
    min_interval : float
        A landmark is used at most once per this many seconds.
    noise_inflation : float
        Factor on the sensor's calibrated ``Q`` (range and bearing).
    innovation_gate : float or None
        The filters' gate (squared Mahalanobis distance, 2 dof).
    max_range : float
        Readings beyond this range are left out, m.
    filter : str
        The filter whose estimate the episode records.
    max_active : int
        Its ``k`` (SEIF, ESEIF).
    """

    dt: float = 0.05
    min_interval: float = 2.0
    noise_inflation: float = 12.0
    innovation_gate: float | None = 13.8
    max_range: float = 10.0
    filter: str = "seif"
    max_active: int = 8

    def __post_init__(self) -> None:
        for name in ("dt", "noise_inflation", "max_range"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        if not (isinstance(self.min_interval, (int, float)) and self.min_interval >= 0):
            raise ValueError(f"min_interval must be a number >= 0, got {self.min_interval!r}")

    def env_kwargs(self, calibration: Calibration, num_landmarks: int) -> dict[str, Any]:
        """The episode's configuration: the calibrated models, inflated, and this conversion's settings."""
        root = math.sqrt(self.noise_inflation)
        calibrated = calibration.env_kwargs()
        slope, low, high = calibrated["range_noise"]
        return {
            **calibrated,
            "range_noise": (slope * root, low * root, high * root),
            "sigma_bearing": calibrated["sigma_bearing"] * root,
            "sigma_range": high * root,
            "innovation_gate": self.innovation_gate,
            "sensor_range": self.max_range,
            "fov": 2.0 * math.pi,  # the readings are given; the filters do not need the camera's field of view
            "dt": self.dt,
            "num_landmarks": int(num_landmarks),
            "arena_size": 12.0,
            "max_speed": 0.2,
            "max_turn_rate": 1.0,
            "filter": self.filter,
            "max_active": self.max_active,
        }


def log_to_episode(
    log: mrclam.MrclamLog, calibration: Calibration, conversion: EpisodeConversion = EpisodeConversion()
) -> Episode:
    """One robot's log as an :class:`~seif_gym.episodes.Episode` (module docstring).

    Parameters
    ----------
    log : MrclamLog
        From :func:`seif_gym.datasets.mrclam.load`.
    calibration : Calibration
        :func:`seif_gym.datasets.mrclam.calibration.calibrate`'s result (or
        ``Calibration.load``).
    conversion : EpisodeConversion

    Returns
    -------
    Episode

    Raises
    ------
    TypeError
        If ``log``, ``calibration`` or ``conversion`` have the wrong type.
    ValueError
        If the log has no ground truth at its first odometry time, or is
        shorter than one step.
    """
    if not isinstance(log, mrclam.MrclamLog):
        raise TypeError(f"log must be an MrclamLog, got {type(log).__name__}")
    if not isinstance(calibration, Calibration):
        raise TypeError(f"calibration must be a Calibration, got {type(calibration).__name__}")
    if not isinstance(conversion, EpisodeConversion):
        raise TypeError(f"conversion must be an EpisodeConversion, got {type(conversion).__name__}")
    offsets = calibration.robot(log.robot)
    odo, meas, gt = log.odometry, log.measurements, log.ground_truth
    start = float(odo.time[0])
    end = min(float(odo.time[-1]), float(gt.time[-1]))
    steps = int(math.floor((end - start) / conversion.dt))
    if steps < 1:
        raise ValueError(f"robot {log.robot}: the log is shorter than one step of {conversion.dt} s")
    edges = np.asarray(start + conversion.dt * np.arange(steps + 1), dtype=np.float64)
    truth = ground_truth(log, edges, offsets.heading_offset, max_gap=math.inf)
    if not np.all(np.isfinite(truth)):
        raise ValueError(f"robot {log.robot}: no ground truth at the first odometry time")
    controls = mean_controls(log, calibration, edges)
    # camera frames, dated sensor_latency before their stamps, measured at the end of their step
    frame_stamps, frame_start = meas.frames()
    frame_times = frame_stamps - calibration.sensor_latency
    frame_step = np.ceil((frame_times - start) / conversion.dt - 1e-9).astype(np.int64)
    ranges_all = meas.range - offsets.range_bias
    bearings_all = wrap_angle(meas.bearing - offsets.bearing_bias)
    rows_of_landmark = log.landmarks.index(meas.subject)
    per_step: list[list[int]] = [[] for _ in range(steps + 1)]
    last_used: dict[int, float] = {}
    for frame in np.flatnonzero((frame_step >= 0) & (frame_step <= steps)).tolist():
        rows = np.arange(frame_start[frame], frame_start[frame + 1])
        rows = rows[ranges_all[rows] <= conversion.max_range]
        rows, _ = thin_frame(rows, meas.subject, float(frame_times[frame]), last_used, conversion.min_interval)
        per_step[int(frame_step[frame])].extend(rows.tolist())
    order = np.array([row for rows in per_step for row in rows], dtype=np.int64)
    counts = np.array([len(rows) for rows in per_step], dtype=np.int64)
    config = SeifExploreEnv(**conversion.env_kwargs(calibration, len(log.landmarks))).config
    arrays: dict[str, Any] = {
        "config": config,
        "seed": None,
        "dt": conversion.dt,
        "landmarks": log.landmarks.positions,
        "true_poses": truth,
        "commanded_controls": controls,
        "executed_controls": controls,
        "ranges": ranges_all[order],
        "bearings": bearings_all[order],
        "ids": rows_of_landmark[order],
        "offsets": np.concatenate([[0], np.cumsum(counts)]),
    }
    # the configuration's own filter over the readings: the episode's recorded estimate
    draft = Episode(**arrays, estimated_poses=truth, rewards=np.zeros(steps), map_errors=np.zeros(steps + 1))
    result = replay(draft, conversion.filter)
    map_errors = np.asarray(result.map_errors)
    return Episode(**arrays, estimated_poses=result.poses, rewards=-np.diff(map_errors), map_errors=map_errors)


# -- command line -----------------------------------------------------------------------------------
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m seif_gym.datasets.mrclam episodes",
        description="Convert MRCLAM robot logs into SeifExplore episodes (one .npz per robot) for the harness.",
    )
    parser.add_argument("--data", default=None,
                        help="an MRCLAM dataset folder (default: $SEIF_GYM_DATA/mrclam/MRCLAM_Dataset6)")  # fmt: skip
    parser.add_argument("--calibration", default=str(DATASET6),
                        help="a calibration file (python -m seif_gym.datasets.mrclam calibrate; "
                        "default: the shipped calibration of Dataset 6)")  # fmt: skip
    parser.add_argument("--out", required=True, help="output folder: robot<N>.npz")
    parser.add_argument("--robots", type=int, nargs="+", default=list(mrclam.ROBOTS), help="robots (default all five)")
    defaults = EpisodeConversion()
    parser.add_argument("--dt", type=float, default=defaults.dt, help=f"seconds per step (default {defaults.dt})")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    return parser  # fmt: skip


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point (``python -m seif_gym.datasets.mrclam episodes ...``); returns the exit status.

    2 for bad arguments, and for data or a calibration file not found or
    malformed (one line on stderr naming the file).
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    unknown = sorted(set(args.robots) - set(mrclam.ROBOTS))
    if unknown:
        parser.error(f"--robots: unknown robot(s) {unknown}; the datasets have {list(mrclam.ROBOTS)}")
    try:
        conversion = EpisodeConversion(dt=args.dt)
    except ValueError as error:
        parser.error(f"--dt: {error}")

    def command() -> int:
        out = output_folder(args.out, "--out")  # before any work: an --out that cannot be written fails at once
        calibration = Calibration.load(args.calibration)
        logs = {robot: mrclam.load(args.data, robot) for robot in args.robots}
        with Progress(len(args.robots), "MRCLAM episodes", enabled=not args.quiet, unit="robots") as progress:
            for robot in args.robots:
                episode = log_to_episode(logs[robot], calibration, conversion)
                path = episode.save(out / f"robot{robot}.npz")
                progress.update(1, f"robot {robot}: {episode.steps} steps, {len(episode.ranges)} readings")
                print(
                    f"robot {robot}: {episode.steps} steps of {episode.dt} s, {len(episode.ranges)} readings -> {path}"
                )
        return 0

    return run_cli(parser.prog, command)


if __name__ == "__main__":  # ``python -m seif_gym.datasets.mrclam.episodes``: the module's own main (imported once)
    from seif_gym.datasets.mrclam import episodes as _command_module

    sys.exit(_command_module.main())
