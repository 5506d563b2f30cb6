r"""The replay harness: recorded episodes replayed through every filter, and scored.

.. code-block:: bash

    # record with policies, then score (the agents package: it owns the policies)
    python -m agents.robustness --agents random,frontier,revisit,ppo=runs/ppo/model.zip \
        --layouts uniform,loop --episodes 5 --seed 0 --steps 300 --out eval/robustness
    # score episodes recorded before (this module: nothing but the library)
    python -m seif_gym.harness --episodes-dir eval/robustness/episodes --filters seif-k8,eseif,ekf --out eval/replayed

An episode (:class:`~seif_gym.episodes.Episode`) of a ``SeifExplore`` env is
**recorded once** with :class:`~seif_gym.episodes.EpisodeRecorder` (the
policy acts on the env's own SEIF, ``max_active=8``, exactly as it would in
training) and then **replayed** through every filter of ``--filters`` with
:func:`seif_gym.episodes.replay`: all filters see the identical executed
controls and noisy measurements, so differences between them are
differences of the filters alone. This module replays and scores
(:func:`score_replay`, :func:`score_episode`, :func:`evaluate_episodes`),
aggregates (:func:`summary_tables`) and writes the outputs
(:func:`write_outputs`); the policy-driven recording is
:mod:`agents.robustness` (``docs/filters/robustness.md`` was measured with it on
``SeifExplore-v0``). ``seif_gym`` never imports ``agents``.

``python -m seif_gym.harness --episodes-dir PATH ... [--episodes N]`` scores
saved episodes (folders of ``.npz`` files of :meth:`Episode.save
<seif_gym.episodes.Episode.save>`, or the files themselves; ``--episodes N``:
only the first ``N`` found, in the folders' sorted order, as ``--episodes``
is a count in every command). ``--episodes PATH``, this command's spelling
before ``seif_gym`` 1.0 (when it was ``python -m seif_gym.evaluate``), still
works with a ``DeprecationWarning``. A row's ``policy`` is the file's name without the
``_LAYOUT_SEED`` that :mod:`agents.robustness` appends; its ``layout`` and
``seed`` come from the episode.

Filters (``--filters``, comma separated; default :func:`default_filters`):

=================  ==============================================================
``seif-kN``        SEIF with ``max_active=N`` and the env version's mean
                   recovery (``-v0``: round robin, ``-v1``: wavefront; the
                   env's filter is ``seif-k8``)
``seif-kN-exact``  SEIF with ``max_active=N`` and ``mean_recovery="exact"``
``seif-exact``     ``seif-k8-exact``
``seif-full``      SEIF without sparsification, exact recovery (= EIF = EKF)
``eseif``          ESEIF with ``max_active=8``, the env version's recovery (``eseif-kN``:
                   ``max_active=N``; ``eseif-exact``, ``eseif-kN-exact``: exact
                   recovery); in the default set only when ``"eseif"`` is in
                   :data:`seif_gym.slam.FILTERS`
``cseif``          ConservativeSEIF with ``max_active=8`` and the env version's recovery
                   (``cseif-kN``, ``cseif-exact``, ``cseif-kN-exact`` as for the ESEIF);
                   not in the default set
``eif``, ``ekf``   the exact filters
=================  ==============================================================

Metrics
-------
Collected per step by the ``callback`` of :func:`~seif_gym.episodes.replay`
(after the measurement of time ``t``, ``t = 0 .. T``); ``e = truth − estimate``
with the heading error wrapped to ``[-π, π)``. The metrics themselves live in
:mod:`seif_gym.metrics`.

* **pose error** ``‖e_xy‖`` (m) and the absolute heading error.
* **pose NEES** ``eᵀ P⁻¹ e`` (global frame, 3 dof) with the filter's
  *exact* marginal pose covariance ``P`` (``filter.pose_covariance``: a sparse
  solve for the information filters; never the SEIF's constant-time
  Markov-blanket covariance, which is tighter). Consistent: χ²(3), mean 3.
* **pose σ**: ``sqrt(trace P_xy)`` (m), the position uncertainty the filter
  claims; the summary's *σ ratio vs EKF* divides it by the EKF's on the same
  episode (below 1: more certain than the exact filter).
* **map RMSE**: ``sqrt(mean ‖m̂_i − m_i‖²)`` over the *mapped* landmarks (m);
  and the env's capped map error ``E_t`` (unmapped landmarks count ``d_cap``),
  :attr:`~seif_gym.episodes.ReplayResult.map_errors`.
* **relative NEES**: the *joint* NEES of the positions of all mapped
  landmarks relative to the first-mapped one, ``d_i = m_i − m_0``
  (``i = 1 .. m−1``), ``NEES_rel = dᵀ (A Σ_L Aᵀ)⁻¹ d`` with ``Σ_L`` the exact
  joint covariance of the map (from ``filter.covariance()``) and ``A`` the
  difference operator. It has ``2(m−1)`` dof and is *the same for any
  anchor or any spanning tree of pairs* (they are invertible linear maps of
  each other), so it measures the consistency of the map's shape with the
  common translation removed, independently of the pose drift. Reported
  **per relative landmark** (divided by ``m−1``): consistent mean 2.
  Averages over runs and steps pool the sums: ``Σ NEES_rel / Σ (m−1)``, whose
  95 % band is ``χ²(2Σ(m−1)) / Σ(m−1)``.
* **map NEES** (global frame): the joint NEES ``e_Lᵀ Σ_L⁻¹ e_L`` of all mapped
  landmark positions, per landmark (``/ m``): consistent mean 2.
* The relative and map NEES need the full covariance: they are computed
  every ``--nees-every`` steps (default 1: every step; a dense inverse of at
  most ``3 + 2n`` = 63 dimensions with the default 30 landmarks, ~0.2 ms) and
  at the last step; on those steps the pose block of the same matrix (the
  same exact marginal) gives the pose NEES and σ.
* **divergence**: the position error exceeds the env's
  ``divergence_threshold`` (5 m) at some step. The recorded episode ends
  early when the *env's* filter (``seif-k8``) diverges; the other filters
  are scored on the same, shorter data.
* **time per step**: :attr:`~seif_gym.episodes.ReplayResult.step_seconds`
  (one ``predict`` + ``update``; metric computations are not timed). Every
  filter is run once on a short warm-up episode first (:func:`warm_up`:
  numba compilation). The command lines pin BLAS to one thread
  (:func:`seif_gym.threads.limit_blas_threads`): with these small matrices
  threads only add contention.

Outputs (``--out``)
-------------------
``results.csv``
    One row per policy × layout × seed × filter, columns :data:`RESULT_COLUMNS`
    (documented in :data:`COLUMN_DOCS`).
``timeseries.npz``
    Per-step curves, keys :data:`TIMESERIES_KEYS` (no pickle): string arrays
    ``policy``, ``layout``, ``filter`` and int ``seed`` (one entry per row of
    ``results.csv``, same order) and float arrays of shape ``(rows, T_max + 1)``
    (``step_seconds``: ``(rows, T_max)``), NaN after a run's end.
``map_rmse.png``, ``pose_rmse.png``
    Map RMSE (mean over runs) and pose RMSE (root mean square position
    error over runs) against the step, one panel per policy, one line per
    filter.
``nees.png``
    Run-averaged pose NEES (top) and relative NEES per relative landmark
    (bottom) against the step, one panel per policy, with the 95 % χ² band of
    a consistent filter for the number of runs (and landmarks) averaged.
``time_per_step.png``
    Mean and median µs per step of each filter.
``summary.md``
    The Markdown tables printed at the end: per filter over all runs, and per
    policy × filter.
``config.json``
    The arguments of the run.
``episodes/``
    The recorded episodes (``POLICY_LAYOUT_SEED.npz``, :meth:`Episode.save`),
    unless ``--no-save-episodes`` (:mod:`agents.robustness` only).

From Python: :func:`evaluate_episodes` returns the rows and the per-run
series of labelled episodes, :func:`write_outputs` writes the files,
:func:`summary_tables` the tables.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import re
import sys
import time
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from scipy.stats import chi2

import seif_gym  # noqa: F401  (registers the environments)
from seif_gym._atomic import atomic_write, atomic_write_text
from seif_gym.datasets._files import OutputPathError, output_folder, save_figure, save_npz
from seif_gym.envs.explore import SeifExploreEnv
from seif_gym.episodes import Episode, EpisodeRecorder, replay
from seif_gym.metrics import CHI2_975_3DOF, MIN_RELATIVE_LANDMARKS, _map_nees, pose_nees
from seif_gym.progress import Progress
from seif_gym.slam import FILTERS
from seif_gym.slam.models import wrap_angle
from seif_gym.threads import limit_blas_threads
from seif_gym.world import LAYOUTS

__all__ = [
    "RESULT_COLUMNS",
    "COLUMN_DOCS",
    "TIMESERIES_KEYS",
    "LAYOUTS",
    "FilterSpec",
    "default_filters",
    "parse_filter",
    "parse_filters",
    "score_replay",
    "score_episode",
    "warm_up",
    "evaluate_episodes",
    "load_episodes",
    "write_outputs",
    "summary_tables",
    "limit_blas_threads",
    "main",
]

#: The relative NEES's anchor-free definition needs at least this many mapped landmarks.
_MIN_RELATIVE = MIN_RELATIVE_LANDMARKS

#: ``results.csv`` column -> meaning (the order is :data:`RESULT_COLUMNS`).
COLUMN_DOCS: dict[str, str] = {
    "policy": "policy label (baseline name, LABEL of LABEL=PATH.zip, or the .zip's stem / run folder)",
    "layout": "landmark layout of the env",
    "seed": "seed of env.reset (landmarks, start and all noise)",
    "filter": "filter label (seif-k8, seif-exact, eseif, eif, ekf, ...)",
    "steps": "steps T of the recorded episode (shorter than --steps if the env's SEIF diverged)",
    "landmarks_total": "landmarks in the world",
    "landmarks_mapped": "landmarks in the filter's map at the end",
    "final_map_error": "env's map error E_T (mean over all landmarks of min(error, d_cap), unmapped = d_cap), m",
    "final_map_rmse": "RMS position error of the mapped landmarks at the end, m",
    "mean_map_rmse": "map RMSE averaged over the steps with at least one mapped landmark, m",
    "final_pose_error": "position error at the end, m",
    "pose_rmse": "RMS over steps 0..T of the position error, m",
    "heading_rmse_deg": "RMS over steps 0..T of the wrapped heading error, degrees",
    "anees_pose": "mean over steps 1..T of the pose NEES (3 dof, exact marginal; consistent: 3)",
    "pose_nees_above": "fraction of steps 1..T whose pose NEES exceeds chi2(3) 97.5% (9.35; consistent: 0.025)",
    "anees_relative": "sum over NEES steps of the joint relative-map NEES / sum of (m-1) (per relative landmark; consistent: 2)",
    "anees_map": "sum over NEES steps of the joint global map NEES / sum of m (per landmark; consistent: 2)",
    "mean_pose_sigma": "mean over steps 1..T of sqrt(trace) of the exact position covariance, m (what the filter claims)",
    "final_nees_pose": "pose NEES at the end",
    "final_nees_relative": "relative-map NEES per relative landmark at the end (NaN if < 2 mapped)",
    "diverged": "1 if the position error exceeded divergence_threshold at some step, else 0",
    "diverged_step": "first such step, -1 if none",
    "us_per_step_mean": "mean wall time of one predict + update, microseconds",
    "us_per_step_median": "median wall time of one predict + update, microseconds",
}
#: Columns of ``results.csv``, in order.
RESULT_COLUMNS: tuple[str, ...] = tuple(COLUMN_DOCS)

#: Float curves of one run, length ``T + 1`` (index ``t`` = after the measurement of time ``t``).
_CURVES: tuple[str, ...] = (
    "pose_error",  # m
    "heading_error",  # |wrapped| rad
    "pose_nees",  # 3 dof
    "pose_sigma",  # sqrt(trace P_xy), m: the claimed position uncertainty
    "map_rmse",  # m, NaN without mapped landmarks
    "map_error",  # env's E_t
    "landmarks_mapped",
    "relative_nees",  # joint, 2(m-1) dof; NaN when not computed
    "relative_count",  # m-1 where relative_nees was computed, else 0
    "map_nees",  # joint, 2m dof; NaN when not computed
    "map_count",  # m where map_nees was computed, else 0
)
#: Keys of ``timeseries.npz``.
TIMESERIES_KEYS: tuple[str, ...] = ("policy", "layout", "seed", "filter", *_CURVES, "step_seconds")


# -- filters ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FilterSpec:
    """A filter to replay: ``label``, a name of :data:`seif_gym.slam.FILTERS` and its options.

    ``factory`` (``factory(motion, sensor, initial_pose, **options)``), if
    given, builds the filter instead of ``FILTERS[filter]`` (e.g. an
    instrumented subclass in tests).
    """

    label: str
    filter: str
    options: Mapping[str, Any] = field(default_factory=dict)
    factory: Callable[..., Any] | None = None

    def build(self) -> Callable[..., Any]:
        if self.factory is not None:
            return self.factory
        if self.filter not in FILTERS:
            raise ValueError(
                f"filter {self.label!r} needs {self.filter!r}, which is not in seif_gym.slam.FILTERS {tuple(FILTERS)}"
            )
        return FILTERS[self.filter]


def default_filters() -> list[str]:
    """SEIF k = 2, 4, 8, 16, SEIF(8) with exact recovery, ESEIF(8) if available, EIF, EKF."""
    labels = ["seif-k2", "seif-k4", "seif-k8", "seif-k16", "seif-exact"]
    if "eseif" in FILTERS:
        labels.append("eseif")
    return labels + ["eif", "ekf"]


def _max_active_options(name: str, k: int) -> dict[str, Any]:
    cls = FILTERS.get(name)
    accepted = getattr(cls, "OPTIONS", {}) if cls is not None else {"max_active": None}
    return {"max_active": k} if "max_active" in accepted else {}


def parse_filter(spec: str | FilterSpec) -> FilterSpec:
    """The :class:`FilterSpec` of a label (see the module docstring), or ``spec`` itself."""
    if isinstance(spec, FilterSpec):
        return spec
    label = spec.strip()
    if label in ("eif", "ekf"):
        return FilterSpec(label, label, {})
    if label == "seif-full":
        return FilterSpec(label, "seif", {"max_active": None, "mean_recovery": "exact"})
    match = re.fullmatch(r"(seif|eseif|cseif)(?:-k(\d+))?(-exact)?", label)
    if match and (match.group(2) or match.group(3) or match.group(1) in ("eseif", "cseif")):
        name = match.group(1)
        k = int(match.group(2) or 8)
        options: dict[str, Any] = {"max_active": k} if name == "seif" else _max_active_options(name, k)
        if match.group(3):
            options["mean_recovery"] = "exact"
        return FilterSpec(label, name, options)
    raise ValueError(
        f"unknown filter {spec!r}: use seif-kN, seif-kN-exact, seif-exact, seif-full, eseif, eseif-kN, eseif-exact, "
        "eseif-kN-exact, cseif, cseif-kN, cseif-exact, cseif-kN-exact, eif or ekf"
    )


# -- metrics of one replay (the definitions: seif_gym.metrics) --------------------------------------
def score_replay(
    episode: Episode, spec: str | FilterSpec, *, nees_every: int = 1
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Replay ``episode`` through ``spec`` and score it.

    Returns
    -------
    row : dict
        The :data:`RESULT_COLUMNS` but ``policy``, ``layout``, ``seed`` and ``filter``.
    series : dict
        The per-step curves (``_CURVES``, length ``T + 1``) and ``step_seconds`` (length ``T``).
    """
    spec = parse_filter(spec)
    nees_every = int(nees_every)
    if nees_every < 1:
        raise ValueError(f"nees_every must be positive, got {nees_every}")
    steps = episode.steps
    truth_landmarks = np.asarray(episode.landmarks)
    curves = {name: np.full(steps + 1, math.nan) for name in _CURVES}
    curves["relative_count"][:] = 0.0
    curves["map_count"][:] = 0.0

    def callback(t: int, filt: Any) -> None:
        pose = np.asarray(filt.pose, dtype=np.float64)
        true_pose = episode.true_poses[t]
        ids = np.asarray(filt.landmark_ids, dtype=np.int64)
        estimates = np.asarray(filt.landmarks, dtype=np.float64).reshape(-1, 2)
        truth = truth_landmarks[ids]
        m = len(ids)
        curves["pose_error"][t] = math.hypot(true_pose[0] - pose[0], true_pose[1] - pose[1])
        curves["heading_error"][t] = abs(wrap_angle(float(true_pose[2] - pose[2])))
        curves["landmarks_mapped"][t] = m
        if m:
            curves["map_rmse"][t] = math.sqrt(float(np.mean(np.sum((estimates - truth) ** 2, axis=1))))
        if t % nees_every == 0 or t == steps:
            cov = np.asarray(filt.covariance(), dtype=np.float64)  # exact joint covariance (dense)
            pose_cov = cov[:3, :3]
            if m:
                global_nees, relative_nees = _map_nees(truth, estimates, cov[3:, 3:])
                curves["map_nees"][t], curves["map_count"][t] = global_nees, m
                if m >= _MIN_RELATIVE:
                    curves["relative_nees"][t], curves["relative_count"][t] = relative_nees, m - 1
        else:
            pose_cov = np.asarray(filt.pose_covariance, dtype=np.float64)  # exact marginal (sparse solve)
        curves["pose_nees"][t] = pose_nees(true_pose, pose, pose_cov)
        curves["pose_sigma"][t] = math.sqrt(max(float(pose_cov[0, 0] + pose_cov[1, 1]), 0.0))

    result = replay(episode, filter_factory=spec.build(), callback=callback, **dict(spec.options))
    curves["map_error"][:] = result.map_errors
    seconds = np.asarray(result.step_seconds, dtype=np.float64)

    threshold = float(episode.config["divergence_threshold"])
    beyond = np.flatnonzero(curves["pose_error"] > threshold)
    pose_nees_steps = curves["pose_nees"][1:] if steps else curves["pose_nees"]
    relative_total = float(np.nansum(curves["relative_nees"]))
    relative_count = float(np.sum(curves["relative_count"]))
    map_total = float(np.nansum(curves["map_nees"]))
    map_count = float(np.sum(curves["map_count"]))
    mapped_rmse = curves["map_rmse"][np.isfinite(curves["map_rmse"])]
    final_relative = (
        curves["relative_nees"][-1] / curves["relative_count"][-1] if curves["relative_count"][-1] else math.nan
    )
    row = {
        "steps": steps,
        "landmarks_total": len(truth_landmarks),
        "landmarks_mapped": int(curves["landmarks_mapped"][-1]),
        "final_map_error": float(result.map_errors[-1]),
        "final_map_rmse": float(curves["map_rmse"][-1]),
        "mean_map_rmse": float(np.mean(mapped_rmse)) if len(mapped_rmse) else math.nan,
        "final_pose_error": float(curves["pose_error"][-1]),
        "pose_rmse": math.sqrt(float(np.mean(curves["pose_error"] ** 2))),
        "heading_rmse_deg": math.degrees(math.sqrt(float(np.mean(curves["heading_error"] ** 2)))),
        "anees_pose": float(np.mean(pose_nees_steps)),
        "pose_nees_above": float(np.mean(pose_nees_steps > CHI2_975_3DOF)),
        "anees_relative": relative_total / relative_count if relative_count else math.nan,
        "anees_map": map_total / map_count if map_count else math.nan,
        "mean_pose_sigma": float(np.mean(curves["pose_sigma"][1:])) if steps else float(curves["pose_sigma"][0]),
        "final_nees_pose": float(curves["pose_nees"][-1]),
        "final_nees_relative": float(final_relative),
        "diverged": int(len(beyond) > 0),
        "diverged_step": int(beyond[0]) if len(beyond) else -1,
        "us_per_step_mean": 1e6 * float(np.mean(seconds)) if len(seconds) else math.nan,
        "us_per_step_median": 1e6 * float(np.median(seconds)) if len(seconds) else math.nan,
    }
    return row, {**curves, "step_seconds": seconds}


