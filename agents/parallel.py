"""Where the harnesses run their episodes: this process, local processes, or a Ray cluster.

One home for the parallelism of :mod:`agents.evaluate` and
:mod:`agents.robustness`. A harness cuts its work into *tasks*, each a call
``function(*arguments)`` of a module-level function whose result depends only
on its arguments (every episode starts from ``env.reset(seed=...)``, every
agent is built inside the task). :meth:`Executor.map` runs them

- ``Executor()``: one after another in this process (the default);
- ``Executor(workers=N)``: on ``N`` local processes (``spawn``: no state is
  inherited from the parent, as on a cluster);
- ``Executor(ray="auto")`` or ``Executor(ray="HOST:PORT")``: as Ray tasks of one
  CPU each on a running cluster (``ray start --head`` on one machine,
  ``ray start --address HOST:PORT`` on the others, see ``docs/training/ray.md``); an
  already initialised Ray connection (``ray.init``) is used as it is.

and returns the results in task order whatever order they finish in, calling
``on_result`` once per task as each one arrives (the harness's progress). So
a harness's rows are the same on every backend; only measured times differ.

On Ray a task survives the loss of the node or worker process that runs it:
Ray runs it again elsewhere (up to ``retries`` times; a finished task's
result lost with its node is recomputed the same way), and since a task's
result depends only on its arguments, the rerun gives the same result. Only
system failures are retried: an exception raised by the task's own code
(a bug, a bad argument) fails the map at once, with that exception.

Ray is imported only by the Ray backend (the optional ``ray`` extra). The
tasks' code must be importable on every node: install the project there
(``pip install -e .`` on a shared checkout, or Ray's ``runtime_env``), and
give model paths that every node can read (a shared filesystem).
"""

from __future__ import annotations

import multiprocessing
import os
import socket
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any

__all__ = ["Executor", "add_arguments", "from_arguments", "chunks"]

#: A task: the positional arguments of the mapped function.
Task = tuple[Any, ...]
#: Reruns of a Ray task whose worker process or node died (Ray's own default ``max_retries``).
DEFAULT_RETRIES = 3


def _exit_with_parent(parent: int, period: float = 0.5) -> None:
    """End this worker once ``parent`` (the process that started it) is gone."""
    while os.getppid() == parent:
        time.sleep(period)
    os._exit(1)


def _worker_setup(parent: int) -> None:
    """Initializer of the local workers: one BLAS / OpenMP / torch thread each, and no life after the parent.

    N workers on N cores each running a multi-threaded BLAS would fight over
    the cores; a task's results do not depend on the thread count (as Ray
    gives its tasks one thread). A worker runs a task to its end, and a task
    can be a whole task of the leaderboard: killed while one runs, the
    parent would leave its workers computing for nobody, so a watcher thread
    ends the worker when its parent process is gone.
    """
    for variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[variable] = "1"  # read by torch (and any BLAS) loaded from here on
    from seif_gym.threads import limit_blas_threads

    limit_blas_threads(1)  # the BLAS already loaded with numpy
    threading.Thread(target=_exit_with_parent, args=(parent,), name="exit-with-parent", daemon=True).start()


def _local_node() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _call(function: Callable[..., Any], arguments: Task) -> tuple[str, Any]:
    """Run one task where it was placed; returns ``(where, result)``."""
    return _local_node(), function(*arguments)


def _ray_call(function: Callable[..., Any], arguments: Task) -> tuple[str, Any]:
    import ray

    return ray.get_runtime_context().get_node_id(), function(*arguments)


