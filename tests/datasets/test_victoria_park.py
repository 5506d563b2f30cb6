"""Tests of ``seif_gym.datasets.victoria_park``: loader, GPS ground truth, runner.

The full-data tests read ``$SEIF_GYM_DATA/victoria_park/victoria_park.npz``
and are skipped, saying so, when it is not there. The synthetic tests write a
small log in the same layout (``victoria_park_fixtures``), and malformed
copies of it, to ``tmp_path``, and always run. The data are never part of the
repository.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import zipfile

import numpy as np
import pytest
from shared_data import full_data  # tests/datasets/ is on sys.path under pytest
from victoria_park_fixtures import START, synthetic_arrays, write_victoria_park

from seif_gym.datasets import DATA_ENV, DataFormatError, DataNotFoundError
from seif_gym.datasets import victoria_park as vp
from seif_gym.slam.car_model import AckermannLaserModel

#: ``$SEIF_GYM_DATA/victoria_park``, and the mark of the tests that read it.
DATA_DIR, requires_data = full_data("victoria_park/victoria_park.npz", "Victoria Park data")
DATA_DIR = DATA_DIR.parent


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
    by_file = vp.load(DATA_DIR / vp.FILE_NAME, verify=True)  # the published copy's checksum
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


# ---------------------------------------------------------------------------
# a synthetic log in the same layout (always runs)
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """``(folder, arrays, trees)``: a synthetic ``victoria_park.npz`` in ``folder``."""
    arrays, trees = synthetic_arrays()
    folder = tmp_path_factory.mktemp("vp") / "victoria_park"
    write_victoria_park(folder, arrays)
    return folder, arrays, trees


def test_synthetic_log_loads_with_the_documented_conventions(synthetic):
    folder, arrays, _ = synthetic
    data = vp.load(folder)
    assert data.path == folder / vp.FILE_NAME
    assert len(data.odometry) == len(arrays["odo_time_ms"]) and len(data.scans) == len(arrays["laser_time_ms"])
    np.testing.assert_allclose(data.odometry.time, arrays["odo_time_ms"] / 1000.0)
    np.testing.assert_allclose(data.scans.bearing, arrays["det_bearing"] - math.pi / 2)
    assert data.scans.scan.dtype == np.int64 and data.scans.start[-1] == len(arrays["det_scan"])
    assert vp.load(folder / vp.FILE_NAME).odometry.speed.tolist() == data.odometry.speed.tolist()
    assert vp.load(folder.parent).path == data.path  # a SEIF_GYM_DATA-style folder, given explicitly
    with pytest.raises(DataFormatError, match="does not match the published copy"):
        vp.load(folder, verify=True)


def test_runner_end_to_end_on_the_synthetic_log(synthetic, tmp_path, capsys):
    folder, arrays, trees = synthetic
    out = tmp_path / "run" / "seif.npz"
    assert vp.main(["--data", str(folder), "--filter", "seif", "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    for phrase in ("time per step", "total time", "landmarks mapped", "RMSE vs GPS"):
        assert phrase in printed
    with np.load(out) as result:
        time, pose, landmarks, rmse = result["time"], result["pose"], result["landmarks"], float(result["rmse"])
        assert str(result["filter"]) == "seif" and len(result["scan_time"]) == len(arrays["laser_time_ms"])
    assert len(time) == len(arrays["odo_time_ms"]) + len(arrays["laser_time_ms"])  # after every step and scan
    assert pose.shape == (len(time), 3) and np.all(np.diff(time) >= 0) and np.all(np.isfinite(pose))
    np.testing.assert_allclose(pose[0], START, atol=0.2)
    assert rmse < 0.5  # one loop, 5 cm GPS noise
    assert 0.9 * len(trees) <= len(landmarks) <= 1.2 * len(trees)
    assert (tmp_path / "run" / "seif.png").is_file()
    # a second run compared with the first on the plot; the EKF too
    out_ekf = tmp_path / "ekf.npz"
    assert vp.main(["--data", str(folder), "--filter", "ekf", "--out", str(out_ekf), "--no-progress",
                    "--compare", str(out)]) == 0  # fmt: skip
    assert out_ekf.with_suffix(".png").is_file()


def test_data_come_from_the_argument_else_seif_gym_data(synthetic, tmp_path, monkeypatch, capsys):
    folder, _, _ = synthetic
    monkeypatch.delenv(DATA_ENV, raising=False)
    with pytest.raises(DataNotFoundError, match=DATA_ENV) as error:
        vp.load()
    message = str(error.value)
    assert isinstance(error.value, FileNotFoundError) and "\n" not in message
    assert "--data" in message and "docs/data/victoria_park.md" in message and "ACFR" in message
    out = tmp_path / "x.npz"
    assert vp.main(["--out", str(out), "--no-progress", "--no-plot"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and DATA_ENV in err and not out.exists()
    monkeypatch.setenv(DATA_ENV, str(folder.parent))
    assert vp.locate() == folder / vp.FILE_NAME and len(vp.load().odometry) > 0
    assert vp.main(["--out", str(out), "--no-progress", "--no-plot", "--steps", "100"]) == 0
    monkeypatch.setenv(DATA_ENV, str(tmp_path))
    with pytest.raises(DataNotFoundError, match="has no victoria_park/victoria_park.npz"):
        vp.load()
    with pytest.raises(DataNotFoundError, match="no victoria_park.npz in"):
        vp.load(tmp_path)
    with pytest.raises(DataNotFoundError, match="does not exist"):
        vp.load(tmp_path / "nowhere")


def _malformed(arrays, **changes):
    copy = dict(arrays)
    for name, value in changes.items():
        if value is None:
            del copy[name]
        else:
            copy[name] = value
    return copy


@pytest.mark.parametrize(
    ("change", "says"),
    [
        (lambda a: _malformed(a, gps_y=None), r"lacks the array\(s\) \['gps_y'\]"),
        (lambda a: _malformed(a, odo_time_ms=a["odo_time_ms"].astype(np.float64)),
         "array 'odo_time_ms' has dtype float64, expected integers"),
        (lambda a: _malformed(a, det_range=a["det_range"].astype(str)), "array 'det_range' has dtype <U"),
        (lambda a: _malformed(a, det_range=np.stack([a["det_range"]] * 2, axis=1)),
         r"array 'det_range' has shape \(\d+, 2\), expected one dimension"),
        (lambda a: _malformed(a, gps_y=a["gps_y"][:-1]), "array 'gps_y' has shape .* like the other gps_ arrays"),
        (lambda a: _malformed(a, odo_speed=np.where(np.arange(len(a["odo_speed"])) == 7, np.nan, a["odo_speed"])),
         "array 'odo_speed' has a non-finite value .* at index 7"),
        (lambda a: _malformed(a, laser_time_ms=a["laser_time_ms"][::-1].copy()), "array 'laser_time_ms' is not sorted"),
        (lambda a: _malformed(a, det_scan=a["det_scan"] + 1000), "array 'det_scan' must be sorted scan indices"),
        (lambda a: _malformed(a, det_range=-a["det_range"]), "array 'det_range' has a range <= 0 at index 0"),
        (lambda a: _malformed(a, gps_time_ms=a["gps_time_ms"][:0], gps_x=a["gps_x"][:0], gps_y=a["gps_y"][:0]),
         "array 'gps_time_ms' is empty"),
    ],
)  # fmt: skip
def test_a_malformed_array_is_named(synthetic, tmp_path, change, says):
    _, arrays, _ = synthetic
    path = write_victoria_park(tmp_path, change(arrays))
    with pytest.raises(DataFormatError, match=f"{path}.*{says}"):
        vp.load(path)


def test_a_corrupt_file_is_named_without_numpy_advice(synthetic, tmp_path, capsys):
    folder, arrays, _ = synthetic
    good = (folder / vp.FILE_NAME).read_bytes()
    path = tmp_path / vp.FILE_NAME
    for content in (good[: len(good) // 2], b"", b"not numpy at all\n" * 4, good[:-200]):
        path.write_bytes(content)
        with pytest.raises(DataFormatError, match=f"{path}: not a readable .npz archive") as error:
            vp.load(path)
        assert "allow_pickle" not in str(error.value)
    # a member damaged inside an intact archive
    with zipfile.ZipFile(path, "w") as archive:
        for name, array in arrays.items():
            with archive.open(f"{name}.npy", "w") as member:
                np.lib.format.write_array(member, array)
    with zipfile.ZipFile(path, "a") as archive, pytest.warns(UserWarning, match="Duplicate name"):
        archive.writestr("gps_x.npy", b"\x93NUMPY garbage")  # a second member of that name: the one read
    with pytest.raises(DataFormatError, match=f"{path}: array 'gps_x' cannot be read"):
        vp.load(path)
    # pickled objects are never loaded, and numpy's advice to allow them is not passed on
    np.savez(path, **_malformed(arrays, det_diameter=np.array([object()] * len(arrays["det_diameter"]))))
    with pytest.raises(DataFormatError, match="array 'det_diameter' cannot be read: it holds Python objects") as error:
        vp.load(path)
    assert "allow_pickle" not in str(error.value)
    np.save(tmp_path / "bare.npy", arrays["gps_x"])
    with pytest.raises(DataFormatError, match=r"bare.npy: a single array \(.npy\)"):
        vp.load(tmp_path / "bare.npy")
    # the command line: one line naming the file, exit status 2; the same for a bad --compare file
    assert vp.main(["--data", str(path), "--out", str(tmp_path / "x.npz"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err and "Traceback" not in err
    assert vp.main(["--data", str(folder), "--out", str(tmp_path / "x.npz"), "--no-progress",
                    "--compare", str(tmp_path / "bare.npy")]) == 2  # fmt: skip
    assert "bare.npy" in capsys.readouterr().err and not (tmp_path / "x.npz").exists()


def test_module_entry_point_reports_missing_data_in_one_line(tmp_path):
    env = {key: value for key, value in os.environ.items() if key != DATA_ENV}
    result = subprocess.run([sys.executable, "-W", "error::RuntimeWarning", "-m", "seif_gym.datasets.victoria_park",
                             "--out", str(tmp_path / "x.npz")], capture_output=True, text=True, timeout=120,
                            check=False, env=env)  # fmt: skip
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and DATA_ENV in result.stderr


def test_loader_errors_are_the_builtin_kinds():
    assert issubclass(DataFormatError, ValueError) and issubclass(DataNotFoundError, FileNotFoundError)
