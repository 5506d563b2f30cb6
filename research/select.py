"""Choose a training run's checkpoint on the validation seeds, as the protocol says.

Usage::

    python -m research.select runs/tll2_s1 runs/tll2_s2 runs/tll2_s3 --env SeifExploreClusteredBudget-v2 --workers 2

The benchmark's protocol (``docs/benchmark/protocol.md``) lets a run's checkpoints be
compared only on the *validation* seeds (500 000 … 500 099); the held-out
seeds report the chosen one and choose nothing. This command does that step:
for every run folder it scores every candidate (each checkpoint
``rl_model_<N>_steps.zip``, the validation callback's
``best_map_error/model.zip`` and the run's final model ``<EnvId>.zip``) and
the baselines on the same validation seeds, with
:func:`agents.evaluate.evaluate_agents`, and chooses the candidate of lowest
mean final map error (ties go to the earlier checkpoint). It refuses seeds
that reach into the held-out ones. A candidate with the same policy as an
earlier one (the callback's best is often the final model or the last
checkpoint, saved again) is scored once and shares its figures.

Written, for each run, to ``RUN/selected/``: ``model.zip`` (a copy of the
chosen candidate), its normalisation statistics as ``vecnormalize.pkl``
(:mod:`agents.checkpoints` finds them there), and ``selection.json`` (what was
chosen from what, on which seeds, with the figures); and to ``--out``:
:func:`agents.evaluate.write_outputs` of the whole evaluation and
``selection.md``, one table per run with each candidate's mean and paired
difference to the best baseline. The callback's own choice rests on its 10 to
30 episodes; on 100 it is often not the best (``docs/benchmark/protocol.md``).

``--best-of-runs DIR`` also keeps one model for the runs together: the run
whose chosen candidate has the lowest validation mean (ties go to the run
given first), copied to ``DIR/selected/`` as above, its ``selection.json``
naming the runs it was chosen from. A recipe that trains several runs per
training seed and keeps the best on validation (``docs/research/experiments.md``,
"best of two runs") is this one call per training seed::

    python -m research.select runs/r2_31_a runs/r2_31_b --env SeifExploreClusteredBudget-v2 --best-of-runs runs/r2_31
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym

from agents import BASELINES
from agents.checkpoints import behaviour_fingerprint, vecnormalize_path
from agents.cli import json_object
from agents.evaluate import PAIRED_METRIC, evaluate_agents, signed, write_outputs
from agents.parallel import Executor
from agents.parallel import add_arguments as add_executor_arguments
from agents.parallel import from_arguments as executor_from_arguments
from agents.protocol import HELD_OUT_SEEDS, VALIDATION_EPISODES, VALIDATION_SEED
from seif_gym.validation import as_count

__all__ = [
    "Candidate",
    "best_of_runs",
    "candidates",
    "main",
    "save_selected",
    "select_checkpoints",
    "selection_table",
]

_CHECKPOINT = re.compile(r"rl_model_(?P<steps>\d+)_steps\.zip")


@dataclass(frozen=True)
class Candidate:
    """A saved model of a run that may be chosen.

    Attributes
    ----------
    label : str
        ``<run folder name>:<name>``: ``…:50000`` for a checkpoint, ``…:best`` for the
        callback's best, ``…:final`` for the final model.
    path : Path
        The model's ``.zip``.
    steps : int or None
        Training steps of a checkpoint (``None`` for the other two).
    """

    label: str
    path: Path
    steps: int | None


def candidates(run: str | Path) -> list[Candidate]:
    """The models of run folder ``run``: checkpoints by steps, then the callback's best, then the final model.

    Raises
    ------
    TypeError
        If ``run`` is not a path.
    ValueError
        If ``run`` is not a folder, or holds no model.
    """
    if not isinstance(run, (str, Path)):
        raise TypeError(f"run must be a path, got {type(run).__name__}")
    folder = Path(run)
    if not folder.is_dir():
        raise ValueError(f"run: {str(folder)!r} is not a folder")
    name = folder.name
    found: list[Candidate] = []
    checkpoints = [
        (int(m["steps"]), p) for p in folder.glob("rl_model_*_steps.zip") if (m := _CHECKPOINT.fullmatch(p.name))
    ]
    for steps, path in sorted(checkpoints):
        found.append(Candidate(f"{name}:{steps}", path, steps))
    best = folder / "best_map_error" / "model.zip"
    if best.is_file():
        found.append(Candidate(f"{name}:best", best, None))
    finals = sorted(p for p in folder.glob("*.zip") if not _CHECKPOINT.fullmatch(p.name))
    for path in finals:  # rl-zoo3's <EnvId>.zip (one per run)
        found.append(Candidate(f"{name}:final" if len(finals) == 1 else f"{name}:{path.stem}", path, None))
    if not found:
        raise ValueError(f"run: {str(folder)!r} holds no model (rl_model_<N>_steps.zip, best_map_error/, <EnvId>.zip)")
    return found


def _check_seeds(seed: int, episodes: int) -> None:
    as_count(seed, "seed")
    as_count(episodes, "episodes", minimum=1)
    if seed < HELD_OUT_SEEDS.stop and seed + episodes > HELD_OUT_SEEDS.start:
        raise ValueError(
            f"seed: {seed}…{seed + episodes - 1} reaches into the held-out seeds {HELD_OUT_SEEDS.start}…"
            f"{HELD_OUT_SEEDS.stop - 1}, which choose nothing (docs/benchmark/protocol.md)"
        )


def select_checkpoints(
    runs: Sequence[str | Path],
    env_id: str,
    env_kwargs: Mapping[str, Any] | None = None,
    *,
    episodes: int = VALIDATION_EPISODES,
    seed: int = VALIDATION_SEED,
    baselines: Sequence[str] = ("info_gain",),
    executor: Executor | None = None,
    verbose: bool = False,
) -> tuple[dict[str, dict[str, Any]], list[dict[str, Any]], dict[str, Any]]:
    """Score every candidate of every run on the seeds ``seed … seed + episodes − 1`` and choose one per run.

    Parameters
    ----------
    runs : sequence of path
        Run folders of ``agents.train`` (or rl-zoo3), each with at least one model.
    env_id : str
        The task the models are chosen for (it need not be the one they trained on).
    env_kwargs : mapping, optional
        Keyword arguments of ``gym.make``.
    episodes, seed : int
        The validation seeds (default: the protocol's 100 from 500 000); they may not reach into
        the held-out seeds.
    baselines : sequence of str
        Baselines run on the same seeds; the best of them is the reference of the paired differences.
    executor : agents.parallel.Executor, optional
        Where the episodes run.
    verbose : bool
        Progress on stderr.

    Returns
    -------
    selection : dict
        Run folder -> ``{"chosen", "path", "steps", "mean", "candidates": {label: mean}, "paired",
        "same_as"}``; ``same_as`` maps each candidate that acts exactly as an earlier one
        (:func:`agents.checkpoints.behaviour_fingerprint`: the same weights, policy and observation
        normalisation) to that one, whose episodes it shares: it is scored once, and since equal
        means go to the earlier candidate the choice is the one scoring both would make.
    rows, summary
        :func:`agents.evaluate.evaluate_agents`' results of every candidate and baseline.

    Raises
    ------
    TypeError, ValueError
        On a bad argument (named), before any episode runs: a run folder without models, the same
        folder twice, an unknown baseline or env id, seeds in the held-out range, a candidate that
        is not a saved SB3 model.
    """
    _check_seeds(seed, episodes)
    if not isinstance(env_id, str):
        raise TypeError(f"env_id must be a registered env id, got {type(env_id).__name__}")
    if env_id.split(":")[-1] not in gym.registry:
        raise ValueError(f"env_id: unknown env {env_id!r}")
    if isinstance(baselines, str) or not baselines or not all(b in BASELINES for b in baselines):
        raise ValueError(f"baselines must be one or more names of {BASELINES}, got {baselines!r}")
    per_run = {str(run): candidates(run) for run in runs}
    if len({Path(r).resolve() for r in runs}) != len(runs):
        raise ValueError(f"runs: a folder is given twice: {[str(r) for r in runs]}")
    everyone = [c for found in per_run.values() for c in found]
    labels = [c.label for c in everyone]
    if len(set(labels)) != len(labels):
        raise ValueError("runs: two run folders have the same name; their candidates' labels would clash")
    if any("=" in label or "," in label for label in labels):
        raise ValueError("runs: a run folder's name holds '=' or ',', which agent specs reserve")
    # a candidate that acts as an earlier one (the callback's best is often the final model) is scored once
    first_of: dict[str, str] = {}
    same_as: dict[str, str] = {}
    for c in everyone:
        same_as[c.label] = first_of.setdefault(behaviour_fingerprint(c.path), c.label)
    scored = [c for c in everyone if same_as[c.label] == c.label]
    specs = [*baselines, *(f"{c.label}={c.path}" for c in scored)]
    rows, summary = evaluate_agents(specs, episodes, seed, env_id, env_kwargs, verbose=verbose, executor=executor)
    rows, summary = _with_duplicates(rows, summary, everyone, same_as, baselines)
    means = {label: float(entry[PAIRED_METRIC]["mean"]) for label, entry in summary["agents"].items()}
    paired = summary["paired"]["agents"]
    selection: dict[str, dict[str, Any]] = {}
    for run, found in per_run.items():
        # the lowest mean; on a tie the first in candidates' order (the earlier checkpoint)
        chosen = min(found, key=lambda c: means[c.label])
        selection[run] = {
            "chosen": chosen.label,
            "path": str(chosen.path),
            "steps": chosen.steps,
            "mean": means[chosen.label],
            "candidates": {c.label: means[c.label] for c in found},
            "paired": paired.get(chosen.label),
            "same_as": {c.label: same_as[c.label] for c in found if same_as[c.label] != c.label},
        }
    return selection, rows, summary


def _with_duplicates(
    rows: list[dict[str, Any]],
    summary: dict[str, Any],
    everyone: Sequence[Candidate],
    same_as: Mapping[str, str],
    baselines: Sequence[str],
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """``rows`` and ``summary`` with every candidate, a duplicate carrying the figures of the one it acts as.

    Rows and agents come in the order: baselines, then the candidates in ``everyone``'s order (the
    order a run without duplicates is scored in), so the outputs keep their form; which candidate
    was scored for which is in the selection's ``same_as``.
    """
    by_agent: dict[str, list[dict[str, Any]]] = {}
    for row in rows:
        by_agent.setdefault(row["agent"], []).append(row)
    labels = [*baselines, *(c.label for c in everyone)]
    source = {label: same_as.get(label, label) for label in labels}
    all_rows = [{**row, "agent": label} for label in labels for row in by_agent[source[label]]]
    specs = {c.label: f"{c.label}={c.path}" for c in everyone}
    agents = {
        label: {**summary["agents"][source[label]], **({"spec": specs[label]} if source[label] != label else {})}
        for label in labels
    }
    paired_agents = summary["paired"]["agents"]
    paired = {
        **summary["paired"],
        "agents": {label: paired_agents[source[label]] for label in labels if source[label] in paired_agents},
    }
    return all_rows, {**summary, "agents": agents, "paired": paired}


def best_of_runs(selection: Mapping[str, Mapping[str, Any]]) -> tuple[str, Mapping[str, Any]]:
    """The run of ``selection`` (:func:`select_checkpoints`' first result) whose chosen candidate is lowest.

    Ties go to the run that comes first in ``selection`` (the order the runs were given).

    Raises
    ------
    TypeError
        If ``selection`` is not a mapping.
    ValueError
        If ``selection`` is empty, or a run's entry has no ``"mean"``.
    """
    if not isinstance(selection, Mapping):
        raise TypeError(f"selection must be a mapping of run -> choice, got {type(selection).__name__}")
    missing = [run for run, choice in selection.items() if "mean" not in choice]
    if missing:
        raise ValueError(f"selection: no validation mean for {missing}")
    if not selection:
        raise ValueError("selection: no run to choose from")
    return min(selection.items(), key=lambda item: item[1]["mean"])  # min keeps the first of equal means


def save_selected(run: str | Path, choice: Mapping[str, Any], provenance: Mapping[str, Any]) -> Path:
    """Copy the chosen model (and its statistics) to ``run/selected/`` with ``selection.json``; returns the model.

    The folder is written whole beside the old one and then put in its place, so a failure
    midway leaves the earlier choice as it was, and no file of it survives a new choice.
    """
    folder = Path(run) / "selected"
    partial = Path(run) / ".selected.partial"
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir()
    source = Path(choice["path"])
    shutil.copyfile(source, partial / "model.zip")
    stats = vecnormalize_path(source)
    if stats is not None:
        shutil.copyfile(stats, partial / "vecnormalize.pkl")
    record = {**provenance, **choice, "statistics": None if stats is None else str(stats)}
    (partial / "selection.json").write_text(json.dumps(record, indent=2, allow_nan=False) + "\n")
    # swap by renames only: a deletion that fails halfway would leave half of the earlier choice
    previous = Path(run) / ".selected.previous"
    shutil.rmtree(previous, ignore_errors=True)
    if folder.exists():
        folder.rename(previous)
    try:
        partial.rename(folder)
    except OSError:
        if previous.exists():
            previous.rename(folder)
        raise
    shutil.rmtree(previous, ignore_errors=True)
    return folder / "model.zip"


def selection_table(selection: Mapping[str, Mapping[str, Any]], summary: Mapping[str, Any]) -> str:
    """Markdown: per run, each candidate's mean final map error and paired difference to the best baseline."""
    paired = summary["paired"]
    reference = paired["reference"]
    reference_mean = summary["agents"][reference][PAIRED_METRIC]["mean"]
    lines = []
    for run, choice in selection.items():
        lines += [
            f"### {run}",
            "",
            f"| candidate | final map error (m) | − {reference} ({reference_mean:.3f}), paired 95% | verdict |",
            "|---|--:|--:|---|",
        ]
        for label, mean in choice["candidates"].items():
            p = paired["agents"][label]
            mark = " (chosen)" if label == choice["chosen"] else ""
            if label in choice.get("same_as", {}):
                mark += f" (the policy of {choice['same_as'][label]}: scored once)"
            interval = f"{signed(p['mean'])} [{signed(p['ci95_low'])}, {signed(p['ci95_high'])}]"
            lines.append(f"| {label}{mark} | {mean:.3f} | {interval} | {p['verdict']} |")
        lines.append("")
    return "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m research.select",
        description="Score every checkpoint of training runs on the validation seeds and choose one per run.",
    )
    parser.add_argument("runs", nargs="+", help="run folders (agents.train --out)")
    parser.add_argument("--env", required=True, help="the task to choose for (a registered env id)")
    parser.add_argument(
        "--env-kwargs", type=json_object, default="{}", help="JSON object of gym.make keyword arguments"
    )
    parser.add_argument("--episodes", type=int, default=VALIDATION_EPISODES, help="validation episodes (default 100)")
    parser.add_argument(
        "--seed", type=int, default=VALIDATION_SEED, help=f"first validation seed (default {VALIDATION_SEED})"
    )
    parser.add_argument(
        "--baselines", default="info_gain", help="comma-separated baselines to pair with (default info_gain)"
    )
    parser.add_argument("--out", default="selection", help="folder of the evaluation's outputs (default ./selection)")
    parser.add_argument(
        "--best-of-runs",
        default=None,
        metavar="DIR",
        help="also copy the lowest of the runs' chosen models to DIR/selected/ (one model for all the runs)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    add_executor_arguments(parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    baselines = [b.strip() for b in args.baselines.split(",") if b.strip()]
    if args.best_of_runs is not None and Path(args.best_of_runs).resolve() in {Path(r).resolve() for r in args.runs}:
        parser.error("--best-of-runs: the folder must not be one of the runs")  # before any worker starts
    executor = executor_from_arguments(args, parser)
    started = time.perf_counter()
    try:
        selection, rows, summary = select_checkpoints(
            args.runs, args.env, args.env_kwargs, episodes=args.episodes, seed=args.seed, baselines=baselines,
            executor=executor, verbose=not args.quiet,
        )  # fmt: skip
    except (TypeError, ValueError) as error:
        parser.error(str(error))
    write_outputs(rows, summary, args.out)
    table = selection_table(selection, summary)
    Path(args.out, "selection.md").write_text(table + "\n")
    provenance = {
        "env_id": args.env,
        "env_kwargs": args.env_kwargs,
        "seeds": [args.seed, args.seed + args.episodes - 1],
    }
    print(f"{args.env}, validation seeds {args.seed}..{args.seed + args.episodes - 1}\n\n{table}")
    for run, choice in selection.items():
        print(f"{run}: chose {choice['chosen']} -> {save_selected(run, choice, provenance)}")
    if args.best_of_runs is not None:
        best_run, best = best_of_runs(selection)
        Path(args.best_of_runs).mkdir(parents=True, exist_ok=True)
        kept = save_selected(args.best_of_runs, best, {**provenance, "runs": list(selection), "run": best_run})
        print(f"best of the runs: {best['chosen']} ({best['mean']:.3f}) -> {kept}")
    print(f"wrote {args.out}/ in {time.perf_counter() - started:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
