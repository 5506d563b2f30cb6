"""Faults on a two-node loopback Ray cluster: a worker node or an env runner dies mid-run, and the run finishes.

Each test that kills part of a cluster builds its own (a head and a worker
node, one CPU each, every process bound to 127.0.0.1, session files in a
private temporary directory); the fixture shuts the rest down whether the
test passes or fails. The harnesses run as subprocesses (``--ray ADDRESS``):
each is watched until one of its tasks runs on the worker node (a Ray worker
process of that node titled ``ray::_ray_call``), then the node is killed; the
run must exit 0 with the rows of a serial run (every column but the measured
times). Without retries (``--ray-retries 0``) the same kill fails the run,
which shows the kill lands on a running task. The RLlib test kills an env
runner's process after the first training iteration and checks that the
training reaches its timesteps with the runner restarted.

Linux only (the Ray processes are found in ``/proc``); skipped without Ray.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# before ray is imported: node addresses resolve to loopback, no auth token is written under ~/.ray
os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
os.environ.setdefault("RAY_AUTH_MODE", "disabled")

import pytest

ray = pytest.importorskip("ray", reason="the optional 'ray' extra is not installed")

from ray._private import ray_constants
from ray.cluster_utils import Cluster

from agents.parallel import Executor, add_arguments, from_arguments

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="finds the Ray processes in /proc (Linux)"),
]

ROOT = Path(__file__).resolve().parents[2]
LOOPBACK = "127.0.0.1"
#: Measured times: the only columns allowed to differ from a serial run's.
TIMED = ("decision_time_ms", "us_per_step_mean", "us_per_step_median")
#: Longest a command may run (they take seconds; a hang fails the test instead of the CI job).
TIMEOUT_S = 240


@contextlib.contextmanager
def _two_nodes():
    """``(cluster, worker)``: a head and a worker node on 127.0.0.1, one CPU each; shut down on leaving."""
    previous = os.environ.get("RAY_TMPDIR")
    os.environ["RAY_TMPDIR"] = tempfile.mkdtemp(prefix="ray-fault-", dir="/tmp")  # short: Unix socket paths
    cluster = None
    try:
        cluster = Cluster(
            initialize_head=True,
            head_node_args={"num_cpus": 1, "node_ip_address": LOOPBACK, "include_dashboard": False},
            shutdown_at_exit=True,
        )
        worker = cluster.add_node(num_cpus=1, node_ip_address=LOOPBACK)
        cluster.wait_for_nodes()
        yield cluster, worker
    finally:
        if ray.is_initialized():
            ray.shutdown()
        if cluster is not None:
            cluster.shutdown()
        shutil.rmtree(os.environ["RAY_TMPDIR"], ignore_errors=True)
        if previous is None:
            os.environ.pop("RAY_TMPDIR")
        else:
            os.environ["RAY_TMPDIR"] = previous


@pytest.fixture
def nodes():
    """A cluster of its own for a test that kills part of it."""
    with _two_nodes() as both:
        yield both


@pytest.fixture(scope="module")
def driver():
    """One cluster for the tests that kill no node, this process connected to it as a Ray driver.

    The task functions of this module travel by value: the Ray workers cannot import a test module.
    """
    with _two_nodes() as (cluster, worker):
        ray.init(address=cluster.address, _node_ip_address=LOOPBACK, logging_level="ERROR", log_to_driver=False)
        module = sys.modules[__name__]
        ray.cloudpickle.register_pickle_by_value(module)
        try:
            yield cluster, worker
        finally:
            ray.cloudpickle.unregister_pickle_by_value(module)


# -- the Ray processes ------------------------------------------------------------------------------
def _raylet_pid(node) -> int:
    return node.all_processes[ray_constants.PROCESS_TYPE_RAYLET][0].process.pid


def _children(parents: set[int], title: str) -> list[int]:
    """Processes whose parent is in ``parents`` and whose command line (Ray's process title) starts with ``title``."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as handle:
                parent = int(handle.read().rsplit(")", 1)[1].split()[1])
            if parent not in parents:
                continue
            with open(f"/proc/{entry}/cmdline", "rb") as handle:
                if handle.read().replace(b"\0", b" ").decode(errors="replace").startswith(title):
                    found.append(int(entry))
        except (OSError, IndexError, ValueError):  # the process ended meanwhile
            continue
    return found


def _wait_for(condition, process: subprocess.Popen, what: str, timeout: float = TIMEOUT_S):
    """Poll ``condition()`` every 0.05 s until it is truthy; fail if ``process`` ends first or on timeout."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        if process.poll() is not None:
            output = process.stdout.read() if process.stdout else ""
            pytest.fail(f"the command ended (status {process.returncode}) before {what}:\n{output[-3000:]}")
        time.sleep(0.05)
    process.kill()
    pytest.fail(f"timed out waiting for {what}")


def _run(command: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT_S)


def _run_and_kill_worker(cluster, worker, command: list[str]) -> tuple[int, str, float]:
    """Start ``command``, kill ``worker`` once one of its tasks runs there; ``(status, output, seconds to kill)``."""
    started = time.monotonic()
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        raylet = _raylet_pid(worker)
        _wait_for(lambda: _children({raylet}, "ray::_ray_call"), process, "a task ran on the worker node")
        cluster.remove_node(worker, allow_graceful=False)
        killed = time.monotonic() - started
        output, _ = process.communicate(timeout=TIMEOUT_S)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    return process.returncode, output, killed


def _untimed(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return [{key: value for key, value in row.items() if key not in TIMED} for row in csv.DictReader(handle)]


# -- the harnesses ----------------------------------------------------------------------------------
EVALUATE = ["--agents", "frontier,revisit", "--episodes", "4", "--env", "SeifExplore-v1", "--quiet"]
EVALUATE += ["--env-kwargs", '{"max_episode_steps": 1000}']


def test_evaluate_finishes_after_the_worker_node_dies(nodes, tmp_path):
    cluster, worker = nodes
    serial = _run([sys.executable, "-m", "agents.evaluate", *EVALUATE, "--out", str(tmp_path / "serial")])
    assert serial.returncode == 0, serial.stderr[-3000:]
    command = [sys.executable, "-m", "agents.evaluate", *EVALUATE, "--ray", cluster.address]
    status, output, _ = _run_and_kill_worker(cluster, worker, [*command, "--out", str(tmp_path / "ray")])
    assert status == 0, output[-3000:]
    rows = _untimed(tmp_path / "ray" / "results.csv")
    assert len(rows) == 8 and rows == _untimed(tmp_path / "serial" / "results.csv")
    summary = json.loads((tmp_path / "ray" / "summary.json").read_text())
    assert summary["paired"] == json.loads((tmp_path / "serial" / "summary.json").read_text())["paired"]


def test_without_retries_the_node_loss_fails_the_run(nodes, tmp_path):
    """``--ray-retries 0`` (the behaviour before retries): the same kill ends the run with Ray's node-death error."""
    cluster, worker = nodes
    command = [sys.executable, "-m", "agents.evaluate", *EVALUATE, "--ray", cluster.address, "--ray-retries", "0"]
    status, output, _ = _run_and_kill_worker(cluster, worker, [*command, "--out", str(tmp_path)])
    assert status == 1 and "NodeDiedError" in output, output[-3000:]
    assert not (tmp_path / "results.csv").exists()


def test_robustness_finishes_after_the_worker_node_dies(nodes, tmp_path):
    cluster, worker = nodes
    arguments = ["--agents", "frontier,revisit", "--episodes", "2", "--steps", "300", "--filters", "seif-k4,ekf"]
    arguments += ["--env", "SeifExplore-v1", "--no-save-episodes", "--quiet"]
    serial = _run([sys.executable, "-m", "agents.robustness", *arguments, "--out", str(tmp_path / "serial")])
    assert serial.returncode == 0, serial.stderr[-3000:]
    command = [sys.executable, "-m", "agents.robustness", *arguments, "--ray", cluster.address]
    status, output, _ = _run_and_kill_worker(cluster, worker, [*command, "--out", str(tmp_path / "ray")])
    assert status == 0, output[-3000:]
    rows = _untimed(tmp_path / "ray" / "results.csv")
    assert len(rows) == 2 * 2 * 2 and rows == _untimed(tmp_path / "serial" / "results.csv")
    executor = json.loads((tmp_path / "ray" / "config.json").read_text())["executor"]
    # every task, the one that was running on the worker node included, finished on the head node
    assert executor["retries"] == 3 and sum(executor["tasks_per_node"].values()) == 4
    assert worker.node_id not in executor["tasks_per_node"]


def test_benchmark_finishes_after_the_worker_node_dies(nodes, tmp_path):
    cluster, worker = nodes
    arguments = ["--tasks", "SeifExplore-v1", "--episodes", "4", "--agents", "frontier,revisit", "--quiet"]
    serial = _run([sys.executable, "-m", "agents.benchmark", *arguments, "--out", str(tmp_path / "serial")])
    assert serial.returncode == 0, serial.stderr[-3000:]
    command = [sys.executable, "-m", "agents.benchmark", *arguments, "--ray", cluster.address]
    status, output, _ = _run_and_kill_worker(cluster, worker, [*command, "--out", str(tmp_path / "ray")])
    assert status == 0, output[-3000:]
    results = Path("SeifExplore-v1") / "results.csv"
    assert _untimed(tmp_path / "ray" / results) == _untimed(tmp_path / "serial" / results)
    board = (tmp_path / "ray" / "leaderboard.csv").read_text()
    assert board == (tmp_path / "serial" / "leaderboard.csv").read_text()


# -- the executor: what is retried, what is not -------------------------------------------------------
def _die_first_time(marks: str, index: int) -> int:
    """Kill this worker process the first time task 1 runs (a system failure); ``index ** 2`` otherwise."""
    mark = Path(marks) / f"{index}.died"
    if index == 1 and not mark.exists():
        mark.touch()
        os._exit(1)
    return index * index


def _fail_counting(marks: str, index: int) -> int:
    """Count the attempts of task ``index`` in a file; task 2 raises (a bug of the task's own)."""
    with (Path(marks) / f"{index}.attempts").open("a") as handle:
        handle.write("attempt\n")
    if index == 2:
        raise RuntimeError("task two failed")
    return index


def test_a_task_whose_worker_dies_reruns_and_is_reported_once(driver, tmp_path):
    reported = []
    executor = Executor(ray=driver[0].address)
    results = executor.map(
        _die_first_time, [(str(tmp_path), k) for k in range(3)], on_result=lambda i, r: reported.append(i)
    )
    assert results == [0, 1, 4]
    assert sorted(reported) == [0, 1, 2]  # once per task, though task 1 ran twice
    assert [path.name for path in tmp_path.iterdir()] == ["1.died"]


def test_a_task_exception_is_not_retried(driver, tmp_path):
    executor = Executor(ray=driver[0].address)
    with pytest.raises(RuntimeError, match="task two failed"):
        executor.map(_fail_counting, [(str(tmp_path), k) for k in range(4)])
    assert (tmp_path / "2.attempts").read_text() == "attempt\n"  # ran once: not retried


@pytest.mark.parametrize("retries", [-1, 1.5, True, "3"])
def test_executor_rejects_bad_retries(retries):
    with pytest.raises(ValueError, match="retries"):
        Executor(ray="auto", retries=retries)


def test_ray_retries_option():
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    executor = from_arguments(parser.parse_args(["--ray", "127.0.0.1:6379", "--ray-retries", "0"]), parser)
    assert executor.retries == 0 and executor.describe()["retries"] == 0
    assert Executor(ray="auto").retries == 3 and Executor().describe()["retries"] is None
    with pytest.raises(SystemExit) as stopped:
        from_arguments(parser.parse_args(["--ray", "auto", "--ray-retries", "-1"]), parser)
    assert stopped.value.code == 2


# -- RLlib: an env runner dies ---------------------------------------------------------------------
def test_rllib_training_survives_a_killed_env_runner(nodes, tmp_path):
    cluster, worker = nodes
    steps = 64 * 30  # 30 iterations of 2 runners x 2 envs x 16 steps: time for the killed runner to come back
    command = [sys.executable, "-m", "agents.rllib_train", "--address", cluster.address, "--env", "SeifExplore-v0"]
    command += ["--timesteps", str(steps), "--num-env-runners", "2", "--num-envs-per-env-runner", "2"]
    command += ["--train-batch-size", "64", "--minibatch-size", "32", "--num-epochs", "1", "--seed", "3"]
    command += ["--checkpoint-every", "1000", "--quiet", "--out", str(tmp_path)]
    progress = tmp_path / "progress.csv"
    raylets = {_raylet_pid(cluster.head_node), _raylet_pid(worker)}
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        # after the first iteration: both runners sampled, then one of them is killed
        _wait_for(lambda: progress.is_file() and len(progress.read_text().splitlines()) > 1, process, "an iteration")
        runners = _children(raylets, "ray::SingleAgentEnvRunner")
        assert len(runners) == 2, runners
        os.kill(runners[0], signal.SIGKILL)
        output, _ = process.communicate(timeout=TIMEOUT_S)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 0, output[-3000:]
    with progress.open() as handle:
        rows = list(csv.DictReader(handle))
    assert int(rows[-1]["env_steps"]) >= steps
    assert any(row["healthy_env_runners"] == "1" for row in rows), "the kill should have taken a runner out"
    assert rows[-1]["healthy_env_runners"] == "2" and int(rows[-1]["env_runner_restarts"]) >= 1
    assert (tmp_path / "checkpoint").is_dir()