class Executor:
    """Runs a harness's tasks serially, on local processes or on a Ray cluster.

    Parameters
    ----------
    workers : int
        Local processes (1: this process). Ignored with ``ray``.
    ray : str, optional
        ``"auto"`` (the cluster this machine belongs to) or a cluster's
        ``HOST:PORT``; ``None``: no Ray.
    retries : int
        With ``ray``: how many times Ray reruns a task whose worker process
        or node died (Ray's ``max_retries``; 0: a node loss fails the map).
        Exceptions raised by the task itself are never retried.

    Attributes
    ----------
    placements : list of str
        Where each task of the last :meth:`map` ran, in task order: the Ray
        node id, or ``host:pid`` for this process and local workers.

    Raises
    ------
    ValueError
        If ``workers`` is not a positive int, ``ray`` is not a non-empty string, or ``retries`` is not
        an int >= 0.

    Examples
    --------
    >>> from agents.parallel import Executor
    >>> Executor().map(pow, [(2, 3), (3, 2)])
    [8, 9]
    """

    def __init__(self, workers: int = 1, ray: str | None = None, retries: int = DEFAULT_RETRIES) -> None:
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise ValueError(f"workers must be a positive int, got {workers!r}")
        if ray is not None and (not isinstance(ray, str) or not ray.strip()):
            raise ValueError(f"ray must be 'auto' or a cluster address HOST:PORT, got {ray!r}")
        if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
            raise ValueError(f"retries must be an int >= 0, got {retries!r}")
        self.workers = int(workers)
        self.ray = ray.strip() if ray is not None else None
        self.retries = int(retries)
        self.placements: list[str] = []

    @property
    def kind(self) -> str:
        """``"serial"``, ``"processes"`` or ``"ray"``."""
        if self.ray is not None:
            return "ray"
        return "processes" if self.workers > 1 else "serial"

    def __repr__(self) -> str:
        if self.ray is not None:
            return f"Executor(ray={self.ray!r}, retries={self.retries})"
        return f"Executor(workers={self.workers})"

    def slots(self) -> int:
        """Tasks that can run at once: the workers, or the CPUs of the Ray cluster (connects to it)."""
        if self.ray is None:
            return self.workers
        ray = self._connect()
        return max(int(ray.cluster_resources().get("CPU", 1)), 1)

    def describe(self) -> dict[str, Any]:
        """What ran where (for a run's ``config.json``): the backend and the tasks per place."""
        counts: dict[str, int] = {}
        for place in self.placements:
            counts[place] = counts.get(place, 0) + 1
        return {
            "backend": self.kind,
            "workers": self.workers,
            "ray": self.ray,
            "retries": self.retries if self.ray is not None else None,
            "tasks_per_node": counts,
        }

    # -- running ----------------------------------------------------------------------------------
    def map(
        self,
        function: Callable[..., Any],
        tasks: Sequence[Task],
        on_result: Callable[[int, Any], None] | None = None,
    ) -> list[Any]:
        """``[function(*task) for task in tasks]``, run by this executor's backend.

        Parameters
        ----------
        function : callable
            A module-level function (it is pickled to the workers).
        tasks : sequence of tuple
            The positional arguments of each call.
        on_result : callable, optional
            ``on_result(index, result)``, called in this process as each task
            finishes (in the order they finish), once per task (a task Ray
            reran after a node loss is reported once, with its rerun's result).

        Returns
        -------
        list
            The results in task order.

        Raises
        ------
        Exception
            The first failing task's exception; the tasks not yet started are
            cancelled. On Ray: the task's own exception (Ray's ``RayTaskError``
            subclass of its type), or Ray's error for a task whose worker or
            node died more than ``retries`` times.
        """
        tasks = [tuple(task) for task in tasks]
        self.placements = []
        if not tasks:
            return []
        if self.ray is not None:
            outcomes = self._map_ray(function, tasks, on_result)
        elif self.workers > 1 and len(tasks) > 1:
            outcomes = self._map_processes(function, tasks, on_result)
        else:
            outcomes = []
            for index, task in enumerate(tasks):
                outcome = _call(function, task)
                outcomes.append(outcome)
                if on_result is not None:
                    on_result(index, outcome[1])
        self.placements = [where for where, _ in outcomes]
        return [result for _, result in outcomes]

    def _map_processes(
        self, function: Callable[..., Any], tasks: list[Task], on_result: Callable[[int, Any], None] | None
    ) -> list[tuple[str, Any]]:
        outcomes: list[Any] = [None] * len(tasks)
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(
            min(self.workers, len(tasks)), mp_context=context, initializer=_worker_setup, initargs=(os.getpid(),)
        ) as pool:
            futures: dict[Future[tuple[str, Any]], int] = {
                pool.submit(_call, function, task): index for index, task in enumerate(tasks)
            }
            pending = set(futures)
            try:
                while pending:
                    done, pending = wait(pending, return_when=FIRST_COMPLETED)
                    for future in sorted(done, key=futures.__getitem__):
                        index = futures[future]
                        outcomes[index] = future.result()
                        if on_result is not None:
                            on_result(index, outcomes[index][1])
            except BaseException:
                for future in pending:
                    future.cancel()
                raise
        return outcomes

    def _connect(self) -> Any:
        try:
            import ray
        except ImportError as error:  # pragma: no cover - the ray extra is installed in CI
            raise ImportError("--ray needs the optional 'ray' extra: pip install -e '.[ray]'") from error
        if not ray.is_initialized():
            ray.init(address=self.ray, logging_level="ERROR", log_to_driver=False)
        return ray

    def _map_ray(
        self, function: Callable[..., Any], tasks: list[Task], on_result: Callable[[int, Any], None] | None
    ) -> list[tuple[str, Any]]:
        ray = self._connect()
        # system failures (a worker process or node lost) rerun the task, lineage recomputes a lost result;
        # an exception of the task's own code is not retried
        remote = ray.remote(num_cpus=1, max_retries=self.retries, retry_exceptions=False)(_ray_call)
        references = [remote.remote(function, task) for task in tasks]
        index_of = {reference: index for index, reference in enumerate(references)}
        outcomes: list[Any] = [None] * len(tasks)
        pending = list(references)
        try:
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for reference in done:
                    index = index_of[reference]
                    outcomes[index] = ray.get(reference)
                    if on_result is not None:
                        on_result(index, outcomes[index][1])
        except BaseException:
            for reference in pending:
                ray.cancel(reference)
            raise
        return outcomes