# -- episodes ---------------------------------------------------------------------------------------
def score_episode(episode: Episode, filters: Sequence[str | FilterSpec], *, policy: str,
                  nees_every: int = 1) -> tuple[list[dict[str, Any]], list[dict[str, np.ndarray]]]:  # fmt: skip
    """Replay ``episode`` through every filter of ``filters``: one row (and one series) per filter.

    Parameters
    ----------
    episode : Episode
        A recorded episode.
    filters : sequence of str or FilterSpec
        The filters (:func:`parse_filter`).
    policy : str
        The ``policy`` column (who drove the episode).
    nees_every : int
        Steps between computations of the full covariance.

    Returns
    -------
    rows : list of dict
        Keys :data:`RESULT_COLUMNS`; ``layout`` and ``seed`` from the episode
        (``seed`` -1 for an episode not started with a seed).
    series : list of dict
        The per-step curves of each row (:func:`score_replay`).
    """
    if not isinstance(episode, Episode):
        raise TypeError(f"episode must be an Episode, got {type(episode).__name__}")
    layout = str(episode.config.get("layout", ""))
    seed = -1 if episode.seed is None else int(episode.seed)
    rows: list[dict[str, Any]] = []
    series: list[dict[str, np.ndarray]] = []
    for spec in filters:
        spec = parse_filter(spec)
        row, curves = score_replay(episode, spec, nees_every=nees_every)
        rows.append({"policy": str(policy), "layout": layout, "seed": seed, "filter": spec.label, **row})
        series.append(curves)
    return rows, series


