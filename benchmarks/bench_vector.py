"""Vector env throughput: the native SeifExplore vector env against Gymnasium's and CartPole-v1's.

Usage::

    python benchmarks/bench_vector.py [--env SeifExplore-v2] [--env-kwargs JSON] [--sizes 1,16,64,256]
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

``--stages`` also splits the native env's step (one thread) into its
compiled calls (the worlds, the motion and measurement updates, the
observations, the scores) and the Python around them, in µs per env step:
the compiled calls' sum bounds what any Python-side work can reach, at
``1e6 / sum`` env steps per second per thread.
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
from seif_gym import LATEST_ID  # noqa: E402
from seif_gym.envs import vector as vector_module  # noqa: E402


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


def stage_times(env_id: str, n: int, kwargs: dict, seconds: float) -> dict[str, float]:
    """µs per env step of each compiled call of the native env's ``step`` (one thread), and the rest.

    Wraps the calls the step makes (the batch's world and filter methods, the module's encoder and
    score kernels) with timers for one run of about ``seconds``; restores them afterwards.
    """
    env = gym.make_vec(env_id, n, **kwargs).unwrapped
    if getattr(env, "backend", None) != "compiled":
        env.close()
        raise SystemExit(f"--stages needs the compiled native env; {env_id} {kwargs} runs as a SyncVectorEnv")
    totals: dict[str, float] = {}

    def timed(name: str, function):  # type: ignore[no-untyped-def]
        def call(*args):  # type: ignore[no-untyped-def]
            started = time.perf_counter()
            result = function(*args)
            totals[name] = totals.get(name, 0.0) + time.perf_counter() - started
            return result

        return call

    world, filters = env._world, env._filters
    world.step, world.measure = timed("world: motion", world.step), timed("world: sensor", world.measure)
    filters.predict_trusted = timed("filter: motion update", filters.predict_trusted)
    filters.update_trusted = timed("filter: measurement update, recovery, sparsification", filters.update_trusted)
    encode, score = vector_module.encode_many, vector_module._score_many
    vector_module.encode_many = timed("observations (blanket covariances, raster)", encode)
    vector_module._score_many = timed("rewards, map error, pose NEES", score)
    try:
        env.reset(seed=0)
        env.action_space.seed(0)
        actions = [env.action_space.sample() for _ in range(64)]
        for action in actions:
            env.step(action)  # compiled and warm
        totals.clear()
        steps, started = 0, time.perf_counter()
        while time.perf_counter() - started < seconds:
            env.step(actions[steps % 64])
            steps += 1
        elapsed = time.perf_counter() - started
    finally:
        vector_module.encode_many, vector_module._score_many = encode, score
        env.close()
    per_step = {name: total / (steps * n) * 1e6 for name, total in totals.items()}
    per_step["Python around them (infos, checks, autoresets)"] = elapsed / (steps * n) * 1e6 - sum(per_step.values())
    return per_step


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default=LATEST_ID)
    parser.add_argument(
        "--env-kwargs", default="{}", help='keyword arguments of every env, JSON (e.g. \'{"filter": "eseif"}\')'
    )
    parser.add_argument("--sizes", default="1,16,64,256", help="comma-separated numbers of sub-envs")
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--stages", action="store_true", help="also time the native step's compiled calls (1 thread)")
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
    if args.stages:
        stages = {n: stage_times(args.env, n, kwargs, args.seconds) for n in sizes}
        print()
        print("| µs per env step, native, 1 thread | " + " | ".join(f"N = {n}" for n in sizes) + " |")
        print("|---|" + "---:|" * len(sizes))
        for name in stages[sizes[0]]:
            print(f"| {name} | " + " | ".join(f"{stages[n][name]:.1f}" for n in sizes) + " |")
        compiled = {n: sum(v for k, v in stages[n].items() if not k.startswith("Python")) for n in sizes}
        print("| **compiled calls, sum** | " + " | ".join(f"**{compiled[n]:.1f}**" for n in sizes) + " |")
        print(
            "| their ceiling, env steps/s per thread | " + " | ".join(f"{1e6 / compiled[n]:,.0f}" for n in sizes) + " |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
