"""``--resume OUT`` of ``agents.evaluate``, ``agents.benchmark`` and ``agents.robustness``: a killed run goes on.

Each command runs in a subprocess that is killed (``SIGKILL``: no handler, no cleanup) at one of three
points, then is resumed in another, and its outputs are compared with those of a run left alone:

- *mid-task*: inside an env step of a task's episodes (the task's finished episodes are not kept);
- *between tasks*: right after a task's results were kept in the run's journal;
- *mid-write*: inside an atomic write, the temporary file whole, before it replaces the target (a
  journal unit, or one of the outputs);

and once by the test itself, from outside, as soon as the first task is kept. The resumed outputs equal
the uninterrupted ones byte for byte where a file holds no measured time (the leaderboard, the plots,
the episodes), and in every column but the measured times otherwise. The fast tests check the journal,
the manifest and the refusals without running an episode.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from agents.evaluate import read_run
from agents.evaluate.journal import (
    JOURNAL,
    MANIFEST,
    ResumeError,
    RunFinished,
    RunJournal,
    UnfinishedRunError,
    read_manifest,
    verify_manifest,
    write_manifest,
)

ROOT = Path(__file__).resolve().parents[2]

#: Runs a command's ``main`` with its arguments after arranging its own SIGKILL:
#: ``call MODULE:ATTR[,MODULE:ATTR] N`` dies on the N-th call of them (before it runs), ``after MODULE:ATTR N``
#: right after the N-th call returns, ``replace PATTERN N`` inside the N-th atomic write of a file matching
#: PATTERN (its temporary written whole, not yet in place), ``none`` not at all.
DRIVER = r"""
import fnmatch, functools, importlib, os, signal, sys

mode, target, count, command = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
calls = [0]


def die():
    os.kill(os.getpid(), signal.SIGKILL)


def patch(target, wrap):
    module_name, _, path = target.partition(":")
    owner = importlib.import_module(module_name)
    *parents, name = path.split(".")
    for parent in parents:
        owner = getattr(owner, parent)
    original = getattr(owner, name)

    @functools.wraps(original)
    def wrapped(*args, **kwargs):
        return wrap(original, *args, **kwargs)

    setattr(owner, name, wrapped)


def before(original, *args, **kwargs):
    calls[0] += 1
    if calls[0] == count:
        die()
    return original(*args, **kwargs)


def after(original, *args, **kwargs):
    result = original(*args, **kwargs)
    calls[0] += 1
    if calls[0] == count:
        die()
    return result


if mode in ("call", "after"):
    for one in target.split(","):  # one count for them all
        patch(one, before if mode == "call" else after)
elif mode == "replace":
    real = os.replace

    def replace(source, destination, *args, **kwargs):
        if fnmatch.fnmatch(os.path.basename(os.fspath(destination)), target):
            calls[0] += 1
            if calls[0] == count:
                assert os.path.getsize(source) > 0  # the temporary is whole; the target not yet replaced
                die()
        return real(source, destination, *args, **kwargs)

    os.replace = replace
