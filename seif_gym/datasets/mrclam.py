"""The UTIAS MRCLAM dataset (Leung et al., IJRR 2011): loader for the original text files.

The UTIAS Multi-Robot Cooperative Localization and Mapping dataset has nine
datasets in one format. In each, five iRobot Create robots (subjects 1-5) drive
among 15 stationary landmarks (barcoded tubes, subjects 6-20) for ~15 minutes;
every robot logs its **commanded** forward and angular velocity (~100 Hz) and
the range and bearing of the barcodes its monocular camera reads. A Vicon
system gives ground-truth robot poses (~67 Hz) and a survey gives the landmark
positions. It matches :mod:`seif_gym.slam`'s models (velocity controls,
range-bearing landmarks, known correspondences) and has real ground truth for
both trajectory and map. The data are *not* in the package: :func:`load` takes
the folder of one dataset (``shared/data/mrclam/MRCLAM_Dataset6`` in this
project, whose README documents the figures). Cite K. Y. K. Leung, Y. Halpern,
T. D. Barfoot, H. H. T. Liu, "The UTIAS Multi-Robot Cooperative Localization
and Mapping Dataset", IJRR 30(8), 2011, when you use them.

Format (whitespace-separated text, ``#`` comment lines at the top)::

    Barcodes.dat               subject, barcode
    Landmark_Groundtruth.dat   subject, x [m], y [m], std x [m], std y [m]
    RobotN_Groundtruth.dat     time [s], x [m], y [m], theta [rad]
    RobotN_Odometry.dat        time [s], v [m/s], omega [rad/s]
    RobotN_Measurement.dat     time [s], barcode, range [m], bearing [rad]

Units: times are UNIX seconds on one clock shared by all files of a dataset
(kept absolute, float64: millisecond resolution is preserved); positions and
ranges in metres; angles in radians, bearings in the robot frame (0 straight
ahead, counter-clockwise positive).

Pitfalls (from the data README) and what the loader does about each:

* Measurements name **barcodes**, not subjects (the header says "Subject #"):
  they are mapped to subjects with ``Barcodes.dat``. Sightings of the other
  robots (subjects 1-5) go to :attr:`MrclamLog.robot_sightings`, apart from
  the landmark measurements (:attr:`MrclamLog.measurements`), which hold only
  surveyed landmarks. Barcodes that map to no subject (misreads), to a subject
  that is neither a robot nor a surveyed landmark, or to the robot itself are
  dropped; their barcodes are kept in :attr:`MrclamLog.dropped_barcodes`.
* The odometry is what was **commanded**, not measured: it is returned as is
  (``v``, ``omega``); motion noise and command bias must be estimated, e.g.
  from the ground truth.
* Odometry, measurements and ground truth have **different rates and start
  times** (ground truth starts several seconds before odometry; robot 1's
  ground truth of Dataset 6 ends ~2 minutes before its odometry). Nothing is
  resampled or trimmed: each stream keeps its own time stamps;
  :meth:`GroundTruth.interpolate` gives the pose at any time inside the span.
* Several measurements share one time stamp (one camera frame): kept as
  separate rows with equal times (:meth:`Measurements.frames` groups them).
* Odometry rows are missing for up to ~1.4 s while the robot moves: not
  filled; a runner should hold the last command.
* Heavy-tailed bearings, misread barcodes that map to a landmark, correlated
  sensor errors, ground-truth heading offsets: properties of the data that a
  filter or calibration must handle; the loader does not alter the values.

Every stream is sorted by time (a stable sort; the files of Dataset 6 are
already sorted). All arrays are read-only.

Command line::

    python -m seif_gym.datasets.mrclam calibrate --data DIR [--robots 1 2 ...] [--out FILE]
    python -m seif_gym.datasets.mrclam episodes --data DIR --calibration FILE --out DIR [--robots ...] [--dt S]
    python -m seif_gym.datasets.mrclam --data DIR --robot N|all --filter ekf|eif|seif|eseif --out OUT.npz \
        [--association known|ml] [--calibration FILE]

The first estimates the command correction, the per-second motion noise and
the sensor noise from the ground truth (:mod:`seif_gym.datasets.mrclam_calibration`)
and writes them to a JSON file (:class:`~seif_gym.datasets.mrclam_calibration.Calibration`);
the second runs a filter over the logs and scores it against Vicon and the
survey (:mod:`seif_gym.datasets.mrclam_runner`).

Example::

    from seif_gym.datasets import mrclam

    log = mrclam.load("../shared/data/mrclam/MRCLAM_Dataset6", robot=1)
    log.odometry.controls          # (n, 2): v [m/s], omega [rad/s]
    log.measurements.subject       # landmark subjects 6..20
    log.ground_truth.interpolate(log.odometry.time[0])  # initial pose (x, y, theta)
    log.landmarks.positions        # (15, 2) surveyed map
    logs = mrclam.load_all("../shared/data/mrclam/MRCLAM_Dataset6")  # {1: ..., 5: ...}
"""

