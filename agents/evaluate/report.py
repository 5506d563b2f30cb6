"""An evaluation's files: the tables, the plot, ``write_outputs`` and reading a stored run back.

The files and their schema are described in :mod:`agents.evaluate`.
"""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluate.journal import JOURNAL, forget_manifest, read_manifest, write_manifest
from agents.evaluate.schema import INTEGER_COLUMNS, READABLE_SCHEMA_VERSIONS, RESULT_COLUMNS, TABLE_COLUMNS
from seif_gym._atomic import atomic_write, atomic_write_bytes, atomic_write_text

__all__ = [
    "load_stored_run",
    "markdown_table",
    "paired_table",
    "plot_map_error",
    "read_run",
    "save_figure",
    "signed",
    "signed_interval",
    "write_outputs",
]


def _format(stat: Mapping[str, Any], digits: int = 3) -> str:
    mean, half = stat["mean"], stat["ci95_half_width"]
    if mean is None:
        return "n/a"
    return f"{mean:.{digits}f}" if half is None else f"{mean:.{digits}f} ± {half:.{digits}f}"


def markdown_table(summary: Mapping[str, Any]) -> str:
    """The means ± 95 % CI half-widths of ``summary``, one row per agent, as a Markdown table.

    Parameters
    ----------
    summary : mapping
        :func:`~agents.evaluate.rollout.evaluate_agents`' summary.

    Returns
    -------
    str
        A header, then one row per agent: the columns of
        :data:`~agents.evaluate.schema.TABLE_COLUMNS`.
    """
    headers = ["agent", *(header for _, header in TABLE_COLUMNS)]
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join(["---"] + ["--:"] * len(TABLE_COLUMNS)) + "|"]
    for label, entry in summary["agents"].items():
        digits = {"length": 1, "wall_contacts": 1, "landmarks_mapped": 1, "decision_time_ms": 2, "diverged": 2}
        cells = [_format(entry[metric], digits.get(metric, 3)) for metric, _ in TABLE_COLUMNS]
        lines.append("| " + " | ".join([label, *cells]) + " |")
    return "\n".join(lines)


def signed(value: float | None, digits: int = 3) -> str:
    """``value`` with its sign (``+0.012``), or ``n/a`` for ``None``."""
    return "n/a" if value is None else f"{value:+.{digits}f}"


def signed_interval(low: float | None, high: float | None, digits: int = 3) -> str:
    """``[−0.070, −0.003]``, or ``n/a`` without an interval."""
    return "n/a" if low is None or high is None else f"[{signed(low, digits)}, {signed(high, digits)}]"


