"""Every bad input to the comparison commands gets one line and exit status 2, before any episode runs.

``agents.evaluate``, ``agents.benchmark``, ``agents.robustness`` and ``agents.showcase`` check what they
are given first (:mod:`agents.cli`): every saved model opened (a text file renamed ``.zip``, a truncated
zip, a zip that is not a model), the output folder writable, the seeds and counts valid, the env made
with its arguments, ``--resume`` naming a run of the same configuration. Each case here exits with status 2
and one line naming the option or the file, without a traceback, and writes nothing. No episode runs: the
commands' episode runners are replaced by stand-ins that fail the test if called.
"""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path

import pytest

from agents import benchmark, robustness, showcase
from agents.evaluate import cli as evaluate_cli
from agents.evaluate import rollout
from agents.evaluate.journal import RunJournal, write_manifest
from agents.loading import SHIPPED_POLICIES, check_model_file

MAINS = {
    "evaluate": evaluate_cli.main,
    "benchmark": benchmark.main,
    "robustness": robustness.main,
    "showcase": showcase.main,
}
#: The arguments of a small run of each command, but for the agents and the output folder.
BASE = {
    "evaluate": ["--agents", "frontier", "--episodes", "2", "--env-kwargs", '{"num_landmarks": 10}'],
    "benchmark": ["--tasks", "SeifExploreBudget-v2", "--agents", "frontier", "--episodes", "2"],
    "robustness": ["--agents", "frontier", "--episodes", "2", "--steps", "10"],
    "showcase": ["--episodes", "2"],
}


@pytest.fixture(autouse=True)
def no_episode(monkeypatch):
    """Any episode run fails the test: every refusal comes before."""

    def refuse(*args, **kwargs):
        raise AssertionError("an episode ran before the input was checked")

    monkeypatch.setattr(rollout, "_run_episodes", refuse)
    monkeypatch.setattr(robustness, "_record_and_score", refuse)


