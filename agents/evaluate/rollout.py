"""Running an evaluation: every agent on the same seeds, batched or one episode at a time, on any executor.

:func:`evaluate_agents` is the entry point; :func:`run_episode` is the one episode loop that the
evaluation, the validation callback and the robustness harness share, and
:func:`~agents.evaluate.batched.run_batched_episodes` its batched counterpart (the same rows).
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

import seif_gym  # noqa: F401  (registers the environments)
from agents.base import Agent
from agents.baselines import BASELINES, baseline_class
from agents.evaluate.batched import batch_env, batch_refusal, batch_sizes, run_batched_episodes
from agents.evaluate.journal import RunJournal
from agents.evaluate.report import load_stored_run
from agents.evaluate.schema import SCHEMA_VERSION, SUMMARY_METRICS
from agents.evaluate.statistics import mean_ci, mean_curve, paired_comparison
from agents.loading import agent_labels, check_agent_spec, load_agent
from agents.parallel import Executor, chunks
from agents.sb3_agent import InexactBatchError, SB3Agent, check_threads, torch_threads
from seif_gym import LATEST_ID
from seif_gym.progress import Progress

__all__ = [
    "DEFAULT_BATCH_SIZE",
    "build_agent",
    "evaluate_agents",
    "limited_threads",
    "make_evaluation_env",
    "run_episode",
    "without_exact_nees",
]

#: Most sub-envs of one batch (:func:`evaluate_agents`' ``batch_size``): a policy's batched forward pass
#: and the vector env's step gain little beyond it, and a task's episodes run in batches of at most this.
DEFAULT_BATCH_SIZE = 100

#: One episode's result in a task: run_episode's row and trace, the planning seconds and plans it took.
EpisodeResult = tuple[dict[str, Any], list[float], float, int]


def build_agent(spec: str, env: gym.Env, env_id: str, env_kwargs: Mapping[str, Any], seed: int) -> Agent:
    """The agent of ``spec`` for an evaluation of ``env_id`` with ``env_kwargs``: :func:`agents.load_agent`.

    Parameters
    ----------
    spec : str
        A baseline, a shipped policy, a saved model's path or ``rllib:CHECKPOINT`` (no ``LABEL=``).
    env : gymnasium.Env
        The env it acts in.
    env_id : str
        The registered id of ``env``.
    env_kwargs : mapping
        The keyword arguments ``env`` was made with (a saved model's statistics are loaded on an env
        made alike).
    seed : int
        Seed of the ``random`` baseline.

    Returns
    -------
    Agent

    Raises
    ------
    ValueError, FileNotFoundError
        As :func:`agents.loading.load_agent`.
    """
    return load_agent(spec, env, seed=seed, env_factory=lambda: gym.make(env_id, **env_kwargs))


def run_episode(agent: Agent, env: gym.Env, seed: int) -> tuple[dict[str, Any], list[float]]:
    """One episode of ``agent`` in ``env`` from ``env.reset(seed=seed)``, with deterministic actions.

    Parameters
    ----------
    agent : Agent
        Anything with SB3's ``predict``; its ``reset()``, if it has one, is called after the env's.
        Its ``state`` is passed back at every step (a recurrent policy's memory), with
        ``episode_start`` set at the first.
    env : gymnasium.Env
        A ``SeifExplore`` env (its ``info`` holds the ground truth the metrics read).
    seed : int
        Seed of ``env.reset``.

    Returns
    -------
    row : dict
        The :data:`~agents.evaluate.schema.RESULT_COLUMNS` but ``agent`` and ``episode``.
    map_errors : list of float
        ``info["map_error"]`` after the reset and after every step.

    Notes
    -----
    ``pose_rmse`` is ``sqrt(mean_t ‖p_t − p̂_t‖²)`` over the positions of the reset and of every
    step; ``decision_time_ms`` the mean wall time of one ``predict``.
    """
    observation, info = env.reset(seed=seed)
    if hasattr(agent, "reset"):
        agent.reset()
    map_errors = [float(info["map_error"])]
    squared = [float(np.sum((info["true_pose"][:2] - info["pose_estimate"][:2]) ** 2))]
    total, length, walls, diverged, thinking = 0.0, 0, 0, False, 0.0
    state, start = None, True
    while True:
        started = time.perf_counter()
        action, state = agent.predict(observation, state=state, episode_start=np.array([start]), deterministic=True)
        thinking += time.perf_counter() - started
        start = False
        observation, reward, terminated, truncated, info = env.step(np.asarray(action).reshape(2))
        total += float(reward)
        length += 1
        walls += int(bool(info["wall_contact"]))
        diverged = diverged or bool(info["diverged"])
        map_errors.append(float(info["map_error"]))
        squared.append(float(np.sum((info["true_pose"][:2] - info["pose_estimate"][:2]) ** 2)))
        if terminated or truncated:
            break
    row = {
        "seed": int(seed),
        "final_map_error": map_errors[-1],
        "initial_map_error": map_errors[0],
        "pose_rmse": float(math.sqrt(np.mean(squared))),
        "landmarks_mapped": int(info["landmarks_mapped"]),
        "landmarks_total": int(info["landmarks_total"]),
        "return": total,
        "length": length,
        "wall_contacts": walls,
        "diverged": int(diverged),
        "decision_time_ms": 1e3 * thinking / max(length, 1),
    }
    return row, map_errors


def _carries_over(target: str) -> bool:
    """Whether the agent of ``target`` carries state from one episode into the next (random's generator)."""
    return target in BASELINES and baseline_class(target).carries_over_episodes


def without_exact_nees(env_kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """``env_kwargs`` with ``exact_pose_nees=False`` unless they set it (:func:`make_evaluation_env`).

    Raises
    ------
    TypeError
        If ``env_kwargs`` is not a mapping.
    """
    if not isinstance(env_kwargs, Mapping):
        raise TypeError(f"env_kwargs must be a mapping, got {type(env_kwargs).__name__}")
    return {"exact_pose_nees": False, **env_kwargs}


def make_evaluation_env(env_id: str, env_kwargs: Mapping[str, Any]) -> gym.Env:
    """The env an evaluation steps: ``gym.make(env_id, **env_kwargs)`` with ``exact_pose_nees=False``.

    No metric of an evaluation reads ``info["pose_nees"]``, whose exact pose
    marginal factorises the information matrix every step (its cost:
    ``docs/performance_notes.md``); everything else the env computes is the
    same (``tests/agents/test_agents.py``). ``env_kwargs`` may still ask for it.

    Raises
    ------
    TypeError
        If ``env_kwargs`` is not a mapping.
    """
    return gym.make(env_id, **without_exact_nees(env_kwargs))


@contextlib.contextmanager
def limited_threads(count: int) -> Iterator[None]:
    """Inside the block, the BLAS libraries (numpy's, scipy's) and torch (once loaded) use ``count`` threads.

    Set through ``threadpoolctl`` and ``torch.set_num_threads`` and restored on exit. A saved policy's
    forward passes follow its own :attr:`~agents.sb3_agent.SB3Agent.threads`, which the evaluation sets
    to ``count`` too.

    Raises
    ------
    TypeError, ValueError
        If ``count`` is not a positive int.
    """
    count = check_threads(count, "threads") or 1
    import scipy.linalg  # noqa: F401  (loads scipy's BLAS, so that it is limited too)
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=count, user_api="blas"), torch_threads(count if "torch" in sys.modules else None):
        yield


def _serial_episodes(agent: Agent, env: gym.Env, seeds: Sequence[int]) -> list[EpisodeResult]:
    """:func:`run_episode` of ``agent`` on each seed, in order, with the planning time of each episode."""
    out = []
    for episode_seed in seeds:
        times = getattr(agent, "planning_times", None)
        before = len(times) if times is not None else 0
        row, trace = run_episode(agent, env, int(episode_seed))
        times = getattr(agent, "planning_times", None)
        new = times[before:] if times is not None else []
        out.append((row, trace, float(sum(new)), len(new)))
    return out


def _batched_episodes(agent: Agent, env_id: str, env_kwargs: Mapping[str, Any], seeds: Sequence[int],
                      batch_size: int) -> tuple[list[EpisodeResult] | None, str | None]:  # fmt: skip
    """``seeds`` in batches of at most ``batch_size`` sub-envs; ``(None, reason)`` where they cannot be batched."""
    reason = batch_refusal(agent)
    if reason is not None:
        return None, reason
    out: list[EpisodeResult] = []
    first = 0
    exact = agent.exact_batches() if isinstance(agent, SB3Agent) else contextlib.nullcontext()
    try:
        with exact:
            for size in batch_sizes(len(seeds), batch_size):
                env, why = batch_env(env_id, without_exact_nees(env_kwargs), size)
                if env is None:
                    return None, why
                try:
                    episodes = run_batched_episodes(agent, env, seeds[first : first + size])
                finally:
                    env.close()
                out.extend(episodes)
                first += size
    except InexactBatchError as error:  # a BLAS that rounds a batch otherwise: the serial path's rows instead
        return None, str(error)
    return out, None


def _run_episodes(env_id: str, env_kwargs: Mapping[str, Any], target: str, agent_seed: int, seeds: Sequence[int],
                  batch_size: int = 0, threads: int = 1) -> tuple[list[EpisodeResult], str | None]:  # fmt: skip
    """One task of :func:`evaluate_agents`: the agent of ``target`` on ``seeds``, in order.

    With ``batch_size > 1`` the episodes run as sub-envs of native vector envs (at most ``batch_size``
    each) where the agent and the env allow it, else one after another in a fresh single env; on
    ``threads`` threads (:func:`limited_threads`).

    Returns
    -------
    episodes : list of tuple
        Per episode, :func:`run_episode`'s row and map-error trace and the planning seconds and plans
        it took (agents that plan and time it).
    serial_reason : str or None
        Why a batched run fell back to the serial path (``None``: batched, or not asked to be).
    """
    seeds = [int(seed) for seed in seeds]
    with limited_threads(threads):
        env = make_evaluation_env(env_id, env_kwargs)
        try:
            agent = build_agent(target, env, env_id, env_kwargs, agent_seed)
            if isinstance(agent, SB3Agent):
                agent.threads = threads
            reason = None
            if batch_size > 1:
                episodes, reason = _batched_episodes(agent, env_id, env_kwargs, seeds, batch_size)
                if episodes is not None:
                    return episodes, None
            return _serial_episodes(agent, env, seeds), reason
        finally:
            env.close()


def _unit_key(label: str, target: str, seeds: Sequence[int]) -> dict[str, Any]:
    """The journal's key of a task of :func:`evaluate_agents`: the agent and its seeds."""
    return {"unit": "episodes", "agent": label, "target": target, "seeds": [int(seed) for seed in seeds]}


def _owner_of(key: Mapping[str, Any], labelled: Sequence[tuple[str, str]], seeds: Sequence[int]) -> int | None:
    """The agent number whose task ``key`` names (:func:`_unit_key`), ``None`` for none of this run's.

    An agent whose state carries over is kept only from a task of all of its seeds.
    """
    if key.get("unit") != "episodes" or [key.get("agent"), key.get("target")] not in [list(p) for p in labelled]:
        return None
    number = [list(pair) for pair in labelled].index([key["agent"], key["target"]])
    if _carries_over(labelled[number][1]) and list(key["seeds"]) != list(seeds):
        return None
    return number


def evaluate_agents(
    agent_specs: Sequence[str],
    episodes: int,
    seed: int,
    env_id: str = LATEST_ID,
    env_kwargs: Mapping[str, Any] | None = None,
    *,
    verbose: bool = False,
    bootstrap: int = 0,
    executor: Executor | None = None,
    stored_run: str | os.PathLike | None = None,
    batch: bool = True,
    batch_size: int = DEFAULT_BATCH_SIZE,
    threads: int = 1,
    journal: RunJournal | None = None,
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Run every agent on the seeds ``seed … seed + episodes − 1``.

    Parameters
    ----------
    agent_specs : sequence of str
        Baseline names (:data:`agents.BASELINES`), SB3 ``.zip`` paths,
        ``rllib:CHECKPOINT``, each optionally ``LABEL=SPEC`` (:func:`agent_label`).
    episodes : int
        Episodes per agent.
    seed : int
        First seed.
    env_id : str
        A registered env id.
    env_kwargs : mapping, optional
        Keyword arguments of ``gym.make`` (may include ``max_episode_steps``).
    verbose : bool
        Progress on stderr: a bar over all episodes and one line per agent.
    bootstrap : int
        Resamples of the bootstrap interval of the paired differences (0: t interval only).
    executor : agents.parallel.Executor, optional
        Where the episodes run (default: one after another in this process);
        the rows are the same on every executor but for ``decision_time_ms``.
    stored_run : str or PathLike, optional
        An earlier run's folder (:func:`~agents.evaluate.report.load_stored_run`: same env, arguments
        and seeds): its agents' episodes join this run's, after them, without
        running again; its baselines count as baselines of the paired
        comparison. Its labels may not repeat this run's.
    batch : bool
        Run each task's episodes as the sub-envs of native vector envs, the agent acting for all of
        them in one call (:func:`~agents.evaluate.batched.run_batched_episodes`; the same rows but for
        ``decision_time_ms``). Agents that cannot act so (:func:`~agents.evaluate.batched.batch_refusal`:
        ``random``, ``info_gain``, RLlib checkpoints) and configurations the vector env runs as single
        envs (:func:`~agents.evaluate.batched.batch_env`) run one episode at a time, as with ``False``;
        progress says so once per agent (``verbose``).
    batch_size : int
        Most sub-envs of one batch (a task's episodes run in as few batches as that allows); 1: one
        episode at a time, as ``batch=False``.
    threads : int
        BLAS and torch threads of each task (:func:`limited_threads`; a saved policy's
        :attr:`~agents.sb3_agent.SB3Agent.threads`); with one, the rows are the same on every
        executor and batched or not.
    journal : agents.evaluate.journal.RunJournal, optional
        Keeps each task's episodes as it finishes, and gives back those a killed run of the same
        configuration kept (:meth:`~agents.evaluate.journal.RunJournal.start` with ``resume``): they are
        not run again (an agent whose state carries from one episode into the next is run again
        unless all of its episodes were kept). The rows are those of a run left alone but for
        ``decision_time_ms``.

    Returns
    -------
    rows : list of dict
        One per agent × episode, keys :data:`~agents.evaluate.schema.RESULT_COLUMNS`.
    summary : dict
        Keys :data:`~agents.evaluate.schema.SUMMARY_KEYS` (their meaning: :mod:`agents.evaluate`).

    Raises
    ------
    ValueError
        If no agent is given, ``episodes``, ``batch_size`` or ``threads`` is not positive, an agent
        spec is unknown, or the stored run does not fit (:func:`~agents.evaluate.report.load_stored_run`),
        all before any episode runs.
    FileNotFoundError
        If a saved model or the stored run's files do not exist.
    TypeError
        If ``stored_run`` is not a path, or ``batch_size`` or ``threads`` is not an int.
    """
    threads = check_threads(threads, "threads") or 1
    if isinstance(batch_size, bool) or not isinstance(batch_size, (int, np.integer)):
        raise TypeError(f"batch_size must be a positive int, got {batch_size!r}")
    if batch_size < 1:
        raise ValueError(f"batch_size must be a positive int, got {batch_size!r}")
    if isinstance(agent_specs, str):
        agent_specs = [spec for spec in agent_specs.split(",") if spec]
    if not agent_specs:
        raise ValueError("give at least one agent")
    if int(episodes) < 1:
        raise ValueError(f"episodes must be positive, got {episodes}")
    env_kwargs = dict(env_kwargs or {})
    seeds = [int(seed) + k for k in range(int(episodes))]
    executor = executor if executor is not None else Executor()
    labelled = agent_labels(agent_specs)
    for _, target in labelled:
        check_agent_spec(target)  # before any episode runs
    baselines = [label for label, target in labelled if target in BASELINES]
    stored_rows: list[dict[str, Any]] = []
    stored_agents: dict[str, Any] = {}
    if stored_run is not None:  # read and checked before any episode runs
        stored_rows, stored_agents = load_stored_run(stored_run, env_id, env_kwargs, seeds,
                                                     [label for label, _ in labelled])  # fmt: skip
        baselines += [label for label, entry in stored_agents.items() if entry["spec"] in BASELINES]
    # tasks: runs of consecutive seeds of one agent; an agent whose state carries over between
    # episodes (random's generator) gets all of its seeds in one task, as in a serial run
    slots = executor.slots() if executor.kind != "serial" else 1
    size = int(batch_size) if batch else 0
    if size > 1:  # the configuration's batching, told once for every agent
        probe, why = batch_env(env_id, without_exact_nees(env_kwargs), 1)
        if probe is None:
            size = 0
            if verbose:
                print(f"{env_id}: every agent runs one episode at a time ({why})", file=sys.stderr)
        else:
            probe.close()
    # what a killed run of this configuration finished: its episodes, per agent and seed
    restored: list[dict[int, EpisodeResult]] = [{} for _ in labelled]
    if journal is not None:
        for key, (result, _) in journal.units():
            number = _owner_of(key, labelled, seeds)
            if number is not None:
                restored[number].update({int(item[0]["seed"]): tuple(item) for item in result})
    tasks: list[tuple[Any, ...]] = []
    owner: list[int] = []
    for number, (_, target) in enumerate(labelled):
        missing = [episode_seed for episode_seed in seeds if episode_seed not in restored[number]]
        for run in chunks(missing, slots, together=_carries_over(target)):
            tasks.append((env_id, env_kwargs, target, int(seed), run, size, threads))
            owner.append(number)
    remaining = [owner.count(number) for number in range(len(labelled))]
    collected: dict[int, list[EpisodeResult]] = {}
    told: set[int] = set()
    started = time.perf_counter()
    progress = Progress(len(labelled) * len(seeds), f"{env_id}", enabled=verbose, unit="episodes")

    def episodes_of(number: int) -> list[EpisodeResult]:
        found = dict(restored[number])
        for index in sorted(collected):
            if owner[index] == number:
                found.update({int(item[0]["seed"]): item for item in collected[index]})
        return [found[episode_seed] for episode_seed in seeds]

    def agent_line(number: int, note: str = "") -> None:
        done = episodes_of(number)
        plans = sum(count for _, _, _, count in done)
        planning = sum(seconds for _, _, seconds, _ in done) / plans if plans else math.nan
        extra = f", {1e3 * planning:.2f} ms per plan" if math.isfinite(planning) else ""
        mean = float(np.mean([row["final_map_error"] for row, _, _, _ in done]))
        progress.write(f"{labelled[number][0]}: {len(seeds)} episodes{note} after {time.perf_counter() - started:.1f} s, "
                       f"final map error {mean:.3f} m{extra}")  # fmt: skip

    def arrived(index: int, outcome: tuple[list[EpisodeResult], str | None]) -> None:
        number = owner[index]
        label, target = labelled[number]
        result, reason = outcome
        if journal is not None:  # kept before anything else: a kill from here on loses nothing of it
            journal.record(_unit_key(label, target, tasks[index][4]), outcome)
        collected[index] = result
        if reason is not None and number not in told:  # once per agent
            told.add(number)
            progress.write(f"{label}: one episode at a time ({reason})")
        for row, _, _, _ in result:
            progress.update(1, f"{label} seed {row['seed']}: {row['final_map_error']:.3f} m")
        remaining[number] -= 1
        if remaining[number] == 0:  # the agent's last task: its line
            agent_line(number)

    with progress:
        kept = sum(len(found) for found in restored)
        if kept:
            progress.update(kept, f"{kept} episodes kept by the killed run")
            for number in range(len(labelled)):
                if remaining[number] == 0:
                    agent_line(number, " (kept)")
        executor.map(_run_episodes, tasks, on_result=arrived)
    rows: list[dict[str, Any]] = []
    agents_summary: dict[str, Any] = {}
    for number, (spec, (label, _)) in enumerate(zip(agent_specs, labelled)):
        done = episodes_of(number)
        agent_rows = [{"agent": label, "episode": episode, **row} for episode, (row, _, _, _) in enumerate(done)]
        rows.extend(agent_rows)
        entry: dict[str, Any] = {"spec": spec, "episodes": len(seeds)}
        for metric in SUMMARY_METRICS:
            entry[metric] = mean_ci([row[metric] for row in agent_rows])
        entry["map_error_over_time"] = mean_curve([trace for _, trace, _, _ in done])
        agents_summary[label] = entry
    rows.extend(stored_rows)
    agents_summary.update(stored_agents)
    summary = {
        "schema_version": SCHEMA_VERSION,
        "env_id": env_id,
        "env_kwargs": env_kwargs,
        "episodes": len(seeds),
        "seeds": seeds,
        "metrics": list(SUMMARY_METRICS),
        "agents": agents_summary,
        "paired": paired_comparison(rows, baselines, bootstrap=bootstrap),
        "stored_run": None if stored_run is None else str(stored_run),
    }
    return rows, summary
