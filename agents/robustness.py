r"""The filter robustness harness with policies: ``python -m agents.robustness``.

.. code-block:: bash

    python -m agents.robustness --policies random,frontier,revisit,ppo=runs/ppo/model.zip \
        --layouts uniform,loop --seeds 5 --seed 0 --steps 300 --out eval/robustness \
        [--workers N | --ray auto|ADDRESS] [--quiet]

For every (policy, layout, seed) one episode of ``--env`` (default
``SeifExplore-v0``, on which ``docs/robustness.md`` was measured; pass
``--env SeifExplore-v1`` for the current filters; with ``layout=`` the layout
and ``max_episode_steps=`` ``--steps``) is **recorded once** (the policy acts
on the env's own SEIF through :class:`~seif_gym.episodes.EpisodeRecorder`,
exactly as it would in training; :func:`record_episode`) and then
**replayed** through every filter of ``--filters`` and scored by
:mod:`seif_gym.evaluate`, whose docstring defines the filters, the metrics
and the outputs. This module adds only what needs the agents: building the
policies and driving the recording. ``python -m seif_gym.evaluate
--episodes DIR`` scores saved episodes again without them.

Policies (``--policies``, comma separated; default every baseline of
:data:`agents.BASELINES`): baseline names, the path of a Stable-Baselines3
``.zip`` (with ``vecnormalize.pkl`` beside it when present) or
``rllib:CHECKPOINT``, each optionally labelled ``LABEL=SPEC``
(:func:`agents.evaluate.agent_label`). Every policy acts with
``deterministic=True``; ``random`` is seeded with the episode seed. Progress
goes to stderr (``--quiet``: none). The episodes are recorded and replayed one
after another in this process, on ``--workers N`` local processes or as Ray
tasks on a cluster (``--ray``; :mod:`agents.parallel`, ``docs/ray.md``): the
rows are the same but for the measured times.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, cast

import gymnasium as gym
import numpy as np

import seif_gym  # noqa: F401  (registers the environments)
from agents.baselines import BASELINES, Agent
from agents.evaluate import agent_labels, build_agent, check_agent_spec, run_episode
from agents.parallel import Executor, chunks
from agents.parallel import add_arguments as add_executor_arguments
from agents.parallel import from_arguments as executor_from_arguments
from seif_gym.envs.explore import SeifExploreEnv
from seif_gym.episodes import Episode, EpisodeRecorder
from seif_gym.evaluate import (
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

__all__ = ["DEFAULT_POLICIES", "record_episode", "evaluate", "main"]

#: Policies of a run without ``--policies``.
DEFAULT_POLICIES: tuple[str, ...] = BASELINES


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
    """
    if not isinstance(env, EpisodeRecorder):
        raise TypeError(f"env must be an EpisodeRecorder, got {type(env).__name__}")
    run_episode(agent, env, int(seed))
    return env.episode