def paired_table(summary: Mapping[str, Any], digits: int = 3) -> str:
    """The paired comparison of ``summary`` as a sentence and a Markdown table.

    Parameters
    ----------
    summary : mapping
        :func:`~agents.evaluate.rollout.evaluate_agents`' summary; its ``paired`` entry
        (:func:`~agents.evaluate.statistics.paired_comparison`) is shown.
    digits : int
        Decimals of the differences.

    Returns
    -------
    str
        Empty when there is no reference (no baseline among the agents).
    """
    paired = summary.get("paired") or {}
    reference = paired.get("reference")
    if reference is None or not paired.get("agents"):
        return ""
    seeds = summary["seeds"]
    level = f"{100 * paired['confidence']:g}%"
    bootstrap = int(paired.get("bootstrap") or 0)
    lines = [
        f"Paired per-seed differences of {paired['metric'].replace('_', ' ')} to the best baseline, {reference} "
        f"(every agent on the same seeds {seeds[0]}..{seeds[-1]}; mean difference with its {level} Student-t interval"
        + (f", and a {level} percentile bootstrap interval of {bootstrap} resamples" if bootstrap else "")
        + "; negative is better; an agent beats the reference only when the t interval lies below 0)",
        "",
        "| agent | mean difference | t interval | " + ("bootstrap interval | " if bootstrap else "") + "verdict |",
        "|---|--:|--:|" + ("--:|" if bootstrap else "") + "---|",
    ]
    for label, entry in paired["agents"].items():
        cells = [label, signed(entry["mean"], digits), signed_interval(entry["ci95_low"], entry["ci95_high"], digits)]
        if bootstrap:
            cells.append(signed_interval(entry["bootstrap_ci95_low"], entry["bootstrap_ci95_high"], digits))
        verdict = entry["verdict"]
        cells.append(f"{verdict} {reference}" if verdict in ("beats",) else verdict)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_outputs(
    rows: Sequence[Mapping[str, Any]],
    summary: Mapping[str, Any],
    out: str | os.PathLike,
    *,
    command: str = "agents.evaluate",
    config: Mapping[str, Any] | None = None,
    manifest: bool = True,
) -> dict[str, Path]:
    """Write ``results.csv``, ``summary.json``, ``summary.md`` and ``map_error.png`` into ``out``, then ``manifest.json``.

    Every file is written whole or not at all (:mod:`seif_gym._atomic`); the folder's manifest is
    deleted first and written last (:func:`~agents.evaluate.journal.write_manifest`), so that the folder
    reads as a finished run (:func:`read_run`) only once every file is there.

    Parameters
    ----------
    rows, summary
        :func:`~agents.evaluate.rollout.evaluate_agents`' results (the files' schema: :mod:`agents.evaluate`).
    out : str or PathLike
        The folder, created if missing; files of the same names are replaced.
    command : str
        The command named by the manifest.
    config : mapping, optional
        The run's configuration in the manifest; default the summary's task, seeds and agents.
    manifest : bool
        Write the manifest (``False``: the caller writes it after files of its own).

    Returns
    -------
    dict
        ``{"csv", "json", "markdown", "plot"}`` (and ``"manifest"``) -> path written.

    Raises
    ------
    ValueError
        If the summary holds a number JSON cannot write (``nan``, ``inf``), before any file is replaced.
    """
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    forget_manifest(folder)
    paths = {
        "csv": folder / "results.csv",
        "json": folder / "summary.json",
        "markdown": folder / "summary.md",
        "plot": folder / "map_error.png",
    }
    text = json.dumps(summary, indent=2, allow_nan=False) + "\n"  # refused before any file is touched
    handle = io.StringIO(newline="")
    writer = csv.DictWriter(handle, fieldnames=list(RESULT_COLUMNS))
    writer.writeheader()
    for row in rows:
        writer.writerow({column: row[column] for column in RESULT_COLUMNS})
    atomic_write_bytes(paths["csv"], handle.getvalue().encode())
    atomic_write_text(paths["json"], text)
    paired = paired_table(summary)
    atomic_write_text(paths["markdown"], markdown_table(summary) + "\n" + (f"\n{paired}\n" if paired else ""))
    plot_map_error(summary, paths["plot"])
    if manifest:
        if config is None:
            config = {"env_id": summary["env_id"], "env_kwargs": summary["env_kwargs"], "seeds": summary["seeds"],
                      "agents": {label: entry["spec"] for label, entry in summary["agents"].items()}}  # fmt: skip
        paths["manifest"] = write_manifest(folder, list(paths.values()), command, config)
    return paths


def save_figure(figure: Any, path: str | os.PathLike) -> Path:
    """Save a matplotlib ``figure`` to ``path`` whole or not at all, in the format of ``path``'s suffix (``png``).

    Returns
    -------
    Path
        ``path``.
    """
    kind = Path(path).suffix.lstrip(".").lower() or "png"
    return atomic_write(path, lambda temporary: figure.savefig(temporary, format=kind))


def plot_map_error(summary: Mapping[str, Any], path: str | os.PathLike) -> None:
    """Mean map error over time per agent, with the 95 % band, saved to ``path`` (any format matplotlib writes).

    Parameters
    ----------
    summary : mapping
        Needs ``env_id``, ``episodes`` and every agent's ``map_error_over_time``.
    path : str or PathLike
        The image's path; its suffix picks the format.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4), dpi=120)
    for label, entry in summary["agents"].items():
        curve = entry["map_error_over_time"]
        steps = np.asarray(curve["step"])
        line = ax.plot(steps, curve["mean"], label=label)[0]
        if curve["ci95_low"] and curve["ci95_low"][0] is not None:
            ax.fill_between(
                steps, curve["ci95_low"], curve["ci95_high"], color=line.get_color(), alpha=0.2, linewidth=0
            )
    ax.set_xlabel("step")
    ax.set_ylabel("map error (m)")
    ax.set_title(f"{summary['env_id']}: mean map error, 95% CI ({summary['episodes']} episodes)")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    try:
        save_figure(fig, path)
    finally:
        plt.close(fig)


def _seed_range(seeds: Any) -> str:
    """``first..last (n seeds)`` of a list of seeds, else its repr."""
    if isinstance(seeds, list) and seeds:
        return f"{seeds[0]}..{seeds[-1]} ({len(seeds)} seeds)"
    return repr(seeds)


def load_stored_run(
    folder: str | os.PathLike,
    env_id: str,
    env_kwargs: Mapping[str, Any],
    seeds: Sequence[int],
    labels: Sequence[str] = (),
    name: str = "stored_run",
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The episodes of an earlier run (an ``--out`` folder of this command), checked to be of the same task.

    Lets a run pair its agents with agents already run on the same seeds (the
    baselines' held-out episodes of a declared experiment, say) instead of
    running them again. On one machine an episode is determined by the env,
    its arguments, the agent and the seed, so the stored ones are what a new
    run there would give (another machine may round a planner's near-tie
    differently: ``docs/benchmark/protocol.md``).

    Parameters
    ----------
    folder : str or PathLike
        Holds ``results.csv`` and ``summary.json`` of the earlier run.
    env_id, env_kwargs, seeds
        This run's: the stored run must have been made with the same ones, in
        a schema of :data:`~agents.evaluate.schema.READABLE_SCHEMA_VERSIONS` (:func:`read_run`).
    labels : sequence of str
        This run's agent labels, which the stored run's may not repeat.
    name : str
        The start of every error message, as in :func:`read_run`.

    Returns
    -------
    rows : list of dict
        Its ``results.csv`` rows (keys :data:`~agents.evaluate.schema.RESULT_COLUMNS`, typed as written).
    agents : dict
        Its ``summary.json["agents"]`` entries (label -> :data:`~agents.evaluate.schema.AGENT_KEYS`).

    Raises
    ------
    TypeError, FileNotFoundError
        As :func:`read_run`.
    ValueError
        As :func:`read_run`, and if the stored run's env id, env arguments or
        seeds differ from this run's, its rows do not cover every agent on
        every seed, or its labels repeat one of ``labels``.
    """
    rows, stored = read_run(folder, name)
    path = Path(folder)
    expected_seeds = [int(seed) for seed in seeds]
    checks: dict[str, Any] = {"env_id": env_id, "env_kwargs": dict(env_kwargs), "seeds": expected_seeds}
    for key, expected in checks.items():
        found = stored.get(key)
        if found != expected:
            if key == "seeds":  # a range, not a thousand numbers
                expected, found = _seed_range(expected), _seed_range(found)
            raise ValueError(f"{name}: {path} was made with {key} {found!r}, this run has {expected!r}")
    agents = stored["agents"]
    repeated = sorted(set(agents) & set(labels))
    if repeated:
        raise ValueError(f"{name}: {path} already has the agents {repeated}: label this run's otherwise")
    for label in agents:
        if sorted(row["seed"] for row in rows if row["agent"] == label) != sorted(expected_seeds):
            raise ValueError(f"{name}: {path / 'results.csv'} lacks episodes of {label!r} on this run's seeds")
    return rows, agents


