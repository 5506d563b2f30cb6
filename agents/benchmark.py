"""The leaderboard: every baseline and every shipped policy on every registered variant.

Usage::

    python -m agents.benchmark [--variants SeifExplore,SeifExploreLoop,...] [--version 1]
        [--episodes N] [--seed 1000000] [--agents ...] [--jobs 2 | --workers 16 | --ray auto]
        [--out benchmark] [--quiet]

The protocol is in ``docs/benchmark.md``: each variant is run on the same
*held-out* seeds ``seed … seed + episodes − 1`` (default 1 000 000 …
1 000 099, and … 1 000 399 on the short budget tasks,
:func:`held_out_episodes`; training and checkpoint selection never reset
with them), every
agent on the same seeds, deterministic actions, through
:func:`agents.evaluate.evaluate_agents`. For each variant the agents are
compared with the best baseline (the baseline of lowest mean final map error)
by the paired per-seed difference of their final map errors, with a 95 %
Student-t interval; an agent *beats* the best baseline only when that interval
lies below zero (:func:`agents.evaluate.paired_comparison`, the statistics'
one home).

A shipped policy (:data:`SHIPPED_POLICIES`) runs on every variant whose
observation and action spaces it accepts; on the others it is left out and
the leaderboard says so.

Written to ``--out``:

``leaderboard.md``
    One table per variant (agents by mean final map error) and the verdicts.
``leaderboard.csv`` / ``leaderboard.json``
    One row per variant × agent: :data:`LEADERBOARD_COLUMNS`.
``<env id>/``
    :func:`agents.evaluate.write_outputs` of that variant: ``results.csv``
    (per episode), ``summary.json``, ``summary.md`` and ``map_error.png``
    (map error over time, the plot of the variant).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym

import seif_gym
from agents import BASELINES
from agents.evaluate import evaluate_agents, write_outputs
from agents.loading import SHIPPED_POLICIES, ShippedPolicy
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
from seif_gym.validation import as_count

__all__ = [
    "LEADERBOARD_COLUMNS",
    "EXPLORERS",
    "benchmark_variant",
    "default_variants",
    "main",
    "policy_fits",
    "run_benchmark",
]

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
    """The env ids of every layout at ``version`` (default the newest), in registration order."""
    version = seif_gym.LATEST_VERSION if version is None else version
    if version not in seif_gym.VERSIONS:
        raise ValueError(f"version must be one of {sorted(seif_gym.VERSIONS)}, got {version!r}")
    return [env_id for env_id in seif_gym.VARIANTS if env_id.endswith(f"-v{version}")]


def _resolve_variants(names: Sequence[str], version: int | None) -> list[str]:
    """Env ids from layout names (``SeifExploreLoop``) or ids (``SeifExploreLoop-v0``)."""
    known = default_variants(version)
    resolved: list[str] = []
    for name in names:
        if name in seif_gym.VARIANTS:
            env_id = name
        else:
            matches = [env_id for env_id in known if env_id.rsplit("-v", 1)[0] == name]
            if not matches:
                layouts = sorted({env_id.rsplit("-v", 1)[0] for env_id in seif_gym.VARIANTS})
                raise ValueError(f"variants: unknown variant {name!r} (layouts: {', '.join(layouts)}; or an env id)")
            env_id = matches[0]
        if env_id not in resolved:
            resolved.append(env_id)
    return resolved


def policy_fits(policy: ShippedPolicy, env_id: str) -> bool:
    """Whether ``policy`` accepts the observation and action spaces of ``env_id``."""
    model = sb3_algorithm(policy.path).load(policy.path, device="cpu")
    env = gym.make(env_id)
    try:
        # a policy with entries of its own (the budget's clock, the coverage memory) adds them itself
        space = policy_view(env, model.observation_space).observation_space
        return model.observation_space == space and model.action_space == env.action_space
    finally:
        env.close()


def benchmark_variant(env_id: str, agents: Sequence[str], episodes: int, seed: int, out: Path,
                      verbose: bool = False, executor: Executor | None = None) -> list[dict[str, Any]]:  # fmt: skip
    """Run ``agents`` (baseline names and shipped-policy labels) on ``env_id``; the leaderboard rows.

    Writes the variant's :func:`~agents.evaluate.write_outputs` into ``out / env_id``. ``executor``
    runs the variant's episodes (default: this process).
    """
    specs: list[str] = []
    labels: dict[str, str] = {}
    kinds: dict[str, str] = {}
    skipped: list[str] = []
    for name in agents:
        if name in BASELINES:
            specs.append(name)
            labels[name], kinds[name] = name, "baseline"
        else:
            policy = SHIPPED_POLICIES[name]
            if not policy_fits(policy, env_id):
                skipped.append(name)
                continue
            # labelled by its leaderboard name, so the variant's own summary says what the leaderboard says
            specs.append(f"{name}={policy.path}")
            labels[name], kinds[name] = name, "policy"
    started = time.perf_counter()
    rows, summary = evaluate_agents(
        specs, episodes=episodes, seed=seed, env_id=env_id, env_kwargs={}, verbose=verbose, executor=executor
    )
    write_outputs(rows, summary, out / env_id)
    if verbose:
        print(f"{env_id}: {len(specs)} agents x {episodes} episodes in {time.perf_counter() - started:.0f} s"
              + (f" (left out, spaces differ: {', '.join(skipped)})" if skipped else ""), file=sys.stderr)  # fmt: skip
    # the paired comparison with the best baseline is agents.evaluate's (one home for the statistics)
    paired = summary["paired"]
    best = paired["reference"]
    table: list[dict[str, Any]] = []
    for label, entry in summary["agents"].items():
        row: dict[str, Any] = {
            "env_id": env_id, "agent": labels[label], "kind": kinds[label], "episodes": entry["episodes"],
            "final_map_error": entry["final_map_error"]["mean"],
            "final_map_error_ci95": entry["final_map_error"]["ci95_half_width"],
            "pose_rmse": entry["pose_rmse"]["mean"], "landmarks_mapped": entry["landmarks_mapped"]["mean"],
            "return": entry["return"]["mean"], "best_baseline": labels[best] if best else None,
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
                  jobs: int = 1, verbose: bool = False, executor: Executor | None = None) -> list[dict[str, Any]]:  # fmt: skip
    """Every agent on every variant; writes the leaderboard files.

    ``episodes`` per agent and variant; ``None``: the protocol's (:func:`held_out_episodes`).
    Two ways to spread the work: ``jobs`` processes, one variant each (the largest variant
    sets the wall time), or ``executor`` (:class:`agents.parallel.Executor`: local processes or
    a Ray cluster), which runs the variants one after another with each variant's episodes
    spread over all of its slots. Either gives the rows of one process.
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
    unknown = [name for name in agents if name not in BASELINES and name not in SHIPPED_POLICIES]
    if unknown:
        raise ValueError(f"agents: unknown {unknown} (baselines {list(BASELINES)}, policies {list(SHIPPED_POLICIES)})")
    # before anything is written: an unknown variant leaves no folder behind
    counts = {env_id: held_out_episodes(env_id) for env_id in variants}  # checks each id is registered
    if episodes is not None:
        counts = dict.fromkeys(counts, int(episodes))
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    work = [(env_id, list(agents), counts[env_id], int(seed), folder, verbose) for env_id in variants]
    if executor is not None and executor.kind != "serial":
        tables = [benchmark_variant(*task, executor=executor) for task in work]  # a variant's episodes at once
    else:
        tables = Executor(workers=int(jobs)).map(benchmark_variant, work)  # one variant per task
    rows = [row for table in tables for row in table]
    with (folder / "leaderboard.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(LEADERBOARD_COLUMNS))
        writer.writeheader()
        writer.writerows(rows)
    meta = {"episodes": counts, "seeds": {env_id: [int(seed), int(seed) + n - 1] for env_id, n in counts.items()},
            "seif_gym": seif_gym.__version__, "rows": rows}  # fmt: skip
    (folder / "leaderboard.json").write_text(json.dumps(meta, indent=2, allow_nan=False) + "\n")
    (folder / "leaderboard.md").write_text(leaderboard_markdown(rows, seed))
    return rows


def _number(value: Any, digits: int = 3) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def leaderboard_markdown(rows: Sequence[Mapping[str, Any]], seed: int) -> str:
    """One Markdown table per variant, agents by mean final map error, with the paired verdicts."""
    lines = [f"# seif_gym {seif_gym.__version__} leaderboard", "",
             f"Held-out seeds from {seed}, the same for every agent of a variant (each variant's count below); "
             "difference: paired per-seed difference of the final map error to the best baseline, "
             "95% Student-t interval. Protocol: docs/benchmark.md.", ""]  # fmt: skip
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


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--variants", default="", help="comma-separated layouts or env ids (default: every layout)")
    parser.add_argument("--version", type=int, default=None, help="version of the layouts (default: the newest)")
    parser.add_argument(
        "--episodes",
        type=int,
        default=None,
        help=f"held-out episodes per agent and variant (default: the protocol's, {SHORT_TASK_HELD_OUT_EPISODES} on "
        f"tasks of at most {SHORT_TASK_STEPS} steps, {HELD_OUT_EPISODES} on the others)",
    )
    parser.add_argument("--seed", type=int, default=HELD_OUT_SEED, help="first held-out seed (default %(default)s)")
    parser.add_argument("--agents", default=",".join([*BASELINES, *EXPLORERS]),
                        help="comma-separated baselines and shipped policies (default: all)")  # fmt: skip
    parser.add_argument("--jobs", type=int, default=1, help="worker processes, one variant each")
    parser.add_argument("--out", default="benchmark", help="output folder (default %(default)s)")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    add_executor_arguments(parser)  # --workers / --ray: each variant's episodes spread over them
    args = parser.parse_args(argv)
    executor = executor_from_arguments(args, parser)
    try:
        names = [name.strip() for name in args.variants.split(",") if name.strip()]
        variants = _resolve_variants(names, args.version) if names else default_variants(args.version)
        agents = [name.strip() for name in args.agents.split(",") if name.strip()]
        started = time.perf_counter()
        run_benchmark(variants, agents, args.episodes, args.seed, args.out, jobs=args.jobs, verbose=not args.quiet,
                      executor=executor)  # fmt: skip
    except ValueError as error:
        parser.error(str(error))
    print((Path(args.out) / "leaderboard.md").read_text())
    if not args.quiet:
        print(f"{len(variants)} variants in {time.perf_counter() - started:.0f} s; wrote {args.out}/leaderboard.md, "
              f".csv, .json and one folder per variant", file=sys.stderr)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
