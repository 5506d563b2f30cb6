"""Tests of ``seif_gym.datasets.mrclam``: the MRCLAM text-format loader.

The full-data tests read Dataset 6 at ``$SEIF_GYM_DATA/mrclam/MRCLAM_Dataset6``
and are skipped, saying so, when it is not there; the figures they assert are
those measured on that copy (docs/data/mrclam.md). The synthetic tests write a
tiny dataset in the same text format to ``tmp_path`` (valid and malformed) and
always run. The data are never part of the repository.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from mrclam_fixtures import DATA_DIR, requires_data  # tests/datasets/ is on sys.path under pytest

from seif_gym.datasets import DATA_ENV, DataFormatError, DataNotFoundError, mrclam

# Measured on Dataset 6 (docs/data/mrclam.md):
# robot: (duration s, odometry rows, landmark measurements, robot sightings, unknown barcodes)
FIGURES = {
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
    for robot, (duration, n_odo, n_landmark, n_robot, n_unknown) in FIGURES.items():
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
        # Ground truth starts several seconds before the odometry (docs/data/mrclam.md).
        assert 1.0 < log.odometry.time[0] - gt.time[0] < 60.0
        if robot == 1:  # robot 1's ground truth ends at 772 s, its odometry runs on (docs/data/mrclam.md)
            assert log.odometry.time[-1] > gt.time[-1] + 60.0
        else:
            assert log.odometry.time[-1] <= gt.time[-1]
        # Rates: odometry median gap 10 ms; ground truth ~67 Hz (docs/data/mrclam.md).
        assert np.median(np.diff(log.odometry.time)) == pytest.approx(0.010, abs=0.002)
        assert 50.0 < 1.0 / np.median(np.diff(gt.time)) < 85.0


@requires_data
def test_units_plausible(logs):
    for log in logs.values():
        odo = log.odometry
        # docs/data/mrclam.md: v <= 0.09 m/s, |omega| <= 0.57 rad/s.
        assert np.all((odo.v >= 0.0) & (odo.v <= 0.09))
        assert np.all(np.abs(odo.omega) <= 0.57 + 1e-9)
        for stream in (log.measurements, log.robot_sightings):
            # docs/data/mrclam.md: ranges between ~0.9 m and ~8.6 m.
            assert np.all((stream.range > 0.8) & (stream.range < 10.0))
            # The docs give no field of view: a forward-looking camera sees
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
        assert len(times) < len(log.measurements)  # several readings share a camera frame (docs/data/mrclam.md)


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


# ---------------------------------------------------------------------------
# Where the data are found
# ---------------------------------------------------------------------------
def test_data_come_from_the_argument_else_seif_gym_data(tiny, tmp_path, monkeypatch):
    monkeypatch.delenv(DATA_ENV, raising=False)
    with pytest.raises(DataNotFoundError, match=DATA_ENV) as error:
        mrclam.load(robot=1)
    message = str(error.value)
    assert "--data" in message and "docs/data/mrclam.md" in message and "\n" not in message
    # SEIF_GYM_DATA holds mrclam/MRCLAM_Dataset6
    root = tmp_path / "data"
    (root / "mrclam").mkdir(parents=True)
    tiny.rename(root / "mrclam" / "MRCLAM_Dataset6")
    monkeypatch.setenv(DATA_ENV, str(root))
    assert mrclam.locate() == root / "mrclam" / "MRCLAM_Dataset6"
    assert mrclam.load(robot=1).measurements.subject.tolist() == [6, 7, 7]
    assert sorted(mrclam.load_all()) == [1, 2, 3, 4, 5]
    # an explicit argument wins; it may name the dataset, or a folder holding it (or holding mrclam/ with it)
    assert mrclam.locate(root / "mrclam") == root / "mrclam" / "MRCLAM_Dataset6"
    assert mrclam.locate(root) == root / "mrclam" / "MRCLAM_Dataset6"
    with pytest.raises(DataNotFoundError, match="elsewhere"):
        mrclam.load(tmp_path / "elsewhere", 1)
    monkeypatch.setenv(DATA_ENV, str(tmp_path / "empty"))
    with pytest.raises(DataNotFoundError, match="has no mrclam/MRCLAM_Dataset6"):
        mrclam.load(robot=1)


# ---------------------------------------------------------------------------
# Malformed files: a ValueError naming the file and the line
# ---------------------------------------------------------------------------
def _replace_line(path: Path, number: int, text: str) -> None:
    lines = path.read_text().splitlines()
    lines[number - 1] = text
    path.write_text("\n".join(lines) + "\n")


def _header_lines(path: Path) -> int:
    return sum(1 for line in path.read_text().splitlines() if line.startswith("#"))


@pytest.mark.parametrize(
    ("file", "row", "text", "says"),
    [
        ("Robot1_Odometry.dat", 5, "101.04 0.05 abc", "'abc' is not a number"),
        ("Robot1_Odometry.dat", 7, "101.06 0.05", "2 values, expected 3"),
        ("Robot1_Odometry.dat", 9, "101.08 nan -0.1", "not finite"),
        ("Robot1_Groundtruth.dat", 3, "101.03 0.02 0.0 inf", "not finite"),
        ("Robot1_Measurement.dat", 2, "102.5 81.5 2.5 -0.2", "barcode is not an integer"),
        ("Robot1_Measurement.dat", 4, "102.7 5 -1.0 0.0", "range is not positive"),
        ("Barcodes.dat", 8, "8 63", "barcode appears twice"),
        ("Barcodes.dat", 2, "2 14.5", "subject or barcode is not an integer"),
        ("Landmark_Groundtruth.dat", 2, "7 1.0 0.5 0.0003 0.0004", "subject appears twice"),
        ("Landmark_Groundtruth.dat", 1, "7.5 2.0 -1.0 0.0001 0.0002", "subject is not an integer"),
    ],
)
def test_a_malformed_line_is_named(tiny, file, row, text, says):
    path = tiny / file
    line = _header_lines(path) + row
    _replace_line(path, line, text)
    with pytest.raises(DataFormatError, match=f"{file}, line {line}: .*{says}") as error:
        mrclam.load(tiny, 1)
    assert isinstance(error.value, ValueError) and str(path) in str(error.value)


def test_a_truncated_or_empty_file_is_named(tiny):
    odometry = tiny / "Robot2_Odometry.dat"
    text = odometry.read_text()
    odometry.write_text(text[: len(text) // 2 - 3])  # cut inside a line
    last = len(odometry.read_text().splitlines())
    with pytest.raises(DataFormatError, match=f"Robot2_Odometry.dat, line {last}: "):
        mrclam.load(tiny, 2)
    odometry.write_text("# Time [s]    v    omega\n")
    with pytest.raises(DataFormatError, match="Robot2_Odometry.dat: no data rows"):
        mrclam.load(tiny, 2)
    (tiny / "Robot3_Measurement.dat").write_text("# no readings\n")  # a robot that saw nothing is fine
    assert len(mrclam.load(tiny, 3).measurements) == 0
    (tiny / "Robot4_Groundtruth.dat").write_bytes(b"\x00\x01\xff" * 50)
    with pytest.raises(DataFormatError, match="Robot4_Groundtruth.dat, line 1: "):
        mrclam.load(tiny, 4)


def test_the_old_module_names_warn_and_work():
    import importlib
    import sys

    from seif_gym.datasets.mrclam import calibration, episodes, runner

    for name, new in (("calibration", calibration), ("episodes", episodes), ("runner", runner)):
        sys.modules.pop(f"seif_gym.datasets.mrclam_{name}", None)
        with pytest.warns(DeprecationWarning, match=f"seif_gym.datasets.mrclam.{name}"):
            old = importlib.import_module(f"seif_gym.datasets.mrclam_{name}")
        assert all(getattr(old, attribute) is getattr(new, attribute) for attribute in new.__all__)
        assert old.main is new.main