main = importlib.import_module(command).main
sys.exit(main(sys.argv[5:]))
"""

#: A step of a single env or of a native vector env (a batch of episodes): inside a task's episodes.
STEP = "seif_gym.envs.explore:SeifExploreEnv.step,seif_gym.envs.vector:SeifExploreVectorEnv.step"
RECORD = "agents.evaluate.journal:RunJournal.record"
#: A unit's file in the journal: the hash of its key.
UNIT = "?" * 32 + ".json"
TINY = json.dumps({"num_landmarks": 10, "max_episode_steps": 20})
EVALUATE = ["--agents", "frontier,random,revisit", "--episodes", "3", "--seed", "4", "--env", "SeifExplore-v2",
            "--env-kwargs", TINY, "--quiet"]  # fmt: skip
BENCHMARK = ["--tasks", "SeifExploreBudget-v2,SeifExploreLoopBudget-v2", "--agents", "frontier,random",
             "--episodes", "2", "--seed", "9", "--quiet"]  # fmt: skip
ROBUSTNESS = ["--agents", "frontier,random", "--episodes", "2", "--steps", "15", "--env-kwargs",
              json.dumps({"num_landmarks": 10}), "--filters", "seif-k8,ekf", "--quiet"]  # fmt: skip


def run(command: str, arguments: list[str], mode: str = "none", target: str = "-", count: int = 0,
        timeout: float = 120) -> subprocess.CompletedProcess:  # fmt: skip
    """``python -c DRIVER``: the command ``main(arguments)`` in a subprocess, killed as ``mode`` says."""
    environment = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-c", DRIVER, mode, target, str(count), command, *arguments], cwd=ROOT,
                          env=environment, capture_output=True, text=True, timeout=timeout)  # fmt: skip


def killed(result: subprocess.CompletedProcess) -> None:
    assert result.returncode == -signal.SIGKILL, (result.returncode, result.stderr[-2000:])


def finished(result: subprocess.CompletedProcess) -> None:
    assert result.returncode == 0, result.stderr[-3000:]


def _csv(path: Path, timed: tuple[str, ...]) -> list[dict[str, str]]:
    """The rows of ``path`` without the columns ``timed`` (measured times)."""
    with path.open(newline="") as handle:
        return [{key: value for key, value in row.items() if key not in timed} for row in csv.DictReader(handle)]


def _untimed(value, timed: tuple[str, ...]):
    """``value`` (JSON data) with every entry named in ``timed`` taken out."""
    if isinstance(value, dict):
        return {key: _untimed(item, timed) for key, item in value.items() if key not in timed}
    if isinstance(value, list):
        return [_untimed(item, timed) for item in value]
    return value


def same_evaluation(folder: Path, reference: Path) -> None:
    """The outputs of ``agents.evaluate`` in ``folder`` equal ``reference``'s, but for ``decision_time_ms``."""
    timed = ("decision_time_ms",)
    assert _csv(folder / "results.csv", timed) == _csv(reference / "results.csv", timed)
    summaries = [json.loads((path / "summary.json").read_text()) for path in (folder, reference)]
    assert _untimed(summaries[0], timed) == _untimed(summaries[1], timed)
    assert (folder / "map_error.png").read_bytes() == (reference / "map_error.png").read_bytes()
    verify_manifest(folder)
    assert not (folder / JOURNAL).exists() and not list(folder.rglob(".*.tmp"))


@pytest.fixture(scope="module")
def evaluation(tmp_path_factory) -> Path:
    """An evaluation left alone."""
    folder = tmp_path_factory.mktemp("evaluation") / "alone"
    finished(run("agents.evaluate.cli", [*EVALUATE, "--out", str(folder)]))
    return folder


# -- agents.evaluate ----------------------------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize(
    "mode, target, count, kept",
    [
        ("call", STEP, 30, 1),  # mid-task: in random's episodes (frontier's task kept, random's not)
        ("after", RECORD, 1, 1),  # between tasks: frontier's kept, random's not started
        ("replace", UNIT, 2, 1),  # mid-write of random's unit in the journal: only frontier's kept
        ("replace", "results.csv", 1, 3),  # mid-write of the outputs: every task kept, no manifest
    ],
    ids=["mid-task", "between-tasks", "mid-write-journal", "mid-write-results"],
)
def test_a_killed_evaluation_resumes_to_the_outputs_of_one_left_alone(tmp_path, evaluation, mode, target, count,
                                                                      kept):  # fmt: skip
    out = tmp_path / "run"
    killed(run("agents.evaluate.cli", [*EVALUATE, "--out", str(out)], mode, target, count))
    assert len(list((out / JOURNAL / "units").glob("*.json"))) == kept
    assert not (out / MANIFEST).exists()
    with pytest.raises(UnfinishedRunError, match="not a finished run: no manifest.json.*--resume"):
        read_run(out, "stored_run")
    if mode == "replace" and target == "results.csv":  # the temporary lies there whole; the target is not written
        assert not (out / "results.csv").exists() and len(list(out.glob(".results.csv.*.tmp"))) == 1
    # how the episodes run is no part of the configuration: one resume spreads them over two processes
    spread = ["--workers", "2"] if mode == "after" else []
    finished(run("agents.evaluate.cli", [*EVALUATE, "--resume", str(out), *spread]))
    same_evaluation(out, evaluation)
    if mode == "call":  # once: a finished run says so
        again = run("agents.evaluate.cli", [*EVALUATE, "--resume", str(out)])
        finished(again)
        assert "finished run of agents.evaluate" in again.stdout and "nothing to resume" in again.stdout