def parse_filters(filters: Sequence[str | FilterSpec] | None) -> list[FilterSpec]:
    """Parsed, distinct and available filters (default :func:`default_filters`).

    Raises
    ------
    ValueError
        If a label is unknown or repeated, a filter is not available, or ``filters`` is empty.
    """
    specs = [parse_filter(f) for f in (default_filters() if filters is None else filters)]
    if not specs:
        raise ValueError("filters: give at least one filter")
    labels = [spec.label for spec in specs]
    if len(set(labels)) != len(labels):
        raise ValueError(f"filters: labels must be distinct, got {labels}")
    for spec in specs:
        spec.build()  # fail early on an unavailable filter
    return specs


def warm_up(filters: Sequence[str | FilterSpec], config: Mapping[str, Any], nees_every: int = 1) -> None:
    """Replay a short episode through every filter before timing (numba compilation, first scipy calls).

    Parameters
    ----------
    filters : sequence of str or FilterSpec
    config : mapping
        Keyword arguments of the env to record the warm-up episode in (an
        episode's :attr:`~seif_gym.episodes.Episode.config`).
    nees_every : int
        As in the timed replays.
    """
    env = EpisodeRecorder(gym.wrappers.TimeLimit(SeifExploreEnv(**dict(config)), max_episode_steps=15))
    try:
        env.reset(seed=123_456_789)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(np.array([0.8, 0.3]))
            done = terminated or truncated
        for spec in filters:
            score_replay(env.episode, spec, nees_every=nees_every)
    finally:
        env.close()


