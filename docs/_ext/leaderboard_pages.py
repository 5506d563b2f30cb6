"""The leaderboard pages, written at build time from the json files ``python -m agents.benchmark`` writes.

``leaderboard_pages`` (conf.py) lists the pages, each a mapping of paths relative
to ``docs/``: ``json`` (the run), ``page`` (the page to write), ``intro`` and,
optionally, ``after`` (hand-written Markdown included above and below the
tables). Each page gets one table per task (the columns of the benchmark's
own ``leaderboard.md``: final map error with its 95% interval, pose RMSE,
landmarks mapped, the paired difference to the best baseline and the
verdict), a line saying which agents beat the best baseline, the seeds and
episode counts of the run and the seif_gym version it ran, from the json. The
intro says what the run was, on which commit, what changed; ``after`` holds
what is not in the json (a task measured apart from the run). Under each table
a plot drawn from the same rows (:func:`plot_task`: every agent's final map
error with its 95% interval, baselines and learned policies told apart, the
best baseline's mean as a line), and the run's map error over time,
``docs/images/leaderboard/<id>_map_error.png``, where that file exists.

The pages are generated and kept out of git; the json files are the record.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from sphinx.application import Sphinx
from sphinx.errors import ExtensionError

COLUMNS = (
    "agent",
    "final map error (m)",
    "pose RMSE (m)",
    "landmarks mapped",
    "difference to best baseline (m)",
    "verdict",
)


def signed(value: float) -> str:
    return f"{value:+.3f}"


def row_cells(row: dict[str, Any]) -> list[str]:
    """A leaderboard row's cells, formatted as ``agents.benchmark`` formats its Markdown table."""
    if row.get("difference") is None:
        difference = ""
    else:
        low, high = row["difference_ci95_low"], row["difference_ci95_high"]
        difference = f"{signed(row['difference'])} [{signed(low)}, {signed(high)}]"
    return [
        str(row["agent"]),
        f"{row['final_map_error']:.3f} ± {row['final_map_error_ci95']:.3f}",
        f"{row['pose_rmse']:.3f}",
        f"{row['landmarks_mapped']:.1f}",
        difference,
        str(row["verdict"]),
    ]


def table(rows: list[dict[str, Any]]) -> str:
    lines = ["| " + " | ".join(COLUMNS) + " |", "|---|--:|--:|--:|--:|---|"]
    lines += ["| " + " | ".join(row_cells(row)) + " |" for row in rows]
    return "\n".join(lines)


def seeds_line(seeds: Any, episodes: int | None) -> str:
    if isinstance(seeds, list | tuple) and len(seeds) == 2:
        span = f"Seeds {seeds[0]}…{seeds[1]}"
    else:
        span = "Held-out seeds"
    return f"{span}, {episodes} episodes per agent." if episodes else f"{span}."


def per_task(value: Any, env_id: str) -> Any:
    """A json field that is either one value for every task (older runs) or a mapping id -> value."""
    return value.get(env_id) if isinstance(value, dict) else value


def verdict_line(rows: list[dict[str, Any]]) -> str:
    best = next((row["agent"] for row in rows if row.get("verdict") == "best baseline"), None)
    if best is None:
        return ""
    beating = [f"`{row['agent']}`" for row in rows if str(row.get("verdict", "")).startswith("beats")]
    if beating:
        return f"**Verdict:** {', '.join(beating)} beat{'s' if len(beating) == 1 else ''} the best baseline, `{best}`."
    return f"**Verdict:** no agent beats the best baseline, `{best}`."


