r"""Judge a training recipe by its models, one per training seed: ``python -m research.recipe``.

Usage::

    python -m research.recipe --runs runs/e9_held_out runs/eval_base_clu400 \
        --members s120,s121,s122,s123,s124,s125 [--baselines frontier,revisit,info_gain] [--out DIR]

``--runs`` are ``agents.evaluate --out`` folders of one env, env kwargs and
seeds (the recipe's models in one, the baselines' stored episodes in another,
say; no label may appear in two). ``--members`` are the labels of the
recipe's models, one per training seed. The best baseline on these episodes
(lowest mean final map error; by default among every baseline name found in
the runs) is the reference. Printed and written to ``--out`` as
``recipe.md`` and ``recipe.json`` (:func:`agents.evaluate.recipe_comparison`):

* each model against the reference on its own (the paired per-episode
  interval of :func:`agents.evaluate.paired_difference`), with the spread of
  the models' means;
* the recipe against the reference and against every other baseline: the
  mean difference over the models and episodes with the interval of
  :func:`agents.evaluate.recipe_difference`, which treats training seeds and
  episodes as crossed random draws. The protocol's rule for a recipe
  (``docs/benchmark/protocol.md``, "What counts as a result") reads this interval.

Nothing runs here: the episodes are the runs' own.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from agents import BASELINES
from agents.evaluate import PAIRED_METRIC, load_stored_run, read_run, recipe_comparison, signed, signed_interval

__all__ = ["load_runs", "judge_recipe", "recipe_table", "main"]


def load_runs(folders: Sequence[str | Path]) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The rows of several ``agents.evaluate --out`` folders of one task and the same seeds.

    Parameters
    ----------
    folders : sequence of str or Path
        At least one folder (:func:`agents.evaluate.read_run`).

    Returns
    -------
    rows : list of dict
        Every folder's rows, in the order given.
    task : dict
        ``env_id``, ``env_kwargs`` and ``seeds`` the folders share.

    Raises
    ------
    ValueError
        If no folder is given, a folder cannot be read, one differs from the
        first in env id, env arguments or seeds, lacks episodes of one of its
        agents, or repeats a label of one before it
        (:func:`agents.evaluate.load_stored_run`).
    """
    if not folders:
        raise ValueError("runs: give at least one agents.evaluate --out folder")
    _, first = read_run(folders[0], "runs")
    task: dict[str, Any] = {key: first.get(key) for key in ("env_id", "env_kwargs", "seeds")}
    rows: list[dict[str, Any]] = []
    for folder in folders:  # each checked against the first, and its labels against those before it
        folder_rows, _ = load_stored_run(folder, task["env_id"], task["env_kwargs"], task["seeds"],
                                         [row["agent"] for row in rows], name="runs")  # fmt: skip
        rows.extend(folder_rows)
    return rows, task


def judge_recipe(rows: Sequence[Mapping[str, Any]], members: Sequence[str], baselines: Sequence[str] | None = None,
                 metric: str = PAIRED_METRIC) -> dict[str, Any]:  # fmt: skip
    """:func:`agents.evaluate.recipe_comparison`, the baselines by default every name of :data:`agents.BASELINES` in ``rows``."""
    present = {row["agent"] for row in rows}
    chosen = [name for name in BASELINES if name in present] if baselines is None else list(baselines)
    return recipe_comparison(rows, members, chosen, metric)


def recipe_table(result: Mapping[str, Any], digits: int = 3) -> str:
    """Markdown: each model against the reference, then the recipe against every baseline."""
    reference = result["reference"]
    lines = [f"| model | mean | − {reference}, paired 95% | verdict |", "|---|--:|--:|---|"]
    for label, paired in result["members"].items():
        mean = result["spread"]["members"][label]
        interval = signed_interval(paired["ci95_low"], paired["ci95_high"], digits)
        lines.append(f"| {label} | {mean:.{digits}f} | {signed(paired['mean'], digits)} {interval} | "
                     f"{paired['verdict']} |")  # fmt: skip
    recipe = result["recipe"]
    beating = sum(paired["verdict"] == "beats" for paired in result["members"].values())
    spread = result["spread"]
    lines += ["", f"{beating} of {len(result['members'])} models beat {reference} on their own; their means "
              f"{spread['low']:.{digits}f}–{spread['high']:.{digits}f} (mean {spread['mean']:.{digits}f}).", "",
              f"| recipe against | difference over {recipe['n_seeds']} seeds × {recipe['n_episodes']} episodes, "
              "95% | sd of seed means | sd of episode means | dof | verdict |", "|---|--:|--:|--:|--:|---|"]  # fmt: skip
    for name, difference in result["against"].items():
        interval = signed_interval(difference["ci95_low"], difference["ci95_high"], digits)
        dof = "n/a" if difference["dof"] is None else f"{difference['dof']:.1f}"  # None: every cell the same
        lines.append(f"| {name}{' (best)' if name == reference else ''} | {signed(difference['mean'], digits)} "
                     f"{interval} | {difference['std_seeds']:.{digits}f} | {difference['std_episodes']:.{digits}f} | "
                     f"{dof} | {difference['verdict']} |")  # fmt: skip
    return "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m research.recipe",
                                     description="Judge a training recipe by its models, one per training seed, "
                                     "against the best baseline on the same episodes.")  # fmt: skip
    parser.add_argument("--runs", nargs="+", required=True, metavar="DIR",
                        help="agents.evaluate --out folders of one env, env kwargs and seeds")  # fmt: skip
    parser.add_argument("--members", required=True, help="comma-separated labels of the recipe's models")
    parser.add_argument("--baselines", default=None,
                        help="comma-separated baselines (default: every baseline name in the runs)")  # fmt: skip
    parser.add_argument("--out", default=None, metavar="DIR", help="also write recipe.md and recipe.json here")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    members = [label.strip() for label in args.members.split(",") if label.strip()]
    baselines = None if args.baselines is None else [b.strip() for b in args.baselines.split(",") if b.strip()]
    try:
        rows, task = load_runs(args.runs)
        result = judge_recipe(rows, members, baselines)
    except (ValueError, FileNotFoundError, TypeError) as error:
        parser.error(str(error))
    table = recipe_table(result)
    kwargs = f" {json.dumps(task['env_kwargs'])}" if task["env_kwargs"] else ""
    header = f"{task['env_id']}{kwargs}, {len(task['seeds'])} episodes, final map error (m)\n"
    print(header)
    print(table)
    if args.out is not None:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "recipe.md").write_text(header + "\n" + table + "\n")
        (out / "recipe.json").write_text(
            json.dumps({**task, "runs": [str(r) for r in args.runs], **result}, indent=2, allow_nan=False) + "\n"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
