r"""Compare agents on the same seeds: ``python -m agents.evaluate``.

.. code-block:: bash

    python -m agents.evaluate --agents random,frontier,revisit,info_gain,runs/ppo/model.zip \
        --episodes 10 --seed 1000 [--env SeifExplore-v2] [--env-kwargs '{"layout": "loop"}'] [--out DIR] \
        [--bootstrap 10000] [--workers N | --ray auto|ADDRESS] [--quiet]

Every agent runs ``N`` episodes on the seeds ``S, S+1, …, S+N−1`` (the same
for every agent; ``env.reset(seed=s)`` fixes the landmark layout, the start
and all noise of episode ``s``). An agent is a name of
:data:`agents.BASELINES` (built with ``make_agent(name, env)``; ``random``
is seeded with ``S``), the path of a Stable-Baselines3 ``.zip`` (a PPO,
RecurrentPPO or SAC model, :func:`sb3_algorithm`; if a ``vecnormalize.pkl``
lies next to it, its observation normalisation is applied; labelled by the file's stem, or by its folder's
name for ``model.zip`` / ``best_model.zip``) or ``rllib:CHECKPOINT``; any of
them may be labelled ``LABEL=SPEC``. Every agent acts with ``deterministic=True``.
``--env-kwargs`` is a JSON object passed to ``gym.make`` (it may hold
``max_episode_steps``). The episodes run one after another in this process,
on ``--workers N`` local processes or as Ray tasks on a cluster (``--ray``;
:mod:`agents.parallel`, ``docs/ray.md``), with the same rows but for the
measured ``decision_time_ms``.

The metrics come from the env's ``info`` (the ground truth is read here, by
the evaluation, never by the agents). Written to ``--out`` (default
``eval``):

``results.csv``
    One row per agent × episode, columns :data:`RESULT_COLUMNS`:

    ==================== ==========================================================
    column               meaning
    ==================== ==========================================================
    ``agent``            agent label (baseline name, or the ``.zip``'s file stem)
    ``episode``          0 … N−1
    ``seed``             seed of ``env.reset``
    ``final_map_error``  ``info["map_error"]`` at the end, metres (mean over all
                         true landmarks of the capped error, unmapped = ``d_cap``)
    ``initial_map_error`` ``info["map_error"]`` after ``reset``
    ``pose_rmse``        RMS over all observations of the episode (reset
                         included) of ``‖true_pose[:2] − pose_estimate[:2]‖``, m
    ``landmarks_mapped`` ``info["landmarks_mapped"]`` at the end
    ``landmarks_total``  ``info["landmarks_total"]``
    ``return``           sum of the rewards
    ``length``           steps of the episode
    ``wall_contacts``    steps with ``info["wall_contact"]``
    ``diverged``         1 if the episode ended by divergence, else 0
    ``decision_time_ms`` mean wall time of one ``predict`` call, milliseconds
    ==================== ==========================================================

``summary.json``
    ``{key: …}`` with the keys :data:`SUMMARY_KEYS`: ``schema_version``
    (:data:`SCHEMA_VERSION`), ``env_id``, ``env_kwargs``, ``episodes``,
    ``seeds`` (list), ``metrics`` (:data:`SUMMARY_METRICS`), ``agents``.
    ``agents[label]`` has the keys :data:`AGENT_KEYS`: ``spec`` (as given on
    the command line), ``episodes``, one entry per metric of
    :data:`SUMMARY_METRICS`, each a dict with the keys :data:`STAT_KEYS`
    (``mean``, ``std`` (``ddof=1``), ``ci95_low``, ``ci95_high``,
    ``ci95_half_width``, ``n``; the 95 % confidence interval of the mean
    from Student's t, ``null`` for a single episode), and
    ``map_error_over_time``, a dict with the keys :data:`CURVE_KEYS`:
    ``step`` (0 … longest length), ``mean``, ``ci95_low``, ``ci95_high``
    of ``info["map_error"]`` over the episodes at each step (an episode that
    ended early keeps its last value). ``diverged`` is the fraction of
    diverged episodes.

    ``paired`` compares every agent with the *best baseline* (the baseline of
    lowest mean final map error) on the same seeds (:func:`paired_comparison`):
    a dict with the keys :data:`PAIRED_KEYS`: ``metric``
    (``final_map_error``), ``reference`` (the best baseline; ``null`` when no
    agent is a baseline), ``confidence`` (0.95), ``bootstrap`` (resamples of
    the optional bootstrap interval, 0 for none) and ``agents``: label -> the
    keys :data:`PAIRED_STAT_KEYS` and ``verdict``, for every agent but the
    reference. ``mean`` is the mean per-seed difference (agent minus
    reference; negative is better), ``std`` its standard deviation
    (``ddof=1``), ``ci95_low`` / ``ci95_high`` its Student-t interval,
    ``bootstrap_ci95_low`` / ``bootstrap_ci95_high`` a percentile bootstrap
    interval (``null`` without ``--bootstrap``), ``n`` the number of seeds.
    ``verdict`` (:func:`paired_verdict`) is ``beats`` only when the t
    interval lies below zero (``worse`` above it, ``tie (interval holds 0)``
    otherwise).

    ``stored_run`` is the folder of the earlier run whose episodes joined
    this one (``--stored-run``, :func:`load_stored_run`), ``null`` for none.

``map_error.png``
    The mean map error over time per agent with its 95 % band.

The Markdown table of the means ± CI half-widths and the table of the
paired differences (:func:`paired_table`) are printed and also written to
``summary.md``. Progress goes to stderr (``--quiet``: none).

From Python: :func:`evaluate_agents` returns ``(rows, summary)`` as above,
:func:`write_outputs` writes the files.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from scipy import stats

import seif_gym  # noqa: F401  (registers the environments)
from agents.base import Agent
from agents.baselines import BASELINES, baseline_class
from agents.cli import json_object
from agents.loading import agent_label, agent_labels, check_agent_spec, load_agent
from agents.parallel import Executor, chunks
from agents.parallel import add_arguments as add_executor_arguments
from agents.parallel import from_arguments as executor_from_arguments
from agents.sb3_agent import SB3Agent, sb3_algorithm
from seif_gym import LATEST_ID
from seif_gym.progress import Progress
from seif_gym.validation import as_count

__all__ = [
    "RESULT_COLUMNS",
    "SUMMARY_KEYS",
    "SUMMARY_METRICS",
    "AGENT_KEYS",
    "STAT_KEYS",
    "CURVE_KEYS",
    "PAIRED_METRIC",
    "PAIRED_KEYS",
    "PAIRED_STAT_KEYS",
    "SCHEMA_VERSION",
    "INTEGER_COLUMNS",
    "READABLE_SCHEMA_VERSIONS",
    "RECIPE_STAT_KEYS",
    "RECIPE_KEYS",
    "SB3Agent",
    "sb3_algorithm",
    "agent_label",
    "agent_labels",
    "check_agent_spec",
    "build_agent",
    "make_evaluation_env",
    "without_exact_nees",
    "run_episode",
    "mean_ci",
    "paired_difference",
    "paired_verdict",
    "paired_comparison",
    "recipe_difference",
    "recipe_comparison",
    "read_run",
    "load_stored_run",
    "evaluate_agents",
    "write_outputs",
    "markdown_table",
    "paired_table",
    "signed",
    "signed_interval",
    "main",
]

#: Version of the output schema below; bumped on any change of it (2: ``paired``; 3: ``stored_run``).
SCHEMA_VERSION = 3
#: Schemas whose ``results.csv`` and ``summary.json["agents"]`` this version reads as its own (3 only added a key).
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
#: Keys of a paired difference (:func:`paired_difference`); ``paired["agents"][label]`` adds ``verdict``.
PAIRED_STAT_KEYS: tuple[str, ...] = ("mean", "std", "ci95_low", "ci95_high", "n", "bootstrap_ci95_low",
                                     "bootstrap_ci95_high")  # fmt: skip
#: Keys of a recipe's difference over its training seeds and the episodes (:func:`recipe_difference`).
RECIPE_STAT_KEYS: tuple[str, ...] = ("mean", "seed_means", "std_seeds", "std_episodes", "standard_error", "dof",
                                     "ci95_low", "ci95_high", "n_seeds", "n_episodes")  # fmt: skip
#: Keys of :func:`recipe_comparison`'s result.
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


# -- agents ----------------------------------------------------------------------------------------
def build_agent(spec: str, env: gym.Env, env_id: str, env_kwargs: Mapping[str, Any], seed: int) -> Agent:
    """:func:`agents.load_agent` for an evaluation of ``env_id`` with ``env_kwargs`` (``random`` seeded with ``seed``)."""
    return load_agent(spec, env, seed=seed, env_factory=lambda: gym.make(env_id, **env_kwargs))


# -- running ---------------------------------------------------------------------------------------
def run_episode(agent: Agent, env: gym.Env, seed: int) -> tuple[dict[str, Any], list[float]]:
    """One episode of ``agent`` in ``env`` from ``env.reset(seed=seed)``.

    Returns
    -------
    row : dict
        The :data:`RESULT_COLUMNS` but ``agent`` and ``episode``.
    map_errors : list of float
        ``info["map_error"]`` after the reset and after every step.
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
    """``env_kwargs`` with ``exact_pose_nees=False`` unless they set it (:func:`make_evaluation_env`)."""
    if not isinstance(env_kwargs, Mapping):
        raise TypeError(f"env_kwargs must be a mapping, got {type(env_kwargs).__name__}")
    return {"exact_pose_nees": False, **env_kwargs}


