r"""The filter robustness harness with agents: ``python -m agents.robustness``.

.. code-block:: bash

    python -m agents.robustness --agents random,frontier,revisit,ppo=runs/ppo/model.zip \
        --layouts uniform,loop --episodes 5 --seed 0 --steps 300 --out eval/robustness \
        [--env SeifExplore-v2] [--workers N | --ray auto|ADDRESS] [--resume OUT] [--quiet]

For every (agent, layout, seed) one episode of ``--env`` (default the newest
task, :data:`seif_gym.LATEST_ID`; with ``layout=`` the layout, default the
task's own, and ``max_episode_steps=`` ``--steps``) is **recorded once** (the
agent acts on the env's own SEIF through
:class:`~seif_gym.episodes.EpisodeRecorder`, exactly as it would in training;
:func:`record_episode`) and then **replayed** through every filter of
``--filters`` and scored by :mod:`seif_gym.harness`, whose docstring defines
the filters, the metrics and the outputs (where an agent is a *policy*: the
``policy`` column). This module adds only what needs the agents: building
them and driving the recording. ``python -m seif_gym.harness --episodes-dir
DIR`` scores saved episodes again without them.

Agents (``--agents``, comma separated; default every baseline of
:data:`agents.BASELINES`): what :func:`agents.loading.load_agent` builds,
each optionally labelled ``LABEL=SPEC``. Every agent acts with
``deterministic=True``; ``random`` is seeded with the episode seed. Progress
goes to stderr (``--quiet``: none). The episodes are recorded and replayed one
after another in this process, on ``--workers N`` local processes or as Ray
tasks on a cluster (``--ray``; :mod:`agents.parallel`): the rows are the same
but for the measured times.

Every input is checked before any episode runs and before anything is
written (:mod:`agents.cli`): a bad one exits with status 2 and one line.
Each task's rows are kept in ``--out`` as it finishes
(:class:`~agents.evaluate.journal.RunJournal`): a killed run goes on with the
same arguments and ``--resume OUT``, to the rows of a run left alone. Every
file is written whole or not at all, and ``manifest.json`` last.

``--paired-against LABEL`` compares every other agent with ``LABEL``, per
filter and metric, over the episodes they share (the same layout and seed:
the same landmarks, start and noise seed): the mean per-episode difference
with its Student-t and bootstrap 95% intervals, and for the NEES metrics,
whose tails are heavy, also the ratio of geometric means (the paired
difference of the logarithms, exponentiated). :func:`paired_policies`;
written to ``paired.md`` and ``paired.csv``.
"""

from __future__ import annotations

import argparse
import csv
import io
import math
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, cast

import gymnasium as gym
import numpy as np

import seif_gym  # noqa: F401  (registers the environments)
from agents.base import Agent
from agents.baselines import BASELINES
from agents.cli import (
    add_deprecated_alias,
    add_resume_argument,
    agents_help,
    check_agents,
    check_env,
    check_seeds,
    json_object,
    model_digests,
    positive_int,
    resume_folder,
    task,
    tasks_epilog,
    usage_errors,
)
from agents.cli import seed as seed_type
from agents.evaluate import build_agent, paired_difference, paired_verdict, run_episode
from agents.evaluate.journal import RunJournal, journal_for_command_line, write_manifest
from agents.loading import agent_labels, check_agent_spec
from agents.parallel import Executor, chunks
from agents.parallel import add_arguments as add_executor_arguments
from agents.parallel import from_arguments as executor_from_arguments
from seif_gym import LATEST_ID
from seif_gym._atomic import atomic_write_bytes, atomic_write_text
from seif_gym.envs.explore import SeifExploreEnv
from seif_gym.episodes import Episode, EpisodeRecorder
from seif_gym.harness import (
    RESULT_COLUMNS,
    FilterSpec,
    default_filters,
    parse_filters,
    score_episode,
    summary_tables,
    warm_up,
    write_outputs,
)
from seif_gym.progress import Progress
from seif_gym.threads import limit_blas_threads
from seif_gym.world import LAYOUTS

