"""Bad data and bad output paths get one line and exit status 2 from every command line; files are written whole.

* The MRCLAM commands (``python -m seif_gym.datasets.mrclam [calibrate | episodes]`` and the same commands
  run by their module names), the Victoria Park runner and ``python -m seif_gym.harness``: a malformed
  data file, a corrupt or truncated ``.npz`` (a recorded episode, the Victoria Park archive) and an
  ``--out`` under a file are refused before any work, with one line on stderr naming the file (and the
  line for text data), no traceback, no runpy ``RuntimeWarning``, and no numpy advice about pickles.
* What the commands write (runner outputs, calibrations, plots, the harness's folder) appears whole or
  not at all: a failure while writing leaves the previous file as it was and no temporary behind; the
  harness's ``config.json``, written last, marks a finished folder.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from victoria_park_fixtures import write_victoria_park  # tests/datasets/ is on sys.path under pytest

from seif_gym import harness
from seif_gym.datasets import DataFormatError
from seif_gym.datasets import victoria_park as vp
from seif_gym.datasets._files import OutputPathError, output_file, output_folder, save_figure, save_npz
from seif_gym.datasets.mrclam import calibration as mc
from seif_gym.episodes import EpisodeRecorder

HEADER = "# UTIAS Multi-Robot Cooperative Localization and Mapping Dataset\n# synthetic test copy\n"


def _table(path: Path, header: str, rows: list[tuple]) -> None:
    path.write_text(HEADER + f"# {header}\n" + "".join(" \t ".join(str(v) for v in row) + "\n" for row in rows))


@pytest.fixture(scope="module")
def bad_mrclam(tmp_path_factory) -> Path:
    """A one-robot MRCLAM folder whose ``Robot1_Odometry.dat`` has a word in its second data row."""
    folder = tmp_path_factory.mktemp("mrclam") / "MRCLAM_Bad"
    folder.mkdir()
    _table(folder / "Barcodes.dat", "Subject #    Barcode #", [(1, 5), (6, 63)])
    _table(folder / "Landmark_Groundtruth.dat", "Subject #    x [m]    y [m]    x std-dev [m]    y std-dev [m]",
           [(6, 1.0, 0.5, 0.0003, 0.0004)])  # fmt: skip
    _table(folder / "Robot1_Groundtruth.dat", "Time [s]    x [m]    y [m]    orientation [rad]",
           [(100.0 + 0.015 * k, 0.01 * k, 0.0, 0.1) for k in range(50)])  # fmt: skip
    rows: list[tuple] = [(101.0 + 0.01 * k, 0.05, -0.1) for k in range(20)]
    rows[1] = (101.01, "abc", -0.1)
    _table(folder / "Robot1_Odometry.dat", "Time [s]    forward velocity [m/s]    angular velocity[rad/s]", rows)
    _table(
        folder / "Robot1_Measurement.dat",
        "Time [s]    Subject #    range [m]    bearing [rad]",
        [(101.5, 63, 1.0, 0.1)],
    )
    return folder


def _bad_row() -> int:
    """The line number of the bad odometry row: the header's lines, then the second data row."""
    return HEADER.count("\n") + 1 + 2


def run_module(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    environment = {**os.environ, "PYTHONWARNINGS": "default::RuntimeWarning"}
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, cwd=cwd, env=environment,
                          timeout=300)  # fmt: skip


def assert_one_line_exit_2(result: subprocess.CompletedProcess, *needles: str) -> None:
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.stderr and "RuntimeWarning" not in result.stderr
    assert "allow_pickle" not in result.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]


# -- the MRCLAM commands ---------------------------------------------------------------------------------------
MRCLAM_COMMANDS = {
    "runner": ["seif_gym.datasets.mrclam", "--robot", "1", "--out", "{tmp}/run.npz"],
    "runner by module name": ["seif_gym.datasets.mrclam.runner", "--robot", "1", "--out", "{tmp}/run.npz"],
    "episodes": ["seif_gym.datasets.mrclam", "episodes", "--robots", "1", "--out", "{tmp}/episodes"],
    "episodes by module name": ["seif_gym.datasets.mrclam.episodes", "--robots", "1", "--out", "{tmp}/episodes"],
    "calibrate": ["seif_gym.datasets.mrclam", "calibrate", "--robots", "1", "--out", "{tmp}/calibration.json"],
}