def make_evaluation_env(env_id: str, env_kwargs: Mapping[str, Any]) -> gym.Env:
    """The env an evaluation steps: ``gym.make(env_id, **env_kwargs)`` with ``exact_pose_nees=False``.

    No metric of an evaluation reads ``info["pose_nees"]``, and its exact pose
    marginal factorises the information matrix every step (on the large
    world's 120-landmark maps 40% of an episode's time); everything else the
    env computes is the same (``tests/test_agents.py``). ``env_kwargs`` may
    still ask for it.
    """
    return gym.make(env_id, **without_exact_nees(env_kwargs))


def _run_episodes(
    env_id: str, env_kwargs: Mapping[str, Any], target: str, agent_seed: int, seeds: Sequence[int]
) -> list[tuple[dict[str, Any], list[float], float, int]]:
    """One task of :func:`evaluate_agents`: the agent of ``target`` on ``seeds``, in order, in a fresh env.

    Returns, per episode, :func:`run_episode`'s row and map-error trace and
    the planning seconds and plans it took (agents that plan and time it).
    """
    env = make_evaluation_env(env_id, env_kwargs)
    try:
        agent = build_agent(target, env, env_id, env_kwargs, agent_seed)
        out = []
        for episode_seed in seeds:
            times = getattr(agent, "planning_times", None)
            before = len(times) if times is not None else 0
            row, trace = run_episode(agent, env, int(episode_seed))
            times = getattr(agent, "planning_times", None)
            new = times[before:] if times is not None else []
            out.append((row, trace, float(sum(new)), len(new)))
        return out
    finally:
        env.close()