__all__ = ["COMMAND", "DEFAULT_POLICIES", "PAIRED_METRICS", "PAIRED_COLUMNS", "record_episode", "evaluate",
           "paired_policies", "paired_policies_table", "main"]  # fmt: skip

#: The command's name in its journal and manifest.
COMMAND = "agents.robustness"
#: Policies of a run without ``--policies``.
DEFAULT_POLICIES: tuple[str, ...] = BASELINES

#: Metrics of :func:`paired_policies` by default (columns of :data:`seif_gym.harness.RESULT_COLUMNS`).
PAIRED_METRICS: tuple[str, ...] = ("anees_pose", "anees_relative", "final_map_error", "pose_rmse")

#: :func:`agents.evaluate.paired_verdict` (lower is better) in the neutral words of a comparison of policies.
_DIRECTION: dict[str, str] = {
    "beats": "lower",
    "worse": "higher",
    "tie (interval holds 0)": "tie",
    "n/a (one seed)": "tie",
}

#: Columns of :func:`paired_policies`' rows (``paired.csv``).
PAIRED_COLUMNS: tuple[str, ...] = (
    "filter", "metric", "policy", "reference", "n", "policy_mean", "reference_mean", "difference",
    "ci95_low", "ci95_high", "bootstrap_ci95_low", "bootstrap_ci95_high", "ratio", "ratio_ci95_low",
    "ratio_ci95_high", "verdict",
)  # fmt: skip


def record_episode(env: EpisodeRecorder, agent: Agent, seed: int) -> Episode:
    """One episode of ``agent`` in the recording ``env`` from ``reset(seed=seed)`` (``deterministic=True``).

    Parameters
    ----------
    env : EpisodeRecorder
        The recording env.
    agent : Agent
        Anything with SB3's ``predict``.
    seed : int
        Seed of ``env.reset``.

    Returns
    -------
    Episode

    Raises
    ------
    TypeError
        If ``env`` is not an ``EpisodeRecorder``.
    """
    if not isinstance(env, EpisodeRecorder):
        raise TypeError(f"env must be an EpisodeRecorder, got {type(env).__name__}")
    run_episode(agent, env, int(seed))
    return env.episode