@pytest.fixture(scope="module")
def bad_models(tmp_path_factory) -> dict[str, Path]:
    """A text file renamed ``.zip``, a truncated copy of a model, a zip without a model, a damaged entry."""
    folder = tmp_path_factory.mktemp("models")
    good = SHIPPED_POLICIES["ppo"].path
    text = folder / "text.zip"
    text.write_text("not a model\n")
    truncated = folder / "truncated.zip"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    other = folder / "other.zip"
    with zipfile.ZipFile(other, "w") as archive:
        archive.writestr("readme.txt", "hello")
    damaged = folder / "damaged.zip"
    data = bytearray(good.read_bytes())
    with zipfile.ZipFile(good) as archive:  # one byte of policy.pth's stored data flipped: its CRC fails
        info = archive.getinfo("policy.pth")
    local = info.header_offset  # the local header: 30 bytes, then the name and the extra field, then the data
    start = local + 30 + int.from_bytes(data[local + 26 : local + 28], "little")
    start += int.from_bytes(data[local + 28 : local + 30], "little")
    data[start + info.compress_size // 2] ^= 0xFF
    damaged.write_bytes(bytes(data))
    return {"text": text, "truncated": truncated, "other": other, "damaged": damaged}


def refused(command: str, arguments: list[str], capsys) -> str:
    """The one line of a command's refusal (exit status 2, no traceback)."""
    with pytest.raises(SystemExit) as exit_:
        MAINS[command](arguments)
    assert exit_.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines and "Traceback" not in "\n".join(lines)
    assert lines[-1].startswith(f"python -m agents.{command}: error: "), lines
    return lines[-1].split(": error: ", 1)[1]


def _with_agent(command: str, spec: str) -> list[str]:
    if command == "showcase":
        return [*BASE[command], "--policy", spec]
    arguments = list(BASE[command])
    arguments[arguments.index("--agents") + 1] = f"frontier,{spec}"
    return arguments


@pytest.mark.parametrize("command", list(MAINS))
@pytest.mark.parametrize(
    "kind, says",
    [
        ("text", "not a zip archive, or a truncated one"),
        ("truncated", "not a zip archive, or a truncated one"),
        ("other", "not a saved Stable-Baselines3 model (no data, policy.pth in it)"),
        ("damaged", "a damaged zip archive"),
    ],
)
def test_a_model_that_is_not_one_is_refused_naming_its_file(command, kind, says, bad_models, tmp_path, capsys):
    out = tmp_path / "out"
    message = refused(command, [*_with_agent(command, str(bad_models[kind])), "--out", str(out)], capsys)
    option = "--policy" if command == "showcase" else "--agents"
    assert message.startswith(f"{option}: {bad_models[kind]}: ") and says in message, message
    assert not out.exists()


def test_the_model_check_names_the_file(bad_models, tmp_path):
    check_model_file(SHIPPED_POLICIES["ppo"].path)
    for path in bad_models.values():
        with pytest.raises(ValueError, match=f"^{path}: "):
            check_model_file(path)
    with pytest.raises(FileNotFoundError, match="no model at"):
        check_model_file(tmp_path / "none.zip")
    with pytest.raises(ValueError, match="not a file"):
        check_model_file(tmp_path)


@pytest.mark.parametrize("command", list(MAINS))
def test_an_output_folder_under_a_file_is_refused(command, tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    message = refused(command, [*BASE[command], "--out", str(tmp_path / "file" / "out")], capsys)
    assert (
        message == f"--out: {tmp_path / 'file' / 'out'} lies under {tmp_path / 'file'}, which is a file, not a folder"
    )
    message = refused(command, [*BASE[command], "--out", str(tmp_path / "file")], capsys)
    assert message == f"--out: {tmp_path / 'file'} is a file, not a folder"


@pytest.mark.parametrize("command", list(MAINS))
@pytest.mark.parametrize(
    "option, value, says",
    [
        ("--seed", "-5", "argument --seed: a seed is an integer from 0 to 2**63 - 1, got -5"),
        ("--seed", "x", "argument --seed: not an integer: 'x'"),
        ("--episodes", "0", "argument --episodes: must be a positive integer, got 0"),
        ("--seed", str(2**63 - 1), "--seed: the seeds 9223372036854775807..9223372036854775808 are not all in"),
    ],
)
def test_seeds_and_counts_are_checked(command, option, value, says, tmp_path, capsys):
    message = refused(command, [*BASE[command], option, value, "--out", str(tmp_path / "out")], capsys)
    assert message.startswith(says), message
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "command, option, value",
    [
        ("evaluate", "--bootstrap", "-1"),
        ("evaluate", "--batch-size", "0"),
        ("evaluate", "--threads", "0"),
        ("showcase", "--bootstrap", "-1"),
        ("benchmark", "--jobs", "0"),
        ("robustness", "--steps", "0"),
        ("robustness", "--nees-every", "0"),
    ],
)
def test_other_counts_are_checked(command, option, value, tmp_path, capsys):
    message = refused(command, [*BASE[command], option, value, "--out", str(tmp_path / "out")], capsys)
    assert message.startswith(f"argument {option}: must be"), message


@pytest.mark.parametrize("command", ["evaluate", "robustness"])
def test_env_arguments_the_env_refuses_are_answered_first(command, tmp_path, capsys):
    arguments = [
        argument for argument in BASE[command] if "num_landmarks" not in argument and argument != "--env-kwargs"
    ]
    message = refused(command, [*arguments, "--env-kwargs", json.dumps({"num_landmarks": -3}), "--out",
                                str(tmp_path / "out")], capsys)  # fmt: skip
    assert message.startswith("--env-kwargs: num_landmarks must be"), message
    message = refused(command, [*arguments, "--env-kwargs", json.dumps({"no_such": 1}), "--out",
                                str(tmp_path / "out")], capsys)  # fmt: skip
    assert message.startswith("--env-kwargs: ") and "no_such" in message, message
    assert not (tmp_path / "out").exists()


def test_robustness_filters_and_layouts_are_answered_first(tmp_path, capsys):
    message = refused("robustness", [*BASE["robustness"], "--filters", "nofilter", "--out", str(tmp_path)], capsys)
    assert message.startswith("--filters: ") and "nofilter" in message
    message = refused("robustness", [*BASE["robustness"], "--env", "SeifExploreMRCLAM", "--layouts", "loop",
                                     "--out", str(tmp_path / "out")], capsys)  # fmt: skip
    assert message == "--layouts: loop: layout 'loop' needs a square arena (arena_extent=None)"
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", ["evaluate", "benchmark", "robustness", "showcase"])
def test_resume_of_no_run_or_another_folder_is_refused(command, tmp_path, capsys):
    message = refused(command, [*BASE[command], "--resume", str(tmp_path / "none")], capsys)
    assert message == f"--resume: {tmp_path / 'none'} is not a folder (the --out of the run to continue)"
    (tmp_path / "empty").mkdir()
    message = refused(command, [*BASE[command], "--resume", str(tmp_path / "empty")], capsys)
    assert message.startswith(f"--resume: {tmp_path / 'empty'} holds no run of agents.{command} to resume"), message
    message = refused(command, [*BASE[command], "--resume", str(tmp_path / "empty"), "--out", str(tmp_path / "x")],
                      capsys)  # fmt: skip
    assert message.startswith(f"--resume: {tmp_path / 'empty'} is the output folder; --out"), message


def test_resume_with_another_configuration_is_refused_naming_what_differs(tmp_path, capsys):
    """The configuration of a killed run is in its journal; another one is refused, without touching the folder."""
    arguments = [*BASE["evaluate"], "--out", str(tmp_path / "run")]
    with pytest.raises(AssertionError, match="an episode ran"):  # the run starts, its journal written, then "killed"
        evaluate_cli.main(arguments)
    capsys.readouterr()
    kept = sorted(path.name for path in (tmp_path / "run").rglob("*"))
    message = refused("evaluate", [*BASE["evaluate"], "--episodes", "3", "--resume", str(tmp_path / "run")], capsys)
    assert message == f"--resume: {tmp_path / 'run'} was run with another configuration (episodes: 2 there, 3 here)"
    message = refused("evaluate", [*BASE["evaluate"], "--agents", "revisit", "--resume", str(tmp_path / "run")],
                      capsys)  # fmt: skip
    assert message.startswith(f"--resume: {tmp_path / 'run'} was run with another configuration (agents: ")
    assert sorted(path.name for path in (tmp_path / "run").rglob("*")) == kept


def test_resume_with_a_changed_model_file_is_refused(tmp_path, capsys):
    model = tmp_path / "model.zip"
    shutil.copyfile(SHIPPED_POLICIES["ppo"].path, model)
    arguments = ["--agents", f"frontier,{model}", "--episodes", "2", "--env", "SeifExplore-v0"]
    with pytest.raises(AssertionError, match="an episode ran"):
        evaluate_cli.main([*arguments, "--out", str(tmp_path / "run")])
    capsys.readouterr()
    shutil.copyfile(SHIPPED_POLICIES["ppo_adversary_v1"].path, model)  # another model at the same path
    message = refused("evaluate", [*arguments, "--resume", str(tmp_path / "run")], capsys)
    assert message.startswith(f"--resume: {tmp_path / 'run'} was run with another configuration (models: "), message


def test_resume_of_a_finished_run_says_so(tmp_path, capsys):
    config = {"env_id": "SeifExplore-v2", "env_kwargs": {"num_landmarks": 10}, "episodes": 2, "seed": 0,
              "agents": ["frontier"], "models": {}, "bootstrap": 0, "stored_run": None, "threads": 1}  # fmt: skip
    RunJournal.start(tmp_path, "agents.evaluate", config).finish()
    write_manifest(tmp_path, [], "agents.evaluate", config)
    assert evaluate_cli.main([*BASE["evaluate"], "--resume", str(tmp_path)]) == 0
    assert capsys.readouterr().out.strip() == (f"{tmp_path} holds a finished run of agents.evaluate "
                                               "(manifest.json is there): nothing to resume")  # fmt: skip


def test_a_stored_run_without_its_manifest_is_refused(tmp_path, capsys):
    (tmp_path / "stored").mkdir()
    for name in ("results.csv", "summary.json"):
        (tmp_path / "stored" / name).write_text("")
    message = refused("evaluate", [*BASE["evaluate"], "--stored-run", str(tmp_path / "stored"), "--out",
                                   str(tmp_path / "out")], capsys)  # fmt: skip
    assert message.startswith(f"--stored-run: {tmp_path / 'stored'} is not a finished run: no manifest.json")