def chunks(items: Sequence[Any], slots: int, *, together: bool = False) -> list[list[Any]]:
    """Cut ``items`` into consecutive runs for ``slots`` parallel workers.

    About two runs per slot (so a slow run does not leave the others idle),
    each of at least one item; one run when ``slots == 1`` (a serial harness
    builds its agent once) or ``together`` (an agent whose state carries from
    one episode into the next must see all of them, in order).

    Returns
    -------
    list of list
        The runs, in order; their concatenation is ``list(items)`` (no run for no items).

    Examples
    --------
    >>> chunks(range(5), 2)
    [[0, 1], [2, 3], [4]]
    >>> chunks(range(5), 2, together=True)
    [[0, 1, 2, 3, 4]]
    """
    items = list(items)
    if not items:
        return []
    if together or slots <= 1:
        return [items]
    size = max(1, -(-len(items) // (2 * slots)))
    return [items[start : start + size] for start in range(0, len(items), size)]


# -- command line ---------------------------------------------------------------------------------
def available_cores(limit: int = 4) -> int:
    """The cores this process may run on (its CPU affinity), at most ``limit``: a default for ``--workers``."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(int(limit), cores))


def add_arguments(parser: Any, *, workers: int = 1) -> None:
    """Add ``--workers`` (default ``workers``), ``--ray`` and ``--ray-retries`` to a harness's ``argparse`` parser."""
    parser.add_argument(
        "--workers",
        type=int,
        default=workers,
        help=f"local processes running the episodes (default {workers}{': this process' if workers == 1 else ''})",
    )
    parser.add_argument(
        "--ray",
        default=None,
        metavar="auto|ADDRESS",
        help="run the episodes as Ray tasks on a cluster: 'auto' (the one this machine belongs to) or HOST:PORT "
        "(needs the ray extra; see docs/training/ray.md)",
    )
    parser.add_argument(
        "--ray-retries",
        type=int,
        default=DEFAULT_RETRIES,
        metavar="N",
        help="with --ray: reruns of a task whose worker or node died (default %(default)s; 0: a node loss ends "
        "the run)",
    )


def from_arguments(args: Any, parser: Any) -> Executor:
    """The :class:`Executor` of parsed ``--workers`` / ``--ray`` / ``--ray-retries`` (a usage error on bad values)."""
    retries = getattr(args, "ray_retries", DEFAULT_RETRIES)
    if retries < 0:
        parser.error(f"--ray-retries must be >= 0, got {retries}")
    try:
        return Executor(workers=args.workers, ray=args.ray, retries=retries)
    except ValueError as error:
        parser.error(str(error))
        raise  # pragma: no cover - parser.error exits
