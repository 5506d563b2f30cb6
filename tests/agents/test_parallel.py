"""The harnesses' executors (agents.parallel): same rows serially and on local processes; failures surface.

The Ray backend is tested on a two-node loopback cluster in tests/agents/test_ray.py.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from agents.evaluate import evaluate_agents
from agents.parallel import Executor, chunks
from agents.robustness import evaluate as robustness

#: Measured times: the only columns allowed to differ between executors.
TIMED_ROWS = ("decision_time_ms", "us_per_step_mean", "us_per_step_median")


def untimed(rows):
    return [{key: value for key, value in row.items() if key not in TIMED_ROWS} for row in rows]


def _fail_on_three(value: int) -> int:
    if value == 3:
        raise RuntimeError("task three failed")
    return value * value


@pytest.mark.slow
def test_executor_keeps_task_order_and_reports_each_result():
    seen = []
    executor = Executor(workers=2)
    assert executor.kind == "processes"
    results = executor.map(pow, [(2, k) for k in range(6)], on_result=lambda index, result: seen.append(index))
    assert results == [2**k for k in range(6)]
    assert sorted(seen) == list(range(6))
    assert len(executor.placements) == 6 and sum(executor.describe()["tasks_per_node"].values()) == 6
    assert Executor().map(pow, []) == [] and Executor().kind == "serial"


@pytest.mark.parametrize("workers", [1, pytest.param(2, marks=pytest.mark.slow)])
def test_a_failing_task_raises_its_exception(workers):
    with pytest.raises(RuntimeError, match="task three failed"):
        Executor(workers=workers).map(_fail_on_three, [(k,) for k in range(5)])


@pytest.mark.parametrize(
    "kwargs, match",
    [({"workers": 0}, "workers"), ({"workers": 1.5}, "workers"), ({"workers": True}, "workers"), ({"ray": ""}, "ray")],
)
def test_executor_rejects_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Executor(**kwargs)


def test_chunks_cover_the_items_in_order():
    items = list(range(11))
    for slots in (1, 2, 3, 8, 50):
        runs = chunks(items, slots)
        assert [item for run in runs for item in run] == items and all(runs)
    assert chunks(items, 1) == [items] and chunks(items, 4, together=True) == [items]
    assert len(chunks(items, 2)) == 4 and chunks([], 3) == []


@pytest.mark.slow
def test_evaluate_agents_rows_equal_on_local_processes():
    """random carries its generator across episodes (one task); frontier's seeds are split into tasks."""
    kwargs = {"max_episode_steps": 25}
    serial_rows, serial_summary = evaluate_agents(["random", "frontier"], 4, 50, "SeifExplore-v1", kwargs)
    executor = Executor(workers=2)
    rows, summary = evaluate_agents(["random", "frontier"], 4, 50, "SeifExplore-v1", kwargs, executor=executor)
    assert untimed(rows) == untimed(serial_rows)
    assert summary["paired"] == serial_summary["paired"]
    assert len(executor.placements) == 1 + 4  # random's one task, frontier's four (2 slots: 2 runs each)
    # Which of the two workers takes which task is the scheduler's choice (one may take all five
    # before the other has started), so the test asks only that they ran in worker processes.
    pids = {int(place.rsplit(":", 1)[1]) for place in executor.placements}
    assert 1 <= len(pids) <= 2 and os.getpid() not in pids


@pytest.mark.slow
def test_robustness_rows_and_curves_equal_on_local_processes(tmp_path):
    arguments = (["random", "frontier"], ["uniform"], [0, 1], 15, ["seif-k4", "ekf"])
    serial_rows, serial_series = robustness(*arguments, env_id="SeifExplore-v1")
    executor = Executor(workers=2)
    rows, series = robustness(*arguments, env_id="SeifExplore-v1", executor=executor, episode_dir=tmp_path)
    assert len(rows) == 2 * 2 * 2 and untimed(rows) == untimed(serial_rows)
    for ours, theirs in zip(series, serial_series):
        for key in ours:
            if key != "step_seconds":
                np.testing.assert_array_equal(ours[key], theirs[key])
    assert sorted(path.name for path in tmp_path.iterdir()) == [
        f"{policy}_uniform_{seed}.npz" for policy in ("frontier", "random") for seed in (0, 1)
    ]


@pytest.mark.slow
def test_evaluate_command_runs_on_workers(tmp_path):
    command = [sys.executable, "-m", "agents.evaluate", "--agents", "frontier", "--episodes", "2", "--seed", "5"]
    command += ["--env-kwargs", json.dumps({"max_episode_steps": 10}), "--out", str(tmp_path), "--quiet"]
    done = subprocess.run([*command, "--workers", "2"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    # a pool may hand both short tasks to the worker that started first: one or two processes
    assert re.search(r"processes: 2 tasks on [12] processes or nodes", done.stdout), done.stdout
    bad = subprocess.run([*command, "--workers", "0"], capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and "workers must be a positive int" in bad.stderr


def _gone(pid: int) -> bool:
    """Whether process ``pid`` has ended (exited, or a zombie no one reaped)."""
    if Path("/proc/self/stat").exists():
        try:
            return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
        except FileNotFoundError:
            return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


@pytest.mark.slow
def test_a_worker_ends_when_its_parent_is_killed(tmp_path):
    """A parent killed while its workers run long tasks leaves no worker computing for nobody."""
    import signal
    import time

    pid_file = tmp_path / "worker.pid"
    script = tmp_path / "parent.py"
    script.write_text(
        "import os, sys, time\n"
        "from agents.parallel import Executor\n"
        "def task(path):\n"
        "    open(path, 'w').write(str(os.getpid()))\n"
        "    time.sleep(120)\n"
        "if __name__ == '__main__':\n"
        "    Executor(workers=2).map(task, [(sys.argv[1],), (sys.argv[1] + '.2',)])\n"
    )
    parent = subprocess.Popen([sys.executable, str(script), str(pid_file)], cwd=str(Path(__file__).parents[2]))
    try:
        deadline = time.monotonic() + 60
        while not pid_file.exists() or not pid_file.read_text():
            assert time.monotonic() < deadline, "the worker never started its task"
            assert parent.poll() is None, "the parent ended before its worker started"
            time.sleep(0.1)
        worker = int(pid_file.read_text())
        assert not _gone(worker)
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=10)
        deadline = time.monotonic() + 10
        while not _gone(worker):
            assert time.monotonic() < deadline, f"worker {worker} still runs 10 s after its parent was killed"
            time.sleep(0.1)
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        # a failed check leaves nothing running: the workers' own pids, where they were written
        for written in (pid_file, tmp_path / "worker.pid.2"):
            if written.exists() and written.read_text() and not _gone(int(written.read_text())):
                os.kill(int(written.read_text()), signal.SIGKILL)