def evaluate(
    policies: Sequence[str],
    layouts: Sequence[str] | None = None,
    seeds: Sequence[int] = (0,),
    steps: int = 300,
    filters: Sequence[str | FilterSpec] | None = None,
    *,
    env_id: str = LATEST_ID,
    env_kwargs: Mapping[str, Any] | None = None,
    nees_every: int = 1,
    episode_dir: str | Path | None = None,
    verbose: bool = False,
    executor: Executor | None = None,
    journal: RunJournal | None = None,
) -> tuple[list[dict[str, Any]], list[dict[str, np.ndarray]]]:
    """Record one episode per (policy, layout, seed) and replay it through every filter.

    Parameters
    ----------
    policies : sequence of str
        Agent specs (see the module docstring), each labelled ``LABEL=SPEC`` or by itself.
    layouts : sequence of str, optional
        Values of the env's ``layout`` (:data:`seif_gym.world.LAYOUTS`); default the task's own.
    seeds : sequence of int
        ``env.reset`` seeds; the same for every policy and layout.
    steps : int
        ``max_episode_steps`` of the recorded episodes.
    filters : sequence of str or FilterSpec, optional
        Default :func:`seif_gym.harness.default_filters`.
    env_id, env_kwargs
        The env: ``gym.make(env_id, layout=..., max_episode_steps=steps, **env_kwargs)``.
    nees_every : int
        Steps between computations of the full covariance (relative and map NEES).
    episode_dir : path, optional
        Where to save the recorded episodes (``POLICY_LAYOUT_SEED.npz``).
    verbose : bool
        Progress on stderr, and one line per episode.
    executor : agents.parallel.Executor, optional
        Where the episodes are recorded and replayed (default: one after
        another in this process). The rows and curves are the same on every
        executor but for the measured times (``us_per_step_*``,
        ``step_seconds``); the episodes are saved by this process, each whole or not at all.
    journal : agents.evaluate.journal.RunJournal, optional
        Keeps each task's rows and curves as it finishes, and gives back those a killed run of the
        same configuration kept (:meth:`~agents.evaluate.journal.RunJournal.start` with ``resume``):
        their episodes are not recorded again (their saved files are already in ``episode_dir``).

    Returns
    -------
    rows : list of dict
        One per policy × layout × seed × filter (in this nesting order), keys
        :data:`seif_gym.harness.RESULT_COLUMNS`.
    series : list of dict
        The per-step curves of each row (:func:`seif_gym.harness.score_replay`).

    Raises
    ------
    ValueError
        If no agent, layout or seed is given, ``steps`` or ``nees_every`` is not positive, a layout
        or filter is unknown, an agent spec is unknown, or ``env_kwargs`` holds ``layout`` (all before
        any episode runs).
    FileNotFoundError
        If a saved model does not exist.
    """
    if isinstance(policies, str):
        policies = [p for p in policies.split(",") if p]
    if not policies or (layouts is not None and not layouts) or not len(seeds):
        raise ValueError("give at least one policy, one layout and one seed")
    if int(steps) < 1:
        raise ValueError(f"steps must be positive, got {steps}")
    if int(nees_every) < 1:
        raise ValueError(f"nees_every must be positive, got {nees_every}")
    unknown = [layout for layout in layouts or () if layout not in LAYOUTS]
    if unknown:
        raise ValueError(f"layouts: unknown {unknown}; use {', '.join(LAYOUTS)}")
    specs = parse_filters(filters)
    labelled = agent_labels(list(policies))
    for _, target in labelled:
        check_agent_spec(target)  # before any episode runs
    env_kwargs = dict(env_kwargs or {})
    if "layout" in env_kwargs:
        raise ValueError("env_kwargs: give the layout with layouts=, not in env_kwargs")
    if episode_dir is not None:
        episode_dir = Path(episode_dir)
        episode_dir.mkdir(parents=True, exist_ok=True)
    template = gym.make(env_id, **env_kwargs)
    try:
        config = dict(cast(SeifExploreEnv, template.unwrapped).config)
    finally:
        template.close()
    layouts = [str(config["layout"])] if layouts is None else list(layouts)
    executor = executor if executor is not None else Executor()
    slots = executor.slots() if executor.kind != "serial" else 1
    # what a killed run of this configuration finished: each episode's rows and curves
    restored: dict[tuple[str, str, int], tuple[list[dict[str, Any]], list[dict[str, np.ndarray]]]] = {}
    if journal is not None:
        for key, result in journal.units():
            if key.get("unit") == "episodes" and [key.get("agent"), key.get("target")] in [list(p) for p in labelled]:
                for item in result:
                    restored[(str(key["agent"]), str(key["layout"]), int(item["seed"]))] = (
                        item["rows"],
                        item["series"],
                    )
    # tasks: runs of consecutive seeds of one (policy, layout); random is seeded per episode, so every
    # agent here starts each episode afresh and the runs can go anywhere
    tasks: list[tuple[Any, ...]] = []
    for label, target in labelled:
        for layout in layouts:
            missing = [int(seed) for seed in seeds if (label, layout, int(seed)) not in restored]
            for run in chunks(missing, slots):
                tasks.append(
                    (env_id, env_kwargs, config, label, target, layout, run, int(steps), specs, int(nees_every))
                )

    collected: dict[int, list[tuple[Episode, list[dict[str, Any]], list[dict[str, np.ndarray]], float, float]]] = {}
    total = len(labelled) * len(layouts) * len(seeds)
    with Progress(total, f"{env_id} robustness", enabled=verbose, unit="episodes") as progress:
        if restored:
            progress.update(len(restored), f"{len(restored)} episodes kept by the killed run")

        def arrived(index: int, result: list[tuple[Episode, list[dict[str, Any]], Any, float, float]]) -> None:
            label, target, layout = tasks[index][3], tasks[index][4], tasks[index][5]
            for episode, _, _, _, _ in result:  # saved before the journal keeps the task
                if episode_dir is not None:
                    episode.save(Path(episode_dir) / f"{label}_{layout}_{_seed_of(episode)}.npz")  # whole or not at all
            if journal is not None:
                kept = [
                    {"seed": _seed_of(episode), "rows": rows, "series": curves}
                    for episode, rows, curves, _, _ in result
                ]
                journal.record({"unit": "episodes", "agent": label, "target": target, "layout": layout,
                                "seeds": list(tasks[index][6])}, kept)  # fmt: skip
            collected[index] = result
            for episode, _, _, recorded, replayed in result:
                seed = _seed_of(episode)
                progress.update(1, f"{label} {layout} seed {seed}")
                progress.write(f"{label:>12} {layout:>9} seed {seed:>4}: {episode.steps} steps recorded in "
                               f"{recorded:.1f} s, {len(specs)} filters replayed in {replayed:.1f} s")  # fmt: skip

        executor.map(_record_and_score, tasks, on_result=arrived)
    found = dict(restored)
    for index, arguments in enumerate(tasks):
        for episode, episode_rows, episode_series, _, _ in collected[index]:
            found[(arguments[3], arguments[5], _seed_of(episode))] = (episode_rows, episode_series)
    rows: list[dict[str, Any]] = []
    series: list[dict[str, np.ndarray]] = []
    for label, _ in labelled:  # the nesting order of a run left alone: policy, layout, seed
        for layout in layouts:
            for episode_seed in seeds:
                episode_rows, episode_series = found[(label, layout, int(episode_seed))]
                rows += episode_rows
                series += episode_series
    return rows, series