@pytest.mark.slow
def test_an_evaluation_killed_from_outside_resumes(tmp_path, evaluation):
    """A real SIGKILL from another process once the first task is kept (whatever the run does then)."""
    out = tmp_path / "run"
    environment = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    process = subprocess.Popen([sys.executable, "-m", "agents.evaluate", *EVALUATE, "--out", str(out)], cwd=ROOT,
                               env=environment, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    deadline = time.monotonic() + 120
    while not list((out / JOURNAL / "units").glob("*.json")) and process.poll() is None:
        assert time.monotonic() < deadline
        time.sleep(0.005)
    process.send_signal(signal.SIGKILL)
    assert process.wait(timeout=30) == -signal.SIGKILL  # killed, not finished before
    finished(run("agents.evaluate.cli", [*EVALUATE, "--resume", str(out)]))
    same_evaluation(out, evaluation)


@pytest.mark.slow
def test_a_stored_run_killed_mid_write_is_refused_and_not_read(tmp_path, evaluation):
    """``--stored-run`` of a killed run: one line, exit 2, before any episode."""
    out = tmp_path / "run"
    killed(run("agents.evaluate.cli", [*EVALUATE, "--out", str(out)], "replace", "summary.json", 1))
    result = run("agents.evaluate.cli", ["--agents", "info_gain", "--episodes", "3", "--seed", "4", "--env-kwargs",
                                         TINY, "--stored-run", str(out), "--out", str(tmp_path / "new")])  # fmt: skip
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert (
        result.stderr.strip()
        .splitlines()[-1]
        .startswith(f"python -m agents.evaluate: error: --stored-run: {out} is not a finished run: no manifest.json")
    )
    assert not (tmp_path / "new").exists()


# -- agents.benchmark ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def leaderboard(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("leaderboard") / "alone"
    finished(run("agents.benchmark", [*BENCHMARK, "--out", str(folder)]))
    return folder


@pytest.mark.slow
@pytest.mark.parametrize(
    "mode, target, count",
    [("call", STEP, 400), ("after", RECORD, 3), ("replace", "leaderboard.json", 1)],
    ids=["mid-task", "between-tasks", "mid-write"],
)
def test_a_killed_leaderboard_resumes_to_the_same_files(tmp_path, leaderboard, mode, target, count):
    """Killed in the second task's random episodes, after the first task, or writing ``leaderboard.json``."""
    out = tmp_path / "run"
    killed(run("agents.benchmark", [*BENCHMARK, "--out", str(out)], mode, target, count))
    assert not (out / MANIFEST).exists()
    first = out / "SeifExploreBudget-v2"
    verify_manifest(first)  # the first task finished in every case
    before = (first / "results.csv").stat().st_mtime_ns
    resumed = run("agents.benchmark", [*BENCHMARK, "--resume", str(out)])
    finished(resumed)
    assert (first / "results.csv").stat().st_mtime_ns == before  # not run again
    for name in ("leaderboard.csv", "leaderboard.json", "leaderboard.md"):  # no measured time: byte for byte
        assert (out / name).read_bytes() == (leaderboard / name).read_bytes(), name
    for task in ("SeifExploreBudget-v2", "SeifExploreLoopBudget-v2"):
        same_evaluation(out / task, leaderboard / task)
    verify_manifest(out)
    assert set(read_manifest(out)["files"]) == set(read_manifest(leaderboard)["files"])


# -- agents.robustness --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def robustness(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("robustness") / "alone"
    finished(run("agents.robustness", [*ROBUSTNESS, "--out", str(folder)]))
    return folder


@pytest.mark.slow
@pytest.mark.parametrize(
    "mode, target, count",
    [("call", STEP, 40), ("after", RECORD, 1), ("replace", "timeseries.npz", 1)],
    ids=["mid-task", "between-tasks", "mid-write"],
)
def test_a_killed_robustness_run_resumes_to_the_same_rows(tmp_path, robustness, mode, target, count):
    out = tmp_path / "run"
    killed(run("agents.robustness", [*ROBUSTNESS, "--out", str(out)], mode, target, count))
    assert not (out / MANIFEST).exists()
    finished(run("agents.robustness", [*ROBUSTNESS, "--resume", str(out)]))
    timed = ("us_per_step_mean", "us_per_step_median")
    assert _csv(out / "results.csv", timed) == _csv(robustness / "results.csv", timed)
    with np.load(out / "timeseries.npz") as mine, np.load(robustness / "timeseries.npz") as alone:
        assert set(mine.files) == set(alone.files)
        for name in set(mine.files) - {"step_seconds"}:
            np.testing.assert_array_equal(mine[name], alone[name], err_msg=name)
    episodes = sorted(path.name for path in (robustness / "episodes").glob("*.npz"))
    assert sorted(path.name for path in (out / "episodes").glob("*.npz")) == episodes and len(episodes) == 4
    for name in episodes:  # the recorded episodes, byte for byte
        assert (out / "episodes" / name).read_bytes() == (robustness / "episodes" / name).read_bytes(), name
    verify_manifest(out)
    assert not list(out.rglob(".*.tmp"))


# -- fast: the journal, the manifest, the refusals ----------------------------------------------------------
def test_the_journal_keeps_numbers_and_arrays_bit_for_bit(tmp_path):
    journal = RunJournal.start(tmp_path, "test", {"a": 1})
    values = {"f64": np.array([0.1, np.nan, -np.inf, 1e-310]), "f32": np.array([[0.1, 2.5]], dtype=np.float32),
              "i": np.arange(3, dtype=np.int16), "s": np.array(["x", "yz"]), "scalar": np.float32(0.1),
              "n": np.int64(7), "plain": [0.1, float("nan"), None, True, "t"], "tuple": (1, 2.5)}  # fmt: skip
    journal.record({"unit": 1}, values)
    ((key, kept),) = RunJournal.start(tmp_path, "test", {"a": 1}, resume=True).units()
    assert key == {"unit": 1}
    for name in ("f64", "f32", "i", "s"):
        assert kept[name].dtype == values[name].dtype and kept[name].shape == values[name].shape
        np.testing.assert_array_equal(kept[name], values[name])
    assert type(kept["scalar"]) is np.float32 and kept["scalar"] == values["scalar"]
    assert type(kept["n"]) is np.int64 and kept["n"] == 7
    assert kept["plain"][0] == 0.1 and np.isnan(kept["plain"][1]) and kept["plain"][2:] == [None, True, "t"]
    assert kept["tuple"] == [1, 2.5]
    journal.record({"unit": 1}, [1])  # the same unit again replaces itself
    assert RunJournal.start(tmp_path, "test", {"a": 1}, resume=True).units() == [({"unit": 1}, [1])]
    with pytest.raises(TypeError, match="cannot keep a object"):
        journal.record({"unit": 2}, object())
    assert not list(tmp_path.rglob(".*.tmp"))


def test_resume_refuses_another_configuration_command_or_no_run(tmp_path):
    RunJournal.start(tmp_path / "run", "agents.evaluate", {"episodes": 3, "agents": ["frontier"]})
    with pytest.raises(ResumeError, match=r"another configuration \(episodes: 3 there, 4 here\)"):
        RunJournal.start(tmp_path / "run", "agents.evaluate", {"episodes": 4, "agents": ["frontier"]}, resume=True)
    with pytest.raises(ResumeError, match="of a run of 'agents.evaluate', not of agents.benchmark"):
        RunJournal.start(tmp_path / "run", "agents.benchmark", {"episodes": 3, "agents": ["frontier"]}, resume=True)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ResumeError, match="holds no run of agents.evaluate to resume"):
        RunJournal.start(tmp_path / "empty", "agents.evaluate", {}, resume=True)
    # a new run in the folder forgets the old one
    fresh = RunJournal.start(tmp_path / "run", "agents.evaluate", {"episodes": 4})
    assert fresh.discarded == 0 and fresh.units() == []


