"""Bad input to the Victoria Park runner: refused before anything runs; no RMSE from a degenerate GPS fit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from victoria_park_fixtures import write_victoria_park  # tests/datasets/ is on sys.path under pytest

from seif_gym.datasets import DataFormatError
from seif_gym.datasets import victoria_park as vp


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return vp.load(write_victoria_park(tmp_path_factory.mktemp("vp_bad")))


def _backwards(times: np.ndarray, index: int) -> np.ndarray:
    out = np.array(times)
    out[index] = out[index - 1] - 0.5
    return out


@pytest.mark.parametrize("part", ["odometry", "scans", "gps"])
def test_times_that_go_back_are_refused_naming_the_array_and_index(data, part):
    original = getattr(data, part)
    bad = dataclasses.replace(original, time=_backwards(original.time, 7))
    with pytest.raises(DataFormatError, match=rf"{part}\.time is not sorted \(index 7 goes back in time\)") as caught:
        vp.run(dataclasses.replace(data, **{part: bad}), "ekf", steps=50, blas_threads=None)
    assert str(data.path) in str(caught.value)
    assert isinstance(caught.value, ValueError)


def test_empty_gps_is_refused(data):
    gps = data.gps
    empty = dataclasses.replace(gps, time_ms=gps.time_ms[:0], time=gps.time[:0], x=gps.x[:0], y=gps.y[:0])
    with pytest.raises(DataFormatError, match=r"gps\.time is empty"):
        vp.run(dataclasses.replace(data, gps=empty), "ekf", steps=50, blas_threads=None)


def test_gps_error_needs_three_fixes(data):
    gps = data.gps
    time = np.array([gps.time[0], gps.time[1] + 1e-3])  # two fixes in the span
    positions = np.column_stack([gps.x[:2], gps.y[:2]])
    with pytest.raises(ValueError, match=f"only 2 GPS fix\\(es\\) overlap.*at least {vp.MIN_GPS_FIXES}"):
        vp.gps_error(data, time, positions)


def test_a_run_with_too_few_gps_fixes_reports_no_rmse(data, tmp_path):
    odo, gps = data.odometry, data.gps
    # the fewest odometry steps whose span holds exactly two GPS fixes
    steps = next(
        s
        for s in range(2, len(odo))
        if np.count_nonzero((gps.time >= odo.time[0]) & (gps.time <= odo.time[s - 1])) == 2
    )
    result = vp.run(data, "ekf", steps=steps, blas_threads=None)
    assert result.error is None
    assert "only 2 GPS fix(es)" in result.error_note
    assert "RMSE vs GPS         n/a (only 2 GPS fix(es)" in vp.summary(result)
    out = tmp_path / "run.npz"
    result.save(out)
    with np.load(out) as saved:
        assert np.isnan(saved["rmse"])
        assert "at least 3" in str(saved["rmse_note"])
        assert "gps_rotation" not in saved.files
    assert np.isnan(vp._saved_run(out).rmse)
