"""research.select: every checkpoint of a run scored on validation seeds, the lowest mean chosen and copied."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import torch

import seif_gym  # noqa: F401
from agents.checkpoints import behaviour_fingerprint, save_with_vecnormalize, vecnormalize_path
from agents.protocol import HELD_OUT_SEED
from research.select import best_of_runs, candidates, main, save_selected, select_checkpoints

TINY = {"num_landmarks": 10, "max_episode_steps": 20}


def _model(tmp_path: Path):
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    from agents.networks import BeliefPolicy

    venv = VecNormalize(make_vec_env("SeifExplore-v1", n_envs=1, seed=0, env_kwargs=TINY), norm_obs=False)
    return PPO(BeliefPolicy, venv, n_steps=32, batch_size=32, device="cpu", seed=0)


def _drive(model, forward: float, turn: float) -> None:
    """Make the deterministic action the constant (forward, turn): zero weights, the bias set."""
    action_net = model.policy.action_net
    with torch.no_grad():
        action_net.weight.zero_()
        action_net.bias.copy_(torch.tensor([forward, turn]))


@pytest.fixture()
def run(tmp_path):
    """A run folder with three checkpoints (turn on the spot, drive and turn, drive straight), best and final."""
    model = _model(tmp_path)
    folder = tmp_path / "run_a"
    for steps, (forward, turn) in ((100, (-1.0, 1.0)), (200, (1.0, 0.3)), (300, (0.8, 0.0))):
        _drive(model, forward, turn)
        model.get_vec_normalize_env().ret_rms.mean = np.array(float(steps))  # tells the statistics apart
        save_with_vecnormalize(model, folder / f"rl_model_{steps}_steps.zip")
    save_with_vecnormalize(model, folder / "best_map_error" / "model.zip")
    model.save(folder / "SeifExplore-v1.zip")
    model.get_env().close()
    return folder


def test_candidates_are_the_checkpoints_by_steps_then_best_then_final(run):
    found = candidates(run)
    assert [c.label for c in found] == ["run_a:100", "run_a:200", "run_a:300", "run_a:best", "run_a:final"]
    assert [c.steps for c in found] == [100, 200, 300, None, None]
    assert found[3].path == run / "best_map_error" / "model.zip"


def test_select_chooses_the_lowest_validation_mean_and_copies_it_with_its_statistics(run, tmp_path, capsys):
    out = tmp_path / "selection"
    argv = [str(run), "--env", "SeifExplore-v1", "--env-kwargs", json.dumps(TINY), "--episodes", "3", "--seed", "7"]
    assert main([*argv, "--out", str(out), "--quiet"]) == 0
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert {int(r["seed"]) for r in rows} == {7, 8, 9}
    means = {}
    for row in rows:
        means.setdefault(row["agent"], []).append(float(row["final_map_error"]))
    scored = {label: float(np.mean(values)) for label, values in means.items() if label != "info_gain"}
    assert set(scored) == {"run_a:100", "run_a:200", "run_a:300", "run_a:best", "run_a:final"}
    assert scored["run_a:100"] != scored["run_a:200"]  # the candidates act differently
    lowest = min(scored.values())
    chosen_label = next(label for label in scored if scored[label] == lowest)  # the first of the lowest
    record = json.loads((run / "selected" / "selection.json").read_text())
    assert record["chosen"] == chosen_label and record["mean"] == pytest.approx(lowest)
    assert record["seeds"] == [7, 9] and record["env_id"] == "SeifExplore-v1"
    source = Path(record["path"])
    assert (run / "selected" / "model.zip").read_bytes() == source.read_bytes()
    # the statistics of the same moment come along, found where agents.checkpoints looks
    stats = vecnormalize_path(run / "selected" / "model.zip")
    assert stats == run / "selected" / "vecnormalize.pkl"
    assert stats.read_bytes() == vecnormalize_path(source).read_bytes()
    table = (out / "selection.md").read_text()
    assert f"| {chosen_label} (chosen) |" in table and "− info_gain" in table
    assert chosen_label in capsys.readouterr().out


def test_a_later_choice_without_statistics_removes_the_earlier_ones(run, tmp_path):
    selected = run / "selected"
    selected.mkdir()
    (selected / "vecnormalize.pkl").write_bytes(b"stale")
    for checkpoint in run.glob("rl_model_*"):
        checkpoint.unlink()
    (run / "best_map_error").rename(tmp_path / "elsewhere")  # only the final model, saved without statistics
    argv = [str(run), "--env", "SeifExplore-v1", "--env-kwargs", json.dumps(TINY), "--episodes", "1"]
    assert main([*argv, "--seed", "3", "--out", str(tmp_path / "sel"), "--quiet"]) == 0
    assert json.loads((selected / "selection.json").read_text())["chosen"] == "run_a:final"
    assert not (selected / "vecnormalize.pkl").exists()


def _fail_halfway(stage, monkeypatch):
    """Make ``save_selected`` fail while it copies the statistics, or when it swaps the new folder in."""
    import shutil
    from pathlib import Path

    import research.select

    copy, rename = shutil.copyfile, Path.rename

    def failing_copy(source, target):
        if str(source).endswith(".pkl"):
            raise OSError("disk full")
        return copy(source, target)

    def failing_rename(self, target):
        if self.name == ".selected.partial":
            raise OSError("disk full")
        return rename(self, target)

    if stage == "copy":
        monkeypatch.setattr(research.select.shutil, "copyfile", failing_copy)
    else:
        monkeypatch.setattr(Path, "rename", failing_rename)


@pytest.mark.parametrize("stage", ["copy", "swap"])
def test_a_choice_that_fails_midway_leaves_the_earlier_one_as_it_was(run, monkeypatch, stage):
    first = {"chosen": "run_a:100", "path": str(run / "rl_model_100_steps.zip"), "steps": 100}
    save_selected(run, first, {"env_id": "SeifExplore-v1"})
    before = {p.name: p.read_bytes() for p in (run / "selected").iterdir()}
    _fail_halfway(stage, monkeypatch)
    second = {"chosen": "run_a:300", "path": str(run / "rl_model_300_steps.zip"), "steps": 300}
    with pytest.raises(OSError, match="disk full"):
        save_selected(run, second, {"env_id": "SeifExplore-v1"})
    assert {p.name: p.read_bytes() for p in (run / "selected").iterdir()} == before
    monkeypatch.undo()
    save_selected(run, second, {"env_id": "SeifExplore-v1"})  # and a choice that succeeds leaves nothing beside it
    assert json.loads((run / "selected" / "selection.json").read_text())["chosen"] == "run_a:300"
    assert not (run / ".selected.previous").exists() and not (run / ".selected.partial").exists()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"seed": HELD_OUT_SEED - 50}, "held-out"),
        ({"seed": HELD_OUT_SEED + 99}, "held-out"),
        ({"seed": HELD_OUT_SEED + 399}, "held-out"),  # the short tasks' held-out split
        ({"seed": HELD_OUT_SEED + 1599}, "held-out"),  # what a declared experiment may hold out
        ({"episodes": 0}, "episodes"),
        ({"seed": -1}, "seed"),
        ({"baselines": ("greedy",)}, "baselines"),
        ({"baselines": ()}, "baselines"),
    ],
)
def test_bad_arguments_are_refused_before_any_episode(run, kwargs, match):
    with pytest.raises(ValueError, match=match):
        select_checkpoints([run], "SeifExplore-v1", TINY, **kwargs)
    assert not (run / "selected").exists()


def test_runs_without_models_or_twice_or_unknown_env_are_refused(run, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match="holds no model"):
        select_checkpoints([empty], "SeifExplore-v1", TINY)
    with pytest.raises(ValueError, match="is not a folder"):
        select_checkpoints([tmp_path / "missing"], "SeifExplore-v1", TINY)
    with pytest.raises(ValueError, match="given twice"):
        select_checkpoints([run, run], "SeifExplore-v1", TINY)
    with pytest.raises(ValueError, match="env_id"):
        select_checkpoints([run], "NoSuchEnv-v0", TINY)
    with pytest.raises(TypeError, match="env_id"):
        select_checkpoints([run], 3, TINY)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="run"):
        candidates(3)  # type: ignore[arg-type]
    with pytest.raises(SystemExit):
        main([str(empty), "--env", "SeifExplore-v1"])
    assert not (run / "selected").exists()


def test_best_of_runs_keeps_the_run_whose_choice_is_lowest_the_first_given_on_a_tie(run, tmp_path):
    import shutil

    twin = tmp_path / "run_b"  # the same models as run_a: a tie, which goes to the run given first
    shutil.copytree(run, twin)
    straight = tmp_path / "run_c"  # only the checkpoint that drives straight, which maps less here
    straight.mkdir()
    for name in ("rl_model_300_steps.zip", "rl_model_vecnormalize_300_steps.pkl"):
        shutil.copyfile(run / name, straight / name)
    kept = tmp_path / "r2_seed"
    argv = [str(straight), str(twin), str(run), "--env", "SeifExplore-v1", "--env-kwargs", json.dumps(TINY)]
    argv += ["--episodes", "3", "--seed", "7", "--out", str(tmp_path / "sel"), "--quiet", "--best-of-runs", str(kept)]
    assert main(argv) == 0
    chosen = {r: json.loads((r / "selected" / "selection.json").read_text()) for r in (straight, twin, run)}
    assert chosen[straight]["mean"] > chosen[twin]["mean"] == chosen[run]["mean"]
    record = json.loads((kept / "selected" / "selection.json").read_text())
    assert record["run"] == str(twin) and record["runs"] == [str(straight), str(twin), str(run)]
    assert record["chosen"] == chosen[twin]["chosen"] and record["mean"] == chosen[twin]["mean"]
    assert (kept / "selected" / "model.zip").read_bytes() == (twin / "selected" / "model.zip").read_bytes()
    assert vecnormalize_path(kept / "selected" / "model.zip") == kept / "selected" / "vecnormalize.pkl"


def test_best_of_runs_refuses_nothing_to_choose_and_a_run_as_its_folder(run):
    with pytest.raises(ValueError, match="selection"):
        best_of_runs({})
    with pytest.raises(ValueError, match="no validation mean"):
        best_of_runs({"runs/a": {"chosen": "a:100"}})
    with pytest.raises(TypeError, match="selection must be a mapping"):
        best_of_runs([("runs/a", {"mean": 0.3})])  # type: ignore[arg-type]
    with pytest.raises(SystemExit):
        main([str(run), "--env", "SeifExplore-v1", "--best-of-runs", str(run)])
    assert not (run / "selected").exists()


def test_behaviour_fingerprint_is_the_policy_not_the_bytes(tmp_path):
    from stable_baselines3.common.vec_env import VecNormalize

    model = _model(tmp_path)
    _drive(model, 1.0, 0.3)
    first, _ = save_with_vecnormalize(model, tmp_path / "a" / "model.zip")
    model.get_vec_normalize_env().ret_rms.mean = np.array(5.0)  # reward statistics act on nothing evaluated
    model.num_timesteps += 64  # training state saved beside the policy: the bytes differ, the policy not
    again, _ = save_with_vecnormalize(model, tmp_path / "b" / "model.zip")
    bare = tmp_path / "c" / "model.zip"
    model.save(bare)  # no statistics: with norm_obs=False the same observations reach the policy
    assert first.read_bytes() != again.read_bytes()
    assert behaviour_fingerprint(first) == behaviour_fingerprint(again) == behaviour_fingerprint(bare)
    _drive(model, 1.0, 0.3 + 1e-6)
    other, _ = save_with_vecnormalize(model, tmp_path / "d" / "model.zip")
    assert behaviour_fingerprint(other) != behaviour_fingerprint(first)

    # statistics that normalise observations are part of the policy
    normalised = VecNormalize(model.get_env().venv, norm_obs=True)
    model.set_env(normalised)
    _drive(model, 1.0, 0.3)
    e, _ = save_with_vecnormalize(model, tmp_path / "e" / "model.zip")
    key = next(iter(normalised.obs_rms))
    normalised.obs_rms[key].mean = normalised.obs_rms[key].mean + 0.5
    f, _ = save_with_vecnormalize(model, tmp_path / "f" / "model.zip")
    assert len({behaviour_fingerprint(first), behaviour_fingerprint(e), behaviour_fingerprint(f)}) == 3
    model.get_env().close()

    with pytest.raises(TypeError, match="model_path"):
        behaviour_fingerprint(3)
    with pytest.raises(ValueError, match="model_path"):
        behaviour_fingerprint(tmp_path / "model.pkl")
    (tmp_path / "junk.zip").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="model_path"):
        behaviour_fingerprint(tmp_path / "junk.zip")


def test_a_candidate_with_an_earlier_ones_policy_is_scored_once_and_shares_its_figures(run, monkeypatch):
    import research.select as select_module
    from agents.evaluate import evaluate_agents

    scored: list[list[str]] = []

    def recording(specs, *args, **kwargs):
        scored.append([spec.split("=")[0] for spec in specs])
        return evaluate_agents(specs, *args, **kwargs)

    monkeypatch.setattr(select_module, "evaluate_agents", recording)
    selection, rows, summary = select_checkpoints([run], "SeifExplore-v1", TINY, episodes=2, seed=7)
    # the fixture's 300-step checkpoint, best and final hold one policy (best has its own statistics,
    # final none: with norm_obs=False neither changes what the policy sees)
    assert scored == [["info_gain", "run_a:100", "run_a:200", "run_a:300"]]
    choice = selection[str(run)]
    assert choice["same_as"] == {"run_a:best": "run_a:300", "run_a:final": "run_a:300"}
    labels = ["info_gain", "run_a:100", "run_a:200", "run_a:300", "run_a:best", "run_a:final"]
    assert list(summary["agents"]) == labels
    assert [row["agent"] for row in rows] == [label for label in labels for _ in range(2)]
    assert summary["agents"]["run_a:best"]["spec"] == f"run_a:best={run / 'best_map_error' / 'model.zip'}"
    assert summary["paired"]["agents"]["run_a:final"] == summary["paired"]["agents"]["run_a:300"]
    assert choice["candidates"]["run_a:best"] == choice["candidates"]["run_a:300"]

    # the premise, checked: scored on their own, the three give the same episodes to the last bit
    alone, _ = evaluate_agents(
        [f"300={run / 'rl_model_300_steps.zip'}", f"best={run / 'best_map_error' / 'model.zip'}",
         f"final={run / 'SeifExplore-v1.zip'}"], 2, 7, "SeifExplore-v1", TINY,
    )  # fmt: skip
    errors = {}
    for row in alone:
        errors.setdefault(row["agent"], []).append(row["final_map_error"])
    assert errors["300"] == errors["best"] == errors["final"]
    shared = [row["final_map_error"] for row in rows if row["agent"] == "run_a:best"]
    assert shared == errors["best"]


def test_the_table_names_the_candidate_a_duplicate_was_scored_as(run, tmp_path):
    argv = [str(run), "--env", "SeifExplore-v1", "--env-kwargs", json.dumps(TINY), "--episodes", "1", "--seed", "3"]
    assert main([*argv, "--out", str(tmp_path / "sel"), "--quiet"]) == 0
    table = (tmp_path / "sel" / "selection.md").read_text()
    for duplicate in ("run_a:best", "run_a:final"):  # never chosen: the earlier candidate wins the tie
        assert f"| {duplicate} (the policy of run_a:300: scored once) |" in table
    record = json.loads((run / "selected" / "selection.json").read_text())
    assert record["same_as"] == {"run_a:best": "run_a:300", "run_a:final": "run_a:300"}