def page(data: dict[str, Any], intro: str | None, docs: Path, page_dir: Path, after: str | None = None) -> str:
    """The Markdown of one leaderboard page."""
    version = data.get("seif_gym", "?")
    rows = data.get("rows", [])
    tasks = list(dict.fromkeys(row["env_id"] for row in rows))
    out = [f"# Leaderboard (seif_gym {version})", ""]
    if intro is not None:
        out += ["```{include} " + intro, "```", ""]
    out += [
        f"Run with seif_gym {version}. Held-out seeds, the same for every agent of a task; the final map error "
        "is the mean over the episodes with its 95% Student-t interval; the difference is the paired per-seed "
        "difference of the final map error to the best baseline, with its 95% Student-t interval. An agent "
        "beats the best baseline when that interval lies below zero (the {doc}`protocol <protocol>`). `python -m "
        "agents.benchmark` writes the same tables, and each task's map error over time "
        "(`<task>/map_error.png` in its output folder).",
        "",
    ]
    for env_id in tasks:
        task_rows = sorted((r for r in rows if r["env_id"] == env_id), key=lambda r: r["final_map_error"])
        episodes = per_task(data.get("episodes"), env_id) or (task_rows[0].get("episodes") if task_rows else None)
        seeds = per_task(data.get("seeds"), env_id)
        out += [
            f"## {env_id}",
            "",
            seeds_line(seeds, episodes),
            "",
            "```{container} leaderboard",
            table(task_rows),
            "```",
            "",
        ]
        verdict = verdict_line(task_rows)
        if verdict:
            out += [verdict, ""]
        plot_task(task_rows, env_id, docs / page_dir / "_plots" / f"{env_id}_final_map_error.png")
        out += [f"![{env_id}: final map error of every agent](_plots/{env_id}_final_map_error.png)", ""]
        plot = docs / "images" / "leaderboard" / f"{env_id}_map_error.png"
        if plot.is_file():
            relative = Path(*([".."] * len(page_dir.parts))) / plot.relative_to(docs)
            out += [f"![{env_id}: map error over time]({relative.as_posix()})", ""]
    if after is not None:
        out += ["```{include} " + after, "```", ""]
    return "\n".join(out).rstrip() + "\n"


def plot_task(rows: list[dict[str, Any]], env_id: str, path: Path) -> None:
    """Draw ``rows`` (one task's, sorted) as horizontal bars of the final map error with their 95% intervals."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    labels = [str(r["agent"]) for r in rows]
    means = [float(r["final_map_error"]) for r in rows]
    errors = [float(r["final_map_error_ci95"]) for r in rows]
    colours = ["#8c8c8c" if r.get("kind") == "baseline" else "#1f6fd1" for r in rows]
    figure = Figure(figsize=(6.4, 0.32 * len(rows) + 1.0), dpi=100)
    axes = figure.add_subplot()
    positions = list(range(len(rows)))[::-1]
    axes.barh(positions, means, xerr=errors, color=colours, height=0.6, capsize=2, error_kw={"linewidth": 0.8})
    axes.set_yticks(positions, labels, fontsize=8)
    best = [r for r in rows if r.get("best_baseline") == r.get("agent")]
    if best:
        axes.axvline(float(best[0]["final_map_error"]), color="#e8402a", linewidth=0.8, linestyle="--")
    axes.set_xlabel("final map error (m) ± 95%: grey baselines, blue learned, red line the best baseline")
    axes.xaxis.label.set_fontsize(7)
    axes.set_title(env_id, fontsize=9)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path)


def write_leaderboards(app: Sphinx) -> None:
    docs = Path(app.srcdir)
    for entry in app.config.leaderboard_pages:
        json_path = docs / entry["json"]
        if not json_path.is_file():
            raise ExtensionError(f"leaderboard_pages: {json_path} does not exist")
        data = json.loads(json_path.read_text(encoding="utf-8"))
        target = Path(entry["page"])
        page_path = docs / target
        included = {}
        for key in ("intro", "after"):
            if entry.get(key):
                if not (docs / entry[key]).is_file():
                    raise ExtensionError(f"leaderboard_pages: the {key} {docs / entry[key]} does not exist")
                included[key] = Path(entry[key]).relative_to(target.parent).as_posix()
        text = page(data, included.get("intro"), docs, target.parent, included.get("after"))
        page_path.parent.mkdir(parents=True, exist_ok=True)
        if not page_path.is_file() or page_path.read_text(encoding="utf-8") != text:
            page_path.write_text(text, encoding="utf-8")


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_config_value("leaderboard_pages", [], "env", types=[list])
    app.connect("builder-inited", write_leaderboards)
    return {"version": "1.0", "parallel_read_safe": True, "parallel_write_safe": True}
