"""The command line of an evaluation: ``python -m agents.evaluate`` (:func:`main`)."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

from agents.cli import (
    add_resume_argument,
    agents_help,
    check_agents,
    check_env,
    check_seeds,
    json_object,
    model_digests,
    non_negative_int,
    positive_int,
    resume_folder,
    seed,
    task,
    tasks_epilog,
    usage_errors,
)
from agents.evaluate.journal import journal_for_command_line
from agents.evaluate.report import load_stored_run, markdown_table, paired_table, write_outputs
from agents.evaluate.rollout import DEFAULT_BATCH_SIZE, evaluate_agents
from agents.parallel import add_arguments as add_executor_arguments
from agents.parallel import from_arguments as executor_from_arguments
from seif_gym import LATEST_ID

__all__ = ["COMMAND", "add_batch_arguments", "check_batch_arguments", "main"]

#: The command's name in its journal and manifest.
COMMAND = "agents.evaluate"


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m agents.evaluate",
        description="Run agents on the same seeds of a SeifExplore env and compare them.",
        epilog=f"{agents_help()}\n\n{tasks_epilog()}\n\nThe output files: python -c 'import agents.evaluate as e; help(e)'.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--agents", required=True, help="comma-separated agents (see below)")
    parser.add_argument("--episodes", type=positive_int, default=10, help="episodes per agent (default %(default)s)")
    parser.add_argument("--seed", type=seed, default=0, help="seed of the first episode (default %(default)s)")
    parser.add_argument("--env", type=task, default=LATEST_ID, metavar="TASK",
                        help="registered env id or family (default %(default)s)")  # fmt: skip
    parser.add_argument(
        "--env-kwargs", type=json_object, default="{}", help="JSON object of gym.make keyword arguments"
    )
    parser.add_argument("--out", default=None, help="output folder (default ./eval)")
    add_resume_argument(parser)
    parser.add_argument("--bootstrap", type=non_negative_int, default=0, metavar="N",
                        help="also a percentile bootstrap interval of the paired differences, N resamples (default 0: none)")  # fmt: skip
    parser.add_argument(
        "--stored-run",
        default=None,
        metavar="DIR",
        help="an earlier --out folder of this command on the same env, env kwargs and seeds: its agents' episodes "
        "join this run's without running again (e.g. the baselines' held-out episodes)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    add_batch_arguments(parser)
    add_executor_arguments(parser)
    return parser


def add_batch_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--no-batch``, ``--batch-size`` and ``--threads`` (:func:`~agents.evaluate.evaluate_agents`'s)."""
    parser.add_argument("--no-batch", action="store_true",
                        help="run every agent one episode at a time in a single env (the rows are the same; "
                        "by default the episodes run as the sub-envs of native vector envs, the agent acting "
                        "for all of them in one call, where the agent and the env allow it)")  # fmt: skip
    parser.add_argument("--batch-size", type=positive_int, default=DEFAULT_BATCH_SIZE, metavar="N",
                        help="most sub-envs of one batch (default %(default)s; 1: as --no-batch)")  # fmt: skip
    parser.add_argument("--threads", type=positive_int, default=1, metavar="N",
                        help="BLAS and torch threads per process (default %(default)s: the rows are then the same "
                        "batched or not and on every executor)")  # fmt: skip


def check_batch_arguments(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """A usage error (exit status 2) for a ``--batch-size`` or ``--threads`` below 1."""
    if args.batch_size < 1:
        parser.error(f"--batch-size must be positive, got {args.batch_size}")
    if args.threads < 1:
        parser.error(f"--threads must be positive, got {args.threads}")


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``python -m agents.evaluate`` with ``argv`` (default ``sys.argv[1:]``).

    Every input is checked before any episode runs and before anything is written (:mod:`agents.cli`);
    each task's episodes are kept in ``--out`` as they finish (:class:`~agents.evaluate.journal.RunJournal`),
    so that ``--resume OUT`` continues a killed run.

    Returns
    -------
    int
        The exit status, 0 (also for ``--resume`` of a finished run, which says so); a bad argument exits
        through ``argparse`` (status 2, one line) before any episode runs.
    """
    parser = _parser()
    args = parser.parse_args(argv)
    specs = [spec.strip() for spec in args.agents.split(",") if spec.strip()]
    check_batch_arguments(args, parser)
    with usage_errors(parser):
        labelled = check_agents(specs)
        seeds = check_seeds(args.seed, args.episodes)
        out, resume = resume_folder(args, "eval")
        check_env(args.env, args.env_kwargs)
        if args.stored_run is not None:
            try:
                load_stored_run(args.stored_run, args.env, args.env_kwargs, seeds, [label for label, _ in labelled])
            except (ValueError, FileNotFoundError) as error:
                raise type(error)(str(error).replace("stored_run:", "--stored-run:", 1)) from None
    executor = executor_from_arguments(args, parser)
    config = {
        "env_id": args.env, "env_kwargs": args.env_kwargs, "episodes": args.episodes, "seed": args.seed,
        "agents": specs, "models": model_digests(labelled), "bootstrap": args.bootstrap,
        "stored_run": args.stored_run, "threads": args.threads,
    }  # fmt: skip
    journal = journal_for_command_line(parser, out, COMMAND, config, resume)
    if journal is None:
        return 0
    if journal.discarded and not args.quiet:
        print(f"{out} held an unfinished run ({journal.discarded} tasks kept): starting afresh "
              f"(--resume {out} would have continued it)", file=sys.stderr)  # fmt: skip
    started = time.perf_counter()
    rows, summary = evaluate_agents(specs, args.episodes, args.seed, args.env, args.env_kwargs, verbose=not args.quiet,
                                    bootstrap=args.bootstrap, executor=executor, stored_run=args.stored_run,
                                    batch=not args.no_batch, batch_size=args.batch_size, threads=args.threads,
                                    journal=journal)  # fmt: skip
    paths = write_outputs(rows, summary, out, command=COMMAND, config=config)
    journal.finish()
    print(f"{args.env}, {args.episodes} episodes per agent, seeds {args.seed}..{args.seed + args.episodes - 1}; "
          "mean ± 95% CI half-width\n")  # fmt: skip
    print(markdown_table(summary))
    paired = paired_table(summary)
    if paired:
        print(f"\n{paired}")
    print(f"\nwrote {', '.join(str(path) for path in paths.values())} in {time.perf_counter() - started:.1f} s "
          f"({executor.kind}: {len(executor.placements)} tasks on {len(set(executor.placements))} processes or nodes)")  # fmt: skip
    return 0