def _seed_of(episode: Episode) -> int:
    return int(episode.seed) if episode.seed is not None else -1


def paired_policies(
    rows: Sequence[Mapping[str, Any]],
    reference: str,
    metrics: Sequence[str] = PAIRED_METRICS,
    *,
    bootstrap: int = 2000,
    relative_to: str | None = None,
) -> list[dict[str, Any]]:
    """Every policy against ``reference``, per filter and metric, paired over (layout, seed).

    Parameters
    ----------
    rows : sequence of dict
        :func:`evaluate`'s rows (``policy``, ``layout``, ``seed``, ``filter`` and the metrics).
    reference : str
        The policy label the others are compared with.
    metrics : sequence of str
        Numeric columns of the rows.
    bootstrap : int
        Resamples of the percentile bootstrap interval (:func:`agents.evaluate.paired_difference`).
    relative_to : str, optional
        A filter label: compare each filter's value minus this filter's on the
        same episode (e.g. ``"ekf"`` with ``final_map_error``: the map error gap
        to the exact filter, the adversary's objective), for the other filters.

    Returns
    -------
    list of dict
        One row per (filter, metric, policy other than ``reference``), keys
        :data:`PAIRED_COLUMNS`. ``difference`` is the mean of ``policy −
        reference`` over the episodes both have with a finite value (``n``);
        ``verdict`` is ``"higher"`` or ``"lower"`` when the t interval
        excludes zero, else ``"tie"``. For a metric whose name starts with
        ``anees`` (positive, heavy-tailed) ``ratio`` is ``exp(mean(log
        policy − log reference))``, the ratio of the geometric means, with the
        exponentiated t interval; ``None`` for the other metrics.

    Raises
    ------
    ValueError
        If ``reference`` is not a policy of the rows, a metric is not a
        column, or no episode is shared.

    Examples
    --------
    >>> rows = [{"policy": p, "layout": "loop", "seed": s, "filter": "seif-k8", "anees_pose": v}
    ...         for p, vs in (("ppo", (3.0, 4.0, 5.0)), ("adversary", (6.0, 8.0, 11.0))) for s, v in enumerate(vs)]
    >>> row = paired_policies(rows, "ppo", ["anees_pose"], bootstrap=0)[0]
    >>> row["policy"], row["difference"], row["verdict"], round(row["ratio"], 3)
    ('adversary', 4.333333333333333, 'higher', 2.065)
    """
    policies = list(dict.fromkeys(str(row["policy"]) for row in rows))
    if reference not in policies:
        raise ValueError(f"reference: {reference!r} is not a policy of the rows ({', '.join(policies)})")
    missing = [metric for metric in metrics if rows and metric not in rows[0]]
    if missing:
        raise ValueError(f"metrics: not columns of the rows: {missing}")
    values: dict[tuple[str, str], dict[tuple[str, int], Mapping[str, Any]]] = {}
    for row in rows:
        values.setdefault((str(row["filter"]), str(row["policy"])), {})[(str(row["layout"]), int(row["seed"]))] = row
    filters = list(dict.fromkeys(str(row["filter"]) for row in rows))
    if relative_to is not None:
        if relative_to not in filters:
            raise ValueError(f"relative_to: {relative_to!r} is not a filter of the rows ({', '.join(filters)})")
        filters.remove(relative_to)
        for (filter_label, policy), episodes in list(values.items()):
            if filter_label == relative_to:
                continue
            baseline = values.get((relative_to, policy), {})
            values[(filter_label, policy)] = {
                key: {metric: float(row[metric]) - float(baseline[key][metric]) for metric in metrics}
                for key, row in episodes.items() if key in baseline
            }  # fmt: skip
    out: list[dict[str, Any]] = []
    for filter_label in filters:
        base = values.get((filter_label, reference), {})
        for metric in metrics:
            for policy in policies:
                if policy == reference:
                    continue
                mine = values.get((filter_label, policy), {})
                pairs = [(float(mine[k][metric]), float(base[k][metric])) for k in mine if k in base]
                pairs = [(a, b) for a, b in pairs if math.isfinite(a) and math.isfinite(b)]
                if not pairs:
                    raise ValueError(
                        f"{policy} and {reference} share no episode with a finite {metric} ({filter_label})"
                    )
                a, b = np.array(pairs).T
                stats = paired_difference(a, b, bootstrap=bootstrap)
                low, high = stats["ci95_low"], stats["ci95_high"]
                verdict = _DIRECTION[paired_verdict(stats)]
                ratio = ratio_low = ratio_high = None
                if relative_to is None and metric.startswith("anees") and np.all(a > 0.0) and np.all(b > 0.0):
                    logs = paired_difference(np.log(a), np.log(b))
                    ratio = math.exp(logs["mean"])
                    if logs["ci95_low"] is not None:
                        ratio_low, ratio_high = math.exp(logs["ci95_low"]), math.exp(logs["ci95_high"])
                out.append({
                    "filter": filter_label if relative_to is None else f"{filter_label} − {relative_to}",
                    "metric": metric, "policy": policy, "reference": reference,
                    "n": stats["n"], "policy_mean": float(a.mean()), "reference_mean": float(b.mean()),
                    "difference": stats["mean"], "ci95_low": low, "ci95_high": high,
                    "bootstrap_ci95_low": stats["bootstrap_ci95_low"],
                    "bootstrap_ci95_high": stats["bootstrap_ci95_high"],
                    "ratio": ratio, "ratio_ci95_low": ratio_low, "ratio_ci95_high": ratio_high, "verdict": verdict,
                })  # fmt: skip
    return out


