"""RLlib sampling throughput on ``SeifExplore``: env steps per second with 1, 2, ... env runners.

Usage::

    python benchmarks/rllib_sampling.py --env SeifExplore-v2 --runners 1,2 --envs-per-runner 8 \\
        --steps 4096 --repeats 3 [--vectorize native,sync] [--address auto]

For each number of remote env runners (and each ``--vectorize`` mode) the
PPO algorithm of ``agents.rllib_train`` (:func:`agents.rllib_train.build_config`,
the :class:`~agents.rllib_agent.BeliefRLModule` policy, exploration on) is
built, one warm-up round of sampling is run (actor start, env construction,
compiled kernels loaded, first resets), then ``--repeats`` timed rounds, each
collecting ``--steps`` env steps from all runners in parallel (RLlib's
``synchronous_parallel_sample``, what one PPO iteration does before it
learns). Reported: env steps per second of wall time, mean and min/max over
the rounds. Learning is not timed.

Without ``--address`` a local Ray instance on 127.0.0.1 with ``--num-cpus``
CPUs (default: all) is started and stopped; each runner takes one CPU.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")  # before ray is imported: loopback only

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np

from seif_gym import LATEST_ID


def _sample(algo: Any, steps: int) -> Any:
    """One round of parallel sampling from all env runners, as a PPO iteration does it."""
    from ray.rllib.execution.rollout_ops import synchronous_parallel_sample

    return synchronous_parallel_sample(
        worker_set=algo.env_runner_group, max_env_steps=steps, concat=False, _uses_new_env_runners=True
    )


def _env_steps(episodes: Any) -> int:
    """Env steps in a (nested) list of RLlib episodes."""
    if isinstance(episodes, (list, tuple)):
        return sum(_env_steps(item) for item in episodes)
    return int(episodes.env_steps())


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default=LATEST_ID)
    parser.add_argument("--runners", default="1,2", help="comma-separated numbers of remote env runners")
    parser.add_argument("--envs-per-runner", type=int, default=8)
    parser.add_argument("--vectorize", default="native", help="comma-separated: native, sync")
    parser.add_argument("--steps", type=int, default=4096, help="env steps per timed round (all runners)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--address", default=None, help="a running cluster ('auto' or HOST:PORT); default local")
    parser.add_argument("--num-cpus", type=int, default=None, help="CPUs of the local instance (default: all)")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Print a Markdown table of the sampling throughput."""
    args = _parser().parse_args(argv)
    runners = [int(r) for r in args.runners.split(",")]
    modes = args.vectorize.split(",")
    if any(r < 1 for r in runners) or any(m not in ("native", "sync") for m in modes):
        raise SystemExit("--runners must be positive ints and --vectorize native and/or sync")

    import ray

    from agents.rllib_train import build_config, stop_algorithm

    kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False, "logging_level": "ERROR"}
    if args.address is None:
        ray.init(address="local", num_cpus=args.num_cpus, _node_ip_address="127.0.0.1", **kwargs)
    else:
        ray.init(address=args.address, **kwargs)
    print(
        f"{args.env}, {args.envs_per_runner} envs per runner, {args.steps} steps per round, "
        f"{args.repeats} rounds, {int(ray.cluster_resources().get('CPU', 0))} CPUs"
    )
    print("| env runners | vector env | env steps / s (mean) | min | max |")
    print("|---:|---|---:|---:|---:|")
    try:
        for mode in modes:
            for count in runners:
                config = build_config(
                    args.env,
                    num_env_runners=count,
                    num_envs_per_env_runner=args.envs_per_runner,
                    vectorize=mode,
                    train_batch_size=args.steps,
                    minibatch_size=args.steps,
                )
                algo = config.build_algo()
                try:
                    _sample(algo, args.steps)  # warm-up
                    rates = []
                    for _ in range(args.repeats):
                        tick = time.perf_counter()
                        episodes = _sample(algo, args.steps)
                        seconds = time.perf_counter() - tick
                        rates.append(_env_steps(episodes) / seconds)
                    print(
                        f"| {count} | {mode} | {np.mean(rates):.0f} | {min(rates):.0f} | {max(rates):.0f} |", flush=True
                    )
                finally:
                    stop_algorithm(algo)
    finally:
        ray.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