def read_run(folder: str | os.PathLike, name: str = "folder") -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The rows and summary of an ``--out`` folder of this command, as written (schemas :data:`~agents.evaluate.schema.READABLE_SCHEMA_VERSIONS`).

    Parameters
    ----------
    folder : str or PathLike
        Holds ``results.csv`` and ``summary.json``.
    name : str
        What the folder is to the caller, the start of every error message.

    Returns
    -------
    rows : list of dict
        The ``results.csv`` rows (keys :data:`~agents.evaluate.schema.RESULT_COLUMNS`, typed as written).
    summary : dict
        ``summary.json``.

    Raises
    ------
    TypeError
        If ``folder`` is not a path.
    FileNotFoundError
        If either file is missing.
    ValueError
        If either file cannot be read as this command writes it, or its schema
        is not one of :data:`~agents.evaluate.schema.READABLE_SCHEMA_VERSIONS`;
        :class:`~agents.evaluate.journal.UnfinishedRunError` if the folder holds no
        ``manifest.json`` (:func:`~agents.evaluate.journal.read_manifest`: the run was killed
        before its end, is still running, or was written before the manifests).
    """
    if not isinstance(folder, (str, os.PathLike)):
        raise TypeError(f"{name} must be a folder's path, got {type(folder).__name__}")
    path = Path(folder)
    summary_path, results_path = path / "summary.json", path / "results.csv"
    for needed in (summary_path, results_path):
        if not needed.is_file() and not (path / JOURNAL).is_dir():
            raise FileNotFoundError(f"{name}: {needed} does not exist (an agents.evaluate --out folder?)")
    read_manifest(path, name)  # a run killed before its end is not read as one
    try:
        summary = json.loads(summary_path.read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{name}: {summary_path} is not JSON ({error})") from error
    if not isinstance(summary, dict) or summary.get("schema_version") not in READABLE_SCHEMA_VERSIONS:
        found = summary.get("schema_version") if isinstance(summary, dict) else None
        raise ValueError(f"{name}: {path} was made with schema_version {found!r}, "
                         f"this command reads {READABLE_SCHEMA_VERSIONS}")  # fmt: skip
    with open(results_path, newline="") as handle:
        reader = csv.DictReader(handle)
        if tuple(reader.fieldnames or ()) != RESULT_COLUMNS:
            raise ValueError(f"{name}: {results_path} does not have the columns {RESULT_COLUMNS}")
        try:
            rows = [{column: value if column == "agent" else int(value) if column in INTEGER_COLUMNS else float(value)
                     for column, value in row.items()} for row in reader]  # fmt: skip
        except (TypeError, ValueError) as error:
            raise ValueError(f"{name}: {results_path} holds a value this command does not write ({error})") from error
    return rows, summary