def test_a_finished_run_says_so_and_its_manifest_lists_every_file(tmp_path):
    config = {"episodes": 3}
    journal = RunJournal.start(tmp_path, "agents.evaluate", config)
    journal.record({"unit": 1}, [1.5])
    (tmp_path / "results.csv").write_text("a\n1\n")
    write_manifest(tmp_path, [tmp_path / "results.csv"], "agents.evaluate", config)
    journal.finish()
    assert not (tmp_path / JOURNAL).exists()
    with pytest.raises(RunFinished, match="finished run of agents.evaluate.*nothing to resume"):
        RunJournal.start(tmp_path, "agents.evaluate", config, resume=True)
    with pytest.raises(ResumeError, match="another configuration"):
        RunJournal.start(tmp_path, "agents.evaluate", {"episodes": 4}, resume=True)
    assert verify_manifest(tmp_path)["files"] == {"results.csv": read_manifest(tmp_path)["files"]["results.csv"]}
    (tmp_path / "results.csv").write_text("a\n2\n")
    with pytest.raises(ValueError, match="results.csv in .* changed after its manifest.json was written"):
        verify_manifest(tmp_path)
    (tmp_path / "results.csv").unlink()
    with pytest.raises(UnfinishedRunError, match="lacks results.csv, which its manifest.json lists"):
        read_manifest(tmp_path)


def test_a_folder_a_live_run_writes_is_refused_and_a_killed_runs_is_taken(tmp_path):
    RunJournal.start(tmp_path, "agents.evaluate", {"episodes": 3})
    owner = tmp_path / JOURNAL / "owner.json"
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        owner.write_text(json.dumps({**json.loads(owner.read_text()), "pid": other.pid}))
        for resume in (False, True):
            with pytest.raises(
                ResumeError, match=f"is being written by a run still going on \\(process {other.pid}\\)"
            ):
                RunJournal.start(tmp_path, "agents.evaluate", {"episodes": 3}, resume=resume)
    finally:
        other.kill()
        other.wait()
    journal = RunJournal.start(tmp_path, "agents.evaluate", {"episodes": 3}, resume=True)  # its process is gone
    assert json.loads(owner.read_text())["pid"] == os.getpid() and journal.units() == []