def evaluate_episodes(
    episodes: Iterable[tuple[str, Episode]],
    filters: Sequence[str | FilterSpec] | None = None,
    *,
    nees_every: int = 1,
    warm: bool = True,
    verbose: bool = False,
) -> tuple[list[dict[str, Any]], list[dict[str, np.ndarray]]]:
    """Replay every episode through every filter and score it.

    Parameters
    ----------
    episodes : iterable of (str, Episode)
        ``(policy label, episode)`` pairs, in the order of the rows.
    filters : sequence of str or FilterSpec, optional
        Default :func:`default_filters`.
    nees_every : int
        Steps between computations of the full covariance (relative and map NEES).
    warm : bool
        Run :func:`warm_up` first (with the first episode's configuration), so
        that compilation is not timed.
    verbose : bool
        Progress on stderr.

    Returns
    -------
    rows : list of dict
        One per episode × filter (in this nesting order), keys :data:`RESULT_COLUMNS`.
    series : list of dict
        The per-step curves of each row (see :func:`score_replay`).
    """
    pairs = list(episodes)
    if not pairs:
        raise ValueError("episodes: give at least one (label, episode) pair")
    specs = parse_filters(filters)
    if int(nees_every) < 1:
        raise ValueError(f"nees_every must be positive, got {nees_every}")
    if warm:
        warm_up(specs, pairs[0][1].config, int(nees_every))
    rows: list[dict[str, Any]] = []
    series: list[dict[str, np.ndarray]] = []
    with Progress(len(pairs), "replaying", enabled=verbose, unit="episodes") as progress:
        for label, episode in pairs:
            episode_rows, episode_series = score_episode(episode, specs, policy=label, nees_every=int(nees_every))
            rows += episode_rows
            series += episode_series
            progress.update(1, f"{label} {episode_rows[0]['layout']} seed {episode_rows[0]['seed']}")
    return rows, series


