"""Tests of ``seif_gym.datasets.victoria_park``: loader, GPS ground truth, runner.

They read the shared copy of the data, ``../shared/data/victoria_park``
beside the repository (or the directory in ``$VICTORIA_PARK_DATA``), and are
skipped, saying so, only when it is absent. The data are never part of the
repository.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from seif_gym.datasets import victoria_park as vp
from seif_gym.slam.car_model import AckermannLaserModel

SHARED_COPY = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "victoria_park"
DATA_DIR = Path(os.environ.get("VICTORIA_PARK_DATA", SHARED_COPY))
requires_data = pytest.mark.skipif(
    not (DATA_DIR / vp.FILE_NAME).is_file(),
    reason=f"Victoria Park data not found at {DATA_DIR} (expected ../shared/data/victoria_park beside the repository)",
)


@pytest.fixture(scope="module")
def data():
    return vp.load(DATA_DIR)


@pytest.fixture(scope="module")
def raw():
    with np.load(DATA_DIR / vp.FILE_NAME) as arrays:
        return {name: arrays[name] for name in arrays.files}


# ---------------------------------------------------------------------------
# loader
# ---------------------------------------------------------------------------
@requires_data
def test_shapes_and_types(data):
    odo, scans, gps = data.odometry, data.scans, data.gps
    assert len(odo) == 61945 and odo.speed.shape == odo.steering.shape == odo.time.shape == (61945,)
    assert len(scans) == 7249 and scans.start.shape == (7250,)
    assert scans.num_detections == 52974
    for name in ("scan", "range", "bearing", "diameter"):
        assert getattr(scans, name).shape == (52974,)
    assert len(gps) == 4466 and gps.x.shape == gps.y.shape == (4466,)
    assert odo.controls.shape == (61945, 2) and gps.positions.shape == (4466, 2)
    for array in (odo.time_ms, scans.time_ms, gps.time_ms, scans.start, scans.scan):
        assert array.dtype == np.int64
    floats = (odo.time, odo.speed, odo.steering, scans.time, scans.range, scans.bearing, scans.diameter, gps.x, gps.y)
    for array in floats:
        assert array.dtype == np.float64
        assert not array.flags.writeable


@requires_data
def test_units_and_clock(data, raw):
    odo, scans, gps = data.odometry, data.scans, data.gps
    # one clock, milliseconds and seconds
    np.testing.assert_array_equal(odo.time_ms, raw["odo_time_ms"])
    np.testing.assert_allclose(odo.time, raw["odo_time_ms"] / 1000.0)
    np.testing.assert_allclose(np.diff(odo.time), 0.025, atol=1e-9)  # every 25 ms
    assert scans.time[0] < odo.time[0]  # the first scan precedes the first odometry sample
    assert 213 <= np.diff(scans.time_ms).min() and np.diff(scans.time_ms).max() <= 215
    assert np.all(np.diff(gps.time) > 0)
    # speed m/s, steering rad, ranges and diameters m
    assert -0.1 < odo.speed.min() and odo.speed.max() < 7.0
    assert -0.6 < odo.steering.min() and odo.steering.max() < 0.6
    assert 1.4 < scans.range.min() and scans.range.max() < 75.5
    assert 0.0 < scans.diameter.min() and scans.diameter.max() < 1.5


@requires_data
def test_bearings_are_converted_to_the_robot_frame(data, raw):
    """Robot frame: 0 straight ahead, positive to the left (laser frame 0 ... pi from the right)."""
    np.testing.assert_allclose(data.scans.bearing, raw["det_bearing"] - math.pi / 2, atol=1e-15)
    assert -math.pi / 2 < data.scans.bearing.min() and data.scans.bearing.max() < math.pi / 2


@requires_data
def test_detections_are_grouped_by_scan(data):
    scans = data.scans
    assert scans.start[0] == 0 and scans.start[-1] == scans.num_detections
    counts = np.diff(scans.start)
    assert np.count_nonzero(counts == 0) == 19 and counts.max() == 18
    assert counts.mean() == pytest.approx(7.3, abs=0.05)
    k = 1234
    ranges, bearings, diameters = scans.detections(k)
    assert len(ranges) == counts[k] == len(bearings) == len(diameters)
    assert np.all(scans.scan[scans.start[k] : scans.start[k + 1]] == k)


@requires_data
def test_conventions_make_consecutive_scans_agree(data):
    """Project the trees of scans a second apart with dead reckoning: the same trees fall on each other.

    With the robot-frame bearing and the car model the nearest tree of the
    later scan is a few decimetres away; a flipped bearing, or the raw laser
    bearing, scatters them by metres (the car drives 2-4 m in between).
    """
    model = AckermannLaserModel()
    odo, scans = data.odometry, data.scans
    first, last = 300, 420  # the car drives here (scans ~64-90 s into the run)
    LAG = 5  # scans, about a second
    pose = np.zeros(3)
    i = int(np.searchsorted(odo.time, scans.time[first]))
    poses = {}
    for k in range(first, last):
        while odo.time[i] < scans.time[k]:
            pose = model.predict(pose, odo.controls[i], 0.025)
            i += 1
        poses[k] = pose

    def median_gap(bearing_of):
        gaps = []
        for k in range(first, last - LAG):
            points = []
            for scan in (k, k + LAG):
                ranges, bearings, _ = scans.detections(scan)
                angle = bearing_of(bearings) + poses[scan][2]
                points.append(poses[scan][:2] + np.column_stack([ranges * np.cos(angle), ranges * np.sin(angle)]))
            if len(points[0]) and len(points[1]):
                gaps.extend(np.min(np.linalg.norm(points[1][:, None] - points[0][None], axis=2), axis=1))
        return float(np.median(gaps))

    assert median_gap(lambda b: b) < 0.3
    assert median_gap(lambda b: -b) > 1.5
    assert median_gap(lambda b: b + math.pi / 2) > 1.5


@requires_data
def test_load_variants_and_errors(tmp_path):
    by_file = vp.load(DATA_DIR / vp.FILE_NAME, verify=True)  # checksum of the data README
    assert len(by_file.odometry) == 61945
    with pytest.raises(FileNotFoundError, match="not found"):
        vp.load(tmp_path)
    np.savez(tmp_path / vp.FILE_NAME, odo_time_ms=np.arange(3))
    with pytest.raises(ValueError, match="lacks"):
        vp.load(tmp_path)


# ---------------------------------------------------------------------------
# ground truth
# ---------------------------------------------------------------------------
@requires_data
def test_gps_outliers(data):
    keep = vp.gps_inliers(data)
    assert 0.95 * len(keep) < keep.sum() < len(keep)
    # the isolated fix 190 m off the track, 1222 s into the run, is dropped
    far = np.flatnonzero(data.gps.x < -240)
    assert len(far) == 1 and not keep[far[0]]


def test_rigid_alignment_recovers_a_known_motion():
    rng = np.random.default_rng(0)
    source = rng.uniform(-50, 50, (100, 2))
    angle = 0.7
    rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    target = source @ rotation.T + np.array([3.0, -4.0])
    found_rotation, found_translation = vp.rigid_alignment(source, target)
    np.testing.assert_allclose(found_rotation, rotation, atol=1e-12)
    np.testing.assert_allclose(found_translation, [3.0, -4.0], atol=1e-10)
    # a reflection is never returned
    mirrored = target * np.array([1.0, -1.0])
    assert np.linalg.det(vp.rigid_alignment(source, mirrored)[0]) == pytest.approx(1.0)


@requires_data
def test_gps_error_of_the_gps_itself_is_zero(data):
    keep = vp.gps_inliers(data)
    angle = 0.3
    rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    moved = data.gps.positions[keep] @ rotation.T + 10.0
    error = vp.gps_error(data, data.gps.time[keep], moved)
    assert error.rmse < 1e-9
    assert error.used == keep.sum()
    np.testing.assert_allclose(error.transform(moved), data.gps.positions[keep], atol=1e-8)


# ---------------------------------------------------------------------------
# runner
# ---------------------------------------------------------------------------
@requires_data
def test_runner_short_run_writes_the_documented_output(tmp_path, capsys):
    out = tmp_path / "run" / "seif.npz"
    code = vp.main(["--data", str(DATA_DIR), "--filter", "seif", "--out", str(out), "--steps", "3000", "--no-progress"])
    assert code == 0
    printed = capsys.readouterr().out
    for phrase in ("time per step", "total time", "landmarks mapped", "RMSE vs GPS"):
        assert phrase in printed
    with np.load(out) as result:
        time, pose, landmarks = result["time"], result["pose"], result["landmarks"]
        rmse = float(result["rmse"])
    assert time.ndim == 1 and pose.shape == (len(time), 3) and landmarks.ndim == 2 and landmarks.shape[1] == 2
    assert np.all(np.diff(time) >= 0) and time[-1] <= 22.0 + 3000 * 0.025
    assert len(time) > 3000  # after every odometry step and every scan
    assert 50 < len(landmarks) < 200
    assert np.all(np.isfinite(pose)) and np.all(np.abs(pose[:, 2]) <= math.pi)
    assert rmse < 3.0
    assert (tmp_path / "run" / "seif.png").is_file()


@requires_data
def test_runner_rejects_bad_arguments(tmp_path, capsys):
    with pytest.raises(SystemExit):
        vp.main(["--data", str(DATA_DIR), "--filter", "nope", "--out", str(tmp_path / "x.npz")])
    assert vp.main(["--data", str(tmp_path), "--out", str(tmp_path / "x.npz"), "--no-progress"]) == 2
    assert "not found" in capsys.readouterr().err