from __future__ import annotations

import os
import sys
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray

from seif_gym.datasets._arrays import frozen
from seif_gym.slam.models import wrap_angle
from seif_gym.type_aliases import FloatArray, IntArray

#: The robots' subject numbers (in every MRCLAM dataset).
ROBOTS: tuple[int, ...] = (1, 2, 3, 4, 5)
BARCODES_FILE = "Barcodes.dat"
LANDMARKS_FILE = "Landmark_Groundtruth.dat"
_ROBOT_FILES = {"odometry": "Robot{}_Odometry.dat", "measurement": "Robot{}_Measurement.dat",
                "groundtruth": "Robot{}_Groundtruth.dat"}  # fmt: skip

__all__ = [
    "ROBOTS", "GroundTruth", "Landmarks", "Measurements", "MrclamLog", "Odometry", "load", "load_all",
]  # fmt: skip


@dataclass(frozen=True)
class Odometry:
    """Commanded velocities of one robot, one row per command (~100 Hz, with gaps).

    Attributes
    ----------
    time : float64 (n,)
        UNIX seconds (dataset clock), sorted.
    v : float64 (n,)
        Commanded forward velocity, m/s.
    omega : float64 (n,)
        Commanded angular velocity, rad/s, counter-clockwise positive.
    """

    time: FloatArray
    v: FloatArray
    omega: FloatArray

    def __len__(self) -> int:
        return len(self.time)

    @property
    def controls(self) -> FloatArray:
        """``(v, omega)`` per row, shape (n, 2): the controls of the velocity motion model."""
        return np.column_stack([self.v, self.omega])


@dataclass(frozen=True)
class Measurements:
    """Range-bearing readings of barcodes, mapped to subjects.

    Attributes
    ----------
    time : float64 (m,)
        UNIX seconds, sorted; rows of one camera frame share a time stamp.
    subject : int64 (m,)
        Subject number seen (landmarks 6..20, or robots 1..5 for sightings).
    barcode : int64 (m,)
        The barcode as read (the file's second column).
    range : float64 (m,)
        Range, m.
    bearing : float64 (m,)
        Bearing in the robot frame, rad: 0 straight ahead, counter-clockwise positive.
    """

    time: FloatArray
    subject: IntArray
    barcode: IntArray
    range: FloatArray
    bearing: FloatArray

    def __len__(self) -> int:
        return len(self.time)

    def frames(self) -> tuple[FloatArray, IntArray]:
        """Group rows by time stamp: ``(times, start)``.

        Rows of frame ``k`` (time ``times[k]``) are ``start[k]:start[k + 1]``;
        ``start`` has one more entry than ``times``.
        """
        if len(self.time) == 0:
            return np.empty(0), np.zeros(1, dtype=np.int64)
        new = np.flatnonzero(np.diff(self.time) != 0) + 1
        start = np.concatenate([[0], new, [len(self.time)]]).astype(np.int64)
        return self.time[start[:-1]], start


