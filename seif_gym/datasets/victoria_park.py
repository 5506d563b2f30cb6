r"""The Victoria Park dataset (ACFR, Guivant & Nebot): loader, GPS ground truth and runner.

A utility car drove ~4 km through Victoria Park, Sydney, logging wheel-encoder
speed and steering (40 Hz), a SICK laser (trees extracted as range, bearing,
diameter; 4.7 Hz) and a failing GPS. The data are *not* in the package: the
readers take a compact copy, ``victoria_park.npz`` (:data:`FILE_NAME`; its
arrays, how it is derived from the publisher's MATLAB files and its SHA-256
are in ``docs/data/victoria_park.md``), from ``data=`` (``--data``), else from
``$SEIF_GYM_DATA/victoria_park/``. Cite J. Guivant, E. Nebot, IEEE T-RA 17(3),
2001 when you use them.

* :func:`load` returns typed, read-only arrays (:class:`VictoriaPark`):
  times on the dataset clock in ms and s, bearings converted to the robot
  frame (0 ahead, positive left).
* :func:`gps_inliers`, :func:`rigid_alignment`, :func:`gps_error`: the RMSE of
  a trajectory against the GPS after a rigid 2-D fit, GPS faults removed.
* :func:`run` drives any filter of :mod:`seif_gym.slam` with the car model
  (:class:`~seif_gym.slam.car_model.AckermannLaserModel`) and unknown
  correspondences (:class:`~seif_gym.slam.association.Associator`).
* Command line::

      python -m seif_gym.datasets.victoria_park [--data DIR] --filter seif --out OUT.npz \
          [--steps N] [--plot OUT.png] [--signature] [--compare RUN.npz]

  writes ``OUT.npz`` (``time`` (N,) s, ``pose`` (N, 3) the estimated laser
  pose after every odometry step and every scan; ``landmarks`` (M, 2) the
  final map; plus ``landmark_ids``, ``scan_time``, ``scan_elapsed``,
  ``scan_landmarks``, ``total_seconds``, ``cpu_seconds``, ``rmse``,
  ``gps_rotation``, ``gps_translation``; when fewer than
  :data:`MIN_GPS_FIXES` GPS fixes overlap the run, ``rmse`` is NaN and
  ``rmse_note`` says why, and there is no alignment), a plot of the aligned trajectory and
  map over the GPS with the time per step, and prints the time per step, the
  total time, the landmarks mapped and the RMSE against the GPS.

The settings (:class:`RunConfig`) are not fitted to the GPS; how they were
chosen, and the results, are in ``docs/data/victoria_park.md``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from seif_gym.datasets._arrays import frozen
from seif_gym.datasets._files import (
    DATA_ENV,
    DataFormatError,
    check_vector,
    data_root,
    load_npz,
    not_found,
    output_file,
    run_cli,
    save_figure,
    save_npz,
)
from seif_gym.datasets._geometry import rigid_alignment
from seif_gym.progress import Progress
from seif_gym.threads import limit_blas_threads  # noqa: F401  (public here before seif_gym.threads existed)
from seif_gym.type_aliases import FloatArray, IntArray

if TYPE_CHECKING:
    from seif_gym.slam.association import AssociationStats, Associator
    from seif_gym.slam.base import SlamFilter
    from seif_gym.slam.car_model import AckermannLaserModel
    from seif_gym.slam.models import RangeBearingSensor


#: File name of the compact NumPy copy inside the data directory.
FILE_NAME = "victoria_park.npz"
#: Folder of that file under ``$SEIF_GYM_DATA``.
FOLDER = "victoria_park"
#: SHA-256 of that file (``docs/data/victoria_park.md``).
SHA256 = "075e12eb87e94033e9c2fa32ec02397ae19bfa59b20dffef89ff45ed1ea20de8"
_ARRAYS = (
    "odo_time_ms", "odo_speed", "odo_steering", "laser_time_ms", "det_scan", "det_range",
    "det_bearing", "det_diameter", "gps_time_ms", "gps_x", "gps_y",
)  # fmt: skip


@dataclass(frozen=True)
class Odometry:
    """Wheel-encoder speed and steering angle, one row per sample (every 25 ms).

    Attributes
    ----------
    time_ms : int64 (n,)
        Dataset clock, milliseconds.
    time : float64 (n,)
        The same clock in seconds (``time_ms / 1000``).
    speed : float64 (n,)
        ``v_e``, m/s, measured at the **rear-left wheel** (not the axle centre).
    steering : float64 (n,)
        ``alpha``, front-wheel steering angle, rad, positive = left turn.
    """

    time_ms: IntArray
    time: FloatArray
    speed: FloatArray
    steering: FloatArray

    def __len__(self) -> int:
        return len(self.time_ms)

    @property
    def controls(self) -> FloatArray:
        """``(v_e, alpha)`` per sample, shape (n, 2): the controls of the car model."""
        return np.column_stack([self.speed, self.steering])


@dataclass(frozen=True)
class Scans:
    """Laser scans and the trees detected in them.

    Attributes
    ----------
    time_ms, time : (s,)
        Scan timestamps, dataset clock (ms, and s).
    start : int64 (s + 1,)
        Detections of scan ``k`` are rows ``start[k]:start[k + 1]`` of the
        detection arrays (:meth:`detections`).
    scan : int64 (d,)
        Scan index of each detection (non-decreasing).
    range : float64 (d,)
        Range from the laser to the trunk centre, m.
    bearing : float64 (d,)
        Bearing in the **robot frame**, rad: 0 straight ahead, positive to
        the left (the file's laser-frame bearing, 0 … pi from the right,
        minus pi/2).
    diameter : float64 (d,)
        Estimated trunk diameter, m (a signature for data association).
    """

    time_ms: IntArray
    time: FloatArray
    start: IntArray
    scan: IntArray
    range: FloatArray
    bearing: FloatArray
    diameter: FloatArray

    def __len__(self) -> int:
        return len(self.time_ms)

    @property
    def num_detections(self) -> int:
        return len(self.range)

    def detections(self, k: int) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(range, bearing, diameter)`` of scan ``k`` (read-only views)."""
        rows = slice(int(self.start[k]), int(self.start[k + 1]))
        return self.range[rows], self.bearing[rows], self.diameter[rows]


