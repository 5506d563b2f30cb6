"""MRCLAM logs as Episodes (``seif_gym.datasets.mrclam.episodes``): the harness runs every filter on real data.

* On simulated logs with known parameters (``simulate_logs``) and the true
  models (no inflation, every reading): the episode holds the calibrated
  models, its readings and truth, replays bit for bit, and the EKF scored by
  the harness is accurate and consistent.
* The command line converts a simulated dataset folder, and the harness's
  command line scores the episodes it writes.
* On Dataset 6 under ``SEIF_GYM_DATA`` (skipped, saying so, when absent):
  every robot converts, and the harness's EKF on robot 3 matches the runner's
  figures (docs/data/mrclam.md).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from mrclam_fixtures import DATA_DIR, TRUTH, requires_data  # tests/datasets/ is on sys.path under pytest

from seif_gym.datasets import mrclam
from seif_gym.datasets.mrclam import calibration as mc
from seif_gym.datasets.mrclam.episodes import EpisodeConversion, log_to_episode
from seif_gym.episodes import Episode, replay
from seif_gym.harness import score_episode

#: The simulator's errors are white and its models true: no inflation, every reading.
PLAIN = EpisodeConversion(noise_inflation=1.0, min_interval=0.0, innovation_gate=None)


@pytest.fixture(scope="module")
def simulated():
    logs = mc.simulate_logs(TRUTH, np.random.default_rng(9), robots=(1,), duration=120.0, outlier_fraction=0.0)
    return logs[1], log_to_episode(logs[1], TRUTH, PLAIN)


def test_episode_holds_the_calibrated_models_readings_and_truth(simulated):
    log, episode = simulated
    assert isinstance(episode, Episode) and episode.seed is None and episode.dt == PLAIN.dt
    config = episode.config
    assert config["motion_model"] == "per_second" and config["motion_noise"] == (*TRUTH.forward, *TRUTH.turn,
                                                                                 *TRUTH.lateral)  # fmt: skip
    assert config["range_noise"] == (TRUTH.range_slope, *TRUTH.range_bounds)
    assert config["sigma_bearing"] == TRUTH.sigma_bearing and config["innovation_gate"] is None
    np.testing.assert_array_equal(episode.landmarks, log.landmarks.positions)
    span = min(log.odometry.time[-1], log.ground_truth.time[-1]) - log.odometry.time[0]
    assert episode.steps == math.floor(span / PLAIN.dt)
    assert np.all(np.isfinite(episode.true_poses))
    # every reading inside the span and range, one per landmark and frame, is in the episode, biases removed
    assert 0.9 * len(log.measurements) <= len(episode.ranges) <= len(log.measurements)
    assert set(np.unique(episode.ids)) <= set(range(len(log.landmarks)))
    np.testing.assert_array_equal(episode.commanded_controls, episode.executed_controls)


def test_episode_replays_its_recorded_estimate(simulated):
    _, episode = simulated
    result = replay(episode, episode.config["filter"])
    np.testing.assert_array_equal(result.poses, episode.estimated_poses)
    np.testing.assert_array_equal(result.map_errors, episode.map_errors)
    np.testing.assert_array_equal(episode.rewards, -np.diff(episode.map_errors))


def test_harness_scores_the_simulated_log_accurately_and_consistently(simulated):
    _, episode = simulated
    rows, _ = score_episode(episode, ["ekf", "seif-k8"], policy="simulated")
    ekf, seif = rows
    assert ekf["pose_rmse"] < 0.1, ekf["pose_rmse"]
    assert 1.0 < ekf["anees_pose"] < 6.0, ekf["anees_pose"]
    assert seif["pose_rmse"] < 1.5 * ekf["pose_rmse"] + 0.02


def test_bad_arguments_raise(simulated):
    log, _ = simulated
    with pytest.raises(TypeError, match="log"):
        log_to_episode("robot1", TRUTH)
    with pytest.raises(TypeError, match="calibration"):
        log_to_episode(log, {"forward": (0, 0, 0)})
    with pytest.raises(ValueError, match="dt"):
        EpisodeConversion(dt=0.0)
    with pytest.raises(ValueError, match="min_interval"):
        EpisodeConversion(min_interval=-1.0)


def test_command_lines_convert_a_folder_and_the_harness_scores_it(simulated, tmp_path, capsys):
    from seif_gym import harness
    from seif_gym.datasets.mrclam.__main__ import main

    log, _ = simulated
    folder = mc.write_dataset(tmp_path / "MRCLAM_Sim", {1: log})
    truth = TRUTH.save(tmp_path / "truth.json")
    out = tmp_path / "episodes"
    assert main(["episodes", "--data", str(folder), "--calibration", str(truth), "--out", str(out), "--robots", "1",
                 "--dt", "0.1", "--quiet"]) == 0  # fmt: skip
    episode = Episode.load(out / "robot1.npz")
    assert episode.dt == 0.1 and episode.steps > 1000 and len(episode.ranges) > 100
    scored = tmp_path / "scored"
    assert harness.main(["--episodes-dir", str(out), "--episodes", "1", "--filters", "ekf", "--out", str(scored),
                         "--quiet"]) == 0  # fmt: skip
    assert "robot1" in capsys.readouterr().out and (scored / "results.csv").is_file()
    # a malformed log: one line naming the file and the line, exit status 2
    odometry = folder / "Robot1_Odometry.dat"
    lines = odometry.read_text().splitlines()
    lines[10] = "not a number"
    odometry.write_text("\n".join(lines) + "\n")
    assert main(["episodes", "--data", str(folder), "--calibration", str(truth), "--out", str(out), "--robots", "1",
                 "--quiet"]) == 2  # fmt: skip
    assert capsys.readouterr().err.strip() == (
        f"python -m seif_gym.datasets.mrclam episodes: error: {odometry}, line 11: 'not' is not a number"
    )


@requires_data
def test_dataset6_episodes_through_the_harness(tmp_path):
    from seif_gym.datasets.mrclam.episodes import main

    calibration = mc.DATASET6
    assert main(["--data", str(DATA_DIR), "--calibration", str(calibration), "--out", str(tmp_path),
                 "--robots", "3", "--quiet"]) == 0  # fmt: skip
    episode = Episode.load(tmp_path / "robot3.npz")
    assert episode.config["innovation_gate"] == 13.8 and episode.steps > 15000
    rows, _ = score_episode(episode, ["ekf"], policy="robot3")
    # the runner's EKF on robot 3 (docs/data/mrclam.md): about 0.11 m, consistent
    assert rows[0]["pose_rmse"] < 0.2 and rows[0]["anees_pose"] < 3.0
    logs = mrclam.load_all(DATA_DIR)
    assert len(log_to_episode(logs[1], mc.Calibration.load(calibration)).ranges) > 300
