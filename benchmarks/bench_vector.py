"""Vector env throughput: the native SeifExplore vector env against Gymnasium's and CartPole-v1's.

Usage::

    python benchmarks/bench_vector.py [--env SeifExplore-v1] [--env-kwargs JSON] [--sizes 1,16,64,256]
        [--seconds 3] [--repeats 3]

All in one process, random actions (each vector env's own seeded action
space), autoreset on. Env steps per second count every sub-env's step (N per
vector step). Measured for each N of ``--sizes``:

* ``native``: ``gym.make_vec(env, num_envs=N)``, the native vector env
  (``SeifExploreVectorEnv``: the worlds, filters, observations and rewards of
  all N envs in compiled calls, one thread by default), and for N >= 32 also
  with ``num_threads`` = numba's thread count (the cores);
* ``sync`` / ``async``: Gymnasium's ``SyncVectorEnv`` / ``AsyncVectorEnv``
  over the single env (``async`` only for N <= 16: one process per sub-env);

and, as the reference the issue set, CartPole-v1's ``SyncVectorEnv(64)`` and
its native vector env at 64. Each figure is the best of ``--repeats`` runs of
about ``--seconds`` seconds. The ratios are to CartPole's ``SyncVectorEnv(64)``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import gymnasium as gym  # noqa: E402
import numba  # noqa: E402
import numpy as np  # noqa: E402

import seif_gym  # noqa: E402,F401


def env_steps_per_second(env: gym.vector.VectorEnv, seconds: float) -> float:
    """Sub-env steps per second over about ``seconds`` of random-action vector steps."""
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(64)]
    env.step(actions[0])  # compiled kernels and first-step work out of the timing
    steps, started = 0, time.perf_counter()
    while True:
        for action in actions[:8]:
            env.step(action)
        steps += 8
        elapsed = time.perf_counter() - started
        if elapsed >= seconds:
            return steps * env.num_envs / elapsed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="SeifExplore-v1")
    parser.add_argument(
        "--env-kwargs", default="{}", help='keyword arguments of every env, JSON (e.g. \'{"filter": "eseif"}\')'
    )
    parser.add_argument("--sizes", default="1,16,64,256", help="comma-separated numbers of sub-envs")
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    sizes = [int(size) for size in args.sizes.split(",") if size.strip()]
    kwargs = json.loads(args.env_kwargs)
    if not isinstance(kwargs, dict):
        parser.error("--env-kwargs must be a JSON object")
    if not sizes or min(sizes) < 1:
        parser.error("--sizes must be positive ints")
    makers: dict[str, object] = {
        "CartPole-v1 SyncVectorEnv (64)": lambda: gym.make_vec("CartPole-v1", 64, vectorization_mode="sync"),
        "CartPole-v1 native (64)": lambda: gym.make_vec("CartPole-v1", 64, vectorization_mode="vector_entry_point"),
    }
    threads = numba.config.NUMBA_NUM_THREADS
    for n in sizes:
        makers[f"{args.env} native ({n})"] = lambda n=n: gym.make_vec(args.env, n, **kwargs)
        if threads > 1 and n >= 32:
            makers[f"{args.env} native ({n}, {threads} threads)"] = lambda n=n: gym.make_vec(
                args.env, n, num_threads=threads, **kwargs
            )
        makers[f"{args.env} sync ({n})"] = lambda n=n: gym.make_vec(args.env, n, vectorization_mode="sync", **kwargs)
        if n <= 16:
            makers[f"{args.env} async ({n})"] = lambda n=n: gym.make_vec(
                args.env, n, vectorization_mode="async", **kwargs
            )
    best = dict.fromkeys(makers, 0.0)
    for name, make in makers.items():
        env = make()  # type: ignore[operator]
        try:
            for _ in range(args.repeats):
                best[name] = max(best[name], env_steps_per_second(env, args.seconds))
        finally:
            env.close()
        print(f"{name}: {best[name]:,.0f} steps/s", file=sys.stderr)
    reference = best["CartPole-v1 SyncVectorEnv (64)"]
    print(f"Python {platform.python_version()}, numpy {np.__version__}, numba {numba.__version__} "
          f"({numba.config.NUMBA_NUM_THREADS} threads), gymnasium {gym.__version__}, {os.cpu_count()} CPUs; "
          f"best of {args.repeats} runs of {args.seconds:g} s; env kwargs {kwargs}")  # fmt: skip
    print()
    print("| vector env | env steps/s | µs per env step | ratio to CartPole SyncVectorEnv(64) |")
    print("|---|---:|---:|---:|")
    for name, rate in best.items():
        print(f"| {name} | {rate:,.0f} | {1e6 / rate:.1f} | {rate / reference:.3f} |")
    print()
    for n in sizes:
        native, sync = best[f"{args.env} native ({n})"], best[f"{args.env} sync ({n})"]
        print(f"N = {n}: native (1 thread) {native / sync:.2f}x the SyncVectorEnv")
    return 0


if __name__ == "__main__":
    sys.exit(main())