def _finite_or_none(value: float) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def mean_ci(values: Sequence[float], confidence: float = 0.95) -> dict[str, float | int | None]:
    """Mean, std (``ddof=1``) and the Student-t confidence interval of the mean (keys :data:`STAT_KEYS`)."""
    data = np.asarray(values, dtype=np.float64)
    n = int(data.size)
    mean = float(np.mean(data)) if n else math.nan
    if n >= 2:
        std = float(np.std(data, ddof=1))
        half = float(stats.t.ppf(0.5 + 0.5 * confidence, n - 1) * std / math.sqrt(n))
    else:
        std = half = math.nan
    return {
        "mean": _finite_or_none(mean),
        "std": _finite_or_none(std),
        "ci95_low": _finite_or_none(mean - half),
        "ci95_high": _finite_or_none(mean + half),
        "ci95_half_width": _finite_or_none(half),
        "n": n,
    }


def paired_difference(values: Sequence[float], reference: Sequence[float], confidence: float = 0.95, *,
                      bootstrap: int = 0, seed: int = 0) -> dict[str, Any]:  # fmt: skip
    """Mean of the per-seed differences ``values − reference``, with its Student-t interval.

    Parameters
    ----------
    values, reference : sequence of float
        One number per seed, the same seeds in the same order.
    confidence : float
        Coverage of the intervals, in ``(0, 1)``.
    bootstrap : int
        Resamples of a percentile bootstrap interval of the mean difference
        (0: none). It is reported beside the t interval, which alone decides
        :func:`paired_verdict`.
    seed : int
        Seed of the bootstrap's generator (the interval is reproducible).

    Returns
    -------
    dict
        The keys :data:`PAIRED_STAT_KEYS`: ``mean``, ``std`` (of the
        differences, ``ddof=1``), ``ci95_low``, ``ci95_high`` (the t interval;
        ``None`` for one seed), ``n``, ``bootstrap_ci95_low`` and
        ``bootstrap_ci95_high`` (``None`` without ``bootstrap``).

    Raises
    ------
    ValueError
        If the sequences differ in length or are empty, or ``confidence`` or
        ``bootstrap`` is out of range.

    Notes
    -----
    With ``d_i = values_i − reference_i`` over ``n`` seeds, the interval is
    ``mean(d) ± t_{(1+c)/2, n−1} · s_d / sqrt(n)``: the paired comparison,
    which removes the seed-to-seed spread both agents share (the seed fixes
    the landmarks, the start and all noise).

    Examples
    --------
    >>> d = paired_difference([1.0, 2.0, 4.0], [0.5, 1.0, 3.0])  # differences 0.5, 1, 1
    >>> round(d["mean"], 4), round(d["std"], 4), d["n"]
    (0.8333, 0.2887, 3)
    """
    a = np.asarray(values, dtype=np.float64)
    b = np.asarray(reference, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 1 or a.size == 0:
        raise ValueError(f"values and reference must be one number per seed, same length, got {a.shape} and {b.shape}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence!r}")
    as_count(bootstrap, "bootstrap")
    d = a - b
    n = int(d.size)
    mean = float(d.mean())
    result: dict[str, Any] = dict.fromkeys(PAIRED_STAT_KEYS)
    result.update(mean=mean, n=n)
    if n >= 2:
        std = float(d.std(ddof=1))
        half = float(stats.t.ppf(0.5 + 0.5 * confidence, n - 1) * std / math.sqrt(n))
        result.update(std=std, ci95_low=mean - half, ci95_high=mean + half)
        if bootstrap:
            means = d[np.random.default_rng(seed).integers(0, n, size=(int(bootstrap), n))].mean(axis=1)
            low, high = np.quantile(means, [0.5 - 0.5 * confidence, 0.5 + 0.5 * confidence])
            result.update(bootstrap_ci95_low=float(low), bootstrap_ci95_high=float(high))
    return result


def paired_verdict(paired: Mapping[str, Any]) -> str:
    """``"beats"`` if the t interval of the difference lies below zero (lower is better), ``"worse"`` above it.

    ``"tie (interval holds 0)"`` otherwise, ``"n/a (one seed)"`` without an
    interval: an agent beats another only when the interval excludes zero.
    """
    low, high = paired["ci95_low"], paired["ci95_high"]
    if low is None or high is None:
        return "n/a (one seed)"
    if high < 0.0:
        return "beats"
    if low > 0.0:
        return "worse"
    return "tie (interval holds 0)"


def paired_comparison(rows: Sequence[Mapping[str, Any]], baselines: Sequence[str], metric: str = PAIRED_METRIC,
                      confidence: float = 0.95, *, bootstrap: int = 0) -> dict[str, Any]:  # fmt: skip
    """Every agent against the best baseline, by paired per-seed differences of ``metric``.

    Parameters
    ----------
    rows : sequence of dict
        :func:`evaluate_agents`' rows (``agent``, ``seed`` and ``metric``).
    baselines : sequence of str
        The labels that are baselines; the one of lowest mean ``metric`` is
        the reference.
    metric : str
        A column of the rows where lower is better.
    confidence : float
        Coverage of the intervals.
    bootstrap : int
        Resamples of the optional bootstrap interval (:func:`paired_difference`).

    Returns
    -------
    dict
        The keys :data:`PAIRED_KEYS`: ``metric``, ``reference`` (``None``
        without a baseline), ``confidence``, ``bootstrap`` and ``agents``:
        label -> :func:`paired_difference` plus ``verdict``
        (:func:`paired_verdict`), for every agent but the reference.

    Raises
    ------
    ValueError
        If the agents did not run on the same seeds.
    """
    per_agent = _values_by_agent(rows, metric)
    means = {label: float(np.mean(list(values.values()))) for label, values in per_agent.items()}
    candidates = [label for label in per_agent if label in set(baselines)]
    reference = min(candidates, key=means.__getitem__) if candidates else None
    result: dict[str, Any] = {"metric": metric, "reference": reference, "confidence": confidence,
                              "bootstrap": int(bootstrap), "agents": {}}  # fmt: skip
    if reference is None:
        return result
    seeds = sorted(per_agent[reference])
    for label, values in per_agent.items():
        if label == reference:
            continue
        if sorted(values) != seeds:
            raise ValueError(f"rows: {label!r} and {reference!r} ran on different seeds; the comparison is paired")
        paired = paired_difference([values[s] for s in seeds], [per_agent[reference][s] for s in seeds], confidence,
                                   bootstrap=bootstrap)  # fmt: skip
        result["agents"][label] = {**paired, "verdict": paired_verdict(paired)}
    return result


def recipe_difference(values: Any, reference: Sequence[float], confidence: float = 0.95) -> dict[str, Any]:
    """Mean difference of a recipe's models to a reference over training seeds and episodes, with its interval.

    The question "does this recipe beat the baseline?" is about the recipe's
    expected lead over *both* of its random draws: the training seed that made
    a model and the episode it is scored on. This interval treats the two as
    crossed random samples, so a recipe beats only if its lead would hold for
    other training seeds and other episodes of the task.

    Parameters
    ----------
    values : array_like, shape (n_seeds, n_episodes)
        ``values[s, e]``: the metric of the model of training seed ``s`` on
        episode ``e`` (lower is better).
    reference : sequence of float, shape (n_episodes,)
        The reference agent's metric on the same episodes, in the same order.
    confidence : float
        Coverage of the interval, in ``(0, 1)``.

    Returns
    -------
    dict
        The keys :data:`RECIPE_STAT_KEYS`: ``mean`` (of ``d = values −
        reference`` over every cell), ``seed_means`` (per seed, list),
        ``std_seeds`` (of the seed means, ``ddof=1``), ``std_episodes`` (of
        the episode means over seeds, ``ddof=1``), ``standard_error``,
        ``dof`` (Welch–Satterthwaite; ``None`` when every cell holds the same
        difference, whose interval is then the point), ``ci95_low``,
        ``ci95_high`` (the t interval at ``confidence``), ``n_seeds``,
        ``n_episodes``.

    Raises
    ------
    ValueError
        If ``values`` is not two-dimensional with at least two seeds and two
        episodes, ``reference`` does not have one number per episode, either
        holds a non-finite number, or ``confidence`` is out of range.

    Notes
    -----
    With ``d[s, e]`` over ``S`` seeds and ``E`` episodes, a model of crossed
    random effects ``d[s, e] = δ + a_s + b_e + ε_se`` gives ``Var(mean d) =
    σ_a²/S + σ_b²/E + σ_ε²/(SE)``. The estimate here is

    ``V = var_s(mean_e d)/S + var_e(mean_s d)/E``,

    whose expectation is ``σ_a²/S + σ_b²/E + 2σ_ε²/(SE)``: the interaction
    counted twice, so a little conservative (``σ_ε²/(SE)`` is small against the
    other two at hundreds of episodes). The interval is ``mean(d) ± t_{(1+c)/2,
    ν} √V`` with Welch–Satterthwaite's ``ν = V² / (v_s²/(S−1) + v_e²/(E−1))``,
    ``v_s`` and ``v_e`` the two terms of ``V``. Two limits check it: seeds
    that all give the same episodes leave only the episode term, and the
    interval is :func:`paired_difference`'s of the one model; seeds that differ
    by a constant on every episode leave only the seed term, a t interval over
    the seeds' means.

    Examples
    --------
    >>> d = recipe_difference([[1.0, 2.0, 4.0], [1.0, 2.0, 4.0]], [0.5, 1.0, 3.0])  # both seeds alike
    >>> p = paired_difference([1.0, 2.0, 4.0], [0.5, 1.0, 3.0])
    >>> (round(d["ci95_low"], 6), round(d["ci95_high"], 6)) == (round(p["ci95_low"], 6), round(p["ci95_high"], 6))
    True
    """
    try:
        table = np.asarray(values, dtype=np.float64)
        ref = np.asarray(reference, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(f"values and reference must be numbers ({error})") from error
    if table.ndim != 2 or table.shape[0] < 2 or table.shape[1] < 2:
        raise ValueError(f"values must be (n_seeds, n_episodes) with at least 2 of each, got shape {table.shape}")
    if ref.shape != (table.shape[1],):
        raise ValueError(f"reference must hold one number per episode ({table.shape[1]}), got shape {ref.shape}")
    if not (np.isfinite(table).all() and np.isfinite(ref).all()):
        raise ValueError("values and reference must be finite")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence!r}")
    d = table - ref[None, :]
    n_seeds, n_episodes = d.shape
    seed_means, episode_means = d.mean(axis=1), d.mean(axis=0)
    std_seeds, std_episodes = float(seed_means.std(ddof=1)), float(episode_means.std(ddof=1))
    seed_term, episode_term = std_seeds**2 / n_seeds, std_episodes**2 / n_episodes
    variance = seed_term + episode_term
    mean = float(d.mean())
    if variance > 0.0:
        dof = variance**2 / (seed_term**2 / (n_seeds - 1) + episode_term**2 / (n_episodes - 1))
        half = float(stats.t.ppf(0.5 + 0.5 * confidence, dof) * math.sqrt(variance))
    else:  # every cell the same difference: no spread to estimate, and no degrees of freedom to give
        dof, half = None, 0.0
    return {
        "mean": mean,
        "seed_means": [float(value) for value in seed_means],
        "std_seeds": std_seeds,
        "std_episodes": std_episodes,
        "standard_error": math.sqrt(variance),
        "dof": None if dof is None else float(dof),
        "ci95_low": mean - half,
        "ci95_high": mean + half,
        "n_seeds": int(n_seeds),
        "n_episodes": int(n_episodes),
    }


def _values_by_agent(rows: Sequence[Mapping[str, Any]], metric: str) -> dict[str, dict[int, float]]:
    """The rows' ``metric`` per agent: label -> {seed: value}."""
    values: dict[str, dict[int, float]] = {}
    for row in rows:
        values.setdefault(row["agent"], {})[int(row["seed"])] = float(row[metric])
    return values


def recipe_comparison(rows: Sequence[Mapping[str, Any]], members: Sequence[str], baselines: Sequence[str],
                      metric: str = PAIRED_METRIC, confidence: float = 0.95) -> dict[str, Any]:  # fmt: skip
    """A recipe's models (one per training seed) against the baselines: each on its own, and together.

    ``rows``, ``baselines`` (the best of them is the reference), ``metric``
    and ``confidence`` are as in :func:`paired_comparison`; ``members`` are
    the labels of the recipe's models, one per training seed (at least 2).

    Returns
    -------
    dict
        The keys :data:`RECIPE_KEYS`: ``metric``, ``reference``,
        ``confidence``, ``members`` (label -> :func:`paired_difference` plus
        ``verdict``, each model on its own against the reference), ``recipe``
        (:func:`recipe_difference` of all of them to the reference plus
        ``verdict``, :func:`paired_verdict` of its interval), ``against``
        (baseline -> the same for every baseline with rows) and ``spread``
        (``low``, ``mean``, ``high`` of the models' means, and ``members``:
        label -> its mean).

    Raises
    ------
    ValueError
        If a member or every baseline is missing from the rows, a label is both,
        members repeat, fewer than two are given, or the agents did not run on
        the same seeds.
    """
    members, baselines = list(members), list(baselines)
    if len(members) < 2 or len(set(members)) != len(members):
        raise ValueError(f"members must be at least two distinct labels, got {members}")
    if set(members) & set(baselines):
        raise ValueError(f"members and baselines share {sorted(set(members) & set(baselines))}")
    values = _values_by_agent(rows, metric)
    missing = [label for label in members if label not in values]
    if missing:
        raise ValueError(f"members {missing} have no rows")
    present_baselines = [name for name in baselines if name in values]
    if not present_baselines:
        raise ValueError(f"baselines: none of {baselines} has rows")
    wanted = set(members) | set(present_baselines)
    paired = paired_comparison([row for row in rows if row["agent"] in wanted], baselines, metric, confidence)
    seeds = sorted(values[paired["reference"]])
    table = [[values[label][s] for s in seeds] for label in members]
    against = {}
    for name in present_baselines:
        difference = recipe_difference(table, [values[name][s] for s in seeds], confidence)
        against[name] = {**difference, "verdict": paired_verdict(difference)}
    means = {label: float(np.mean(row)) for label, row in zip(members, table)}
    return {
        "metric": metric,
        "reference": paired["reference"],
        "confidence": confidence,
        "members": {label: paired["agents"][label] for label in members},
        "recipe": against[paired["reference"]],
        "against": against,
        "spread": {
            "low": min(means.values()),
            "mean": float(np.mean(list(means.values()))),
            "high": max(means.values()),
            "members": means,
        },  # fmt: skip
    }


def _curve(traces: Sequence[Sequence[float]]) -> dict[str, list]:
    longest = max(len(trace) for trace in traces)
    padded = np.array([list(trace) + [trace[-1]] * (longest - len(trace)) for trace in traces], dtype=np.float64)
    n = len(traces)
    mean = padded.mean(axis=0)
    if n >= 2:
        half = stats.t.ppf(0.975, n - 1) * padded.std(axis=0, ddof=1) / math.sqrt(n)
        low, high = (mean - half).tolist(), (mean + half).tolist()
    else:
        low = high = [None] * longest
    return {"step": list(range(longest)), "mean": mean.tolist(), "ci95_low": low, "ci95_high": high}


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
    differently: ``docs/benchmark.md``).

    Parameters
    ----------
    folder : str or PathLike
        Holds ``results.csv`` and ``summary.json`` of the earlier run.
    env_id, env_kwargs, seeds
        This run's: the stored run must have been made with the same ones, in
        a schema of :data:`READABLE_SCHEMA_VERSIONS` (:func:`read_run`).
    labels : sequence of str
        This run's agent labels, which the stored run's may not repeat.
    name : str
        The start of every error message, as in :func:`read_run`.

    Returns
    -------
    rows : list of dict
        Its ``results.csv`` rows (keys :data:`RESULT_COLUMNS`, typed as written).
    agents : dict
        Its ``summary.json["agents"]`` entries (label -> :data:`AGENT_KEYS`).

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
    """The rows and summary of an ``--out`` folder of this command, as written (schemas :data:`READABLE_SCHEMA_VERSIONS`).

    Parameters
    ----------
    folder : str or PathLike
        Holds ``results.csv`` and ``summary.json``.
    name : str
        What the folder is to the caller, the start of every error message.

    Returns
    -------
    rows : list of dict
        The ``results.csv`` rows (keys :data:`RESULT_COLUMNS`, typed as written).
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
        is not one of :data:`READABLE_SCHEMA_VERSIONS`.
    """
    if not isinstance(folder, (str, os.PathLike)):
        raise TypeError(f"{name} must be a folder's path, got {type(folder).__name__}")
    path = Path(folder)
    summary_path, results_path = path / "summary.json", path / "results.csv"
    for needed in (summary_path, results_path):
        if not needed.is_file():
            raise FileNotFoundError(f"{name}: {needed} does not exist (an agents.evaluate --out folder?)")
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
        An earlier run's folder (:func:`load_stored_run`: same env, arguments
        and seeds): its agents' episodes join this run's, after them, without
        running again; its baselines count as baselines of the paired
        comparison. Its labels may not repeat this run's.

    Returns
    -------
    rows : list of dict
        One per agent × episode, keys :data:`RESULT_COLUMNS`.
    summary : dict
        Keys :data:`SUMMARY_KEYS` (see the module docstring).
    """
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
    tasks: list[tuple[Any, ...]] = []
    owner: list[int] = []
    for number, (_, target) in enumerate(labelled):
        for run in chunks(seeds, slots, together=_carries_over(target)):
            tasks.append((env_id, env_kwargs, target, int(seed), run))
            owner.append(number)
    remaining = [owner.count(number) for number in range(len(labelled))]
    collected: dict[int, list[tuple[dict[str, Any], list[float], float, int]]] = {}
    started = time.perf_counter()
    progress = Progress(len(labelled) * len(seeds), f"{env_id}", enabled=verbose, unit="episodes")

    def episodes_of(number: int) -> list[tuple[dict[str, Any], list[float], float, int]]:
        return [item for index in sorted(collected) if owner[index] == number for item in collected[index]]

    def arrived(index: int, result: list[tuple[dict[str, Any], list[float], float, int]]) -> None:
        number = owner[index]
        label = labelled[number][0]
        collected[index] = result
        for row, _, _, _ in result:
            progress.update(1, f"{label} seed {row['seed']}: {row['final_map_error']:.3f} m")
        remaining[number] -= 1
        if remaining[number] == 0:  # the agent's last task: its line
            done = episodes_of(number)
            plans = sum(count for _, _, _, count in done)
            planning = sum(seconds for _, _, seconds, _ in done) / plans if plans else math.nan
            extra = f", {1e3 * planning:.2f} ms per plan" if math.isfinite(planning) else ""
            mean = float(np.mean([row["final_map_error"] for row, _, _, _ in done]))
            progress.write(f"{label}: {len(seeds)} episodes after {time.perf_counter() - started:.1f} s, "
                           f"final map error {mean:.3f} m{extra}")  # fmt: skip

    with progress:
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
        entry["map_error_over_time"] = _curve([trace for _, trace, _, _ in done])
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


# -- output ----------------------------------------------------------------------------------------
def _format(stat: Mapping[str, Any], digits: int = 3) -> str:
    mean, half = stat["mean"], stat["ci95_half_width"]
    if mean is None:
        return "n/a"
    return f"{mean:.{digits}f}" if half is None else f"{mean:.{digits}f} ± {half:.{digits}f}"


def markdown_table(summary: Mapping[str, Any]) -> str:
    """The means ± 95 % CI half-widths of ``summary``, one row per agent, as a Markdown table."""
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
    """The paired comparison of ``summary`` (:func:`paired_comparison`) as a sentence and a Markdown table.

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
    rows: Sequence[Mapping[str, Any]], summary: Mapping[str, Any], out: str | os.PathLike
) -> dict[str, Path]:
    """Write ``results.csv``, ``summary.json``, ``summary.md`` and ``map_error.png`` into ``out``.

    Returns
    -------
    dict
        ``{"csv", "json", "markdown", "plot"}`` -> path written.
    """
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {
        "csv": folder / "results.csv",
        "json": folder / "summary.json",
        "markdown": folder / "summary.md",
        "plot": folder / "map_error.png",
    }
    with paths["csv"].open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(RESULT_COLUMNS))
        writer.writeheader()
        for row in rows:
            writer.writerow({column: row[column] for column in RESULT_COLUMNS})
    paths["json"].write_text(json.dumps(summary, indent=2, allow_nan=False) + "\n")
    paired = paired_table(summary)
    paths["markdown"].write_text(markdown_table(summary) + "\n" + (f"\n{paired}\n" if paired else ""))
    plot_map_error(summary, paths["plot"])
    return paths