@dataclass(frozen=True)
class Gps:
    """GPS fixes in a local metric frame (5 Hz when available; with gaps and jumps).

    Attributes
    ----------
    time_ms, time : (g,)
        Dataset clock (ms, and s).
    x, y : float64 (g,)
        Easting and northing, m.
    """

    time_ms: IntArray
    time: FloatArray
    x: FloatArray
    y: FloatArray

    def __len__(self) -> int:
        return len(self.time_ms)

    @property
    def positions(self) -> FloatArray:
        """``(x, y)`` per fix, shape (g, 2)."""
        return np.column_stack([self.x, self.y])


@dataclass(frozen=True)
class VictoriaPark:
    """The whole dataset: odometry, scans with their detections, GPS. All arrays read-only."""

    odometry: Odometry
    scans: Scans
    gps: Gps
    path: Path


#: How to obtain the data, for the error of data not found.
HOW_TO_OBTAIN = (
    f"The data are not part of seif_gym: obtain the Victoria Park dataset from its publisher (ACFR, University of "
    f"Sydney), convert it to {FILE_NAME} as docs/data/victoria_park.md describes, and pass its folder as data= "
    f"(--data DIR) or put it at ${DATA_ENV}/{FOLDER}/{FILE_NAME}"
)
#: The integer arrays of the file, then the real-valued ones.
_INT_ARRAYS = ("odo_time_ms", "laser_time_ms", "gps_time_ms", "det_scan")
_FLOAT_ARRAYS = ("odo_speed", "odo_steering", "det_range", "det_bearing", "det_diameter", "gps_x", "gps_y")


def locate(data: str | os.PathLike[str] | None = None) -> Path:
    """The ``victoria_park.npz`` that ``data`` names, else the one under ``$SEIF_GYM_DATA``.

    Parameters
    ----------
    data : str or Path, optional
        The ``.npz`` itself, the folder holding it, or a folder holding
        ``victoria_park/victoria_park.npz`` (a ``SEIF_GYM_DATA`` folder).
        Without it, ``$SEIF_GYM_DATA/victoria_park/victoria_park.npz``.

    Raises
    ------
    DataNotFoundError
        Nothing there, or neither ``data`` nor ``SEIF_GYM_DATA`` given; the
        message says how to obtain the data and where to put them.
    """
    if data is None:
        root = data_root()
        if root is None:
            raise not_found("Victoria Park data", f"no data= (--data) given and {DATA_ENV} is not set", HOW_TO_OBTAIN)
        file = root / FOLDER / FILE_NAME
        if not file.is_file():
            raise not_found("Victoria Park data", f"{DATA_ENV}={root} has no {FOLDER}/{FILE_NAME}", HOW_TO_OBTAIN)
        return file
    path = Path(data)
    if path.is_file():
        return path
    if path.is_dir():
        for file in (path / FILE_NAME, path / FOLDER / FILE_NAME):
            if file.is_file():
                return file
        raise not_found("Victoria Park data", f"no {FILE_NAME} in {path} (nor in {path / FOLDER})", HOW_TO_OBTAIN)
    raise not_found("Victoria Park data", f"{path} does not exist", HOW_TO_OBTAIN)


def _check(file: Path, d: dict[str, NDArray]) -> None:
    """Dtypes, shapes, finiteness, order and ranges of the arrays of ``file`` (DataFormatError naming the array)."""
    for name in _INT_ARRAYS:
        check_vector(file, name, d[name], "int")
    for name in _FLOAT_ARRAYS:
        check_vector(file, name, d[name], "float")
    for prefix, names, reference in (
        ("odo", ("odo_speed", "odo_steering"), "odo_time_ms"),
        ("gps", ("gps_x", "gps_y"), "gps_time_ms"),
        ("det", ("det_range", "det_bearing", "det_diameter"), "det_scan"),
    ):
        n = len(d[reference])
        for name in names:
            if d[name].shape != (n,):
                raise DataFormatError(
                    f"{file}: array {name!r} has shape {d[name].shape}, expected ({n},) like the other {prefix}_ arrays"
                )
    for name in ("odo_time_ms", "gps_time_ms"):
        if len(d[name]) == 0:
            raise DataFormatError(f"{file}: array {name!r} is empty")
    for name in ("odo_time_ms", "laser_time_ms", "gps_time_ms"):
        back = np.flatnonzero(np.diff(d[name]) < 0)
        if len(back):
            raise DataFormatError(f"{file}: array {name!r} is not sorted (index {back[0] + 1} goes back in time)")
    scan_index = d["det_scan"]
    n_scan = len(d["laser_time_ms"])
    if len(scan_index) and (np.any(np.diff(scan_index) < 0) or scan_index[0] < 0 or scan_index[-1] >= n_scan):
        raise DataFormatError(f"{file}: array 'det_scan' must be sorted scan indices in [0, {n_scan})")
    bad = np.flatnonzero(d["det_range"] <= 0)
    if len(bad):
        raise DataFormatError(f"{file}: array 'det_range' has a range <= 0 at index {bad[0]}")


