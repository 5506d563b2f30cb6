"""``python -m agents.train --resume RUN``: a killed run continues from its newest complete checkpoint.

A tiny run (2 envs of 10 landmarks, 25-step episodes, rollouts of 2 x 32 steps) of 256 steps with a
checkpoint after every rollout (64, 128, 192, 256) is killed and resumed, and compared with the same
run left alone: the step count, the optimizer's, the schedule, the validation's history and best
model, and the final weights bit for bit.
"""

from __future__ import annotations

import csv
import json
import os
import pickle
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("rl_zoo3", reason="rl_zoo3 is in the train extra")

from agents.callbacks import MapErrorEvalCallback, ResumableCheckpointCallback  # noqa: E402
from agents.checkpoints import (  # noqa: E402
    atomic_write,
    behaviour_fingerprint,
    checkpoint_files,
    newest_complete_checkpoint,
    read_checkpoint,
    remove_temporaries,
)
from agents.train import build_parser, main, prepare  # noqa: E402

TOTAL = 256
#: the tiny run: the config's shaping (single envs in a DummyVecEnv) and reward normalisation, a decaying
#: learning rate, a validation every 96 steps and a checkpoint every rollout
TINY = [
    "--env",
    "SeifExplore-v2",
    "--n-envs",
    "2",
    "--seed",
    "3",
    "--env-kwargs",
    json.dumps({"num_landmarks": 10, "max_episode_steps": 25}),
    "--hyperparams",
    "n_steps=32",
    "batch_size=32",
    "n_epochs=2",
    "learning_rate=lin_3e-4",
    "-n",
    str(TOTAL),
    "--checkpoint-freq",
    "64",
    "--eval-freq",
    "96",
    "--eval-episodes",
    "1",
    "--quiet",
]


class Killed(BaseException):
    """Stands for SIGKILL in the in-process runs: nothing catches it, nothing is saved after it."""


def _weights(path: Path) -> dict[str, torch.Tensor]:
    from stable_baselines3 import PPO

    return PPO.load(path, device="cpu").policy.state_dict()