def _episode_label(path: Path, episode: Episode) -> str:
    """The file's name without the ``_LAYOUT_SEED`` that :mod:`agents.robustness` appends."""
    suffix = f"_{episode.config.get('layout', '')}_{-1 if episode.seed is None else int(episode.seed)}"
    return path.stem[: -len(suffix)] if path.stem.endswith(suffix) and len(path.stem) > len(suffix) else path.stem


def load_episodes(paths: Iterable[str | Path], limit: int | None = None) -> list[tuple[str, Episode]]:
    """``(label, episode)`` of saved episodes: ``.npz`` files, and every ``*.npz`` of a folder (sorted).

    ``limit``: only the first ``limit`` files found (in that order).

    Raises
    ------
    FileNotFoundError
        If a path does not exist.
    ValueError
        If nothing is found, ``limit`` is not a positive integer, or a file is
        not a readable saved episode (the message names the file).
    """
    if limit is not None and (isinstance(limit, bool) or not isinstance(limit, int) or limit < 1):
        raise ValueError(f"limit must be a positive integer, got {limit!r}")
    files: list[Path] = []
    for item in paths:
        path = Path(item)
        if path.is_dir():
            files += sorted(path.glob("*.npz"))
        elif path.is_file():
            files.append(path)
        else:
            raise FileNotFoundError(f"episodes: no file or folder {path}")
    if not files:
        raise ValueError("episodes: no .npz episode found")
    loaded = []
    for path in files[:limit]:
        episode = Episode.load(path)  # one-line errors that name the file
        loaded.append((_episode_label(path, episode), episode))
    return loaded


# -- aggregation ------------------------------------------------------------------------------------
def _stack(series: Sequence[Mapping[str, np.ndarray]], key: str, length: int) -> np.ndarray:
    out = np.full((len(series), length), math.nan)
    for i, curves in enumerate(series):
        values = curves[key]
        out[i, : len(values)] = values
    return out