def paired_policies_table(paired: Sequence[Mapping[str, Any]], digits: int = 3) -> str:
    """:func:`paired_policies`' rows as Markdown, one table per metric."""

    def number(value: Any) -> str:
        return "" if value is None else f"{value:+.{digits}f}"

    def interval(low: Any, high: Any, sign: bool = True) -> str:
        if low is None or high is None:
            return ""
        return f"[{number(low)}, {number(high)}]" if sign else f"[{low:.{digits}f}, {high:.{digits}f}]"

    lines: list[str] = []
    for metric in dict.fromkeys(str(row["metric"]) for row in paired):
        chosen = [row for row in paired if row["metric"] == metric]
        lines += [f"### {metric}: policy − {chosen[0]['reference']}, paired over (layout, seed)", "",
                  "| filter | policy | n | policy mean | reference mean | difference | t 95% | bootstrap 95% "
                  "| ratio of geometric means [95%] | verdict |",
                  "|---|---|--:|--:|--:|--:|--:|--:|--:|---|"]  # fmt: skip
        for row in chosen:
            ratio = (
                ""
                if row["ratio"] is None
                else f"{row['ratio']:.2f}× " + interval(row["ratio_ci95_low"], row["ratio_ci95_high"], sign=False)
            )
            lines.append(
                f"| {row['filter']} | {row['policy']} | {row['n']} | {row['policy_mean']:.{digits}f} | "
                f"{row['reference_mean']:.{digits}f} | {number(row['difference'])} | "
                f"{interval(row['ci95_low'], row['ci95_high'])} | "
                f"{interval(row['bootstrap_ci95_low'], row['bootstrap_ci95_high'])} | {ratio} | {row['verdict']} |"
            )
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"


