"""The leaderboard: every baseline and every shipped policy on every task of a version.

Usage::

    python -m agents.benchmark [--tasks SeifExplore,SeifExploreLoop-v2,...] [--version 2]
        [--episodes N] [--seed 1000000] [--agents ...] [--jobs 2 | --workers 16 | --ray auto]
        [--no-batch] [--batch-size 100] [--threads 1] [--out benchmark] [--quiet]

A task is a registered env id, or a family (``SeifExploreLoop``) for its
``--version`` (default: the family's newest); without ``--tasks``, every
family at the newest version (:func:`default_variants`). The protocol is in
``docs/benchmark/protocol.md``: each task is run on the same *held-out* seeds
``seed … seed + episodes − 1`` (default 1 000 000 … 1 000 099, and
… 1 000 399 on the short budget tasks,
:func:`agents.protocol.held_out_episodes`; training and checkpoint selection
never reset with them), every agent on the same seeds, deterministic actions,
through :func:`agents.evaluate.evaluate_agents`. For each task the agents are
compared with the best baseline (the baseline of lowest mean final map error)
by the paired per-seed difference of their final map errors, with a 95 %
Student-t interval; an agent *beats* the best baseline only when that interval
lies below zero (:func:`agents.evaluate.paired_comparison`). ``--no-batch``,
``--batch-size`` and ``--threads`` are :func:`agents.evaluate.evaluate_agents`'
(the episodes run batched where they can, on one thread per process by
default; the rows are the same either way).

``--agents`` takes what ``agents.evaluate`` takes (default: the baselines and
the shipped exploration policies, :data:`EXPLORERS`). A saved model (a shipped
policy, ``PATH.zip``) runs on every task whose observation and action spaces
it accepts (:func:`policy_fits`); on the others it is left out and the
leaderboard says so.

Written to ``--out``:

``leaderboard.md``
    One table per task (agents by mean final map error) and the verdicts.
``leaderboard.csv`` / ``leaderboard.json``
    One row per task × agent: :data:`LEADERBOARD_COLUMNS`.
``<env id>/``
    :func:`agents.evaluate.write_outputs` of that task: ``results.csv``
    (per episode), ``summary.json``, ``summary.md`` and ``map_error.png``
    (map error over time).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import os
import sys
import time
from collections.abc import Mapping, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import gymnasium as gym

import seif_gym
from agents.baselines import BASELINES
from agents.cli import (
    add_deprecated_alias,
    add_resume_argument,
    agents_help,
    check_agents,
    check_seeds,
    model_digests,
    positive_int,
    resolve_tasks,
    resume_folder,
    tasks_epilog,
    usage_errors,
)
from agents.cli import seed as seed_type
from agents.evaluate import DEFAULT_BATCH_SIZE, evaluate_agents, limited_threads, read_run, write_outputs
from agents.evaluate.cli import add_batch_arguments, check_batch_arguments
from agents.evaluate.journal import (
    JOURNAL,
    MANIFEST,
    RunFinished,
    RunJournal,
    finished_with,
    read_manifest,
    write_manifest,
)
from agents.loading import SHIPPED_POLICIES, ShippedPolicy, agent_label, agent_labels, check_agent_spec
from agents.memories import policy_view
from agents.parallel import Executor
from agents.parallel import add_arguments as add_executor_arguments
from agents.parallel import from_arguments as executor_from_arguments
from agents.protocol import (
    HELD_OUT_EPISODES,
    HELD_OUT_SEED,
    SHORT_TASK_HELD_OUT_EPISODES,
    SHORT_TASK_STEPS,
    held_out_episodes,
)
from agents.sb3_agent import sb3_algorithm
from seif_gym._atomic import atomic_write_bytes, atomic_write_text
from seif_gym.validation import as_count

__all__ = [
    "COMMAND",
    "LEADERBOARD_COLUMNS",
    "EXPLORERS",
    "benchmark_variant",
    "default_variants",
    "main",
    "policy_fits",
    "run_benchmark",
]

#: The command's name in its journals and manifests.
COMMAND = "agents.benchmark"

#: The shipped exploration policies: what the leaderboard runs beside the baselines by default.
EXPLORERS: tuple[str, ...] = tuple(name for name, policy in SHIPPED_POLICIES.items() if policy.explorer)

#: Columns of ``leaderboard.csv`` (and keys of each row of ``leaderboard.json``).
LEADERBOARD_COLUMNS: tuple[str, ...] = (
    "env_id",
    "agent",
    "kind",
    "episodes",
    "final_map_error",
    "final_map_error_ci95",
    "pose_rmse",
    "landmarks_mapped",
    "return",
    "best_baseline",
    "difference",
    "difference_ci95_low",
    "difference_ci95_high",
    "verdict",
)


def default_variants(version: int | None = None) -> list[str]:
    """The env ids of every task family registered at ``version``, in registration order.

    Parameters
    ----------
    version : int, optional
        Default :data:`seif_gym.LATEST_VERSION`.

    Raises
    ------
    ValueError
        If ``version`` is not one of :data:`seif_gym.VERSIONS`.
    """
    version = seif_gym.LATEST_VERSION if version is None else version
    if version not in seif_gym.VERSIONS:
        raise ValueError(f"version must be one of {sorted(seif_gym.VERSIONS)}, got {version!r}")
    return [env_id for env_id in seif_gym.VARIANTS if env_id.endswith(f"-v{version}")]


def policy_fits(policy: ShippedPolicy | str | os.PathLike, env_id: str) -> bool:
    """Whether a saved model accepts the observation and action spaces of ``env_id``.

    Parameters
    ----------
    policy : ShippedPolicy, str or PathLike
        A shipped policy, or the path of a saved SB3 / sb3-contrib model.
    env_id : str
        A registered env id.

    Returns
    -------
    bool
        Whether the spaces match, once the entries the policy computes itself (the budget's clock,
        a memory) are added to the env's (:func:`agents.memories.policy_view`).

    Raises
    ------
    ValueError
        If the path is not a saved model of PPO, RecurrentPPO or SAC (:func:`agents.sb3_agent.sb3_algorithm`).
    """
    path = policy.path if isinstance(policy, ShippedPolicy) else Path(policy)
    model = sb3_algorithm(path).load(path, device="cpu")
    env = gym.make(env_id)
    try:
        space = policy_view(env, model.observation_space).observation_space
        return model.observation_space == space and model.action_space == env.action_space
    finally:
        env.close()


def benchmark_variant(env_id: str, agents: Sequence[str], episodes: int, seed: int, out: Path,
                      verbose: bool = False, executor: Executor | None = None, batch: bool = True,
                      batch_size: int = DEFAULT_BATCH_SIZE, threads: int = 1, *,
                      resume: bool = False) -> list[dict[str, Any]]:  # fmt: skip
    """Run ``agents`` on the task ``env_id`` and write its files; the task's leaderboard rows.

    Parameters
    ----------
    env_id : str
        A registered env id.
    agents : sequence of str
        Agent specs (:func:`agents.loading.load_agent`, each optionally ``LABEL=SPEC``); a saved
        model whose spaces do not fit ``env_id`` (:func:`policy_fits`) is left out.
    episodes, seed : int
        The seeds ``seed … seed + episodes − 1``.
    out : Path
        :func:`agents.evaluate.write_outputs` goes to ``out / env_id``, with the task's journal
        (:class:`~agents.evaluate.journal.RunJournal`) while it runs.
    verbose : bool
        Progress on stderr.
    executor : agents.parallel.Executor, optional
        Runs the task's episodes (default: this process).
    batch, batch_size, threads
        As :func:`agents.evaluate.evaluate_agents` takes them.
    resume : bool
        Continue what a killed run of the same configuration left in ``out / env_id``: its finished
        files are read back, its journal's episodes kept.

    Returns
    -------
    list of dict
        One row per agent, keys :data:`LEADERBOARD_COLUMNS`; a left-out agent has ``episodes`` 0.
    """
    specs: list[str] = []
    kinds: dict[str, str] = {}
    skipped: list[str] = []
    for spec in agents:
        label, target = agent_label(spec)
        if target in BASELINES:
            specs.append(spec)
            kinds[label] = "baseline"
            continue
        model = SHIPPED_POLICIES[target] if target in SHIPPED_POLICIES else target
        if not target.startswith("rllib:") and not policy_fits(model, env_id):
            skipped.append(label)
            continue
        # labelled by its leaderboard name, so the task's own summary says what the leaderboard says
        specs.append(f"{label}={model.path if isinstance(model, ShippedPolicy) else target}")
        kinds[label] = "policy"
    started = time.perf_counter()
    folder = out / env_id
    config = {"env_id": env_id, "agents": specs, "models": model_digests(agent_labels(specs)),
              "episodes": int(episodes), "seed": int(seed), "threads": int(threads)}  # fmt: skip
    if resume and finished_with(folder, COMMAND, config):  # killed after the task's files were written
        summary = read_run(folder, env_id)[1]
        if verbose:
            print(f"{env_id}: finished by the killed run ({folder / MANIFEST})", file=sys.stderr)
    else:
        journal = RunJournal.start(folder, COMMAND, config, resume=resume and (folder / JOURNAL).is_dir())
        rows, summary = evaluate_agents(specs, episodes=episodes, seed=seed, env_id=env_id, env_kwargs={},
                                        verbose=verbose, executor=executor, batch=batch, batch_size=batch_size,
                                        threads=threads, journal=journal)  # fmt: skip
        write_outputs(rows, summary, folder, command=COMMAND, config=config)
        journal.finish()
        if verbose:
            print(f"{env_id}: {len(specs)} agents x {episodes} episodes in {time.perf_counter() - started:.0f} s"
                  + (f" (left out, spaces differ: {', '.join(skipped)})" if skipped else ""), file=sys.stderr)  # fmt: skip
    paired = summary["paired"]
    best = paired["reference"]
    table: list[dict[str, Any]] = []
    for label, entry in summary["agents"].items():
        row: dict[str, Any] = {
            "env_id": env_id, "agent": label, "kind": kinds[label], "episodes": entry["episodes"],
            "final_map_error": entry["final_map_error"]["mean"],
            "final_map_error_ci95": entry["final_map_error"]["ci95_half_width"],
            "pose_rmse": entry["pose_rmse"]["mean"], "landmarks_mapped": entry["landmarks_mapped"]["mean"],
            "return": entry["return"]["mean"], "best_baseline": best,
            "difference": None, "difference_ci95_low": None, "difference_ci95_high": None, "verdict": "",
        }  # fmt: skip
        if label == best:
            row["verdict"] = "best baseline"
        elif label in paired["agents"]:
            comparison = paired["agents"][label]
            row["difference"], row["verdict"] = comparison["mean"], comparison["verdict"]
            row["difference_ci95_low"], row["difference_ci95_high"] = comparison["ci95_low"], comparison["ci95_high"]
        table.append(row)
    for name in skipped:
        table.append({**dict.fromkeys(LEADERBOARD_COLUMNS), "env_id": env_id, "agent": name, "kind": "policy",
                      "episodes": 0, "verdict": "left out: observation or action space differs"})  # fmt: skip
    return table


def run_benchmark(variants: Sequence[str], agents: Sequence[str], episodes: int | None, seed: int, out: str | Path,
                  jobs: int = 1, verbose: bool = False, executor: Executor | None = None, *, batch: bool = True,
                  batch_size: int = DEFAULT_BATCH_SIZE, threads: int = 1, resume: bool = False) -> list[dict[str, Any]]:  # fmt: skip
    """Every agent on every task; writes the leaderboard files, ``manifest.json`` last.

    Every file is written whole or not at all (:mod:`seif_gym._atomic`). While it runs, ``out`` holds
    a journal of the finished tasks (:class:`~agents.evaluate.journal.RunJournal`), and each task's
    folder one of its finished episodes; ``resume`` continues from them.

    Parameters
    ----------
    variants : sequence of str
        Registered env ids (the tasks).
    agents : sequence of str
        Agent specs, as :func:`benchmark_variant` takes them; their labels must be distinct.
    episodes : int or None
        Per agent and task; ``None``: the protocol's (:func:`agents.protocol.held_out_episodes`).
    seed : int
        The first held-out seed.
    out : str or Path
        The output folder.
    jobs : int
        Processes, one task each (the largest task sets the wall time).
    verbose : bool
        Progress on stderr.
    executor : agents.parallel.Executor, optional
        Local processes or a Ray cluster that run the tasks one after another, each task's episodes
        spread over all of its slots; excludes ``jobs`` > 1. Every way gives the rows of one process.
    batch, batch_size, threads
        As :func:`agents.evaluate.evaluate_agents` takes them.
    resume : bool
        Continue the killed run of ``out`` (the same tasks, agents, models, episodes, seed and
        threads): its finished tasks are not run again, its unfinished ones keep their finished
        episodes, and the leaderboard files equal those of a run left alone.

    Returns
    -------
    list of dict
        The rows of ``leaderboard.csv`` (:data:`LEADERBOARD_COLUMNS`).

    Raises
    ------
    TypeError
        If ``executor`` is not an :class:`~agents.parallel.Executor`.
    ValueError
        If ``episodes`` or ``jobs`` is not a positive count, both ``jobs`` > 1 and a parallel
        ``executor`` are given, an agent is unknown or its label repeats, or a task is not
        registered (all before anything is written).
    FileNotFoundError
        If a saved model's path does not exist.
    agents.evaluate.journal.ResumeError
        With ``resume``: ``out`` holds no run of this command, or one of another configuration.
    agents.evaluate.journal.RunFinished
        With ``resume``: the run of ``out`` finished.
    """
    if episodes is not None:
        as_count(episodes, "episodes", minimum=1)
    as_count(jobs, "jobs", minimum=1)
    if executor is not None and not isinstance(executor, Executor):
        raise TypeError(f"executor must be an agents.parallel.Executor, got {type(executor).__name__}")
    if executor is not None and executor.kind != "serial" and jobs > 1:
        raise ValueError(
            f"jobs: {jobs} processes of variants and an executor of episodes ({executor!r}) exclude each other"
        )
    labels: list[str] = []
    for spec in agents:
        label, target = agent_label(spec)
        try:
            check_agent_spec(target)
        except ValueError as error:
            raise ValueError(f"agents: {error}") from None
        if label in labels:
            raise ValueError(f"agents: the label {label!r} repeats (name them LABEL=SPEC)")
        labels.append(label)
    # before anything is written: an unknown variant leaves no folder behind
    counts = {env_id: held_out_episodes(env_id) for env_id in variants}  # checks each id is registered
    if episodes is not None:
        counts = dict.fromkeys(counts, int(episodes))
    folder = Path(out)
    config = {"tasks": list(variants), "agents": list(agents), "models": model_digests(agent_labels(list(agents))),
              "episodes": counts, "seed": int(seed), "threads": int(threads)}  # fmt: skip
    journal = RunJournal.start(folder, COMMAND, config, resume=resume)
    kept = {key["env_id"]: table for key, table in journal.units() if key.get("unit") == "task"}
    todo = [env_id for env_id in variants if env_id not in kept]
    work = [(env_id, list(agents), counts[env_id], int(seed), folder, verbose, None, batch, batch_size, threads)
            for env_id in todo]  # fmt: skip
    tables = dict(kept)

    def finished(index: int, table: list[dict[str, Any]]) -> None:
        journal.record({"unit": "task", "env_id": todo[index]}, table)
        tables[todo[index]] = table

    if executor is not None and executor.kind != "serial":
        for index, task in enumerate(work):  # a variant's episodes at once
            finished(index, benchmark_variant(*task[:6], executor, *task[7:], resume=resume))
    else:  # one variant per task
        Executor(workers=int(jobs)).map(partial(benchmark_variant, resume=resume), work, on_result=finished)
    rows = [row for env_id in variants for row in tables[env_id]]
    handle = io.StringIO(newline="")
    writer = csv.DictWriter(handle, fieldnames=list(LEADERBOARD_COLUMNS))
    writer.writeheader()
    writer.writerows(rows)
    meta = {"episodes": counts, "seeds": {env_id: [int(seed), int(seed) + n - 1] for env_id, n in counts.items()},
            "seif_gym": seif_gym.__version__, "rows": rows}  # fmt: skip
    text = json.dumps(meta, indent=2, allow_nan=False) + "\n"
    files = [folder / "leaderboard.csv", folder / "leaderboard.json", folder / "leaderboard.md"]
    atomic_write_bytes(files[0], handle.getvalue().encode())
    atomic_write_text(files[1], text)
    atomic_write_text(files[2], leaderboard_markdown(rows, seed))
    for env_id in variants:  # each task's files, as its own manifest lists them
        if (folder / env_id / MANIFEST).is_file():
            files += [folder / env_id / name for name in read_manifest(folder / env_id, env_id)["files"]]
            files.append(folder / env_id / MANIFEST)
    write_manifest(folder, files, COMMAND, config)
    journal.finish()
    return rows


def _number(value: Any, digits: int = 3) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def leaderboard_markdown(rows: Sequence[Mapping[str, Any]], seed: int) -> str:
    """One Markdown table per variant, agents by mean final map error, with the paired verdicts."""
    lines = [f"# seif_gym {seif_gym.__version__} leaderboard", "",
             f"Held-out seeds from {seed}, the same for every agent of a variant (each variant's count below); "
             "difference: paired per-seed difference of the final map error to the best baseline, "
             "95% Student-t interval. Protocol: docs/benchmark/protocol.md.", ""]  # fmt: skip
    for env_id in dict.fromkeys(row["env_id"] for row in rows):
        mine = [row for row in rows if row["env_id"] == env_id]
        ranked = sorted((row for row in mine if row["episodes"]), key=lambda row: row["final_map_error"])
        episodes = max(row["episodes"] for row in mine)
        lines += [f"## {env_id}", "", f"Seeds {seed}…{seed + episodes - 1}, {episodes} episodes per agent.", "",
                  "| agent | final map error (m) | pose RMSE (m) | landmarks mapped | difference to best baseline (m) | verdict |",
                  "|---|--:|--:|--:|--:|---|"]  # fmt: skip
        for row in ranked:
            error = _number(row["final_map_error"])
            if row["final_map_error_ci95"] is not None:
                error += f" ± {row['final_map_error_ci95']:.3f}"
            difference = ""
            if row["difference"] is not None:
                difference = f"{row['difference']:+.3f}"
                if row["difference_ci95_low"] is not None:
                    difference += f" [{row['difference_ci95_low']:+.3f}, {row['difference_ci95_high']:+.3f}]"
            lines.append(f"| {row['agent']} | {error} | {_number(row['pose_rmse'])} | "
                         f"{_number(row['landmarks_mapped'], 1)} | {difference} | {row['verdict']} |")  # fmt: skip
        for row in mine:
            if not row["episodes"]:
                lines.append(f"\n{row['agent']}: {row['verdict']}.")
        lines += ["", f"Map error over time: `{env_id}/map_error.png`.", ""]
    return "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m agents.benchmark",
        description="The leaderboard: every baseline and shipped policy on every task of a version.",
        epilog=f"{agents_help()}\n\n{tasks_epilog('--tasks')}\n\nThe protocol: docs/benchmark/protocol.md.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--tasks", default="", metavar="TASK,...",
                        help="comma-separated env ids or families (default: every family at --version)")  # fmt: skip
    add_deprecated_alias(parser, "--variants", "--tasks")
    parser.add_argument("--version", type=int, default=None,
                        help="the version a family stands for (default: each family's newest; without --tasks, "
                        f"the newest version, {seif_gym.LATEST_VERSION})")  # fmt: skip
    parser.add_argument(
        "--episodes",
        type=positive_int,
        default=None,
        help=f"held-out episodes per agent and task (default: the protocol's, {SHORT_TASK_HELD_OUT_EPISODES} on "
        f"tasks of at most {SHORT_TASK_STEPS} steps, {HELD_OUT_EPISODES} on the others)",
    )
    parser.add_argument("--seed", type=seed_type, default=HELD_OUT_SEED,
                        help="first held-out seed (default %(default)s)")  # fmt: skip
    parser.add_argument("--agents", default=",".join([*BASELINES, *EXPLORERS]),
                        help="comma-separated agents (default: the baselines and the shipped exploration policies)")  # fmt: skip
    parser.add_argument("--jobs", type=positive_int, default=1, help="worker processes, one task each")
    parser.add_argument("--out", default=None, help="output folder (default benchmark)")
    add_resume_argument(parser)
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    add_batch_arguments(parser)
    add_executor_arguments(parser)  # --workers / --ray: each task's episodes spread over them
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``python -m agents.benchmark`` with ``argv`` (default ``sys.argv[1:]``); prints the leaderboard.

    Returns
    -------
    int
        The exit status, 0 (also for ``--resume`` of a finished run, which says so); a bad argument exits
        through ``argparse`` (status 2, one line) before anything is written.
    """
    parser = _parser()
    args = parser.parse_args(argv)
    check_batch_arguments(args, parser)
    executor = executor_from_arguments(args, parser)
    names = [name.strip() for name in args.tasks.split(",") if name.strip()]
    try:
        variants = resolve_tasks(names, args.version) if names else default_variants(args.version)
    except ValueError as error:
        parser.error(f"--tasks: {error}" if names else f"--version: {error}")
    agents = [name.strip() for name in args.agents.split(",") if name.strip()]
    with usage_errors(parser):  # every input answered before any episode runs and anything is written
        check_agents(agents)
        for env_id in variants:
            check_seeds(args.seed, args.episodes or held_out_episodes(env_id))
        out, resume = resume_folder(args, "benchmark")
    started = time.perf_counter()
    try:
        with limited_threads(args.threads):
            run_benchmark(variants, agents, args.episodes, args.seed, out, jobs=args.jobs, verbose=not args.quiet,
                          executor=executor, batch=not args.no_batch, batch_size=args.batch_size,
                          threads=args.threads, resume=resume)  # fmt: skip
    except RunFinished as done:
        print(done)
        return 0
    except (ValueError, FileNotFoundError) as error:  # ResumeError too
        parser.exit(2, f"{parser.prog}: error: {' '.join(str(error).split())}\n")
    print((out / "leaderboard.md").read_text())
    if not args.quiet:
        print(f"{len(variants)} tasks in {time.perf_counter() - started:.0f} s; wrote {out}/leaderboard.md, "
              f".csv, .json, one folder per task and manifest.json", file=sys.stderr)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