def _band(dof_total: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """95 % band of ``χ²(dof_total) / count`` (NaN where ``dof_total`` is 0)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        low = np.where(dof_total > 0, chi2.ppf(0.025, np.maximum(dof_total, 1)) / count, math.nan)
        high = np.where(dof_total > 0, chi2.ppf(0.975, np.maximum(dof_total, 1)) / count, math.nan)
    return low, high


def _averaged_nees(series: Sequence[Mapping[str, np.ndarray]], length: int) -> dict[str, np.ndarray]:
    """Run-averaged pose NEES and pooled relative NEES per step, with their 95 % bands."""
    pose = _stack(series, "pose_nees", length)
    runs = np.sum(np.isfinite(pose), axis=0).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        pose_mean = np.nansum(pose, axis=0) / runs
        pose_low, pose_high = _band(3 * runs, runs)
        relative = np.nansum(_stack(series, "relative_nees", length), axis=0)
        count = np.nansum(_stack(series, "relative_count", length), axis=0)
        relative_mean = np.where(count > 0, relative / np.maximum(count, 1), math.nan)
        rel_low, rel_high = _band(2 * count, np.maximum(count, 1))
    return {
        "pose": pose_mean, "pose_low": pose_low, "pose_high": pose_high,
        "relative": relative_mean, "relative_low": rel_low, "relative_high": rel_high,
    }  # fmt: skip


def _in_band(mean: np.ndarray, low: np.ndarray, high: np.ndarray) -> tuple[float, float]:
    """Fractions of steps (1..) whose averaged NEES lies in, and above, the band."""
    valid = np.isfinite(low) & np.isfinite(mean)
    valid[0] = False
    if not np.any(valid):
        return math.nan, math.nan
    inside = (mean >= low) & (mean <= high)
    return float(np.mean(inside[valid])), float(np.mean((mean > high)[valid]))


def _fmt(value: float, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    if isinstance(value, float) and math.isinf(value):
        return "inf"
    if abs(value) >= 1000:
        return f"{value:.3g}"
    return f"{value:.{digits}f}"


def _group(
    rows: Sequence[Mapping[str, Any]], series: Sequence[Mapping[str, np.ndarray]], keys: Sequence[str]
) -> dict[tuple, list[int]]:
    groups: dict[tuple, list[int]] = {}
    for i, row in enumerate(rows):
        groups.setdefault(tuple(row[k] for k in keys), []).append(i)
    return groups


def _sigma_ratio(
    rows: Sequence[Mapping[str, Any]], series: Sequence[Mapping[str, np.ndarray]], indices: Sequence[int]
) -> float:
    """Mean over runs and steps 1.. of ``pose_sigma / pose_sigma(ekf)`` on the same episode (NaN without an EKF)."""
    reference = {(r["policy"], r["layout"], r["seed"]): series[i] for i, r in enumerate(rows) if r["filter"] == "ekf"}
    ratios = []
    for i in indices:
        ekf = reference.get((rows[i]["policy"], rows[i]["layout"], rows[i]["seed"]))
        if ekf is not None:
            with np.errstate(invalid="ignore", divide="ignore"):
                ratios.append(series[i]["pose_sigma"][1:] / ekf["pose_sigma"][1:])
    values = np.concatenate(ratios) if ratios else np.empty(0)
    values = values[np.isfinite(values)]
    return float(np.mean(values)) if len(values) else math.nan


def _aggregate(
    rows: Sequence[Mapping[str, Any]], series: Sequence[Mapping[str, np.ndarray]], indices: Sequence[int]
) -> dict[str, float]:
    chosen = [rows[i] for i in indices]
    curves = [series[i] for i in indices]
    length = max(len(c["pose_nees"]) for c in curves)

    def mean(key: str) -> float:
        values = np.array([row[key] for row in chosen], dtype=float)
        return float(np.nanmean(values)) if np.any(np.isfinite(values)) else math.nan

    pose_steps = np.concatenate([c["pose_nees"][1:] for c in curves])
    averaged = _averaged_nees(curves, length)
    in_band, above = _in_band(averaged["pose"], averaged["pose_low"], averaged["pose_high"])
    rel_in, rel_above = _in_band(averaged["relative"], averaged["relative_low"], averaged["relative_high"])
    rel_count = sum(float(np.sum(c["relative_count"])) for c in curves)
    map_count = sum(float(np.sum(c["map_count"])) for c in curves)
    seconds = np.concatenate([c["step_seconds"] for c in curves])
    return {
        "runs": len(chosen),
        "final_map_rmse": mean("final_map_rmse"),
        "final_map_error": mean("final_map_error"),
        "pose_rmse": mean("pose_rmse"),
        "anees_pose": float(np.mean(pose_steps)) if len(pose_steps) else math.nan,
        "median_nees_pose": float(np.median(pose_steps)) if len(pose_steps) else math.nan,
        "pose_in_band": in_band,
        "pose_above_band": above,
        "anees_relative": sum(float(np.nansum(c["relative_nees"])) for c in curves) / rel_count
        if rel_count
        else math.nan,
        "relative_in_band": rel_in,
        "relative_above_band": rel_above,
        "anees_map": sum(float(np.nansum(c["map_nees"])) for c in curves) / map_count if map_count else math.nan,
        "diverged": mean("diverged"),
        "sigma_ratio": _sigma_ratio(rows, series, indices),
        "us_per_step": 1e6 * float(np.mean(seconds)) if len(seconds) else math.nan,
        "us_per_step_median": 1e6 * float(np.median(seconds)) if len(seconds) else math.nan,
    }


def summary_tables(rows: Sequence[Mapping[str, Any]], series: Sequence[Mapping[str, np.ndarray]]) -> str:
    """Markdown: one table per filter over all runs, one per policy × filter."""
    filters = list(dict.fromkeys(row["filter"] for row in rows))
    policies = list(dict.fromkeys(row["policy"] for row in rows))
    by_filter = _group(rows, series, ("filter",))
    lines = [
        "All runs (policies × layouts × seeds) per filter. ANEES: pooled mean over runs and steps "
        "(pose: 3 dof, consistent = 3; relative / map: per landmark, consistent = 2). "
        "in / above band: share of steps whose run-averaged NEES lies in / above the 95% χ² band. "
        "σ ratio: mean over runs and steps of sqrt(trace P_xy) / the EKF's on the same episode "
        "(< 1: the filter claims more certainty than the EKF).",
        "",
        "| filter | runs | final map RMSE (m) | final E_T (m) | pose RMSE (m) | ANEES pose | median NEES pose "
        "| pose in band | pose above band | σ ratio vs EKF | ANEES relative | relative above band | ANEES map | diverged "
        "| µs/step (mean) | µs/step (median) |",
        "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|",
    ]
    for name in filters:
        a = _aggregate(rows, series, by_filter[(name,)])
        lines.append(
            f"| {name} | {a['runs']} | {_fmt(a['final_map_rmse'])} | {_fmt(a['final_map_error'])} | {_fmt(a['pose_rmse'])} "
            f"| {_fmt(a['anees_pose'], 2)} | {_fmt(a['median_nees_pose'], 2)} | {_fmt(100 * a['pose_in_band'], 0)}% "
            f"| {_fmt(100 * a['pose_above_band'], 0)}% | {_fmt(a['sigma_ratio'], 2)} | {_fmt(a['anees_relative'], 2)} "
            f"| {_fmt(100 * a['relative_above_band'], 0)}% "
            f"| {_fmt(a['anees_map'], 2)} | {_fmt(100 * a['diverged'], 0)}% | {_fmt(a['us_per_step'], 0)} | {_fmt(a['us_per_step_median'], 0)} |"
        )
    # per policy
    ekf_error = {(r["policy"], r["layout"], r["seed"]): r["final_map_error"] for r in rows if r["filter"] == "ekf"}
    lines += [
        "",
        "Per policy × filter (all layouts and seeds). ΔE_T vs EKF: mean over runs of the filter's final map error "
        "minus the EKF's on the same data (the adversary's objective for the env's SEIF, seif-k8).",
        "",
        "| policy | filter | runs | final map RMSE (m) | final E_T (m) | ΔE_T vs EKF (m) | pose RMSE (m) | ANEES pose "
        "| pose above band | σ ratio vs EKF | ANEES relative | ANEES map | diverged |",
        "|---|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|",
    ]
    by_pair = _group(rows, series, ("policy", "filter"))
    for policy in policies:
        for name in filters:
            indices = by_pair.get((policy, name))
            if not indices:
                continue
            a = _aggregate(rows, series, indices)
            gaps = [
                rows[i]["final_map_error"] - ekf_error[(rows[i]["policy"], rows[i]["layout"], rows[i]["seed"])]
                for i in indices
                if (rows[i]["policy"], rows[i]["layout"], rows[i]["seed"]) in ekf_error
            ]
            gap = float(np.mean(gaps)) if gaps else math.nan
            lines.append(
                f"| {policy} | {name} | {a['runs']} | {_fmt(a['final_map_rmse'])} | {_fmt(a['final_map_error'])} | {_fmt(gap)} "
                f"| {_fmt(a['pose_rmse'])} | {_fmt(a['anees_pose'], 2)} | {_fmt(100 * a['pose_above_band'], 0)}% "
                f"| {_fmt(a['sigma_ratio'], 2)} | {_fmt(a['anees_relative'], 2)} | {_fmt(a['anees_map'], 2)} | {_fmt(100 * a['diverged'], 0)}% |"
            )
    return "\n".join(lines)


# -- output -----------------------------------------------------------------------------------------
def _csv_value(value: Any) -> Any:
    if isinstance(value, float):
        return (
            repr(value) if math.isfinite(value) else ("nan" if math.isnan(value) else ("inf" if value > 0 else "-inf"))
        )
    return value


def write_outputs(
    rows: Sequence[Mapping[str, Any]],
    series: Sequence[Mapping[str, np.ndarray]],
    out: str | Path,
    config: Mapping[str, Any] | None = None,
) -> dict[str, Path]:
    """Write ``results.csv``, ``timeseries.npz``, the plots, ``summary.md`` (and ``config.json``) into ``out``.

    Each file is written whole or not at all (:mod:`seif_gym._atomic`), ``config.json`` last: a folder
    with it holds a finished run.

    Raises
    ------
    ValueError
        If ``out`` cannot be a folder (it is a file, or not writable); nothing is written then.
    """
    try:
        folder = output_folder(out, "out")
    except OutputPathError as error:
        raise ValueError(str(error)) from None
    paths = {
        "csv": folder / "results.csv",
        "timeseries": folder / "timeseries.npz",
        "map_rmse": folder / "map_rmse.png",
        "pose_rmse": folder / "pose_rmse.png",
        "nees": folder / "nees.png",
        "time_per_step": folder / "time_per_step.png",
        "summary": folder / "summary.md",
    }
    (folder / "config.json").unlink(missing_ok=True)  # the previous run's mark of a finished folder goes first

    def write_csv(temporary: Path) -> None:
        with temporary.open("w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(RESULT_COLUMNS))
            writer.writeheader()
            for row in rows:
                writer.writerow({column: _csv_value(row[column]) for column in RESULT_COLUMNS})

    atomic_write(paths["csv"], write_csv)
    length = max(len(c["pose_nees"]) for c in series)
    arrays: dict[str, Any] = {
        "policy": np.array([row["policy"] for row in rows], dtype=str),
        "layout": np.array([row["layout"] for row in rows], dtype=str),
        "seed": np.array([row["seed"] for row in rows], dtype=np.int64),
        "filter": np.array([row["filter"] for row in rows], dtype=str),
    }
    for key in _CURVES:
        arrays[key] = _stack(series, key, length)
    arrays["step_seconds"] = _stack(series, "step_seconds", max(length - 1, 0))
    save_npz(paths["timeseries"], arrays)
    _plots(rows, series, paths)
    atomic_write_text(paths["summary"], summary_tables(rows, series) + "\n")
    if config is not None:
        paths["config"] = folder / "config.json"
        atomic_write_text(paths["config"], json.dumps(dict(config), indent=2) + "\n")
    return paths


def _plots(
    rows: Sequence[Mapping[str, Any]], series: Sequence[Mapping[str, np.ndarray]], paths: Mapping[str, Path]
) -> None:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    filters = list(dict.fromkeys(row["filter"] for row in rows))
    policies = list(dict.fromkeys(row["policy"] for row in rows))
    colors = {name: plt.get_cmap("tab10")(i % 10) for i, name in enumerate(filters)}
    by_pair = _group(rows, series, ("policy", "filter"))
    length = max(len(c["pose_nees"]) for c in series)
    steps = np.arange(length)
    width = 4.2 * len(policies) + 1.5

    def runs_of(policy: str, name: str) -> list[Mapping[str, np.ndarray]]:
        return [series[i] for i in by_pair.get((policy, name), [])]

    def panels(nrows: int = 1) -> tuple[Any, Any]:
        fig, axes = plt.subplots(
            nrows, len(policies), figsize=(width, 3.6 * nrows), dpi=110, squeeze=False, sharex=True
        )
        return fig, axes

    def finish(fig: Any, axes: Any, path: str | os.PathLike[str]) -> None:
        handles, labels = axes[0, 0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="center right", fontsize=8, frameon=False)
        fig.tight_layout(rect=(0, 0, 1 - 1.3 / width, 1))
        save_figure(fig, path)
        plt.close(fig)

    # map RMSE and pose RMSE
    for key, path, ylabel, reduce in (
        ("map_rmse", paths["map_rmse"], "map RMSE of mapped landmarks (m)", "mean"),
        ("pose_error", paths["pose_rmse"], "pose RMSE over runs (m)", "rms"),
    ):
        fig, axes = panels()
        for col, policy in enumerate(policies):
            ax = axes[0, col]
            for name in filters:
                curves = runs_of(policy, name)
                if not curves:
                    continue
                data = _stack(curves, key, length)
                with np.errstate(invalid="ignore"), _quiet():
                    value = np.nanmean(data, axis=0) if reduce == "mean" else np.sqrt(np.nanmean(data**2, axis=0))
                ax.plot(steps, value, color=colors[name], label=name, linewidth=1.2)
            ax.set_title(f"{policy} ({len(runs_of(policy, filters[0]))} runs)")
            ax.set_xlabel("step")
            ax.set_ylabel(ylabel)
            ax.grid(alpha=0.3)
        finish(fig, axes, path)

    # NEES
    fig, axes = panels(2)
    for col, policy in enumerate(policies):
        band_drawn = [False, False]
        for name in filters:
            curves = runs_of(policy, name)
            if not curves:
                continue
            averaged = _averaged_nees(curves, length)
            for row, (key, dof) in enumerate((("pose", 3), ("relative", 2))):
                ax = axes[row, col]
                shown = slice(1, None)  # from step 1: at the reset the pose is known exactly (NEES ~ 0)
                if not band_drawn[row]:
                    ax.fill_between(steps[shown], averaged[f"{key}_low"][shown], averaged[f"{key}_high"][shown],
                                    color="0.6", alpha=0.35, linewidth=0, label="95% χ² band")  # fmt: skip
                    ax.axhline(dof, color="0.3", linewidth=0.8, linestyle="--")
                    band_drawn[row] = True
                ax.plot(steps[shown], averaged[key][shown], color=colors[name], label=name, linewidth=1.1)
        for row, title in enumerate(("pose NEES (global, 3 dof)", "relative-map NEES per landmark (2 dof)")):
            ax = axes[row, col]
            ax.set_yscale("log")
            ax.set_title(f"{policy}: {title}", fontsize=9)
            ax.set_xlabel("step")
            ax.set_ylabel("run-averaged NEES")
            ax.grid(alpha=0.3, which="both")
    finish(fig, axes, paths["nees"])

    # time per step
    fig, ax = plt.subplots(figsize=(1.1 * len(filters) + 2, 3.6), dpi=110)
    by_filter = _group(rows, series, ("filter",))
    means, medians = [], []
    for name in filters:
        seconds = np.concatenate([series[i]["step_seconds"] for i in by_filter[(name,)]])
        means.append(1e6 * float(np.mean(seconds)) if len(seconds) else math.nan)
        medians.append(1e6 * float(np.median(seconds)) if len(seconds) else math.nan)
    x = np.arange(len(filters))
    ax.bar(x - 0.2, means, 0.4, label="mean", color=[colors[n] for n in filters])
    ax.bar(x + 0.2, medians, 0.4, label="median", color=[colors[n] for n in filters], alpha=0.5)
    ax.set_xticks(x, filters, rotation=30, ha="right")
    ax.set_ylabel("µs per predict + update")
    ax.set_title("time per step (solid: mean, light: median)")
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    save_figure(fig, paths["time_per_step"])
    plt.close(fig)


class _quiet:
    """Silence numpy's "mean of empty slice" warnings (all-NaN steps after an early end)."""

    def __enter__(self) -> _quiet:
        import warnings

        self._catch = warnings.catch_warnings()
        self._catch.__enter__()
        warnings.simplefilter("ignore", RuntimeWarning)
        return self

    def __exit__(self, *exc: Any) -> None:
        self._catch.__exit__(*exc)


# -- command line -----------------------------------------------------------------------------------
def _split(text: str) -> list[str]:
    return [part.strip() for part in text.split(",") if part.strip()]


#: Options of the recording command line, which moved to ``python -m agents.robustness``.
_RECORDING_OPTIONS = ("--agents", "--policies", "--layouts", "--seeds", "--seed", "--steps", "--env", "--env-kwargs",
                      "--no-save-episodes")  # fmt: skip


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m seif_gym.harness",
        description="Replay recorded episodes through every filter and score them "
                    "(recording with policies: python -m agents.robustness).",
        epilog="See the module docstring (python -c 'import seif_gym.harness as h; help(h)') for the metrics and outputs.",
    )  # fmt: skip
    parser.add_argument("--episodes-dir", nargs="+", metavar="PATH", default=[],
                        help="folders of saved episodes (.npz), or the files, e.g. eval/robustness/episodes")  # fmt: skip
    parser.add_argument("--episodes", nargs="+", metavar="N", default=None,
                        help="score only the first N episodes found (default: all); "
                        "--episodes PATH is the deprecated spelling of --episodes-dir PATH")  # fmt: skip
    parser.add_argument(
        "--filters", default=None, help=f"comma-separated filters (default {','.join(default_filters())})"
    )
    parser.add_argument("--nees-every", type=int, default=1, help="steps between full-covariance NEES (default 1)")
    parser.add_argument("--out", default="eval/replayed",
                        help="output folder (default eval/replayed; not the recording run's, whose files it would replace)")  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    for option in _RECORDING_OPTIONS:
        parser.add_argument(option, dest=f"moved_{option[2:].replace('-', '_')}", nargs="?", const=True,
                            help=argparse.SUPPRESS)  # fmt: skip
    return parser


