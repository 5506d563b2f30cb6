"""Tests of the MRCLAM runner (``seif_gym.datasets.mrclam.runner``, ``python -m seif_gym.datasets.mrclam``).

* On a simulated log with known parameters (``mrclam.calibration.simulate_logs``)
  and the true models, the EKF is accurate and consistent (ANEES near 3) and
  the SEIF close to it: the runner's handling of latencies, offsets, biases and
  the prediction schedule matches the simulator's.
* The command line writes the documented outputs (``time``, ``pose`` N x 3,
  ``pose_covariance``, ``landmarks`` M x 2, ``landmark_ids`` survey subjects)
  and a plot, for one robot and for all, with known and ML association.
* On Dataset 6 under ``SEIF_GYM_DATA`` (skipped, saying so, when absent): the
  EKF's figures of ``docs/data/mrclam.md``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from mrclam_fixtures import (  # tests/datasets/ is on sys.path under pytest
    DATA_DIR,
    TRUTH,
    requires_data,
)

from seif_gym.datasets import mrclam
from seif_gym.datasets.mrclam import calibration as mc
from seif_gym.datasets.mrclam import runner as mr
from seif_gym.datasets.mrclam.__main__ import main as mrclam_main

#: The true models, every reading used once (the simulator's errors are white).
PLAIN = replace(mr.RunnerConfig(), noise_inflation=1.0, min_interval=0.0)


@pytest.fixture(scope="module")
def simulated():
    return mc.simulate_logs(TRUTH, np.random.default_rng(9), robots=(1, 2), duration=150.0, outlier_fraction=0.02)


def test_mean_controls_match_a_fine_average(simulated):
    log = simulated[1]
    edges = np.array([log.odometry.time[0], log.odometry.time[0] + 0.13, log.odometry.time[0] + 2.0,
                      log.odometry.time[0] + 7.77])  # fmt: skip
    means = mr.mean_controls(log, TRUTH, edges)
    fine = np.linspace(edges[0], edges[-1], 400001)[:-1] + 0.5 * (edges[-1] - edges[0]) / 400000
    k = np.searchsorted(log.odometry.time + TRUTH.command_latency, fine, side="right") - 1
    corrected = np.where((k >= 0)[:, None], TRUTH.correction.apply(log.odometry.controls)[np.maximum(k, 0)], 0.0)
    for i in range(len(edges) - 1):
        inside = (fine >= edges[i]) & (fine < edges[i + 1])
        np.testing.assert_allclose(means[i], corrected[inside].mean(axis=0), atol=2e-4)


def test_true_models_on_simulated_log_are_consistent(simulated):
    ekf = mr.run_robot(simulated[1], "ekf", TRUTH, PLAIN)
    seif = mr.run_robot(simulated[1], "seif", TRUTH, PLAIN)
    cseif = mr.run_robot(simulated[1], "cseif", TRUTH, PLAIN)
    assert cseif.scores["pose_rmse_anchored"] < 1.3 * ekf.scores["pose_rmse_anchored"]
    assert ekf.scores["pose_rmse_anchored"] < 0.12
    assert 1.5 < ekf.scores["anees"] < 6.0
    assert ekf.scores["map_rmse_aligned"] < 0.05
    assert seif.scores["pose_rmse_anchored"] < 1.5 * ekf.scores["pose_rmse_anchored"]
    assert ekf.gated > 0  # the simulated misreads
    # the outputs' shapes and what they hold
    n = len(ekf.time)
    assert ekf.pose.shape == (n, 3) and ekf.pose_covariance.shape == (n, 3, 3) and ekf.truth.shape == (n, 3)
    assert np.all(np.diff(ekf.time) > 0) and ekf.time[-1] <= simulated[1].odometry.time[-1]
    assert set(ekf.landmark_ids.tolist()) <= set(simulated[1].landmarks.subject.tolist())
    assert np.all(np.isfinite(ekf.pose))
    assert np.all(np.linalg.eigvalsh(ekf.pose_covariance) > 0)


def test_command_line_writes_the_documented_outputs(simulated, tmp_path):
    folder = mc.write_dataset(tmp_path / "MRCLAM_Sim", simulated)
    calibration = TRUTH.save(tmp_path / "truth.json")
    out = tmp_path / "run.npz"
    assert mrclam_main(["--data", str(folder), "--robot", "1", "--filter", "ekf", "--out", str(out),
                        "--calibration", str(calibration), "--quiet"]) == 0  # fmt: skip
    with np.load(out) as data:
        n = len(data["time"])
        assert data["pose"].shape == (n, 3) and data["pose_covariance"].shape == (n, 3, 3)
        assert data["landmarks"].shape == (len(data["landmark_ids"]), 2)
        assert set(data["landmark_ids"].tolist()) <= set(range(6, 21))
        assert data["robots"].tolist() == [1] and str(data["filter"]) == "ekf"
    assert out.with_suffix(".png").is_file()
    out_all = tmp_path / "all.npz"
    assert (
        mrclam_main(
            [
                "--data",
                str(folder),
                "--robot",
                "all",
                "--filter",
                "seif",
                "--out",
                str(out_all),
                "--calibration",
                str(calibration),
                "--association",
                "ml",
                "--quiet",
                "--no-plot",
            ]
        )
        == 0
    )
    with np.load(out_all) as data:
        assert data["robots"].tolist() == [1, 2]  # the robots the folder has
        assert data["r2_pose"].shape[1] == 3


def test_bad_arguments(simulated):
    with pytest.raises(ValueError, match="filter"):
        mr.run_robot(simulated[1], "ukf", TRUTH)
    with pytest.raises(ValueError, match="association"):
        mr.run_robot(simulated[1], "ekf", TRUTH, association="nearest")
    with pytest.raises(TypeError, match="calibration"):
        mr.run_robot(simulated[1], "ekf", {"command_latency": 0.2})
    with pytest.raises(ValueError, match="robot"):
        mr._robots("7")


@requires_data
def test_dataset6_ekf_and_seif():
    """EKF: pose RMSE (anchored, mean over robots) <= 0.45 m with ANEES <= 6; SEIF (k = 8) within 1.3x per robot."""
    logs = mrclam.load_all(DATA_DIR)
    calibration = mc.calibrate(logs)
    ekf = [mr.run_robot(logs[r], "ekf", calibration) for r in mrclam.ROBOTS]
    seif = [mr.run_robot(logs[r], "seif", calibration) for r in mrclam.ROBOTS]
    assert np.mean([r.scores["pose_rmse_anchored"] for r in ekf]) <= 0.45
    assert np.mean([r.scores["anees"] for r in ekf]) <= 6.0
    for a, b in zip(ekf, seif):
        assert b.scores["pose_rmse_anchored"] <= 1.3 * a.scores["pose_rmse_anchored"], a.robot
    assert sum(r.seconds for r in ekf + seif) < 30.0