def plot_map_error(summary: Mapping[str, Any], path: str | os.PathLike) -> None:
    """Mean map error over time per agent, with the 95 % band, saved to ``path``."""
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
    fig.savefig(path)
    plt.close(fig)


# -- command line ----------------------------------------------------------------------------------
def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m agents.evaluate",
        description="Run agents on the same seeds of a SeifExplore env and compare them.",
    )
    parser.add_argument(
        "--agents",
        required=True,
        help=f"comma-separated baseline names ({', '.join(BASELINES)}) and/or paths of SB3 .zip models",
    )
    parser.add_argument("--episodes", type=int, default=10, help="episodes per agent (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first episode (default 0)")
    parser.add_argument("--env", default=LATEST_ID, help="registered env id (default %(default)s)")
    parser.add_argument(
        "--env-kwargs", type=json_object, default="{}", help="JSON object of gym.make keyword arguments"
    )
    parser.add_argument("--out", default="eval", help="output folder (default ./eval)")
    parser.add_argument("--bootstrap", type=int, default=0, metavar="N",
                        help="also a percentile bootstrap interval of the paired differences, N resamples (default 0: none)")  # fmt: skip
    parser.add_argument(
        "--stored-run",
        default=None,
        metavar="DIR",
        help="an earlier --out folder of this command on the same env, env kwargs and seeds: its agents' episodes "
        "join this run's without running again (e.g. the baselines' held-out episodes)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    add_executor_arguments(parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    specs = [spec.strip() for spec in args.agents.split(",") if spec.strip()]
    if args.episodes < 1:
        parser.error(f"--episodes must be positive, got {args.episodes}")
    if args.bootstrap < 0:
        parser.error(f"--bootstrap must be >= 0, got {args.bootstrap}")
    try:
        for _, target in agent_labels(specs):
            check_agent_spec(target)
    except (ValueError, FileNotFoundError) as error:
        parser.error(str(error))
    if args.stored_run is not None:  # its errors as the command's, before any episode runs
        seeds = list(range(args.seed, args.seed + args.episodes))
        try:
            load_stored_run(
                args.stored_run, args.env, args.env_kwargs, seeds, [label for label, _ in agent_labels(specs)]
            )
        except (ValueError, FileNotFoundError) as error:
            parser.error(str(error).replace("stored_run:", "--stored-run:", 1))
    executor = executor_from_arguments(args, parser)
    started = time.perf_counter()
    rows, summary = evaluate_agents(specs, args.episodes, args.seed, args.env, args.env_kwargs, verbose=not args.quiet,
                                    bootstrap=args.bootstrap, executor=executor, stored_run=args.stored_run)  # fmt: skip
    paths = write_outputs(rows, summary, args.out)
    print(f"{args.env}, {args.episodes} episodes per agent, seeds {args.seed}..{args.seed + args.episodes - 1}; "
          "mean ± 95% CI half-width\n")  # fmt: skip
    print(markdown_table(summary))
    paired = paired_table(summary)
    if paired:
        print(f"\n{paired}")
    print(f"\nwrote {', '.join(str(path) for path in paths.values())} in {time.perf_counter() - started:.1f} s "
          f"({executor.kind}: {len(executor.placements)} tasks on {len(set(executor.placements))} processes or nodes)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