def load(data: str | os.PathLike[str] | None = None, *, verify: bool = False) -> VictoriaPark:
    """Load the Victoria Park copy (``victoria_park.npz``).

    Parameters
    ----------
    data : str or Path, optional
        The ``.npz``, its folder, or a ``SEIF_GYM_DATA`` folder (:func:`locate`);
        without it, ``$SEIF_GYM_DATA/victoria_park/victoria_park.npz``.
    verify : bool
        Check the file's SHA-256 against :data:`SHA256` first.

    Returns
    -------
    VictoriaPark
        Typed, read-only arrays. Times are on the dataset clock (the original
        integer milliseconds, and seconds = ms / 1000); bearings are converted
        to the robot frame (``det_bearing - pi/2``: 0 ahead, positive left).

    Raises
    ------
    DataNotFoundError
        No data found (a ``FileNotFoundError``; the message says how to obtain them).
    DataFormatError
        A ``ValueError`` naming the file and the array: not a readable
        ``.npz`` (corrupt, truncated, pickled data), a missing array, a wrong
        dtype, shape or order, a non-finite value, or (with ``verify``) a
        checksum mismatch.
    """
    file = locate(data)
    if verify:
        digest = hashlib.sha256(file.read_bytes()).hexdigest()
        if digest != SHA256:
            raise DataFormatError(f"{file}: SHA-256 {digest} does not match the published copy's {SHA256}")
    d = load_npz(file, _ARRAYS)
    _check(file, d)
    scan_index = d["det_scan"].astype(np.int64)
    start = np.searchsorted(scan_index, np.arange(len(d["laser_time_ms"]) + 1))

    def clock(ms: ArrayLike) -> tuple[IntArray, FloatArray]:
        return frozen(ms, np.int64), frozen(np.asarray(ms, dtype=np.float64) / 1000.0, np.float64)

    odo_ms, odo_s = clock(d["odo_time_ms"])
    scan_ms, scan_s = clock(d["laser_time_ms"])
    gps_ms, gps_s = clock(d["gps_time_ms"])
    return VictoriaPark(
        odometry=Odometry(odo_ms, odo_s, frozen(d["odo_speed"], np.float64), frozen(d["odo_steering"], np.float64)),
        scans=Scans(
            time_ms=scan_ms,
            time=scan_s,
            start=frozen(start, np.int64),
            scan=frozen(scan_index, np.int64),
            range=frozen(d["det_range"], np.float64),
            bearing=frozen(d["det_bearing"] - 0.5 * math.pi, np.float64),
            diameter=frozen(d["det_diameter"], np.float64),
        ),
        gps=Gps(gps_ms, gps_s, frozen(d["gps_x"], np.float64), frozen(d["gps_y"], np.float64)),
        path=file,
    )


# ---------------------------------------------------------------------------
# Ground truth from the GPS
# ---------------------------------------------------------------------------
def gps_inliers(data: VictoriaPark, *, jump: float = 1.0, max_interval: float = 1.0) -> NDArray[np.bool_]:
    """Mask of the GPS fixes kept as ground truth.

    The GPS unit of this run was failing ("it is possible to see jumps and
    regions without gps data", ``info.txt``). Dropouts need nothing (there
    are simply no fixes). Jumps are found with the odometry, independently
    of any filter, by comparing two consecutive fixes with the distance
    ``s`` the encoder says the car drove in between (``|v_e| dt`` summed):

    * fixes at most ``max_interval`` seconds apart must be ``s`` apart
      within ``jump`` metres;
    * fixes farther apart in time (across a dropout) can be at most
      ``1.05 s + jump`` apart (the car cannot have moved farther than it drove).

    A pair that fails drops **both** its fixes (the jump is into or out of
    one of them, and which one is unknown).
    """
    odo, gps = data.odometry, data.gps
    if len(gps) < 2:
        return np.ones(len(gps), dtype=bool)
    driven = np.concatenate([[0.0], np.cumsum(np.abs(odo.speed[:-1]) * np.diff(odo.time))])
    odo_distance = np.diff(np.interp(gps.time, odo.time, driven))
    gps_distance = np.hypot(np.diff(gps.x), np.diff(gps.y))
    close = np.diff(gps.time) <= max_interval
    bad_pair = np.where(close, np.abs(gps_distance - odo_distance) > jump, gps_distance > 1.05 * odo_distance + jump)
    keep = np.ones(len(gps), dtype=bool)
    keep[:-1] &= ~bad_pair
    keep[1:] &= ~bad_pair
    return keep


@dataclass(frozen=True)
class GpsError:
    """Trajectory error against the GPS after a rigid 2-D alignment.

    ``rmse`` (m) over the ``used`` fixes in the trajectory's time span
    (``outliers`` more in the span were dropped by :func:`gps_inliers`);
    ``rotation``, ``translation`` map the estimate into the GPS frame;
    ``gps_time`` and ``residuals`` per fix used.
    """

    rmse: float
    used: int
    outliers: int
    rotation: FloatArray
    translation: FloatArray
    gps_time: FloatArray
    residuals: FloatArray

    def transform(self, points: FloatArray) -> FloatArray:
        """``points`` (n, 2) of the estimate in the GPS frame."""
        return np.asarray(points, dtype=np.float64) @ self.rotation.T + self.translation


