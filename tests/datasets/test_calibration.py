"""Tests of the MRCLAM calibration (``seif_gym.datasets.mrclam.calibration``) and its robust estimators.

* The robust estimators (``seif_gym.datasets.robust``) against their
  definitions and on contaminated samples with known parameters.
* :func:`calibrate` on simulated logs with known parameters
  (:func:`simulate_logs`): it must recover them within the tolerances below,
  which are about three standard errors of each estimate at this amount of data
  (two robots, 500 s each), measured over seeds.
* The command line writes a file that :meth:`Calibration.load` reads back.
* On Dataset 6 under ``SEIF_GYM_DATA`` (skipped, saying so, when absent):
  the figures of docs/data/mrclam.md.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from mrclam_fixtures import (  # tests/datasets/ is on sys.path under pytest
    DATA_DIR,
    TRUTH,
    requires_data,
)

from seif_gym.datasets import DATA_ENV, DataFormatError, mrclam, robust
from seif_gym.datasets.mrclam import calibration as mc
from seif_gym.datasets.mrclam.__main__ import main as mrclam_main


@pytest.fixture(scope="module")
def simulated():
    """Two simulated robots, 500 s each, 3 % gross outliers among the readings."""
    return mc.simulate_logs(TRUTH, np.random.default_rng(4), robots=(1, 2), duration=500.0, outlier_fraction=0.03)


@pytest.fixture(scope="module")
def calibrated(simulated):
    return mc.calibrate(simulated, horizon=5.0)


# ---------------------------------------------------------------------------
# robust estimators
# ---------------------------------------------------------------------------
class TestRobust:
    def test_consistency_constants_match_their_definitions(self):
        u = np.random.default_rng(0).standard_normal(2_000_000)
        k, c = robust.SCALE_K, robust.REJECT_AT
        assert robust.scale_consistency(k) == pytest.approx(np.mean(np.minimum(u * u, k * k)), rel=3e-3)
        assert robust.trimmed_consistency(c) == pytest.approx(np.mean(u[np.abs(u) <= c] ** 2), rel=3e-3)
        assert robust.mad_scale(u) == pytest.approx(1.0, rel=3e-3)

    def test_location_and_regression_ignore_outliers(self):
        rng = np.random.default_rng(1)
        x = 3.0 + 0.5 * rng.standard_normal(4000)
        x[:200] = 50.0  # 5 % far outliers
        assert robust.huber_location(x) == pytest.approx(3.0, abs=0.05)
        X = np.column_stack([np.ones(4000), rng.uniform(0, 2, 4000)])
        y = X @ [1.0, -2.0] + 0.1 * rng.standard_normal(4000)
        y[:200] += 10.0
        coefficients, scale = robust.huber_regression(X, y)
        np.testing.assert_allclose(coefficients, [1.0, -2.0], atol=0.02)
        assert scale == pytest.approx(0.1, rel=0.1)

    def test_scale_model_recovers_a_clipped_slope(self):
        rng = np.random.default_rng(2)
        r = rng.uniform(0.5, 9.0, 6000)
        e = np.clip(0.05 * r, 0.06, 0.3) * rng.standard_normal(6000)
        e[:300] = rng.normal(0.0, 3.0, 300)  # 5 % gross errors
        slope, lo, hi = np.exp(robust.fit_scale_model(
            e, lambda t: np.log(np.clip(np.exp(t[0]) * r, np.exp(t[1]), np.exp(t[2]))), np.log([0.04, 0.05, 0.4])))  # fmt: skip
        assert slope == pytest.approx(0.05, rel=0.06)
        assert lo == pytest.approx(0.06, rel=0.15) and hi == pytest.approx(0.3, rel=0.1)

    def test_variance_regression_recovers_densities_despite_outliers(self):
        rng = np.random.default_rng(3)
        X = np.column_stack([np.full(5000, 5.0), rng.uniform(0.0, 0.05, 5000), rng.uniform(0.0, 1.5, 5000)])
        c = np.array([1e-4, 0.02, 3e-3])
        e = np.sqrt(X @ c) * rng.standard_normal(5000)
        e[:250] *= 30.0
        fitted = robust.fit_variance_regression(e, X)
        assert np.mean(X @ fitted) == pytest.approx(np.mean(X @ c), rel=0.05)
        np.testing.assert_allclose(X @ fitted, X @ c, rtol=0.3)
        assert np.all(fitted >= 0.0)

    def test_robust_correlation(self):
        rng = np.random.default_rng(4)
        a = rng.standard_normal(5000)
        b = 0.6 * a + 0.8 * rng.standard_normal(5000)
        b[:100] = 100.0
        assert robust.robust_correlation(a, b) == pytest.approx(0.6, abs=0.05)

    def test_bad_inputs(self):
        with pytest.raises(ValueError, match="residuals"):
            robust.mad_scale([])
        with pytest.raises(ValueError, match="residuals"):
            robust.fit_variance_regression([1.0, np.nan], np.ones((2, 1)))
        with pytest.raises(ValueError, match="features"):
            robust.fit_variance_regression([1.0, 2.0], -np.ones((2, 1)))
        with pytest.raises(TypeError, match="values"):
            robust.huber_location("abc")


# ---------------------------------------------------------------------------
# calibration on simulated logs with known parameters
# ---------------------------------------------------------------------------
class TestRecovery:
    def test_command_correction_and_latency(self, calibrated):
        c = calibrated.correction
        assert c.speed_scale == pytest.approx(1.05, abs=0.025)
        assert c.turn_slowdown == pytest.approx(1.1, abs=0.08)
        assert c.turn_scale == pytest.approx(0.94, abs=0.01)
        assert c.speed_offset == 0.0 and c.turn_offset == 0.0  # not fitted by default
        assert calibrated.command_latency == pytest.approx(0.22, abs=0.025)

    def test_heading_offsets_and_bearing_biases(self, calibrated):
        for robot in (1, 2):
            true, found = TRUTH.robot(robot), calibrated.robot(robot)
            assert found.heading_offset == pytest.approx(true.heading_offset, abs=0.005)
            assert found.bearing_bias == pytest.approx(true.bearing_bias, abs=0.005)
            # what a filter uses: the bias relative to the corrected heading, which is tighter
            assert found.bearing_bias - found.heading_offset == pytest.approx(
                true.bearing_bias - true.heading_offset, abs=0.0015
            )
            assert found.range_bias == pytest.approx(0.0, abs=0.01)

    def test_sensor_noise_and_latency(self, calibrated):
        assert calibrated.sigma_bearing == pytest.approx(0.009, rel=0.06)
        ranges = np.array([1.5, 3.0, 5.0])
        np.testing.assert_allclose(
            calibrated.sensor().range_sigma(ranges), TRUTH.sensor().range_sigma(ranges), rtol=0.1
        )
        assert calibrated.sensor_latency == pytest.approx(0.035, abs=0.01)

    def test_motion_noise(self, simulated, calibrated):
        """The per-second rates: over the commands driven within 20 %, at single controls within a factor 2."""
        true, found = TRUTH.motion_model(corrected=False), calibrated.motion_model(corrected=False)
        controls = TRUTH.correction.apply(np.vstack([log.odometry.controls for log in simulated.values()]))
        true_mean = np.mean([true.noise_rates(u) for u in controls[::50]], axis=0)
        found_mean = np.mean([found.noise_rates(u) for u in controls[::50]], axis=0)
        np.testing.assert_allclose(found_mean[:2], true_mean[:2], rtol=0.2)  # forward, turn
        assert found_mean[2] == pytest.approx(true_mean[2], rel=1.0)  # lateral: 1e-6 m^2/s, near the Vicon noise
        for control in ((0.06, 0.0), (0.06, 0.4), (0.03, 0.2)):
            ratio = found.noise_rates(control)[:2] / true.noise_rates(control)[:2]
            assert np.all((ratio > 0.5) & (ratio < 2.0)), (control, ratio)
        rates = calibrated.diagnostics["motion_rates_per_horizon"]
        assert set(rates) == {f"{h:g}s" for h in mc.DIAGNOSTIC_HORIZONS}

    def test_outliers_do_not_move_the_sensor_fit(self, simulated, calibrated):
        clean = mc.simulate_logs(TRUTH, np.random.default_rng(4), robots=(1, 2), duration=500.0, outlier_fraction=0.0)
        fit = mc.calibrate(clean, horizon=5.0)
        assert calibrated.sigma_bearing == pytest.approx(fit.sigma_bearing, rel=0.05)
        assert calibrated.range_slope == pytest.approx(fit.range_slope, rel=0.05)
        outliers = calibrated.diagnostics["sensor_outliers"]
        assert all(0.02 < o["bearing_beyond_3_sigma"] < 0.06 for o in outliers.values())

    def test_bad_arguments(self, simulated):
        with pytest.raises(TypeError, match="logs"):
            mc.calibrate([])
        with pytest.raises(ValueError, match="horizon"):
            mc.calibrate(simulated, horizon=0.0)
        with pytest.raises(TypeError, match="rng"):
            mc.simulate_logs(TRUTH, 7)


# ---------------------------------------------------------------------------
# files and the command line
# ---------------------------------------------------------------------------
class TestFiles:
    def test_round_trip(self, calibrated, tmp_path):
        path = calibrated.save(tmp_path / "calibration.json")
        loaded = mc.Calibration.load(path)
        assert loaded == calibrated
        assert json.loads(path.read_text())["format"] == mc.FORMAT

    def test_models_from_the_file(self, calibrated):
        motion = calibrated.motion_model()
        np.testing.assert_allclose(motion.corrected([0.08, 0.3]), calibrated.correction.apply([0.08, 0.3]))
        assert motion.model.forward == calibrated.forward and motion.model.turn == calibrated.turn
        sensor = calibrated.sensor(max_range=8.0, fov=1.2)
        assert sensor.range_bounds == calibrated.range_bounds and sensor.sigma_bearing == calibrated.sigma_bearing

    def test_command_line_writes_what_calibrate_finds(self, simulated, calibrated, tmp_path):
        folder = mc.write_dataset(tmp_path / "MRCLAM_Sim", simulated)
        assert mrclam.load(folder, 1).odometry.time.shape == simulated[1].odometry.time.shape
        out = tmp_path / "cal.json"
        assert (
            mrclam_main(
                [
                    "calibrate",
                    "--data",
                    str(folder),
                    "--robots",
                    "1",
                    "2",
                    "--out",
                    str(out),
                    "--quiet",
                    "--horizon",
                    "5",
                ]
            )
            == 0
        )
        found = mc.Calibration.load(out)
        # the text files round their values: the estimates agree closely, not bit for bit
        assert found.correction.turn_scale == pytest.approx(calibrated.correction.turn_scale, rel=1e-3)
        assert found.sigma_bearing == pytest.approx(calibrated.sigma_bearing, rel=1e-2)
        assert found.source["robots"] == [1, 2]

    def test_module_entry_point(self, tmp_path):
        env = {key: value for key, value in os.environ.items() if key != DATA_ENV}
        result = subprocess.run([sys.executable, "-W", "error::RuntimeWarning", "-m", "seif_gym.datasets.mrclam",
                                 "calibrate", "--help"], capture_output=True, text=True, timeout=120, check=False,
                                env=env)  # fmt: skip
        assert result.returncode == 0 and "--horizon" in result.stdout
        assert "RuntimeWarning" not in result.stderr  # runpy's "found in sys.modules" warning: not raised
        result = subprocess.run([sys.executable, "-m", "seif_gym.datasets.mrclam"], capture_output=True, text=True,
                                timeout=120, check=False, cwd=tmp_path, env=env)  # fmt: skip
        # no data anywhere: one line saying where to put them, exit status 2, no traceback
        assert result.returncode == 2 and "Traceback" not in result.stderr
        assert len(result.stderr.strip().splitlines()) == 1
        assert "--data" in result.stderr and DATA_ENV in result.stderr and "docs/data/mrclam.md" in result.stderr

    def test_bad_files(self, calibrated, tmp_path, capsys):
        data = calibrated.to_dict()
        with pytest.raises(ValueError, match="format"):
            mc.Calibration.from_dict({**data, "format": "other"})
        with pytest.raises(ValueError, match="malformed field"):
            mc.Calibration.from_dict({**data, "sensor_latency": "soon"})
        del data["sensor_noise"]
        with pytest.raises(ValueError, match="sensor_noise"):
            mc.Calibration.from_dict(data)
        with pytest.raises(FileNotFoundError, match="calibration file"):
            mc.Calibration.load(tmp_path / "missing.json")
        broken = tmp_path / "broken.json"
        broken.write_text('{\n  "format": "seif_gym.mrclam.calibration/1",\n  "command_latency": ,\n}\n')
        with pytest.raises(DataFormatError, match=r"broken.json, line 3: not valid JSON"):
            mc.Calibration.load(broken)
        broken.write_text("[1, 2]")
        with pytest.raises(DataFormatError, match="broken.json: a calibration file holds a JSON object"):
            mc.Calibration.load(broken)
        broken.write_text(json.dumps(data))
        with pytest.raises(DataFormatError, match="broken.json: calibration data lacks the field 'sensor_noise'"):
            mc.Calibration.load(broken)
        # the command lines report it in one line, exit status 2
        capsys.readouterr()
        assert mrclam_main(["--calibration", str(broken), "--data", str(tmp_path), "--robot", "1", "--quiet"]) == 2
        assert capsys.readouterr().err.strip().endswith("broken.json: calibration data lacks the field 'sensor_noise'")
        assert mc.DATASET6.is_file() and mc.Calibration.load(mc.DATASET6).source["dataset"] == "MRCLAM_Dataset6"


# ---------------------------------------------------------------------------
# Dataset 6
# ---------------------------------------------------------------------------
@requires_data
def test_dataset6_matches_the_readme():
    """What a careful calibration on Dataset 6 finds (docs/data/mrclam.md), from the ground truth."""
    cal = mc.calibrate(mrclam.load_all(DATA_DIR))
    c = cal.correction
    assert 0.90 <= c.turn_scale <= 0.96  # "the commanded turn rate is ~7 % high"
    assert 0.55 <= c.speed_scale * (1.0 - c.turn_slowdown * 0.35) <= 0.8  # "~0.6 of the commanded speed" in turns
    assert 0.15 <= cal.command_latency <= 0.35  # "~0.25 s"
    assert 0.006 <= cal.sigma_bearing <= 0.011  # "~0.008-0.011 rad"
    sigma = cal.sensor().range_sigma([1.0, 3.0, 5.0])  # "~0.065 m at 1 m, 0.14 m at 3 m, 0.23 m at 5 m" (RMS)
    assert 0.05 <= sigma[0] <= 0.09 and 0.11 <= sigma[1] <= 0.17 and 0.17 <= sigma[2] <= 0.26
    assert 0.0 <= cal.sensor_latency <= 0.06  # "~40 ms"
    for robot in mrclam.ROBOTS:  # "Vicon heading differs from the direction of travel by -16 to +9 mrad"
        assert -0.02 <= cal.robot(robot).heading_offset <= 0.012
    # "robot 4's camera is rotated by ~-0.014 rad" (against the Vicon heading)
    four = cal.robot(4)
    assert four.bearing_bias - four.heading_offset == pytest.approx(-0.014, abs=0.005)
    turn_rates = [cal.diagnostics["motion_rates_per_horizon"][h]["turn"] for h in ("5s", "20s")]
    assert all(2e-4 <= rate <= 1.5e-3 for rate in turn_rates)  # heading random walk "~5-11e-4 rad^2/s"