#: Warm-ups done in this process: (filters, env config, nees_every).
_WARMED: set[str] = set()


def _record_and_score(
    env_id: str,
    env_kwargs: Mapping[str, Any],
    config: Mapping[str, Any],
    label: str,
    target: str,
    layout: str,
    seeds: Sequence[int],
    steps: int,
    specs: Sequence[FilterSpec],
    nees_every: int,
) -> list[tuple[Episode, list[dict[str, Any]], list[dict[str, np.ndarray]], float, float]]:
    """One task of :func:`evaluate`: record ``target``'s episodes on ``seeds`` and replay each through ``specs``.

    Returns, per seed, the episode, its rows and curves
    (:func:`seif_gym.harness.score_episode`) and the seconds spent
    recording and replaying.
    """
    key = repr((list(specs), sorted(config.items()), nees_every))
    if key not in _WARMED:  # compile / load the kernels before anything is timed, once per process
        warm_up(specs, config, nees_every)
        _WARMED.add(key)
    env = EpisodeRecorder(gym.make(env_id, layout=layout, max_episode_steps=steps, **env_kwargs))
    try:
        agent = None if target == "random" else build_agent(target, env, env_id, {**env_kwargs, "layout": layout}, 0)
        out = []
        for seed in seeds:
            started = time.perf_counter()
            policy = build_agent("random", env, env_id, env_kwargs, int(seed)) if agent is None else agent
            episode = record_episode(env, policy, int(seed))
            recorded = time.perf_counter() - started
            episode_rows, episode_series = score_episode(episode, specs, policy=label, nees_every=nees_every)
            out.append((episode, episode_rows, episode_series, recorded, time.perf_counter() - started - recorded))
        return out
    finally:
        env.close()