@dataclass(frozen=True)
class GroundTruth:
    """Vicon poses of one robot (~67 Hz).

    Attributes
    ----------
    time : float64 (g,)
        UNIX seconds, sorted.
    x, y : float64 (g,)
        Position, m, in the dataset's fixed frame (the landmarks' frame).
    theta : float64 (g,)
        Heading, rad, counter-clockwise from the x axis, in [-pi, pi] as the
        file gives it (4 decimals, so -3.1416 occurs).
    """

    time: FloatArray
    x: FloatArray
    y: FloatArray
    theta: FloatArray

    def __len__(self) -> int:
        return len(self.time)

    @property
    def poses(self) -> FloatArray:
        """``(x, y, theta)`` per row, shape (g, 3)."""
        return np.column_stack([self.x, self.y, self.theta])

    def interpolate(self, t: ArrayLike) -> FloatArray:
        """Pose(s) at time(s) ``t`` (s), linear in x, y and in the unwrapped heading.

        Returns shape (3,) for a scalar ``t``, (k, 3) for an array; heading
        wrapped to [-pi, pi). Times outside the span take the end poses.
        """
        t_arr = np.asarray(t, dtype=np.float64)
        theta = np.interp(t_arr, self.time, np.unwrap(self.theta))
        theta = wrap_angle(theta)
        out = np.stack([np.interp(t_arr, self.time, self.x), np.interp(t_arr, self.time, self.y), theta], axis=-1)
        return out


@dataclass(frozen=True)
class Landmarks:
    """Surveyed landmark positions (``Landmark_Groundtruth.dat``).

    Attributes
    ----------
    subject : int64 (L,)
        Subject numbers (6..20 in the nine datasets), sorted.
    x, y : float64 (L,)
        Position, m.
    std_x, std_y : float64 (L,) or None
        Survey standard deviations, m (None when the file has no such columns).
    """

    subject: IntArray
    x: FloatArray
    y: FloatArray
    std_x: FloatArray | None
    std_y: FloatArray | None

    def __len__(self) -> int:
        return len(self.subject)

    @property
    def positions(self) -> FloatArray:
        """``(x, y)`` per landmark, shape (L, 2), in the order of :attr:`subject`."""
        return np.column_stack([self.x, self.y])

    def index(self, subject: ArrayLike) -> IntArray:
        """Row of each subject in these arrays (ValueError for a subject not surveyed)."""
        subject = np.asarray(subject, dtype=np.int64)
        rows = np.searchsorted(self.subject, subject)
        rows_clipped = np.minimum(rows, max(len(self.subject) - 1, 0))
        if len(self.subject) == 0 or np.any(self.subject[rows_clipped] != subject):
            raise ValueError(f"subject(s) not surveyed: {np.setdiff1d(subject, self.subject).tolist()}")
        return rows_clipped


@dataclass(frozen=True)
class MrclamLog:
    """One robot's log from one MRCLAM dataset. All arrays read-only.

    Attributes
    ----------
    robot : int
        The robot (subject 1..5).
    odometry : Odometry
        Commanded ``(v, omega)``.
    measurements : Measurements
        Readings of surveyed landmarks only (subjects of :attr:`landmarks`).
    robot_sightings : Measurements
        Readings of the *other* robots (subjects 1..5, never :attr:`robot`).
    ground_truth : GroundTruth
        This robot's Vicon poses.
    landmarks : Landmarks
        The surveyed map (shared by all robots of the dataset).
    barcodes : int64 (S, 2)
        ``Barcodes.dat``: rows ``(subject, barcode)``.
    dropped_barcodes : int64 (k,)
        Barcodes of the readings dropped: no subject (misreads), a subject
        neither a robot nor surveyed, or the robot itself; in file order.
    path : Path
        The dataset folder.
    """

    robot: int
    odometry: Odometry
    measurements: Measurements
    robot_sightings: Measurements
    ground_truth: GroundTruth
    landmarks: Landmarks
    barcodes: IntArray
    dropped_barcodes: IntArray
    path: Path

    @property
    def num_dropped(self) -> int:
        """Number of readings dropped (see :attr:`dropped_barcodes`)."""
        return len(self.dropped_barcodes)