def evaluate(
    policies: Sequence[str],
    layouts: Sequence[str] = ("uniform",),
    seeds: Sequence[int] = (0,),
    steps: int = 300,
    filters: Sequence[str | FilterSpec] | None = None,
    *,
    env_id: str = "SeifExplore-v0",
    env_kwargs: Mapping[str, Any] | None = None,
    nees_every: int = 1,
    episode_dir: str | Path | None = None,
    verbose: bool = False,
    executor: Executor | None = None,
) -> tuple[list[dict[str, Any]], list[dict[str, np.ndarray]]]:
    """Record one episode per (policy, layout, seed) and replay it through every filter.

    Parameters
    ----------
    policies : sequence of str
        Agent specs (see the module docstring).
    layouts : sequence of str
        Values of the env's ``layout`` (:data:`seif_gym.world.LAYOUTS`).
    seeds : sequence of int
        ``env.reset`` seeds; the same for every policy and layout.
    steps : int
        ``max_episode_steps`` of the recorded episodes.
    filters : sequence of str or FilterSpec, optional
        Default :func:`seif_gym.evaluate.default_filters`.
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
        ``step_seconds``); the episodes are saved by this process.

    Returns
    -------
    rows : list of dict
        One per policy × layout × seed × filter (in this nesting order), keys
        :data:`seif_gym.evaluate.RESULT_COLUMNS`.
    series : list of dict
        The per-step curves of each row (:func:`seif_gym.evaluate.score_replay`).
    """
    if isinstance(policies, str):
        policies = [p for p in policies.split(",") if p]
    if not policies or not layouts or not len(seeds):
        raise ValueError("give at least one policy, one layout and one seed")
    if int(steps) < 1:
        raise ValueError(f"steps must be positive, got {steps}")
    if int(nees_every) < 1:
        raise ValueError(f"nees_every must be positive, got {nees_every}")
    unknown = [layout for layout in layouts if layout not in LAYOUTS]
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
    executor = executor if executor is not None else Executor()
    slots = executor.slots() if executor.kind != "serial" else 1
    # tasks: runs of consecutive seeds of one (policy, layout); random is seeded per episode, so every
    # agent here starts each episode afresh and the runs can go anywhere
    tasks: list[tuple[Any, ...]] = []
    for label, target in labelled:
        for layout in layouts:
            for run in chunks([int(seed) for seed in seeds], slots):
                tasks.append(
                    (env_id, env_kwargs, config, label, target, layout, run, int(steps), specs, int(nees_every))
                )

    collected: dict[int, list[tuple[Episode, list[dict[str, Any]], list[dict[str, np.ndarray]], float, float]]] = {}
    total = len(labelled) * len(layouts) * len(seeds)
    with Progress(total, f"{env_id} robustness", enabled=verbose, unit="episodes") as progress:

        def arrived(index: int, result: list[tuple[Episode, list[dict[str, Any]], Any, float, float]]) -> None:
            collected[index] = result
            label, layout = tasks[index][3], tasks[index][5]
            for episode, _, _, recorded, replayed in result:
                seed = int(episode.seed) if episode.seed is not None else -1
                if episode_dir is not None:
                    episode.save(Path(episode_dir) / f"{label}_{layout}_{seed}.npz")
                progress.update(1, f"{label} {layout} seed {seed}")
                progress.write(f"{label:>12} {layout:>9} seed {seed:>4}: {episode.steps} steps recorded in "
                               f"{recorded:.1f} s, {len(specs)} filters replayed in {replayed:.1f} s")  # fmt: skip

        executor.map(_record_and_score, tasks, on_result=arrived)
    rows: list[dict[str, Any]] = []
    series: list[dict[str, np.ndarray]] = []
    for index in range(len(tasks)):
        for _, episode_rows, episode_series, _, _ in collected[index]:
            rows += episode_rows
            series += episode_series
    return rows, series


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
    (:func:`seif_gym.evaluate.score_episode`) and the seconds spent
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
        description="Record episodes once per (policy, layout, seed) and replay them through every filter.",
        epilog="The metrics and outputs: python -c 'import seif_gym.evaluate as e; help(e)'.",
    )
    parser.add_argument("--policies", default=",".join(DEFAULT_POLICIES),
                        help=f"comma-separated baselines ({', '.join(BASELINES)}), PATH.zip, rllib:CHECKPOINT, "
                             "each optionally LABEL=SPEC")  # fmt: skip
    parser.add_argument(
        "--layouts", default="uniform", help=f"comma-separated layouts from {', '.join(LAYOUTS)} (default uniform)"
    )
    parser.add_argument("--seeds", type=int, default=5, help="episodes per policy and layout (default 5)")
    parser.add_argument("--seed", type=int, default=0, help="first seed (default 0): seeds S .. S+N-1")
    parser.add_argument("--steps", type=int, default=300, help="episode length, max_episode_steps (default 300)")
    parser.add_argument(
        "--filters", default=None, help=f"comma-separated filters (default {','.join(default_filters())})"
    )
    parser.add_argument("--env", default="SeifExplore-v0", help="registered env id (default SeifExplore-v0)")
    parser.add_argument("--env-kwargs", default="{}", help="JSON object of further gym.make keyword arguments")
    parser.add_argument("--nees-every", type=int, default=1, help="steps between full-covariance NEES (default 1)")
    parser.add_argument("--out", default="eval/robustness", help="output folder (default eval/robustness)")
    parser.add_argument("--no-save-episodes", action="store_true", help="do not save the recorded episodes")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    add_executor_arguments(parser)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        env_kwargs = json.loads(args.env_kwargs)
    except json.JSONDecodeError as error:
        parser.error(f"--env-kwargs is not valid JSON: {error}")
    if not isinstance(env_kwargs, dict):
        parser.error("--env-kwargs must be a JSON object")
    if args.seeds < 1 or args.steps < 1 or args.nees_every < 1:
        parser.error("--seeds, --steps and --nees-every must be positive")
    layouts = _split(args.layouts)
    unknown = [layout for layout in layouts if layout not in LAYOUTS]
    if unknown:
        parser.error(f"unknown layout(s) {unknown}; use {', '.join(LAYOUTS)}")
    filters = _split(args.filters) if args.filters else default_filters()
    policies = _split(args.policies)
    try:
        specs = parse_filters(filters)
        for _, target in agent_labels(policies):
            check_agent_spec(target)
    except (ValueError, FileNotFoundError) as error:
        parser.error(str(error))
    seeds = list(range(args.seed, args.seed + args.seeds))
    executor = executor_from_arguments(args, parser)
    out = Path(args.out)
    limit_blas_threads(1)
    started = time.perf_counter()
    rows, series = evaluate(
        policies, layouts, seeds, args.steps, specs,
        env_id=args.env, env_kwargs=env_kwargs, nees_every=args.nees_every,
        episode_dir=None if args.no_save_episodes else out / "episodes", verbose=not args.quiet, executor=executor,
    )  # fmt: skip
    wall = time.perf_counter() - started
    config = {
        "argv": list(sys.argv[1:] if argv is None else argv),
        "policies": policies, "layouts": layouts, "seeds": seeds, "steps": args.steps,
        "filters": [{"label": s.label, "filter": s.filter, "options": dict(s.options)} for s in specs],
        "env": args.env, "env_kwargs": env_kwargs, "nees_every": args.nees_every, "wall_seconds": wall,
        "executor": executor.describe(),
    }  # fmt: skip
    paths = write_outputs(rows, series, out, config)
    print(f"{args.env}: policies {args.policies}; layouts {','.join(layouts)}; seeds {seeds[0]}..{seeds[-1]}; "
          f"{args.steps} steps\n")  # fmt: skip
    print(summary_tables(rows, series))
    print(f"\nwrote {', '.join(str(p) for p in paths.values())}; {wall:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