def _episodes_option(values: list[str] | None) -> tuple[int | None, list[str]]:
    """``--episodes``: ``(count, [])`` for one integer, else ``(None, paths)`` (the deprecated spelling)."""
    if not values:
        return None, []
    if len(values) == 1 and re.fullmatch(r"[+-]?\d+", values[0].strip()) and not Path(values[0]).exists():
        return int(values[0]), []
    warnings.warn(
        "--episodes PATH is deprecated: --episodes is a count (as in every command); give the folders or files "
        "with --episodes-dir PATH",
        DeprecationWarning,
        stacklevel=3,
    )
    return None, list(values)


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    moved = [
        option for option in _RECORDING_OPTIONS if getattr(args, f"moved_{option[2:].replace('-', '_')}") is not None
    ]
    if moved:
        parser.error(f"{', '.join(moved)}: recording episodes with policies moved to `python -m agents.robustness` "
                     "(the same options); this command scores saved episodes (--episodes-dir PATH ...)")  # fmt: skip
    count, old_paths = _episodes_option(args.episodes)
    paths = [*args.episodes_dir, *old_paths]
    if not paths:
        parser.error("give --episodes-dir PATH ... (folders of saved episodes, or the files)")
    if count is not None and count < 1:
        parser.error(f"--episodes must be a positive count, got {count}")
    if args.nees_every < 1:
        parser.error("--nees-every must be positive")
    filters = _split(args.filters) if args.filters else default_filters()
    try:
        specs = parse_filters(filters)
    except ValueError as error:
        parser.error(str(error))
    try:  # the data and --out, before any work: one line on stderr, exit 2
        output_folder(args.out, "--out")
        episodes = load_episodes(paths, limit=count)
    except (ValueError, FileNotFoundError) as error:
        print(f"{parser.prog}: error: {error}", file=sys.stderr)
        return 2
    limit_blas_threads(1)
    started = time.perf_counter()
    rows, series = evaluate_episodes(episodes, specs, nees_every=args.nees_every, verbose=not args.quiet)
    wall = time.perf_counter() - started
    config = {
        "argv": list(sys.argv[1:] if argv is None else argv), "episodes_dir": [str(p) for p in paths],
        "episodes": len(episodes),
        "filters": [{"label": s.label, "filter": s.filter, "options": dict(s.options)} for s in specs],
        "nees_every": args.nees_every, "wall_seconds": wall,
    }  # fmt: skip
    paths_written = write_outputs(rows, series, Path(args.out), config)
    print(f"{len(episodes)} episodes ({', '.join(dict.fromkeys(label for label, _ in episodes))}) through "
          f"{len(specs)} filters\n")  # fmt: skip
    print(summary_tables(rows, series))
    print(f"\nwrote {', '.join(str(p) for p in paths_written.values())}; {wall:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