# ---------------------------------------------------------------------------
# Parsing
# ---------------------------------------------------------------------------
def _resolve_folder(path: str | os.PathLike[str]) -> Path:
    folder = Path(path)
    if not folder.is_dir():
        raise FileNotFoundError(f"MRCLAM dataset folder not found: {folder} (give a folder like MRCLAM_Dataset6)")
    return folder


def _read_table(file: Path, columns: tuple[int, ...], dtype: DTypeLike = np.float64) -> NDArray:
    """Whitespace-separated numbers of ``file``, ``#`` comments skipped; shape (rows, ncols).

    ``columns`` lists the accepted column counts (e.g. ``(3, 5)``).
    """
    if not file.is_file():
        raise FileNotFoundError(f"MRCLAM file not found: {file}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "input contained no data" for an empty table
        try:
            table = np.loadtxt(file, comments="#", dtype=dtype, ndmin=2)
        except ValueError as error:
            raise ValueError(f"{file}: not a table of numbers ({error})") from error
    if table.size == 0:
        return np.empty((0, columns[0]), dtype=dtype)
    if table.shape[1] not in columns:
        raise ValueError(f"{file}: {table.shape[1]} columns, expected {' or '.join(map(str, columns))}")
    return table


def _sorted_rows(table: NDArray) -> NDArray:
    """Rows stably sorted by the first column (time); unchanged when already sorted."""
    if len(table) > 1 and np.any(np.diff(table[:, 0]) < 0):
        return table[np.argsort(table[:, 0], kind="stable")]
    return table


def _measurements(table: NDArray, subject: IntArray, rows: NDArray[np.bool_]) -> Measurements:
    return Measurements(
        time=frozen(table[rows, 0], np.float64),
        subject=frozen(subject[rows], np.int64),
        barcode=frozen(table[rows, 1], np.int64),
        range=frozen(table[rows, 2], np.float64),
        bearing=frozen(table[rows, 3], np.float64),
    )


def _read_shared(folder: Path) -> tuple[IntArray, Landmarks]:
    barcodes = _read_table(folder / BARCODES_FILE, (2,), np.int64)
    if len(np.unique(barcodes[:, 1])) != len(barcodes):
        raise ValueError(f"{folder / BARCODES_FILE}: a barcode appears twice")
    lm = _read_table(folder / LANDMARKS_FILE, (3, 5))
    lm = lm[np.argsort(lm[:, 0], kind="stable")]
    if np.any(lm[:, 0] != np.round(lm[:, 0])) or len(np.unique(lm[:, 0])) != len(lm):
        raise ValueError(f"{folder / LANDMARKS_FILE}: subjects must be distinct integers")
    has_std = lm.shape[1] == 5
    landmarks = Landmarks(
        subject=frozen(lm[:, 0], np.int64),
        x=frozen(lm[:, 1], np.float64),
        y=frozen(lm[:, 2], np.float64),
        std_x=frozen(lm[:, 3], np.float64) if has_std else None,
        std_y=frozen(lm[:, 4], np.float64) if has_std else None,
    )
    return frozen(barcodes, np.int64), landmarks


def _check_robot(robot: int) -> int:
    if isinstance(robot, bool) or not isinstance(robot, (int, np.integer)) or int(robot) not in ROBOTS:
        raise ValueError(f"robot must be an integer in 1..5, got {robot!r}")
    return int(robot)


def _load_robot(folder: Path, robot: int, barcodes: IntArray, landmarks: Landmarks) -> MrclamLog:
    odo = _sorted_rows(_read_table(folder / _ROBOT_FILES["odometry"].format(robot), (3,)))
    gt = _sorted_rows(_read_table(folder / _ROBOT_FILES["groundtruth"].format(robot), (4,)))
    meas = _sorted_rows(_read_table(folder / _ROBOT_FILES["measurement"].format(robot), (4,)))

    # Barcode -> subject (0 = no subject) through a lookup table: vectorised.
    read = meas[:, 1]
    if np.any(read != np.round(read)):
        raise ValueError(f"{folder / _ROBOT_FILES['measurement'].format(robot)}: non-integer barcodes")
    read = read.astype(np.int64)
    size = int(max(barcodes[:, 1].max(initial=0), read.max(initial=0), 0)) + 1
    lookup = np.zeros(size, dtype=np.int64)
    lookup[barcodes[:, 1][barcodes[:, 1] >= 0]] = barcodes[:, 0][barcodes[:, 1] >= 0]
    subject = np.where(read >= 0, lookup[np.maximum(read, 0)], 0)
    is_landmark = np.isin(subject, landmarks.subject) & ~np.isin(subject, ROBOTS)
    is_robot = np.isin(subject, ROBOTS) & (subject != robot)
    dropped = ~(is_landmark | is_robot)

    return MrclamLog(
        robot=robot,
        odometry=Odometry(
            frozen(odo[:, 0], np.float64), frozen(odo[:, 1], np.float64), frozen(odo[:, 2], np.float64)
        ),  # fmt: skip
        measurements=_measurements(meas, subject, is_landmark),
        robot_sightings=_measurements(meas, subject, is_robot),
        ground_truth=GroundTruth(*(frozen(gt[:, k], np.float64) for k in range(4))),
        landmarks=landmarks,
        barcodes=barcodes,
        dropped_barcodes=frozen(read[dropped], np.int64),
        path=folder,
    )


# ---------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------
def load(path: str | os.PathLike[str], robot: int) -> MrclamLog:
    """Load one robot's log from an MRCLAM dataset folder (original text format).

    Parameters
    ----------
    path : str or Path
        The dataset folder (e.g. ``shared/data/mrclam/MRCLAM_Dataset6``),
        holding ``Barcodes.dat``, ``Landmark_Groundtruth.dat`` and
        ``RobotN_{Odometry,Measurement,Groundtruth}.dat``.
    robot : int
        The robot, 1..5.

    Returns
    -------
    MrclamLog
        Read-only arrays: odometry (s, m/s, rad/s), landmark measurements and
        robot sightings (s, subject, barcode, m, rad), ground truth (s, m, m,
        rad), surveyed landmarks (m), the barcodes dropped.

    Raises
    ------
    ValueError
        ``robot`` is not 1..5, or a file is malformed.
    FileNotFoundError
        The folder or one of its files is missing (the message names it).
    """
    robot = _check_robot(robot)
    folder = _resolve_folder(path)
    barcodes, landmarks = _read_shared(folder)
    return _load_robot(folder, robot, barcodes, landmarks)


def load_all(path: str | os.PathLike[str]) -> dict[int, MrclamLog]:
    """Load the logs of the five robots of an MRCLAM dataset folder: ``{1: log1, ..., 5: log5}``.

    The shared files are read once; see :func:`load` for parameters and errors.
    """
    folder = _resolve_folder(path)
    barcodes, landmarks = _read_shared(folder)
    return {robot: _load_robot(folder, robot, barcodes, landmarks) for robot in ROBOTS}


# ---------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------
def main(argv: Sequence[str] | None = None) -> int:
    """``python -m seif_gym.datasets.mrclam [calibrate | episodes] ...``; returns the exit status.

    ``calibrate ...`` runs :func:`seif_gym.datasets.mrclam_calibration.main`,
    ``episodes ...`` :func:`seif_gym.datasets.mrclam_episodes.main`;
    anything else the runner, :func:`seif_gym.datasets.mrclam_runner.main`.
    """
    args = list(sys.argv[1:] if argv is None else argv)
    if args and args[0] == "calibrate":
        from seif_gym.datasets.mrclam_calibration import main as calibrate_main

        return calibrate_main(args[1:])
    if args and args[0] == "episodes":
        from seif_gym.datasets.mrclam_episodes import main as episodes_main

        return episodes_main(args[1:])
    from seif_gym.datasets.mrclam_runner import main as run_main

    return run_main(args)


if __name__ == "__main__":
    sys.exit(main())