#: Fewest GPS fixes :func:`gps_error` fits: a rigid 2-D alignment has 3 parameters, and with 2 fixes its one
#: residual degree of freedom (the difference of two distances) is near zero on any short drive.
MIN_GPS_FIXES = 3


def gps_error(data: VictoriaPark, time: FloatArray, positions: FloatArray, *, jump: float = 1.0) -> GpsError:
    """RMSE of an estimated trajectory against the GPS after a rigid 2-D alignment.

    Parameters
    ----------
    data : VictoriaPark
    time : (n,) seconds on the dataset clock, non-decreasing
    positions : (n, 2) estimated laser positions at ``time``
    jump : float
        Outlier threshold of :func:`gps_inliers`, metres.

    Notes
    -----
    The estimate is interpolated linearly at the GPS times (only fixes
    within ``time``'s span are used), the fixes of :func:`gps_inliers` are
    kept, and the rotation and translation that best map the estimate onto
    them (:func:`rigid_alignment`, no scale) are fitted on those same pairs.
    No residual-based trimming: a fix is dropped only for a GPS fault.
    Fewer than :data:`MIN_GPS_FIXES` fixes raise a ``ValueError``: the fit
    would be degenerate and its RMSE meaningless.
    The GPS antenna is not at the laser; its lever arm (not documented) adds
    a heading-dependent error that no rigid alignment removes.
    """
    time = np.asarray(time, dtype=np.float64)
    positions = np.asarray(positions, dtype=np.float64)
    gps = data.gps
    span = (gps.time >= time[0]) & (gps.time <= time[-1])
    keep = gps_inliers(data, jump=jump) & span
    gps_time = gps.time[keep]
    target = gps.positions[keep]
    if len(gps_time) < MIN_GPS_FIXES:
        raise ValueError(
            f"only {len(gps_time)} GPS fix(es) overlap the trajectory, a rigid 2-D fit needs at least {MIN_GPS_FIXES}"
        )
    source = np.column_stack([np.interp(gps_time, time, positions[:, 0]), np.interp(gps_time, time, positions[:, 1])])
    rotation, translation = rigid_alignment(source, target)
    residuals = np.hypot(*(source @ rotation.T + translation - target).T)
    return GpsError(
        rmse=float(np.sqrt(np.mean(residuals**2))),
        used=int(keep.sum()),
        outliers=int(span.sum() - keep.sum()),
        rotation=rotation,
        translation=translation,
        gps_time=gps_time,
        residuals=residuals,
    )


# ---------------------------------------------------------------------------
# Runner
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class RunConfig:
    """Every setting of a Victoria Park run; the defaults are the documented run.

    * ``sigma_speed`` 0.5 m/s, ``sigma_speed_rel`` 0.05: encoder-speed noise per
      25 ms sample, plus 5% of the speed (wheel radius, slip); car model.
    * ``sigma_steering`` 1 deg: steering-angle noise per 25 ms sample.
    * ``sigma_range`` 0.5 m, ``sigma_bearing`` 1 deg: about twice the spread of
      the innovations of the associated detections (0.2-0.3 m, 0.4-0.7 deg,
      state uncertainty included), whose tails are heavy; the bearing is the
      upper end of the data README's 0.5-1 deg.
    * ``min_range``, ``max_range`` 1 m, 40 m: the detections used (the 5%
      beyond 40 m are the least reliable).
    * ``gate`` 0.999, ``new_landmark`` 0.99999: chi-square levels of the
      association gate and of a new tree (2 dof).
    * ``candidate_radius`` 3 m: Euclidean preselection radius (widened by the
      pose standard deviations).
    * ``min_separation`` 1.5 m: no new tree closer than this to a mapped one
      (the mapped trees' nearest neighbours: 5th percentile 2.3 m).
    * ``signature_sigma`` None, ``signature_per_metre`` 0: trunk-diameter gate
      off; ``--signature`` uses 0.07 m + 0.005 m per metre of range (the
      measured spread of the diameters of one tree).
    * ``max_active`` 8: SEIF/ESEIF active landmarks.
    * ``blanket_neighbours`` 4: strongest links per candidate in the SEIF's
      Markov blanket (bounded block; all links changed no decision here).
    * ``initial_heading_deg`` 36: the usual start heading in the GPS frame.
    * ``revisable`` False: ``--revisable`` lets the associator take decisions
      back (merges and tentative closures, the ``"revisable"`` preset).
    * ``likelihood`` False: ``--likelihood`` uses the ``"likelihood"`` preset
      (``"revisable"`` with the joint hypotheses ranked by likelihood, its
      gate, and new landmarks beside a landmark another measurement took);
      the preset's gate replaces ``gate``.
    """

    sigma_speed: float = 0.5
    sigma_speed_rel: float = 0.05
    sigma_steering: float = math.radians(1.0)
    sigma_range: float = 0.5
    sigma_bearing: float = math.radians(1.0)
    min_range: float = 1.0
    max_range: float = 40.0
    gate: float = 0.999
    new_landmark: float = 0.99999
    candidate_radius: float = 3.0
    min_separation: float = 1.5
    signature_sigma: float | None = None
    signature_per_metre: float = 0.0
    max_active: int = 8
    blanket_neighbours: bool | int = 4
    initial_heading_deg: float = 36.0
    revisable: bool = False
    likelihood: bool = False


