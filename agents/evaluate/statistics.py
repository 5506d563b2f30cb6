r"""The statistics of an evaluation: means with Student-t intervals and paired differences between agents.

Every agent runs on the same seeds, so two agents are compared by their
per-seed differences (:func:`paired_difference`): the seed fixes the landmarks,
the start and all noise, and pairing removes the spread both agents share. An
agent *beats* another only when the interval of the mean difference lies below
zero (:func:`paired_verdict`; lower is better). A recipe (several models, one
per training seed) is judged over both of its random draws, training seeds and
episodes (:func:`recipe_difference`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy import stats

from agents.evaluate.schema import PAIRED_METRIC, PAIRED_STAT_KEYS
from seif_gym.validation import as_count

__all__ = [
    "mean_curve",
    "mean_ci",
    "paired_comparison",
    "paired_difference",
    "paired_verdict",
    "recipe_comparison",
    "recipe_difference",
]


def _finite_or_none(value: float) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def mean_ci(values: Sequence[float], confidence: float = 0.95) -> dict[str, float | int | None]:
    """Mean, standard deviation and the Student-t confidence interval of the mean of ``values``.

    Parameters
    ----------
    values : sequence of float
        The sample (may be empty).
    confidence : float
        Coverage of the interval.

    Returns
    -------
    dict
        The keys :data:`~agents.evaluate.schema.STAT_KEYS`: ``mean``, ``std`` (``ddof=1``),
        ``ci95_low``, ``ci95_high``, ``ci95_half_width`` and ``n``; a value that is not finite
        (every statistic of an empty sample, all but the mean of a single value) is ``None``.

    Notes
    -----
    The half-width is ``t_{(1+c)/2, n−1} · s / sqrt(n)``.
    """
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
        The keys :data:`~agents.evaluate.schema.PAIRED_STAT_KEYS`: ``mean``, ``std`` (of the
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
    """The verdict of a paired difference (lower is better): only an interval that excludes zero decides.

    Parameters
    ----------
    paired : mapping
        Holds ``ci95_low`` and ``ci95_high`` (:func:`paired_difference`, :func:`recipe_difference`).

    Returns
    -------
    str
        ``"beats"`` if the interval lies below zero, ``"worse"`` above it, ``"tie (interval holds 0)"``
        if it holds zero, ``"n/a (one seed)"`` without an interval.
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
        :func:`~agents.evaluate.rollout.evaluate_agents`' rows (``agent``, ``seed`` and ``metric``).
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
        The keys :data:`~agents.evaluate.schema.PAIRED_KEYS`: ``metric``, ``reference`` (``None``
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
        The keys :data:`~agents.evaluate.schema.RECIPE_STAT_KEYS`: ``mean`` (of ``d = values −
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
        The keys :data:`~agents.evaluate.schema.RECIPE_KEYS`: ``metric``, ``reference``,
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


def mean_curve(traces: Sequence[Sequence[float]]) -> dict[str, list]:
    """The mean of several traces at each step, with its 95 % Student-t interval.

    Parameters
    ----------
    traces : sequence of sequence of float
        One non-empty trace per episode (``info["map_error"]`` after the reset and every step); a
        trace shorter than the longest keeps its last value.

    Returns
    -------
    dict
        The keys :data:`~agents.evaluate.schema.CURVE_KEYS`: ``step`` (0 … longest length − 1),
        ``mean``, ``ci95_low`` and ``ci95_high`` (lists; ``None`` at every step for a single trace).
    """
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
