"""The output schema of an evaluation: the columns of ``results.csv`` and the keys of ``summary.json``.

The meaning of every column and key is in :mod:`agents.evaluate` (the package's docstring).
"""

from __future__ import annotations

__all__ = [
    "AGENT_KEYS",
    "CURVE_KEYS",
    "INTEGER_COLUMNS",
    "PAIRED_KEYS",
    "PAIRED_METRIC",
    "PAIRED_STAT_KEYS",
    "READABLE_SCHEMA_VERSIONS",
    "RECIPE_KEYS",
    "RECIPE_STAT_KEYS",
    "RESULT_COLUMNS",
    "SCHEMA_VERSION",
    "STAT_KEYS",
    "SUMMARY_KEYS",
    "SUMMARY_METRICS",
    "TABLE_COLUMNS",
]

#: Version of the output schema; bumped on any change of it.
SCHEMA_VERSION = 3
#: Schemas whose ``results.csv`` and ``summary.json["agents"]`` this version reads as its own (3 added ``stored_run`` to 2).
READABLE_SCHEMA_VERSIONS: tuple[int, ...] = (2, 3)
#: Columns of ``results.csv`` (one row per agent × episode), in order.
RESULT_COLUMNS: tuple[str, ...] = (
    "agent",
    "episode",
    "seed",
    "final_map_error",
    "initial_map_error",
    "pose_rmse",
    "landmarks_mapped",
    "landmarks_total",
    "return",
    "length",
    "wall_contacts",
    "diverged",
    "decision_time_ms",
)
#: Per-episode columns aggregated in ``summary.json`` (mean and 95 % CI each).
SUMMARY_METRICS: tuple[str, ...] = (
    "final_map_error",
    "pose_rmse",
    "landmarks_mapped",
    "return",
    "length",
    "wall_contacts",
    "diverged",
    "decision_time_ms",
)
#: Top-level keys of ``summary.json``.
SUMMARY_KEYS: tuple[str, ...] = (
    "schema_version", "env_id", "env_kwargs", "episodes", "seeds", "metrics", "agents", "paired", "stored_run",
)  # fmt: skip
#: Columns of ``results.csv`` that hold integers (the others but ``agent`` hold floats).
INTEGER_COLUMNS: tuple[str, ...] = ("episode", "seed", "landmarks_mapped", "landmarks_total", "length",
                                    "wall_contacts", "diverged")  # fmt: skip
#: Keys of ``summary.json["agents"][label]``.
AGENT_KEYS: tuple[str, ...] = ("spec", "episodes", *SUMMARY_METRICS, "map_error_over_time")
#: Keys of each metric's statistics.
STAT_KEYS: tuple[str, ...] = ("mean", "std", "ci95_low", "ci95_high", "ci95_half_width", "n")
#: Keys of ``map_error_over_time``.
CURVE_KEYS: tuple[str, ...] = ("step", "mean", "ci95_low", "ci95_high")
#: The metric of the paired comparison (lower is better).
PAIRED_METRIC = "final_map_error"
#: Keys of ``summary.json["paired"]``.
PAIRED_KEYS: tuple[str, ...] = ("metric", "reference", "confidence", "bootstrap", "agents")
#: Keys of a paired difference (:func:`agents.evaluate.statistics.paired_difference`); ``paired["agents"][label]`` adds ``verdict``.
PAIRED_STAT_KEYS: tuple[str, ...] = ("mean", "std", "ci95_low", "ci95_high", "n", "bootstrap_ci95_low",
                                     "bootstrap_ci95_high")  # fmt: skip
#: Keys of a recipe's difference over its training seeds and the episodes (:func:`agents.evaluate.statistics.recipe_difference`).
RECIPE_STAT_KEYS: tuple[str, ...] = ("mean", "seed_means", "std_seeds", "std_episodes", "standard_error", "dof",
                                     "ci95_low", "ci95_high", "n_seeds", "n_episodes")  # fmt: skip
#: Keys of :func:`agents.evaluate.statistics.recipe_comparison`'s result.
RECIPE_KEYS: tuple[str, ...] = ("metric", "reference", "confidence", "members", "recipe", "against", "spread")

#: Columns of the printed Markdown table: (metric, header).
TABLE_COLUMNS: tuple[tuple[str, str], ...] = (
    ("final_map_error", "final map error (m)"),
    ("pose_rmse", "pose RMSE (m)"),
    ("landmarks_mapped", "landmarks mapped"),
    ("return", "return"),
    ("length", "length"),
    ("wall_contacts", "wall contacts"),
    ("diverged", "diverged"),
    ("decision_time_ms", "ms / decision"),
)