#: Trunk-diameter signature settings of --signature (Associator's signature_sigma, signature_per_metre).
SIGNATURE_SETTINGS: dict[str, Any] = {"signature_sigma": 0.07, "signature_per_metre": 0.005}


@dataclass
class RunResult:
    """What a run produces; :meth:`save` writes it as ``.npz``."""

    filter_name: str
    time: FloatArray  # (N,) seconds, dataset clock: after every odometry sample and every scan
    pose: FloatArray  # (N, 3) estimated laser pose (x, y, phi)
    landmarks: FloatArray  # (M, 2) final map
    landmark_ids: IntArray  # (M,)
    scan_time: FloatArray  # (S,) time of each processed scan
    scan_elapsed: FloatArray  # (S,) wall seconds since the start of the run, after each scan
    scan_landmarks: IntArray  # (S,) landmarks in the map after each scan
    odometry_steps: int
    scans: int
    total_seconds: float  # wall clock
    cpu_seconds: float  # CPU time of this process over the same loop
    warm_up_seconds: float
    association: AssociationStats
    error: GpsError | None = None
    error_note: str = ""  # why ``error`` is None (the RMSE against the GPS is not available)

    @property
    def seconds_per_step(self) -> float:
        """Wall time per odometry step (the whole run's time divided by the odometry steps)."""
        return self.total_seconds / max(self.odometry_steps, 1)

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the run as ``.npz``, whole or not at all; returns the file (``.npz`` appended when missing).

        Without a GPS fit, ``rmse`` is NaN and ``rmse_note`` says why.
        """
        extra: dict[str, Any] = {"rmse": np.float64(np.nan), "rmse_note": np.str_(self.error_note or "not computed")}
        if self.error is not None:
            extra = {
                "rmse": np.float64(self.error.rmse),
                "gps_rotation": self.error.rotation,
                "gps_translation": self.error.translation,
            }
        return save_npz(
            path,
            dict(
                time=self.time,
                pose=self.pose,
                landmarks=self.landmarks,
                landmark_ids=self.landmark_ids,
                scan_time=self.scan_time,
                scan_elapsed=self.scan_elapsed,
                scan_landmarks=self.scan_landmarks,
                total_seconds=np.float64(self.total_seconds),
                cpu_seconds=np.float64(self.cpu_seconds),
                warm_up_seconds=np.float64(self.warm_up_seconds),
                filter=np.str_(self.filter_name),
                **extra,
            ),
        )


def make_models(config: RunConfig) -> tuple[AckermannLaserModel, RangeBearingSensor]:
    """The car model and the range-bearing sensor of ``config``."""
    from seif_gym.slam.car_model import AckermannLaserModel
    from seif_gym.slam.models import RangeBearingSensor

    motion = AckermannLaserModel(
        sigma_speed=config.sigma_speed, sigma_speed_rel=config.sigma_speed_rel, sigma_steering=config.sigma_steering
    )
    sensor = RangeBearingSensor(sigma_range=config.sigma_range, sigma_bearing=config.sigma_bearing,
                                max_range=config.max_range, fov=math.pi)  # fmt: skip
    return motion, sensor


def run(
    data: VictoriaPark,
    filter_name: str = "seif",
    *,
    steps: int | None = None,
    config: RunConfig = RunConfig(),
    progress: bool = False,
    blas_threads: int | None = 1,
) -> RunResult:
    """Run a filter with unknown correspondences over the dataset.

    Parameters
    ----------
    data : VictoriaPark
        From :func:`load`.
    filter_name : str
        A key of :data:`seif_gym.slam.FILTERS` (``"seif"``, ``"ekf"``, ``"eif"``,
        ``"eseif"`` where it exists).
    steps : int, optional
        Process only the first ``steps`` odometry samples (and the scans up to
        the last of them); all by default.
    config : RunConfig
    progress : bool
        Show a progress bar (tqdm if installed).
    blas_threads : int or None
        Calls :func:`seif_gym.threads.limit_blas_threads` first (process-wide); ``None`` leaves BLAS alone.

    Raises
    ------
    ValueError
        ``filter_name`` unknown; or (a ``DataFormatError``, naming the file
        and the array) ``data`` has no odometry or GPS, or odometry, scan or
        GPS times that go back, with the first offending index. Checked before
        anything runs.

    Notes
    -----
    Events are processed in time order. An odometry sample sets the control
    ``(v_e, alpha)`` held until the next one (the car model integrates it
    over the exact interval); a scan first predicts to its own time, then
    associates its detections (:class:`~seif_gym.slam.association.Associator`)
    and updates. The filter starts at the first GPS fix with heading
    ``initial_heading_deg`` (the usual start of this dataset; the RMSE is
    taken after a rigid alignment anyway).
    """
    import time as clock

    from seif_gym.slam import FILTERS

    if filter_name not in FILTERS:
        raise ValueError(f"filter must be one of {tuple(FILTERS)}, got {filter_name!r}")
    _check_order(data)
    if blas_threads is not None:
        limit_blas_threads(blas_threads)
    odo, scans = data.odometry, data.scans
    n_odo = len(odo) if steps is None else int(min(max(int(steps), 1), len(odo)))
    n_scan = int(np.searchsorted(scans.time, odo.time[n_odo - 1], side="right"))
    # warm-up, not timed: loads (or compiles, on a first run) the numba kernels
    warm_start = clock.perf_counter()
    warm_odo = min(n_odo, 800)
    _process(data, *_setup(data, filter_name, config), warm_odo,
             int(np.searchsorted(scans.time, odo.time[warm_odo - 1], side="right")), config, None)  # fmt: skip
    warm_up = clock.perf_counter() - warm_start
    filt, associator = _setup(data, filter_name, config)
    bar = Progress(n_odo, f"{filter_name} Victoria Park", enabled=progress, unit="step")
    started, cpu_started = clock.perf_counter(), clock.process_time()
    times, poses, scan_elapsed, scan_landmarks = _process(data, filt, associator, n_odo, n_scan, config, bar)
    total, cpu = clock.perf_counter() - started, clock.process_time() - cpu_started
    bar.close()
    result = RunResult(
        filter_name=filter_name,
        time=times,
        pose=poses,
        landmarks=np.array(filt.landmarks),
        landmark_ids=np.array(filt.landmark_ids),
        scan_time=np.array(scans.time[:n_scan]),
        scan_elapsed=scan_elapsed,
        scan_landmarks=scan_landmarks,
        odometry_steps=n_odo,
        scans=n_scan,
        total_seconds=total,
        cpu_seconds=cpu,
        warm_up_seconds=warm_up,
        association=associator.stats,
    )
    try:
        result.error = gps_error(data, times, poses[:, :2])
    except ValueError as error:
        result.error, result.error_note = None, str(error)
    return result


def _check_order(data: VictoriaPark) -> None:
    """DataFormatError naming the file and array if ``data`` (perhaps not from :func:`load`) cannot be run."""
    for name, times in (("odometry.time", data.odometry.time), ("gps.time", data.gps.time)):
        if len(times) == 0:
            raise DataFormatError(f"{data.path}: {name} is empty")
    for name, times in (
        ("odometry.time", data.odometry.time), ("scans.time", data.scans.time), ("gps.time", data.gps.time)
    ):  # fmt: skip
        back = np.flatnonzero(np.diff(np.asarray(times, dtype=np.float64)) < 0)
        if len(back):
            raise DataFormatError(f"{data.path}: {name} is not sorted (index {back[0] + 1} goes back in time)")


def _setup(data: VictoriaPark, filter_name: str, config: RunConfig) -> tuple[SlamFilter, Associator]:
    """A fresh filter at the start pose and a fresh associator."""
    from seif_gym.slam import FILTERS
    from seif_gym.slam.association import ASSOCIATOR_PRESETS, Associator

    motion, sensor = make_models(config)
    options = {"max_active": config.max_active} if filter_name in ("seif", "eseif", "cseif") else {}
    initial = np.array([data.gps.x[0], data.gps.y[0], math.radians(config.initial_heading_deg)])
    filt = FILTERS[filter_name](motion, sensor, initial, **options)
    association: dict[str, Any] = dict(
        ASSOCIATOR_PRESETS["joint"],  # the settings these runs were measured with, whatever the library's default
        gate=config.gate, new_landmark=config.new_landmark, candidate_radius=config.candidate_radius,
        min_separation=config.min_separation, signature_sigma=config.signature_sigma,
        signature_per_metre=config.signature_per_metre, neighbours=config.blanket_neighbours,
        loop_merge=config.revisable, tentative_closures=config.revisable,
    )  # fmt: skip
    if config.likelihood:
        association.update(ASSOCIATOR_PRESETS["likelihood"])
    associator = Associator(**association)
    return filt, associator


def _process(
    data: VictoriaPark,
    filt: SlamFilter,
    associator: Associator | None,
    n_odo: int,
    n_scan: int,
    config: RunConfig,
    bar: Progress | None,
) -> tuple[FloatArray, FloatArray, FloatArray, IntArray]:
    """The event loop of :func:`run`; returns ``(times, poses, scan_elapsed, scan_landmarks)``."""
    import time as clock

    odo, scans = data.odometry, data.scans
    controls = np.ascontiguousarray(odo.controls[:n_odo])
    odo_time = odo.time
    scan_time = scans.time
    usable = (scans.range >= config.min_range) & (scans.range <= config.max_range)
    use_signatures = config.signature_sigma is not None
    n_events = n_odo + n_scan
    times = np.empty(n_events)
    poses = np.empty((n_events, 3))
    scan_elapsed = np.empty(n_scan)
    scan_landmarks = np.empty(n_scan, dtype=np.int64)
    predict = filt.predict_trusted
    control = np.zeros(2)
    now = min(odo_time[0], scan_time[0]) if n_scan else odo_time[0]
    i = k = e = 0
    reported = 0
    started = clock.perf_counter()
    while i < n_odo or k < n_scan:
        if k < n_scan and (i >= n_odo or scan_time[k] <= odo_time[i]):
            t = scan_time[k]
            if t > now:
                predict(control, t - now)
                now = t
            rows = slice(int(scans.start[k]), int(scans.start[k + 1]))
            keep = usable[rows]
            if keep.any():
                ranges = scans.range[rows][keep]
                bearings = scans.bearing[rows][keep]
                diameters = scans.diameter[rows][keep] if use_signatures else None
                assert associator is not None  # the scans are associated (known ids are not in the data)
                associator.update(filt, ranges, bearings, diameters)
            scan_elapsed[k] = clock.perf_counter() - started
            scan_landmarks[k] = filt.num_landmarks
            k += 1
        else:
            t = odo_time[i]
            if t > now:
                predict(control, t - now)
                now = t
            control = controls[i]
            i += 1
            if bar is not None and i - reported >= 500:
                bar.update(i - reported, f"landmarks {filt.num_landmarks}")
                reported = i
        times[e] = now
        poses[e] = filt.pose
        e += 1
    if bar is not None:
        bar.update(n_odo - reported, f"landmarks {filt.num_landmarks}")
    return times, poses, scan_elapsed, scan_landmarks


# ---------------------------------------------------------------------------
# Plot and command line
# ---------------------------------------------------------------------------
def step_times(result: RunResult, window: int = 250) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Mean wall time per odometry step over windows of ``window`` scans.

    Returns ``(run time at the window's end (s, dataset clock from the
    start), milliseconds per odometry step, landmarks mapped)``.
    """
    ends = np.arange(window, result.scans + 1, window) - 1
    if len(ends) == 0:
        return np.empty(0), np.empty(0), np.empty(0)
    elapsed = result.scan_elapsed[ends]
    starts_elapsed = np.concatenate([[0.0], elapsed[:-1]])
    scan_t = result.scan_time[ends]
    start_t = np.concatenate([[result.time[0]], scan_t[:-1]])
    odometry_steps = np.maximum((scan_t - start_t) / 0.025, 1.0)
    ms_per_step = 1e3 * (elapsed - starts_elapsed) / odometry_steps
    return scan_t - result.time[0], ms_per_step, result.scan_landmarks[ends].astype(np.float64)