def _same_weights(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def _optimizer_steps(path: Path) -> int:
    from stable_baselines3.common.save_util import load_from_zip_file

    _, params, _ = load_from_zip_file(path, device="cpu", load_data=False)
    return int(next(iter(params["policy.optimizer"]["state"].values()))["step"])


def _rows(folder: Path) -> list[dict[str, str]]:
    return list(csv.DictReader((folder / "map_error_evaluations.csv").open()))


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    """``whole``: the run left alone; ``killed``: the same run killed as it wrote its checkpoint at 192 steps.

    The kill comes after the validation at 192 steps (its row written, its model perhaps the best so
    far) and leaves checkpoint 192 truncated, as a kill in the middle of writing it would: the newest
    complete checkpoint is the one at 128 steps.
    """
    folder = tmp_path_factory.mktemp("resume")
    whole, killed = folder / "whole", folder / "killed"
    assert main([*TINY, "--out", str(whole)]) == 0
    original = ResumableCheckpointCallback.save

    def save_then_die(self: ResumableCheckpointCallback) -> Path:
        path = original(self)
        if self.model.num_timesteps == 192:
            with open(path, "r+b") as handle:  # half the model's bytes reached the disk
                handle.truncate(path.stat().st_size // 2)
            raise Killed
        return path

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(ResumableCheckpointCallback, "save", save_then_die)
        with pytest.raises(Killed):
            main([*TINY, "--out", str(killed)])
    assert not (killed / "train_time.json").exists()
    return {"whole": whole, "killed": killed}


def _copy(run: Path, tmp_path: Path) -> Path:
    target = tmp_path / run.name
    shutil.copytree(run, target)
    return target


def test_the_newest_complete_checkpoint_is_taken(runs):
    checkpoint, skipped = newest_complete_checkpoint(runs["killed"])
    assert checkpoint is not None and checkpoint.steps == 128
    assert len(skipped) == 1 and "rl_model_192_steps.zip" in skipped[0] and "truncated" in skipped[0]
    whole, _ = newest_complete_checkpoint(runs["whole"])
    assert whole is not None and whole.steps == TOTAL


def test_a_resumed_run_starts_where_its_checkpoint_stopped(runs, tmp_path):
    """Before it learns: the step count, the optimizer, the schedule, the envs and the validation's state."""
    run = _copy(runs["killed"], tmp_path)
    best_before = _rows(run)  # the killed run's rows, the one at 192 steps among them
    assert [int(r["timesteps"]) for r in best_before] == [96, 192]
    experiment, model = prepare(build_parser().parse_args(["--resume", str(run), "--quiet"]))
    checkpoint = run / "rl_model_128_steps.zip"
    assert model.num_timesteps == 128 and experiment.n_timesteps == TOTAL
    assert _same_weights(model.policy.state_dict(), _weights(checkpoint))
    steps = {int(state["step"]) for state in model.policy.optimizer.state_dict()["state"].values()}
    assert steps == {_optimizer_steps(checkpoint)} and steps != {0}  # Adam's moments go on
    # the schedule continues: SB3's progress is 1 - num_timesteps / total, and the learning rate is where
    # the last update (after 128 steps) set it, not the schedule's start
    assert model._n_updates == 2 * 2  # two rollouts of two epochs
    assert model._current_progress_remaining == pytest.approx(1 - 128 / TOTAL)
    assert model.policy.optimizer.param_groups[0]["lr"] == pytest.approx(3e-4 * (1 - 128 / TOTAL))
    (validation,) = [c for c in experiment.callbacks if isinstance(c, MapErrorEvalCallback)]
    assert [row["timesteps"] for row in validation.evaluations] == [96]
    assert validation.best_timesteps == 96 and validation._last_eval == 96
    # the configuration is the run's own (its config.yml), not the one the command line would give
    assert experiment.n_envs == 2 and model.n_steps == 32
    # the envs go on with their episodes: the last observation is the checkpoint's, not a reset's
    assert model._last_obs is not None and not model._last_episode_starts.all()
    model.get_env().close()


def test_a_resumed_run_ends_as_the_run_left_alone(runs, tmp_path):
    run = _copy(runs["killed"], tmp_path)
    whole = runs["whole"]
    assert main(["--resume", str(run), "--quiet"]) == 0
    final = "SeifExplore-v2.zip"
    assert _same_weights(_weights(run / final), _weights(whole / final))
    assert _optimizer_steps(run / final) == _optimizer_steps(whole / final)
    from stable_baselines3 import PPO

    resumed, alone = PPO.load(run / final, device="cpu"), PPO.load(whole / final, device="cpu")
    assert resumed.num_timesteps == alone.num_timesteps == TOTAL and resumed._n_updates == alone._n_updates
    # the checkpoints taken again, the validation's rows and its best model are those of the run left alone
    for steps in (192, 256):
        name = f"rl_model_{steps}_steps.zip"
        assert behaviour_fingerprint(run / name) == behaviour_fingerprint(whole / name)
    assert _rows(run) == _rows(whole)
    best = Path("best_map_error") / "model.zip"
    assert behaviour_fingerprint(run / best) == behaviour_fingerprint(whole / best)
    # the monitors' logs hold each episode once, as the run left alone wrote them (times aside)
    for log in ("0.monitor.csv", "1.monitor.csv"):
        episodes = [line.split(",")[:2] for line in (run / log).read_text().splitlines()[2:]]
        assert episodes == [line.split(",")[:2] for line in (whole / log).read_text().splitlines()[2:]]
    record = json.loads((run / "train_time.json").read_text())
    assert record["timesteps"] == TOTAL and record["resumed_from"] == 128
    assert not list(run.rglob(".*.tmp"))


def test_resume_of_what_is_not_a_killed_run(runs, tmp_path, capsys):
    for folder in (tmp_path / "missing", tmp_path):
        assert main(["--resume", str(folder)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and str(folder) in err and "not a training run" in err
    assert main(["--resume", str(runs["whole"])]) == 0
    assert "is finished" in capsys.readouterr().err
    # the run's own arguments: others are refused, the harmless ones go with it
    run = _copy(runs["killed"], tmp_path)
    assert main(["--resume", str(run), "--seed", "5", "--timesteps", "512"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--seed" in err and "--timesteps" in err
    # no complete checkpoint at all: nothing to resume from
    for steps in (64, 128):
        checkpoint_files(run, steps)["state"].unlink()
    assert main(["--resume", str(run), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no complete checkpoint" in err


def test_a_run_killed_after_its_last_checkpoint_saves_its_final_model(runs, tmp_path):
    """Killed between the checkpoint at the last step and the final model: the resume trains nothing, saves it."""
    run = _copy(runs["whole"], tmp_path)
    final = run / "SeifExplore-v2.zip"
    for path in (run / "train_time.json", final, run / "SeifExplore-v2" / "vecnormalize.pkl"):
        path.unlink()
    assert main(["--resume", str(run), "--quiet"]) == 0
    assert _same_weights(_weights(final), _weights(runs["whole"] / "SeifExplore-v2.zip"))
    assert (run / "SeifExplore-v2" / "vecnormalize.pkl").is_file()
    assert json.loads((run / "train_time.json").read_text())["resumed_from"] == TOTAL
    assert _rows(run) == _rows(runs["whole"])  # the last validation is not run twice


@pytest.mark.slow
def test_a_run_killed_by_sigkill_resumes_to_the_same_model(tmp_path):
    """Two processes: one left alone, one sent SIGKILL once its second checkpoint exists, then resumed."""
    argv = [sys.executable, "-m", "agents.train", *TINY]
    whole = subprocess.Popen([*argv, "--out", str(tmp_path / "whole")], stderr=subprocess.PIPE, text=True)
    killed = subprocess.Popen([*argv, "--out", str(tmp_path / "killed")], stderr=subprocess.PIPE, text=True)
    second = checkpoint_files(tmp_path / "killed", 128)["state"]
    deadline = time.monotonic() + 600
    while not second.exists() and killed.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert killed.poll() is None, "the run ended before it could be killed"
    os.kill(killed.pid, signal.SIGKILL)
    killed.wait(timeout=60)
    assert killed.returncode == -signal.SIGKILL
    _, errors = whole.communicate(timeout=600)
    assert whole.returncode == 0, errors
    assert not (tmp_path / "killed" / "train_time.json").exists()
    resumed = subprocess.run(
        [sys.executable, "-m", "agents.train", "--resume", str(tmp_path / "killed"), "--quiet"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert resumed.returncode == 0, resumed.stderr
    final = "SeifExplore-v2.zip"
    assert _same_weights(_weights(tmp_path / "killed" / final), _weights(tmp_path / "whole" / final))
    assert _rows(tmp_path / "killed") == _rows(tmp_path / "whole")
    assert json.loads((tmp_path / "killed" / "train_time.json").read_text())["timesteps"] == TOTAL


# -- the pieces ----------------------------------------------------------------------------------------
def test_atomic_write_keeps_the_previous_file_when_the_writer_dies(tmp_path):
    path = tmp_path / "model.zip"
    atomic_write(path, lambda temporary: temporary.write_bytes(b"first"))

    def dies(temporary: Path) -> None:
        temporary.write_bytes(b"half")
        raise Killed

    with pytest.raises(Killed):
        atomic_write(path, dies)
    assert path.read_bytes() == b"first" and [p.name for p in tmp_path.iterdir()] == ["model.zip"]
    (tmp_path / ".model.zip.123.tmp").write_bytes(b"left by a kill")
    assert [p.name for p in remove_temporaries(tmp_path)] == [".model.zip.123.tmp"]
    with pytest.raises(TypeError, match="path"):
        atomic_write(3, lambda temporary: None)


def test_a_checkpoint_is_complete_only_with_every_file_it_records(runs, tmp_path):
    run = _copy(runs["whole"], tmp_path)
    files = checkpoint_files(run, 64)
    assert read_checkpoint(run, 64).vecnormalize == files["vecnormalize"]
    files["vecnormalize"].unlink()
    with pytest.raises(ValueError, match="rl_model_vecnormalize_64_steps.pkl is missing"):
        read_checkpoint(run, 64)
    state = files["state"].read_bytes()
    files["state"].write_bytes(state[: len(state) // 3])  # the state file itself cut short
    with pytest.raises(ValueError, match="does not read"):
        read_checkpoint(run, 64)
    files["state"].write_bytes(pickle.dumps({"format": 0}))
    with pytest.raises(ValueError, match="not a state file"):
        read_checkpoint(run, 64)
    files["state"].unlink()
    with pytest.raises(ValueError, match="never completed"):
        read_checkpoint(run, 64)


def test_the_validation_callbacks_state_goes_with_each_checkpoint(runs):
    state = read_checkpoint(runs["whole"], 192).state
    assert state["env_note"] is None and state["env"] is not None  # the envs' episodes are kept
    (validation,) = [value for key, value in state["callbacks"].items() if key.endswith(":MapErrorEvalCallback")]
    assert [row["timesteps"] for row in validation["evaluations"]] == [96, 192]
    assert validation["next_eval"] == 288 and validation["last_eval"] == 192
    assert validation["best_model"] is not None and validation["best_timesteps"] in (96, 192)
    assert np.isfinite(validation["best_map_error"])
