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
the folder of one dataset from ``data=`` (``--data``), else
``$SEIF_GYM_DATA/mrclam/MRCLAM_Dataset6`` (:func:`locate`;
``docs/data/mrclam.md`` says where to obtain them). Cite K. Y. K. Leung, Y. Halpern,
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

Every file is checked as it is read: a malformed one raises
:class:`~seif_gym.datasets.DataFormatError` (a ``ValueError``) naming the
file and the line.

Pitfalls of the data and what the loader does about each:

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

The command line, ``python -m seif_gym.datasets.mrclam`` (``calibrate``,
``episodes``, or the runner), is :mod:`seif_gym.datasets.mrclam.__main__`.

Example::

    from seif_gym.datasets import mrclam

    log = mrclam.load("MRCLAM_Dataset6", robot=1)  # or mrclam.load(robot=1) with SEIF_GYM_DATA set
    log.odometry.controls          # (n, 2): v [m/s], omega [rad/s]
    log.measurements.subject       # landmark subjects 6..20
    log.ground_truth.interpolate(log.odometry.time[0])  # initial pose (x, y, theta)
    log.landmarks.positions        # (15, 2) surveyed map
    logs = mrclam.load_all("MRCLAM_Dataset6")  # {1: ..., 5: ...}
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray

from seif_gym.datasets._arrays import frozen
from seif_gym.datasets._files import DATA_ENV, DataFormatError, DataNotFoundError, data_lines, data_root, not_found
from seif_gym.slam.models import wrap_angle
from seif_gym.type_aliases import FloatArray, IntArray

#: The robots' subject numbers (in every MRCLAM dataset).
ROBOTS: tuple[int, ...] = (1, 2, 3, 4, 5)
#: Folder of the MRCLAM datasets under ``$SEIF_GYM_DATA``, and the dataset read from there by default.
FOLDER = "mrclam"
DEFAULT_DATASET = "MRCLAM_Dataset6"
#: How to obtain the data, for the error of data not found.
HOW_TO_OBTAIN = (
    f"The data are not part of seif_gym: download an MRCLAM dataset (UTIAS, Leung et al., IJRR 2011; "
    f"docs/data/mrclam.md) and pass its folder as data= (--data DIR) or put it at "
    f"${DATA_ENV}/{FOLDER}/{DEFAULT_DATASET}"
)
BARCODES_FILE = "Barcodes.dat"
LANDMARKS_FILE = "Landmark_Groundtruth.dat"
_ROBOT_FILES = {"odometry": "Robot{}_Odometry.dat", "measurement": "Robot{}_Measurement.dat",
                "groundtruth": "Robot{}_Groundtruth.dat"}  # fmt: skip