def _saved_run(path: str | os.PathLike[str]) -> Any:
    """The fields of a saved run that :func:`step_times` and :func:`plot` need, from its ``.npz``.

    Raises
    ------
    DataFormatError
        Naming the file and the array, if it is not a run's output.
    """
    from types import SimpleNamespace

    file = Path(path)
    if not file.is_file():
        raise not_found("saved run", f"{file} does not exist", "Give the .npz of an earlier run of this command")
    saved = load_npz(
        file, ("filter", "time", "scan_time", "scan_elapsed", "scan_landmarks", "total_seconds"), ("rmse",)
    )
    for name in ("time", "scan_time", "scan_elapsed"):
        check_vector(file, name, saved[name], "float")
    check_vector(file, "scan_landmarks", saved["scan_landmarks"], "int", len(saved["scan_time"]))
    check_vector(file, "scan_elapsed", saved["scan_elapsed"], "float", len(saved["scan_time"]))
    if len(saved["time"]) == 0:
        raise DataFormatError(f"{file}: array 'time' is empty")
    for name in ("filter", "total_seconds", "rmse"):
        if name in saved and saved[name].shape != ():
            raise DataFormatError(f"{file}: array {name!r} has shape {saved[name].shape}, expected a scalar")
    return SimpleNamespace(
        filter_name=str(saved["filter"]),
        time=saved["time"],
        scan_time=saved["scan_time"],
        scan_elapsed=saved["scan_elapsed"],
        scan_landmarks=saved["scan_landmarks"],
        scans=len(saved["scan_time"]),
        rmse=float(saved["rmse"]) if "rmse" in saved else float("nan"),
        total_seconds=float(saved["total_seconds"]),
    )