# -- command line -----------------------------------------------------------------------------------
def _split(text: str) -> list[str]:
    return [part.strip() for part in text.split(",") if part.strip()]


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m agents.robustness",
        description="Record episodes once per (agent, layout, seed) and replay them through every filter.",
        epilog=f"{agents_help()}\n\n{tasks_epilog()}\n\n"
        "The metrics and outputs: python -c 'import seif_gym.harness as h; help(h)'.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--agents", default=",".join(DEFAULT_POLICIES),
                        help="comma-separated agents (see below; default: the baselines)")  # fmt: skip
    add_deprecated_alias(parser, "--policies", "--agents")
    parser.add_argument("--layouts", default=None,
                        help=f"comma-separated landmark layouts, the env's layout keyword: {', '.join(LAYOUTS)} "
                        "(default: the task's own)")  # fmt: skip
    parser.add_argument("--episodes", type=positive_int, default=5, metavar="N",
                        help="episodes per agent and layout (default %(default)s)")  # fmt: skip
    add_deprecated_alias(parser, "--seeds", "--episodes", type=positive_int, metavar="N")
    parser.add_argument("--seed", type=seed_type, default=0, help="first seed (default 0): seeds S .. S+N-1")
    parser.add_argument("--steps", type=positive_int, default=300,
                        help="episode length, max_episode_steps (default 300)")  # fmt: skip
    parser.add_argument(
        "--filters", default=None, help=f"comma-separated filters (default {','.join(default_filters())})"
    )
    parser.add_argument("--env", type=task, default=LATEST_ID, metavar="TASK",
                        help="registered env id or family (default %(default)s)")  # fmt: skip
    parser.add_argument(
        "--env-kwargs", type=json_object, default="{}", help="JSON object of further gym.make keyword arguments"
    )
    parser.add_argument("--nees-every", type=positive_int, default=1,
                        help="steps between full-covariance NEES (default 1)")  # fmt: skip
    parser.add_argument("--out", default=None, help="output folder (default eval/robustness)")
    add_resume_argument(parser)
    parser.add_argument("--no-save-episodes", action="store_true", help="do not save the recorded episodes")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    parser.add_argument(
        "--paired-against",
        default=None,
        metavar="LABEL",
        help="compare every other agent with this one, paired over (layout, seed): paired.md/.csv",
    )
    parser.add_argument(
        "--paired-metrics",
        default=",".join(PAIRED_METRICS),
        help=f"metrics of --paired-against (default {','.join(PAIRED_METRICS)})",
    )
    parser.add_argument("--paired-relative-to", default=None, metavar="FILTER",
                        help="with --paired-against, also compare each filter's value minus this filter's on the same "
                             "episode (e.g. ekf: the map error gap)")  # fmt: skip
    add_executor_arguments(parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``python -m agents.robustness`` with ``argv`` (default ``sys.argv[1:]``).

    Every input is checked before any episode runs and before anything is written (:mod:`agents.cli`);
    each task's rows are kept in ``--out`` as it finishes (:class:`~agents.evaluate.journal.RunJournal`),
    so that ``--resume OUT`` continues a killed run. Every file is written whole or not at all, and
    ``manifest.json`` last.

    Returns
    -------
    int
        The exit status, 0 (also for ``--resume`` of a finished run, which says so); a bad argument exits
        through ``argparse`` (status 2, one line) before any episode runs.
    """
    parser = _parser()
    args = parser.parse_args(argv)
    layouts: list[str] | None = None
    if args.layouts is not None:
        layouts = _split(args.layouts)
        unknown = [layout for layout in layouts if layout not in LAYOUTS]
        if unknown or not layouts:
            parser.error(f"--layouts: unknown layout(s) {unknown}; use {', '.join(LAYOUTS)}")
    filters = _split(args.filters) if args.filters else default_filters()
    policies = _split(args.agents)
    with usage_errors(parser):  # every input answered before any episode runs and anything is written
        try:
            specs = parse_filters(filters)
        except ValueError as error:
            raise ValueError(f"--filters: {error}") from None
        labelled = check_agents(policies)
        seeds = check_seeds(args.seed, args.episodes)
        if "layout" in args.env_kwargs:
            raise ValueError("--env-kwargs: give the layout with --layouts, not in --env-kwargs")
        check_env(args.env, args.env_kwargs, max_episode_steps=args.steps)
        for layout in layouts or []:
            check_env(args.env, args.env_kwargs, f"--layouts: {layout}", max_episode_steps=args.steps, layout=layout)
        out, resume = resume_folder(args, "eval/robustness")
    paired_metrics = _split(args.paired_metrics)
    if args.paired_against is not None:
        labels = [label for label, _ in labelled]
        if args.paired_against not in labels:
            parser.error(f"--paired-against: {args.paired_against!r} is not an agent's label ({', '.join(labels)})")
        unknown_metrics = [m for m in paired_metrics if m not in RESULT_COLUMNS]
        if unknown_metrics:
            parser.error(f"--paired-metrics: not result columns: {unknown_metrics}")
        filter_labels = [spec.label for spec in specs]
        if args.paired_relative_to is not None and args.paired_relative_to not in filter_labels:
            parser.error(f"--paired-relative-to: {args.paired_relative_to!r} is not one of --filters")
    elif args.paired_relative_to is not None:
        parser.error("--paired-relative-to needs --paired-against")
    executor = executor_from_arguments(args, parser)
    filter_config = [{"label": s.label, "filter": s.filter, "options": dict(s.options)} for s in specs]
    run_config = {
        "agents": policies, "models": model_digests(labelled), "layouts": layouts, "seeds": seeds, "steps": args.steps,
        "filters": filter_config, "env": args.env, "env_kwargs": args.env_kwargs, "nees_every": args.nees_every,
        "save_episodes": not args.no_save_episodes, "paired_against": args.paired_against,
        "paired_metrics": paired_metrics, "paired_relative_to": args.paired_relative_to,
    }  # fmt: skip
    journal = journal_for_command_line(parser, out, COMMAND, run_config, resume)
    if journal is None:
        return 0
    limit_blas_threads(1)
    started = time.perf_counter()
    rows, series = evaluate(
        policies, layouts, seeds, args.steps, specs,
        env_id=args.env, env_kwargs=args.env_kwargs, nees_every=args.nees_every,
        episode_dir=None if args.no_save_episodes else out / "episodes", verbose=not args.quiet, executor=executor,
        journal=journal,
    )  # fmt: skip
    wall = time.perf_counter() - started
    layouts = list(dict.fromkeys(str(row["layout"]) for row in rows))  # the task's own when none was given
    config = {
        "argv": list(sys.argv[1:] if argv is None else argv),
        "policies": policies, "layouts": layouts, "seeds": seeds, "steps": args.steps,
        "filters": filter_config, "env": args.env, "env_kwargs": args.env_kwargs, "nees_every": args.nees_every,
        "wall_seconds": wall, "executor": executor.describe(),
    }  # fmt: skip
    paths = write_outputs(rows, series, out, config)  # each file whole or not at all
    print(f"{args.env}: agents {','.join(policies)}; layouts {','.join(layouts)}; seeds {seeds[0]}..{seeds[-1]}; "
          f"{args.steps} steps\n")  # fmt: skip
    print(summary_tables(rows, series))
    if args.paired_against is not None:
        paired = paired_policies(rows, args.paired_against, paired_metrics)
        if args.paired_relative_to is not None:
            paired += paired_policies(rows, args.paired_against, paired_metrics, relative_to=args.paired_relative_to)
        table = paired_policies_table(paired)
        paths["paired_md"] = atomic_write_text(out / "paired.md", table)
        handle = io.StringIO(newline="")
        writer = csv.DictWriter(handle, fieldnames=list(PAIRED_COLUMNS))
        writer.writeheader()
        writer.writerows({key: ("" if row[key] is None else row[key]) for key in PAIRED_COLUMNS} for row in paired)
        paths["paired_csv"] = atomic_write_bytes(out / "paired.csv", handle.getvalue().encode())
        print("\n" + table)
    files = list(paths.values())
    if not args.no_save_episodes:
        files += [out / "episodes" / f"{label}_{layout}_{seed}.npz" for label, _ in labelled for layout in layouts
                  for seed in seeds]  # fmt: skip
    paths["manifest"] = write_manifest(out, files, COMMAND, run_config)
    journal.finish()
    print(f"\nwrote {', '.join(str(p) for p in paths.values())}; {wall:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
