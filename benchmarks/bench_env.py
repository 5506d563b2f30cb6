"""Env steps per second of SeifExplore-v0 next to CartPole-v1, in one process.

Usage::

    python benchmarks/bench_env.py [--steps 20000] [--repeats 5] [--env SeifExplore-v0 ...]

Both envs are made with ``gym.make`` (so the registry's wrappers, time limit
and order enforcing, are included), stepped with random actions from their
seeded action spaces, and reset when an episode ends. The two are measured
in alternation, ``--repeats`` times, and the best of the repeats is kept for
each (the least disturbed by other processes on the machine); the ratio is
SeifExplore's rate over CartPole's. The issue's target is a ratio of at least
0.05. A profile of the env step (``--profile``) lists where the time goes.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import platform
import pstats
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import gymnasium as gym  # noqa: E402
import numba  # noqa: E402
import numpy as np  # noqa: E402

import seif_gym  # noqa: E402,F401

TARGET_RATIO = 0.05


def steps_per_second(env: gym.Env, steps: int) -> float:
    """Random-action steps per second over ``steps`` steps (resets included)."""
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(steps)]
    started = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - started)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", nargs="*", default=["SeifExplore-v0"], help="env ids to measure")
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--profile", action="store_true", help="print a cProfile of the first env's step")
    args = parser.parse_args()

    cartpole = gym.make("CartPole-v1")
    envs = {env_id: gym.make(env_id) for env_id in args.env}
    for env in envs.values():  # compile the numba kernels (cached on disk) before timing
        steps_per_second(env, 200)
    best = {name: 0.0 for name in ["CartPole-v1", *envs]}
    for _ in range(args.repeats):
        best["CartPole-v1"] = max(best["CartPole-v1"], steps_per_second(cartpole, args.steps * 5))
        for env_id, env in envs.items():
            best[env_id] = max(best[env_id], steps_per_second(env, args.steps))

    print(f"Python {platform.python_version()}, numpy {np.__version__}, numba {numba.__version__}, "
          f"gymnasium {gym.__version__}, {os.cpu_count()} CPUs; best of {args.repeats} repeats")  # fmt: skip
    print()
    print("| env | steps/s | µs/step | ratio to CartPole-v1 |")
    print("|---|---:|---:|---:|")
    for name, rate in best.items():
        ratio = rate / best["CartPole-v1"]
        print(f"| {name} | {rate:,.0f} | {1e6 / rate:.1f} | {ratio:.3f} |")
    for env_id in envs:
        ratio = best[env_id] / best["CartPole-v1"]
        verdict = "meets" if ratio >= TARGET_RATIO else "misses"
        print(f"\n{env_id}: ratio {ratio:.3f} {verdict} the target of {TARGET_RATIO}")

    if args.profile:
        env = envs[args.env[0]]
        profile = cProfile.Profile()
        profile.enable()
        steps_per_second(env, 5000)
        profile.disable()
        pstats.Stats(profile).sort_stats("tottime").print_stats(15)


if __name__ == "__main__":
    main()