def plot(
    result: RunResult,
    data: VictoriaPark,
    path: str | os.PathLike[str],
    title: str | None = None,
    compare: Sequence[Any] = (),
) -> None:
    """Save the aligned trajectory and map over the GPS, and the time per step, to ``path``.

    ``compare``: other runs whose time per step is drawn too, as paths of
    their ``.npz`` (or as read by the command line).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax_time) = plt.subplots(1, 2, figsize=(13, 6), gridspec_kw={"width_ratios": [1.6, 1]})
    gps = data.gps
    inliers = gps_inliers(data)
    ax.plot(gps.x[inliers], gps.y[inliers], ".", color="tab:green", ms=2.5, label="GPS (inliers)", zorder=1)
    ax.plot(gps.x[~inliers], gps.y[~inliers], "x", color="tab:red", ms=4, label="GPS outliers (dropped)", zorder=2)
    error = result.error
    transform = error.transform if error is not None else (lambda points: points)
    trajectory = transform(result.pose[:, :2])
    landmarks = transform(result.landmarks)
    name = result.filter_name.upper()
    ax.plot(trajectory[:, 0], trajectory[:, 1], "-", color="tab:blue", lw=0.9, label=f"{name} trajectory", zorder=3)
    ax.plot(landmarks[:, 0], landmarks[:, 1], "+", color="k", ms=4, mew=0.8,
            label=f"map ({len(landmarks)} landmarks)", zorder=4)  # fmt: skip
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="upper left", fontsize=8, markerscale=2)
    rmse = f", RMSE vs GPS {error.rmse:.2f} m" if error is not None else ""
    ax.set_title(title or f"Victoria Park, {result.filter_name.upper()}{rmse}", fontsize=10)
    ax.grid(alpha=0.3)

    t, ms, count = step_times(result)
    label = f"{result.filter_name.upper()}: {result.total_seconds:.1f} s" + (
        f", {error.rmse:.2f} m" if error is not None else ""
    )
    ax_time.plot(t, ms, "-o", ms=3, color="tab:blue", label=label)
    colours = iter(["tab:red", "tab:orange", "tab:purple", "tab:brown"])
    for other_run in compare:
        other = _saved_run(other_run) if isinstance(other_run, (str, os.PathLike)) else other_run
        t_other, ms_other, _ = step_times(other)
        ax_time.plot(t_other, ms_other, "-s", ms=3, color=next(colours, "k"),
                     label=f"{other.filter_name.upper()}: {other.total_seconds:.1f} s, {other.rmse:.2f} m")  # fmt: skip
    ax_time.set_xlabel("dataset time (s)")
    ax_time.set_ylabel("wall time per odometry step (ms)" + (", log scale" if compare else ""))
    if compare:
        ax_time.set_yscale("log")
    else:
        ax_time.set_ylim(0, max(1e-3, 1.5 * float(ms.max())) if len(ms) else 1)
    twin = ax_time.twinx()
    twin.plot(t, count, "--", color="tab:gray", label=f"landmarks mapped ({result.filter_name.upper()})")
    twin.set_ylabel("landmarks mapped")
    twin.set_ylim(0, None)
    lines = ax_time.get_lines() + twin.get_lines()
    ax_time.legend(lines, [line.get_label() for line in lines], loc="upper left", fontsize=8)
    ax_time.set_title(f"time per odometry step (windows of 250 scans), {result.odometry_steps} steps", fontsize=10)
    ax_time.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def summary(result: RunResult) -> str:
    """The figures the runner prints."""
    lines = [
        f"filter              {result.filter_name}",
        f"odometry steps      {result.odometry_steps}   scans {result.scans}",
        f"time per step       {1e3 * result.seconds_per_step:.4f} ms (odometry step; whole run / steps)",
        f"total time          {result.total_seconds:.2f} s wall, {result.cpu_seconds:.2f} s CPU "
        f"(plus {result.warm_up_seconds:.2f} s untimed warm-up: numba kernels)",
        f"landmarks mapped    {len(result.landmarks)}",
    ]
    t, ms, _ = step_times(result)
    if len(ms) >= 2:
        lines.append(f"time per step       {ms[0]:.4f} ms in the first {250} scans, {ms[-1]:.4f} ms in the last")
    stats = result.association
    lines.append(
        f"association         {stats.associated} associated, {stats.new} new, {stats.discarded} discarded, "
        f"{stats.merged} merged"
    )
    if result.error is not None:
        lines.append(
            f"RMSE vs GPS         {result.error.rmse:.3f} m (rigid 2-D alignment, {result.error.used} GPS fixes; "
            f"{result.error.outliers} outliers dropped)"
        )
    else:
        lines.append(f"RMSE vs GPS         n/a ({result.error_note or 'not computed'})")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m seif_gym.datasets.victoria_park [--data DIR] --filter seif --out OUT.npz [--steps N]``.

    Returns the exit status: 0, or 2 for bad arguments and for data not found
    or malformed (one line on stderr naming the file).
    """
    import argparse

    from seif_gym.slam import FILTERS

    prog = "python -m seif_gym.datasets.victoria_park"
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Run a SLAM filter with unknown correspondences over the Victoria Park dataset.",
    )
    parser.add_argument("--data", default=None,
                        help=f"{FILE_NAME}, or its folder (default: ${DATA_ENV}/{FOLDER}/{FILE_NAME})")  # fmt: skip
    parser.add_argument("--filter", default="seif", choices=sorted(FILTERS), help="filter (default seif)")
    parser.add_argument("--out", required=True, help="output .npz (trajectory time/pose, map landmarks)")
    parser.add_argument("--steps", type=int, default=None, help="only the first N odometry steps (default: all)")
    parser.add_argument("--plot", default=None, help="plot path (default: OUT with .png)")
    parser.add_argument("--no-plot", action="store_true", help="do not save a plot")
    parser.add_argument("--compare", action="append", default=[], metavar="RUN.npz",
                        help="another run's output whose time per step the plot shows too (repeatable)")  # fmt: skip
    parser.add_argument("--quiet", "--no-progress", dest="quiet", action="store_true",
                        help="no progress bar on stderr")  # fmt: skip
    parser.add_argument("--signature", action="store_true", help="gate on the trunk diameter too")
    parser.add_argument(
        "--revisable",
        action="store_true",
        help="merge duplicates back and keep deferred lone closures as tentative landmarks",
    )
    parser.add_argument("--likelihood", action="store_true",
                        help="the 'likelihood' preset: revisable, joint hypotheses ranked by likelihood")  # fmt: skip
    parser.add_argument("--max-active", type=int, default=RunConfig.max_active, help="SEIF/ESEIF active landmarks")
    parser.add_argument("--blas-threads", type=int, default=1, help="BLAS threads (default 1; 0 leaves BLAS alone)")
    args = parser.parse_args(argv)
    if args.steps is not None and args.steps < 1:
        parser.error("--steps must be positive")
    return run_cli(prog, lambda: _command(args))


def _command(args: Any) -> int:
    """The command line's work, after its arguments are parsed."""
    data = load(args.data)
    compare = [_saved_run(path) for path in args.compare]  # read before the run: a bad file fails at once
    config = RunConfig(max_active=args.max_active, revisable=args.revisable, likelihood=args.likelihood)
    if args.signature:
        config = dataclasses.replace(config, **SIGNATURE_SETTINGS)
    out = output_file(args.out, "--out")  # before the run: an --out that cannot be written fails at once
    plot_path = None if args.no_plot else output_file(args.plot or out.with_suffix(".png"), "--plot")
    result = run(data, args.filter, steps=args.steps, config=config, progress=not args.quiet,
                 blas_threads=args.blas_threads or None)  # fmt: skip
    out = result.save(out)
    print(summary(result))
    print(f"wrote {out}")
    if plot_path is not None:
        plot(result, data, plot_path, compare=compare)
        print(f"wrote {plot_path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