__all__ = [
    "BARCODES_FILE", "DEFAULT_DATASET", "LANDMARKS_FILE", "ROBOTS", "GroundTruth", "Landmarks", "Measurements",
    "MrclamLog", "Odometry", "load", "load_all", "locate",
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
def locate(data: str | os.PathLike[str] | None = None) -> Path:
    """The MRCLAM dataset folder that ``data`` names, else ``$SEIF_GYM_DATA/mrclam/MRCLAM_Dataset6``.

    Parameters
    ----------
    data : str or Path, optional
        A dataset folder (holding ``Barcodes.dat``, e.g. ``MRCLAM_Dataset6``),
        or a folder holding ``MRCLAM_Dataset6/`` or ``mrclam/MRCLAM_Dataset6/``.

    Raises
    ------
    DataNotFoundError
        No such folder, or neither ``data`` nor ``SEIF_GYM_DATA`` given; the
        message says how to obtain the data and where to put them. (A folder
        that lacks one of the files fails when that file is read.)
    """
    if data is None:
        root = data_root()
        if root is None:
            raise not_found("MRCLAM data", f"no data= (--data) given and {DATA_ENV} is not set", HOW_TO_OBTAIN)
        folder = root / FOLDER / DEFAULT_DATASET
        if not folder.is_dir():
            raise not_found("MRCLAM data", f"{DATA_ENV}={root} has no {FOLDER}/{DEFAULT_DATASET}", HOW_TO_OBTAIN)
        return folder
    folder = Path(data)
    if not folder.is_dir():
        raise not_found("MRCLAM dataset folder", f"{folder} is not a folder", HOW_TO_OBTAIN)
    if not (folder / BARCODES_FILE).is_file():
        for candidate in (folder / DEFAULT_DATASET, folder / FOLDER / DEFAULT_DATASET):
            if (candidate / BARCODES_FILE).is_file():
                return candidate
    return folder


def _line(file: Path, row: int) -> int:
    """The line number of data row ``row`` (0-based, comments and blank lines skipped) of ``file``."""
    return data_lines(file)[row][0]


def _first_bad_line(file: Path, columns: tuple[int, ...], integers: bool) -> DataFormatError:
    """The error of the first line of ``file`` that is not a row of ``columns`` numbers (integers)."""
    expected = " or ".join(map(str, columns))
    width = None
    for number, text in data_lines(file):
        fields = text.split()
        if len(fields) not in columns:
            return DataFormatError(f"{file}, line {number}: {len(fields)} values, expected {expected}")
        if width is not None and len(fields) != width:
            return DataFormatError(f"{file}, line {number}: {len(fields)} values, the lines above have {width}")
        width = len(fields)
        for field in fields:
            try:
                value = float(field)
            except ValueError:
                return DataFormatError(f"{file}, line {number}: {field[:40]!r} is not a number")
            if integers and not value.is_integer():
                return DataFormatError(f"{file}, line {number}: {field[:40]!r} is not an integer")
    return DataFormatError(f"{file}: not a table of numbers")


def _read_table(file: Path, columns: tuple[int, ...], dtype: DTypeLike = np.float64, required: bool = True) -> NDArray:
    """Whitespace-separated numbers of ``file``, ``#`` comments skipped; shape (rows, ncols), in file order.

    ``columns`` lists the accepted column counts (e.g. ``(3, 5)``); every
    value must be finite. ``required``: the file must have a data row.

    Raises
    ------
    DataNotFoundError
        ``file`` does not exist.
    DataFormatError
        Naming ``file`` and the line: a value that is not a number (an
        integer, for an integer ``dtype``), a wrong number of columns, a
        non-finite value, or no data row when ``required``.
    """
    if not file.is_file():
        raise DataNotFoundError(f"MRCLAM file not found: {file} (an MRCLAM dataset folder holds {BARCODES_FILE}, "
                                f"{LANDMARKS_FILE} and RobotN_{{Odometry,Measurement,Groundtruth}}.dat)")  # fmt: skip
    integers = np.dtype(dtype).kind in "iu"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "input contained no data" for an empty table
        try:
            table = np.loadtxt(file, comments="#", dtype=dtype, ndmin=2)
        except ValueError:
            raise _first_bad_line(file, columns, integers) from None
    if table.size == 0:
        if required:
            raise DataFormatError(f"{file}: no data rows")
        return np.empty((0, columns[0]), dtype=dtype)
    if table.shape[1] not in columns:
        expected = " or ".join(map(str, columns))
        raise DataFormatError(f"{file}, line {_line(file, 0)}: {table.shape[1]} values, expected {expected}")
    if not integers:
        bad = np.flatnonzero(~np.all(np.isfinite(table), axis=1))
        if len(bad):
            raise DataFormatError(f"{file}, line {_line(file, int(bad[0]))}: a value is not finite")
    return table


def _check_rows(file: Path, bad: NDArray[np.bool_], what: str) -> None:
    """DataFormatError naming the line of the first row of ``file`` where ``bad`` holds."""
    rows = np.flatnonzero(bad)
    if len(rows):
        raise DataFormatError(f"{file}, line {_line(file, int(rows[0]))}: {what}")


def _repeated(values: NDArray) -> NDArray[np.bool_]:
    """Mask of the entries of ``values`` equal to an earlier one."""
    _, first = np.unique(values, return_index=True)
    mask = np.ones(len(values), dtype=bool)
    mask[first] = False
    return mask


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
    barcodes_file = folder / BARCODES_FILE
    table = _read_table(barcodes_file, (2,))
    _check_rows(barcodes_file, np.any(table != np.round(table), axis=1), "a subject or barcode is not an integer")
    barcodes = table.astype(np.int64)
    _check_rows(barcodes_file, _repeated(barcodes[:, 1]), "the barcode appears twice")
    landmarks_file = folder / LANDMARKS_FILE
    lm = _read_table(landmarks_file, (3, 5))
    _check_rows(landmarks_file, lm[:, 0] != np.round(lm[:, 0]), "the subject is not an integer")
    _check_rows(landmarks_file, _repeated(lm[:, 0]), "the subject appears twice")
    lm = lm[np.argsort(lm[:, 0], kind="stable")]
    has_std = lm.shape[1] == 5
    landmarks = Landmarks(
        subject=frozen(lm[:, 0], np.int64),
        x=frozen(lm[:, 1], np.float64),
        y=frozen(lm[:, 2], np.float64),
        std_x=frozen(lm[:, 3], np.float64) if has_std else None,
        std_y=frozen(lm[:, 4], np.float64) if has_std else None,
    )
    return frozen(barcodes, np.int64), landmarks


def _check_robot(robot: int | None) -> int:
    if isinstance(robot, bool) or not isinstance(robot, (int, np.integer)) or int(robot) not in ROBOTS:
        raise ValueError(f"robot must be an integer in 1..5, got {robot!r}")
    return int(robot)


def _load_robot(folder: Path, robot: int, barcodes: IntArray, landmarks: Landmarks) -> MrclamLog:
    odo = _sorted_rows(_read_table(folder / _ROBOT_FILES["odometry"].format(robot), (3,)))
    gt = _sorted_rows(_read_table(folder / _ROBOT_FILES["groundtruth"].format(robot), (4,)))
    meas_file = folder / _ROBOT_FILES["measurement"].format(robot)
    meas = _read_table(meas_file, (4,), required=False)
    _check_rows(meas_file, meas[:, 1] != np.round(meas[:, 1]), "the barcode is not an integer")
    _check_rows(meas_file, meas[:, 2] <= 0, "the range is not positive")
    meas = _sorted_rows(meas)

    # Barcode -> subject (0 = no subject), vectorised over the barcodes sorted.
    read = meas[:, 1].astype(np.int64)
    order = np.argsort(barcodes[:, 1], kind="stable")
    known, subjects = barcodes[order, 1], barcodes[order, 0]
    at = np.minimum(np.searchsorted(known, read), len(known) - 1)  # Barcodes.dat has rows (_read_table)
    subject = np.where(known[at] == read, subjects[at], 0)
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
def load(data: str | os.PathLike[str] | None = None, robot: int | None = None) -> MrclamLog:
    """Load one robot's log from an MRCLAM dataset folder (original text format).

    Parameters
    ----------
    data : str or Path, optional
        The dataset folder (:func:`locate`), holding ``Barcodes.dat``,
        ``Landmark_Groundtruth.dat`` and ``RobotN_{Odometry,Measurement,Groundtruth}.dat``;
        without it, ``$SEIF_GYM_DATA/mrclam/MRCLAM_Dataset6``.
    robot : int
        The robot, 1..5 (required).

    Returns
    -------
    MrclamLog
        Read-only arrays: odometry (s, m/s, rad/s), landmark measurements and
        robot sightings (s, subject, barcode, m, rad), ground truth (s, m, m,
        rad), surveyed landmarks (m), the barcodes dropped.

    Raises
    ------
    ValueError
        ``robot`` is not 1..5.
    DataFormatError
        A ``ValueError`` naming the file and the line: a value that is not a
        number, a wrong number of columns, a non-finite value, a non-integer
        or repeated barcode or subject, a range that is not positive, no rows
        of odometry or ground truth.
    DataNotFoundError
        A ``FileNotFoundError``: the folder or one of its files is missing (the message names it).
    """
    robot = _check_robot(robot)
    folder = locate(data)
    barcodes, landmarks = _read_shared(folder)
    return _load_robot(folder, robot, barcodes, landmarks)


def load_all(data: str | os.PathLike[str] | None = None) -> dict[int, MrclamLog]:
    """Load the logs of the five robots of an MRCLAM dataset folder: ``{1: log1, ..., 5: log5}``.

    The shared files are read once; see :func:`load` for ``data`` and the errors.
    """
    folder = locate(data)
    barcodes, landmarks = _read_shared(folder)
    return {robot: _load_robot(folder, robot, barcodes, landmarks) for robot in ROBOTS}
