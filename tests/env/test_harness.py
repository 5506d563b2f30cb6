"""The replay harness's command line (``python -m seif_gym.harness``) and its old name, ``seif_gym.evaluate``.

``--episodes-dir PATH ...`` names the saved episodes, ``--episodes N`` is a
count (as in every command); ``--episodes PATH`` and ``seif_gym.evaluate``
(module and ``python -m``) still work for one release, with a
``DeprecationWarning``. A file that is not a saved episode is named in the
error.
"""

from __future__ import annotations

import csv
import importlib
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest

import seif_gym  # noqa: F401  (registers the envs)
from seif_gym import harness
from seif_gym.episodes import EpisodeRecorder


@pytest.fixture(scope="module")
def episodes(tmp_path_factory):
    """A folder of three short saved episodes (random actions)."""
    folder = tmp_path_factory.mktemp("episodes")
    env = EpisodeRecorder(gym.make("SeifExplore-v2", max_episode_steps=8), directory=folder)
    env.action_space.seed(0)
    for seed in range(3):
        env.reset(seed=seed)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            done = terminated or truncated
    env.close()
    return folder


def _rows(path):
    with open(path) as handle:
        return list(csv.DictReader(handle))


def test_episodes_dir_and_a_count(episodes, tmp_path, capsys):
    out = tmp_path / "all"
    assert harness.main(["--episodes-dir", str(episodes), "--filters", "ekf", "--out", str(out), "--quiet"]) == 0
    assert [row["seed"] for row in _rows(out / "results.csv")] == ["0", "1", "2"]
    first = tmp_path / "first"
    assert harness.main(["--episodes-dir", str(episodes), "--episodes", "2", "--filters", "ekf", "--out",
                         str(first), "--quiet"]) == 0  # fmt: skip
    assert [row["seed"] for row in _rows(first / "results.csv")] == ["0", "1"]
    capsys.readouterr()
    for bad in (["--episodes", "0"], ["--episodes", "-3"], []):
        with pytest.raises(SystemExit):
            harness.main(["--episodes-dir", str(episodes), *bad] if bad else ["--filters", "ekf"])
    with pytest.raises(ValueError, match="limit"):
        harness.load_episodes([episodes], limit=0)


def test_episodes_path_still_works_with_a_deprecation_warning(episodes, tmp_path):
    out = tmp_path / "old"
    with pytest.warns(DeprecationWarning, match="--episodes-dir"):
        assert harness.main(["--episodes", str(episodes), "--filters", "ekf", "--out", str(out), "--quiet"]) == 0
    assert len(_rows(out / "results.csv")) == 3


def test_a_file_that_is_not_an_episode_is_named(episodes, tmp_path, capsys):
    for name, content in (("truncated.npz", (episodes / "episode_00000.npz").read_bytes()[:500]),
                          ("text.npz", b"not numpy\n" * 20)):  # fmt: skip
        path = tmp_path / name
        path.write_bytes(content)
        with pytest.raises(ValueError, match=f"{path}: not a readable .npz archive") as error:
            harness.load_episodes([path])
        assert "allow_pickle" not in str(error.value)
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(ValueError, match="other.npz is not a saved Episode"):
        harness.load_episodes([tmp_path / "other.npz"])
    assert harness.main(["--episodes-dir", str(tmp_path / "text.npz"), "--quiet"]) == 2  # a data error: one line
    err = capsys.readouterr().err
    assert "text.npz" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_the_old_module_name_warns_and_works():
    sys.modules.pop("seif_gym.evaluate", None)
    with pytest.warns(DeprecationWarning, match="seif_gym.harness"):
        old = importlib.import_module("seif_gym.evaluate")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert old.score_episode is harness.score_episode and old.main is harness.main
        assert old.RESULT_COLUMNS == harness.RESULT_COLUMNS and old._episode_label is harness._episode_label
    result = subprocess.run([sys.executable, "-W", "error::RuntimeWarning", "-m", "seif_gym.evaluate", "--help"],
                            capture_output=True, text=True, timeout=120, check=False)  # fmt: skip
    assert result.returncode == 0 and "--episodes-dir" in result.stdout
    assert "DeprecationWarning" in result.stderr and "seif_gym.harness" in result.stderr
    result = subprocess.run([sys.executable, "-W", "error::RuntimeWarning", "-m", "seif_gym.harness", "--help"],
                            capture_output=True, text=True, timeout=120, check=False)  # fmt: skip
    assert result.returncode == 0 and "--episodes-dir" in result.stdout and result.stderr == ""
