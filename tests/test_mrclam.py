"""Tests of ``seif_gym.datasets.mrclam``: the MRCLAM text-format loader.

The real-data tests read the shared copy of Dataset 6,
``../shared/data/mrclam/MRCLAM_Dataset6`` beside the repository, and are
skipped, saying so, only when it is absent; the figures they assert are those
of the data README (``../shared/data/mrclam/README.md``). The synthetic tests
write a tiny dataset in the same text format to ``tmp_path`` and always run.
The data are never part of the repository.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from seif_gym.datasets import mrclam

DATA_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "mrclam" / "MRCLAM_Dataset6"
requires_data = pytest.mark.skipif(
    not DATA_DIR.is_dir(),
    reason=f"MRCLAM Dataset 6 not found at {DATA_DIR} (expected ../shared/data/mrclam beside the repository)",
)

# From the data README's table "Figures measured on this copy":
# robot: (duration s, odometry rows, landmark measurements, robot sightings, unknown barcodes)
README_FIGURES = {
    1: (772, 61785, 1534, 407, 1),
    2: (900, 65005, 3239, 792, 0),
    3: (900, 61158, 4348, 1277, 2),
    4: (900, 52916, 2023, 373, 3),
    5: (900, 60567, 4239, 1139, 0),
}


@pytest.fixture(scope="module")
def logs() -> dict[int, mrclam.MrclamLog]:
    return mrclam.load_all(DATA_DIR)


def _arrays(log: mrclam.MrclamLog):
    for stream in (log.odometry, log.measurements, log.robot_sightings, log.ground_truth, log.landmarks):
        for name, value in vars(stream).items():
            if isinstance(value, np.ndarray):
                yield f"{type(stream).__name__}.{name}", value
    yield "barcodes", log.barcodes
    yield "dropped_barcodes", log.dropped_barcodes


# ---------------------------------------------------------------------------
# Dataset 6
# ---------------------------------------------------------------------------
@requires_data
def test_counts_match_readme(logs):
    assert sorted(logs) == [1, 2, 3, 4, 5]
    for robot, (duration, n_odo, n_landmark, n_robot, n_unknown) in README_FIGURES.items():
        log = logs[robot]
        assert log.robot == robot
        assert len(log.odometry) == n_odo
        assert len(log.measurements) == n_landmark
        assert len(log.robot_sightings) == n_robot
        assert log.num_dropped == n_unknown
        gt = log.ground_truth
        assert gt.time[-1] - gt.time[0] == pytest.approx(duration, abs=1.0)
    # 15 landmarks, subjects 6-20, with survey std; subjects 1-5 are the robots.
    landmarks = logs[1].landmarks
    assert landmarks.subject.tolist() == list(range(6, 21))
    assert landmarks.std_x is not None and landmarks.std_y is not None
    assert np.all(landmarks.std_x < 1e-3) and np.all(landmarks.std_y < 1e-3)  # sub-millimetre survey
    assert sorted(logs[1].barcodes[:, 0].tolist()) == list(range(1, 21))


@requires_data
def test_shapes_dtypes_read_only(logs):
    for log in logs.values():
        for name, array in _arrays(log):
            assert not array.flags.writeable, name
            with pytest.raises(ValueError):
                array[...] = 0
            expected = np.int64 if name.endswith(("subject", "barcode", "barcodes")) else np.float64
            assert array.dtype == expected, name
        assert log.odometry.controls.shape == (len(log.odometry), 2)
        assert log.ground_truth.poses.shape == (len(log.ground_truth), 3)
        assert log.landmarks.positions.shape == (15, 2)
        assert log.barcodes.shape == (20, 2)
        for stream in (log.odometry, log.measurements, log.robot_sightings, log.ground_truth):
            for value in vars(stream).values():
                assert value.shape == (len(stream),)


@requires_data
def test_times_sorted_and_within_ground_truth(logs):
    for robot, log in logs.items():
        gt = log.ground_truth
        for stream in (log.odometry, log.measurements, log.robot_sightings, gt):
            assert np.all(np.diff(stream.time) >= 0)
        for stream in (log.measurements, log.robot_sightings):
            assert gt.time[0] <= stream.time[0] and stream.time[-1] <= gt.time[-1]
        # Ground truth starts several seconds before the odometry (README).
        assert 1.0 < log.odometry.time[0] - gt.time[0] < 60.0
        if robot == 1:  # robot 1's ground truth ends at 772 s, its odometry runs on (README)
            assert log.odometry.time[-1] > gt.time[-1] + 60.0
        else:
            assert log.odometry.time[-1] <= gt.time[-1]
        # Rates: odometry median gap 10 ms; ground truth ~67 Hz (README).
        assert np.median(np.diff(log.odometry.time)) == pytest.approx(0.010, abs=0.002)
        assert 50.0 < 1.0 / np.median(np.diff(gt.time)) < 85.0


@requires_data
def test_units_plausible(logs):
    for log in logs.values():
        odo = log.odometry
        # README: v <= 0.09 m/s, |omega| <= 0.57 rad/s.
        assert np.all((odo.v >= 0.0) & (odo.v <= 0.09))
        assert np.all(np.abs(odo.omega) <= 0.57 + 1e-9)
        for stream in (log.measurements, log.robot_sightings):
            # README: ranges between ~0.9 m and ~8.6 m.
            assert np.all((stream.range > 0.8) & (stream.range < 10.0))
            # The README gives no field of view: a forward-looking camera sees
            # only ahead, |bearing| < pi/2 (0 straight ahead).
            assert np.all(np.abs(stream.bearing) < math.pi / 2)
        gt = log.ground_truth
        assert np.all(np.abs(gt.theta) <= math.pi + 1e-3)  # headings in [-pi, pi], 4 decimals
        # The area is ~15 m x 8 m.
        assert np.ptp(gt.x) < 15.0 and np.ptp(gt.y) < 15.0
        # Interpolated ground truth at the first odometry time is near the first poses.
        pose = gt.interpolate(odo.time[0])
        assert pose.shape == (3,)
        assert abs(pose[0] - gt.x[0]) < 1.0 and abs(pose[1] - gt.y[0]) < 1.0


@requires_data
def test_barcode_mapping(logs):
    for robot, log in logs.items():
        table = dict(log.barcodes[:, ::-1].tolist())  # barcode -> subject
        assert np.all(np.isin(log.measurements.subject, log.landmarks.subject))
        assert set(log.measurements.subject.tolist()) <= set(range(6, 21))
        sighted = set(log.robot_sightings.subject.tolist())
        assert sighted <= {1, 2, 3, 4, 5} - {robot}
        for stream in (log.measurements, log.robot_sightings):
            assert [table[b] for b in stream.barcode.tolist()] == stream.subject.tolist()
        assert all(b not in table for b in log.dropped_barcodes.tolist())
        times, start = log.measurements.frames()
        assert start[-1] == len(log.measurements) and len(start) == len(times) + 1
        assert len(times) < len(log.measurements)  # several readings share a camera frame (README)


@requires_data
def test_load_single_robot_matches_load_all(logs):
    log = mrclam.load(str(DATA_DIR), 3)
    assert log.robot == 3 and log.path == DATA_DIR
    np.testing.assert_array_equal(log.measurements.time, logs[3].measurements.time)
    np.testing.assert_array_equal(log.odometry.v, logs[3].odometry.v)


# ---------------------------------------------------------------------------
# Synthetic dataset (always runs)
# ---------------------------------------------------------------------------
HEADER = "# UTIAS Multi-Robot Cooperative Localization and Mapping Dataset\n# synthetic test copy\n"


def _write(path: Path, header: str, rows: list[tuple]) -> None:
    lines = [HEADER + f"# {header}\n"] + [" \t ".join(str(v) for v in row) + "\n" for row in rows]
    path.write_text("".join(lines))


@pytest.fixture
def tiny(tmp_path) -> Path:
    folder = tmp_path / "MRCLAM_Tiny"
    folder.mkdir()
    # Subjects 1-5 robots (barcodes 5, 14, 41, 32, 23); landmarks 6, 7 (63, 81);
    # subject 8 (barcode 7) is in Barcodes.dat but not surveyed.
    _write(folder / "Barcodes.dat", "Subject #    Barcode #",
           [(1, 5), (2, 14), (3, 41), (4, 32), (5, 23), (6, 63), (7, 81), (8, 7)])  # fmt: skip
    _write(folder / "Landmark_Groundtruth.dat", "Subject #    x [m]    y [m]    x std-dev [m]    y std-dev [m]",
           [(7, 2.0, -1.0, 0.0001, 0.0002), (6, 1.0, 0.5, 0.0003, 0.0004)])  # fmt: skip
    for robot in mrclam.ROBOTS:
        t0 = 100.0 + robot
        _write(folder / f"Robot{robot}_Groundtruth.dat", "Time [s]    x [m]    y [m]    orientation [rad]",
               [(t0 + 0.015 * k, 0.01 * k, 0.0, 3.1 if k < 2 else -3.1) for k in range(400)])  # fmt: skip
        _write(folder / f"Robot{robot}_Odometry.dat", "Time [s]    forward velocity [m/s]    angular velocity[rad/s]",
               [(t0 + 1.0 + 0.01 * k, 0.05, -0.1) for k in range(300)])  # fmt: skip
    # Robot 1 sees: landmark 6, landmark 7 (same frame), robot 2, itself (barcode 5),
    # a misread barcode 99, the unsurveyed subject 8, robot 5; rows out of order.
    _write(folder / "Robot1_Measurement.dat", "Time [s]    Subject #    range [m]    bearing [rad]", [
        (102.5, 63, 1.5, 0.1),
        (102.5, 81, 2.5, -0.2),
        (102.6, 14, 3.0, 0.3),
        (102.7, 5, 1.0, 0.0),
        (102.8, 99, 4.0, 0.4),
        (102.9, 7, 2.0, 0.0),
        (103.2, 23, 3.5, -0.3),
        (103.0, 81, 2.4, -0.25),
    ])  # fmt: skip
    for robot in (2, 3, 4, 5):
        _write(folder / f"Robot{robot}_Measurement.dat", "Time [s]    Subject #    range [m]    bearing [rad]",
               [(104.0, 63, 1.0, 0.0)])  # fmt: skip
    return folder


def test_synthetic_mapping_and_separation(tiny):
    log = mrclam.load(tiny, 1)
    m = log.measurements
    assert m.time.tolist() == [102.5, 102.5, 103.0]
    assert m.subject.tolist() == [6, 7, 7]
    assert m.barcode.tolist() == [63, 81, 81]
    assert m.range.tolist() == [1.5, 2.5, 2.4]
    assert m.bearing.tolist() == [0.1, -0.2, -0.25]
    s = log.robot_sightings
    assert s.subject.tolist() == [2, 5] and s.time.tolist() == [102.6, 103.2] and s.range.tolist() == [3.0, 3.5]
    # Dropped: itself (5), the misread (99), the unsurveyed subject 8 (barcode 7), in file order.
    assert log.dropped_barcodes.tolist() == [5, 99, 7] and log.num_dropped == 3
    times, start = m.frames()
    assert times.tolist() == [102.5, 103.0] and start.tolist() == [0, 2, 3]
    # Landmarks sorted by subject, with std.
    assert log.landmarks.subject.tolist() == [6, 7]
    assert log.landmarks.positions.tolist() == [[1.0, 0.5], [2.0, -1.0]]
    assert log.landmarks.std_x.tolist() == [0.0003, 0.0001]
    assert log.landmarks.index([7, 6]).tolist() == [1, 0]
    with pytest.raises(ValueError, match="not surveyed"):
        log.landmarks.index([8])
    # Streams and units.
    assert len(log.odometry) == 300 and np.all(log.odometry.v == 0.05) and np.all(log.odometry.omega == -0.1)
    assert len(log.ground_truth) == 400
    # Heading interpolated across the +-pi wrap, not through 0.
    t_mid = 0.5 * (log.ground_truth.time[1] + log.ground_truth.time[2])
    assert abs(abs(log.ground_truth.interpolate(t_mid)[2]) - math.pi) < 0.05
    for name, array in _arrays(log):
        assert not array.flags.writeable, name
    # Robot 2 sees one landmark; robot 1 is the sighted robot elsewhere only.
    assert mrclam.load(tiny, 2).measurements.subject.tolist() == [6]


def test_synthetic_load_all_and_no_std(tiny):
    lm = tiny / "Landmark_Groundtruth.dat"
    _write(lm, "Subject #    x [m]    y [m]", [(6, 1.0, 0.5), (7, 2.0, -1.0)])
    logs = mrclam.load_all(tiny)
    assert sorted(logs) == [1, 2, 3, 4, 5]
    assert all(log.robot == robot for robot, log in logs.items())
    assert logs[3].landmarks.std_x is None and logs[3].landmarks.std_y is None
    assert len(logs[1].measurements) == 3 and len(logs[4].measurements) == 1


def test_bad_arguments(tiny, tmp_path):
    for robot in (0, 6, -1, 1.0, "1", True, None):
        with pytest.raises(ValueError, match="robot"):
            mrclam.load(tiny, robot)
    missing = tmp_path / "nowhere"
    with pytest.raises(FileNotFoundError, match="nowhere"):
        mrclam.load(missing, 1)
    with pytest.raises(FileNotFoundError, match="nowhere"):
        mrclam.load_all(missing)
    (tiny / "Robot4_Odometry.dat").unlink()
    assert len(mrclam.load(tiny, 3).odometry) == 300  # other robots still load
    with pytest.raises(FileNotFoundError, match="Robot4_Odometry.dat"):
        mrclam.load(tiny, 4)
    with pytest.raises(FileNotFoundError, match="Robot4_Odometry.dat"):
        mrclam.load_all(tiny)
    (tiny / "Barcodes.dat").unlink()
    with pytest.raises(FileNotFoundError, match="Barcodes.dat"):
        mrclam.load(tiny, 1)


def test_malformed_file(tiny):
    _write(tiny / "Robot2_Odometry.dat", "Time [s]    v", [(1.0, 0.05), (2.0, 0.05)])
    with pytest.raises(ValueError, match="Robot2_Odometry.dat"):
        mrclam.load(tiny, 2)