@pytest.mark.parametrize("command", sorted(MRCLAM_COMMANDS))
def test_mrclam_commands_name_the_file_and_line_in_one_line(command, bad_mrclam, tmp_path):
    args = [a.format(tmp=tmp_path) for a in MRCLAM_COMMANDS[command]] + ["--data", str(bad_mrclam)]
    result = run_module(*args, cwd=tmp_path)
    assert_one_line_exit_2(result, "Robot1_Odometry.dat", f"line {_bad_row()}", "'abc' is not a number")
    assert sorted(p.name for p in tmp_path.iterdir()) in ([], ["episodes"])  # nothing written


@pytest.mark.parametrize("command", ["runner", "episodes", "calibrate"])
def test_an_out_under_a_file_is_refused_before_any_work(command, bad_mrclam, tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    args = [a.replace("{tmp}", str(blocker)) for a in MRCLAM_COMMANDS[command]] + ["--data", str(bad_mrclam)]
    result = run_module(*args, cwd=tmp_path)  # the data are bad too: --out is checked first
    assert_one_line_exit_2(result, "--out", f"{blocker} is a file, not a folder")
    assert blocker.read_text() == "not a folder"


# -- the Victoria Park runner ----------------------------------------------------------------------------------
def _damaged(source: Path, folder: Path, how: str) -> Path:
    data = bytearray(source.read_bytes())
    if how == "truncated":
        data = data[: len(data) // 3]
    elif how == "flipped bytes":
        for i in range(200, len(data) - 200, 7):
            data[i] ^= 0x5A
    else:
        data = bytearray(b"time,x,y\n1,2,3\n")
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / source.name
    target.write_bytes(bytes(data))
    return target


@pytest.mark.parametrize("how", ["truncated", "flipped bytes", "text"])
def test_victoria_park_refuses_a_damaged_archive_naming_it(how, tmp_path):
    path = _damaged(write_victoria_park(tmp_path / "good"), tmp_path / "bad", how)
    with pytest.raises(DataFormatError) as caught:
        vp.load(path)
    assert str(path) in str(caught.value) and "allow_pickle" not in str(caught.value)
    assert len(str(caught.value).splitlines()) == 1
    result = run_module("seif_gym.datasets.victoria_park", "--data", str(path), "--out", "run.npz", "--no-plot",
                        cwd=tmp_path)  # fmt: skip
    assert_one_line_exit_2(result, str(path))
    assert not (tmp_path / "run.npz").exists()


def test_victoria_park_refuses_an_out_under_a_file_before_running(tmp_path, capsys):
    path = write_victoria_park(tmp_path / "good")
    (tmp_path / "a_file").write_text("x")
    assert vp.main(["--data", str(path), "--out", str(tmp_path / "a_file" / "run.npz"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out" in err[0] and "is a file, not a folder" in err[0]


# -- the harness -----------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def episode_file(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("recorded")
    env = EpisodeRecorder(gym.make("SeifExplore-v2", max_episode_steps=6), directory=folder)
    env.action_space.seed(0)
    env.reset(seed=3)
    done = False
    while not done:
        *_, terminated, truncated, _ = env.step(env.action_space.sample())
        done = terminated or truncated
    env.close()
    (path,) = sorted(folder.glob("*.npz"))
    return path


@pytest.mark.parametrize("how", ["truncated", "flipped bytes", "text"])
def test_harness_refuses_a_damaged_episode_in_one_line(how, episode_file, tmp_path, capsys):
    path = _damaged(episode_file, tmp_path / "bad", how)
    out = tmp_path / "out"
    assert harness.main(["--episodes-dir", str(path), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and "not a readable .npz archive" in err[0], err
    assert "allow_pickle" not in err[0]
    assert not any(out.glob("*")) if out.exists() else True


def test_harness_refuses_an_out_under_a_file_before_replaying(episode_file, tmp_path, capsys):
    (tmp_path / "a_file").write_text("x")
    assert harness.main(["--episodes-dir", str(episode_file), "--out", str(tmp_path / "a_file" / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out" in err[0] and "is a file, not a folder" in err[0]


def test_harness_as_a_command_says_one_line_without_runpy_warnings(episode_file, tmp_path):
    path = _damaged(episode_file, tmp_path / "bad", "truncated")
    result = run_module("seif_gym.harness", "--episodes-dir", str(path), "--out", "o", "--quiet", cwd=tmp_path)
    assert_one_line_exit_2(result, str(path), "corrupt or truncated")


def test_harness_outputs_mark_a_finished_folder_last(episode_file, tmp_path, monkeypatch):
    episodes = harness.load_episodes([episode_file])
    rows, series = harness.evaluate_episodes(episodes, harness.parse_filters(["ekf"]), verbose=False)
    out = tmp_path / "out"
    paths = harness.write_outputs(rows, series, out, {"run": 1})
    assert json.loads(paths["config"].read_text()) == {"run": 1}
    csv_before = paths["csv"].read_bytes()

    def broken(*args, **kwargs):
        raise RuntimeError("killed while plotting")

    monkeypatch.setattr(harness, "_plots", broken)
    with pytest.raises(RuntimeError, match="killed"):
        harness.write_outputs(rows, series, out, {"run": 2})
    assert not (out / "config.json").exists()  # the folder no longer reads as finished
    assert paths["csv"].read_bytes() == csv_before  # rewritten whole (the same rows)
    assert not list(out.glob(".*.tmp"))


# -- atomic writes ---------------------------------------------------------------------------------------------
def test_save_npz_and_figure_write_whole_or_leave_the_old_file(tmp_path, monkeypatch):
    target = save_npz(tmp_path / "run", {"a": np.arange(3)})
    assert target == tmp_path / "run.npz"
    before = target.read_bytes()

    def broken(handle, **arrays):
        handle.write(b"PK\x03\x04 partial")
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez_compressed", broken)
    with pytest.raises(OSError, match="disk full"):
        save_npz(target, {"a": np.arange(5)})
    assert target.read_bytes() == before and not list(tmp_path.glob(".*.tmp"))
    monkeypatch.undo()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure = plt.figure()
    png = save_figure(figure, tmp_path / "plot.png")
    assert png.read_bytes()[:4] == b"\x89PNG"
    plt.close(figure)


def test_calibration_save_is_atomic(tmp_path, monkeypatch):
    path = tmp_path / "calibration.json"
    calibration = mc.Calibration.load(mc.DATASET6)
    assert calibration.save(path) == path
    before = path.read_text()
    real_write_text = Path.write_text

    def killed_midway(self, text, *args, **kwargs):
        real_write_text(self, text[: len(text) // 2], *args, **kwargs)
        raise KeyboardInterrupt("killed while writing")

    monkeypatch.setattr(Path, "write_text", killed_midway)
    with pytest.raises(KeyboardInterrupt):
        calibration.save(path)
    monkeypatch.undo()
    assert path.read_text() == before and not list(tmp_path.glob(".*.tmp"))
    assert mc.Calibration.load(path) == calibration


def test_output_checks_name_the_argument(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(OutputPathError, match=r"--out .*f is a file, not a folder"):
        output_file(tmp_path / "f" / "g" / "run.npz", "--out")
    with pytest.raises(OutputPathError, match=r"--out .*: .*f is a file, not a folder"):
        output_folder(tmp_path / "f", "--out")
    with pytest.raises(OutputPathError, match="is a folder"):
        output_file(tmp_path, "--out")
    assert output_file(tmp_path / "new" / "run.npz", "--out").parent.is_dir()


def test_an_episode_is_saved_whole_or_not_at_all(episode_file, tmp_path, monkeypatch):
    """A write that fails midway leaves the previous file and no temporary (Episode.save)."""
    from seif_gym.episodes import Episode

    episode = Episode.load(episode_file)
    target = tmp_path / "kept.npz"
    saved = episode.save(target)
    assert saved == target
    before = target.read_bytes()

    def fail(handle, **arrays):
        handle.write(b"PK\x03\x04 half an archive")
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez_compressed", fail)
    with pytest.raises(OSError, match="disk full"):
        episode.save(target)
    assert target.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["kept.npz"]
