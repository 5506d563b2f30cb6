"""How far each task's final map error is from what coverage alone allows: a cheating explorer as a yardstick.

Usage::

    python research/coverage_oracle.py [--env SeifExploreClusteredBudget-v2 ...] [--episodes 100] [--seed 500000] \
        [--env-kwargs '{"max_episode_steps": 500}']

The *coverage oracle* (:mod:`research.oracle`) reads what no agent may read (the true landmarks and
the true pose, ``env.unwrapped.world``) and drives greedily to the unmapped
landmark that is nearest counting one metre per radian of turn, until the
filter has mapped every landmark (the registered ids' known association: the
filter's ids are the true ones). It plans no revisits and no loop closures, so
its final map error is a bound on what exploring for coverage can give, not on
what a policy can reach: where a learned policy beats it, it does so by
accuracy (closing loops, revisiting), where it trails it by far, a better
explorer could exist. It is a diagnostic for the benchmark's tasks
(docs/benchmark/protocol.md, "Tasks"), never an agent of the leaderboard.

Prints, per task, the oracle's mean final map error with its 95% Student-t
interval and the landmarks it mapped, on the validation seeds by default.
``--env-kwargs`` (a JSON object passed to ``gym.make`` with every task, as
``agents.evaluate``'s) measures a task's variant before it is registered:
a step budget, a weaker sensor.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

import seif_gym  # noqa: F401  (registers the envs)
from agents.cli import json_object
from agents.evaluate import mean_ci
from agents.protocol import VALIDATION_SEED
from research.oracle import CoverageOracle


def run_oracle(env_id: str, seeds: Sequence[int], env_kwargs: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The oracle's episodes on ``seeds`` of ``env_id``: final map errors (mean, interval) and landmarks mapped.

    ``env_kwargs`` are passed to ``gym.make`` (for example ``{"max_episode_steps": 500}``).

    Raises
    ------
    ValueError
        If ``seeds`` is empty, or the env associates by maximum likelihood (its filter's ids are then not
        the true ones the oracle compares with).
    """
    seeds = [int(seed) for seed in seeds]
    if not seeds:
        raise ValueError("seeds must hold at least one seed")
    if env_kwargs is not None and not isinstance(env_kwargs, Mapping):
        raise TypeError(f"env_kwargs must be a mapping, got {type(env_kwargs).__name__}")
    env = gym.make(env_id, **dict(env_kwargs or {}))
    errors, mapped = [], []
    try:
        try:
            oracle = CoverageOracle(env)
        except ValueError as error:  # name this function's argument
            raise ValueError(f"env_id: {env_id!r}: {error}") from None
        for seed in seeds:
            observation, info = env.reset(seed=seed)
            while True:
                action, _ = oracle.predict(observation)
                observation, _, terminated, truncated, info = env.step(action)
                if terminated or truncated:
                    break
            errors.append(float(info["map_error"]))
            mapped.append(int(info["landmarks_mapped"]))
    finally:
        env.close()
    return {"env_id": env_id, "final_map_error": mean_ci(errors), "landmarks_mapped": float(np.mean(mapped))}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--env", nargs="+", default=["SeifExploreClusteredBudget-v2"], help="registered env ids")
    parser.add_argument("--episodes", type=int, default=100, help="episodes per task (default %(default)s)")
    parser.add_argument("--seed", type=int, default=VALIDATION_SEED, help="first seed (default %(default)s)")
    parser.add_argument(
        "--env-kwargs", type=json_object, default="{}", help="JSON object of gym.make keyword arguments, every task"
    )
    args = parser.parse_args(argv)
    if args.episodes < 2:
        parser.error(f"--episodes: at least 2 for an interval, got {args.episodes}")
    made_with = f", gym.make(..., **{args.env_kwargs})" if args.env_kwargs else ""
    print(f"coverage oracle, seeds {args.seed}..{args.seed + args.episodes - 1}{made_with}")
    print("| task | final map error (m), 95% interval | landmarks mapped |")
    print("|---|--:|--:|")
    for env_id in args.env:
        result = run_oracle(env_id, range(args.seed, args.seed + args.episodes), args.env_kwargs)
        stat = result["final_map_error"]
        print(f"| `{env_id}` | {stat['mean']:.3f} ± {stat['ci95_half_width']:.3f} | {result['landmarks_mapped']:.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
