"""Evaluation speed: the batched path against the previous one (serial, batch 1), side by side in one run.

Usage::

    python benchmarks/bench_evaluation.py [--episodes 20] [--env SeifExplore-v2] [--policy ppo]
        [--agents random,frontier,revisit,info_gain,ppo] [--decisions 100] [--load 1] [--skip-table]
        [--per-agent] [--workers 2]

Three measurements, each printed as a table:

1. The showcase's table: :func:`agents.evaluate.evaluate_agents` of the main job's agents (the
   baselines and ``--policy``) on ``--episodes`` held-out episodes of ``--env``, once as before
   (``batch=False``, every episode one after another in a single env, on torch's default thread
   count) and once as now (``batch=True`` on one thread per process), each one call of all the
   agents as the showcase makes it (``--per-agent``: also each agent alone), and once more as now
   spread over ``--workers`` processes (``python -m agents.showcase --workers 2``); the rows are
   checked equal but for the measured decision times. The showcase runs the protocol's 100
   episodes; the default here is 20 (``--episodes 100`` for the showcase's own count).
   The ceiling of the batched call (measurement 2) is printed beside it: the decision's
   floating-point operations against this core's one-thread matrix-product rate.
2. Decisions per second of ``--policy``: its ``predict`` on the observations of ``--decisions``
   sub-envs (after 20 random steps), one call per observation (batch 1: on torch's default threads,
   the previous path, and on one thread) and one call for all of them (inside
   :meth:`~agents.sb3_agent.SB3Agent.exact_batches`, as the evaluation runs it; and a plain batched
   call, which rounds otherwise, for comparison).
3. A decision's time under a concurrent CPU load: ``--load`` busy processes (an endless loop each,
   stopped at the end) while the policy decides with batch 1 on torch's default threads and on one
   thread, beside ``frontier``'s decision time, with and without the load.

Figures only: nothing here asserts a time.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import torch

import seif_gym  # noqa: F401  (registers the environments)
from agents.baselines import BASELINES, InfoGainAgent
from agents.evaluate import evaluate_agents, limited_threads, make_evaluation_env
from agents.loading import SHIPPED_POLICIES, load_agent
from agents.parallel import Executor
from agents.protocol import HELD_OUT_SEED
from agents.sb3_agent import SB3Agent
from seif_gym import LATEST_ID

#: torch's thread count before anything here changes it: what an evaluation used before ``--threads``
DEFAULT_THREADS = torch.get_num_threads()


def untimed(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{key: value for key, value in row.items() if key != "decision_time_ms"} for row in rows]


@contextlib.contextmanager
def previous_planner(enabled: bool) -> Iterator[None]:
    """Inside the block (when ``enabled``) info_gain plans as the previous commit did, one deep copy per arc."""
    if not enabled:
        yield
        return
    plan = InfoGainAgent.plan
    InfoGainAgent.plan = InfoGainAgent._plan_reference  # type: ignore[method-assign]
    try:
        yield
    finally:
        InfoGainAgent.plan = plan  # type: ignore[method-assign]


def _evaluate(specs: Sequence[str], episodes: int, env_id: str, *, now: bool, workers: int = 1) -> tuple[float, Any]:
    """Seconds and untimed rows of one :func:`evaluate_agents` call, the previous path or the new one."""
    executor = Executor(workers=workers)
    started = time.perf_counter()
    with previous_planner(enabled=not now):
        result, _ = evaluate_agents(specs, episodes, HELD_OUT_SEED, env_id, batch=now,
                                    threads=1 if now else DEFAULT_THREADS, executor=executor)  # fmt: skip
    return time.perf_counter() - started, untimed(result)


def table_times(specs: Sequence[str], episodes: int, env_id: str, *, per_agent: bool = False, workers: int = 2) -> None:
    """Measurement 1: the showcase's table, the previous path and the batched one (and, optionally, each agent's share)."""
    print(f"## The showcase's table: {', '.join(specs)} on {episodes} held-out episodes of {env_id}\n")
    print(
        f"previous: batch=False, torch's default {DEFAULT_THREADS} threads, info_gain's previous planner "
        "(InfoGainAgent._plan_reference: a deep copy of the filter per arc); now: batch=True, threads=1; "
        "each row one evaluate_agents call, as the showcase makes it\n"
    )
    for now in (False, True):  # loading the compiled kernels and the models out of the timing
        evaluate_agents(specs, 2, HELD_OUT_SEED, env_id, {"max_episode_steps": 3}, batch=now)
    print("| agents | previous (s) | now (s) | speed-up | rows equal |")
    print("|---|--:|--:|--:|---|")
    for spec in specs if per_agent else []:
        (before, expected), (after, rows) = (_evaluate([spec], episodes, env_id, now=now) for now in (False, True))
        equal = "yes" if rows == expected else "NO"
        print(f"| {spec.split('=', 1)[0]} | {before:.1f} | {after:.1f} | {before / after:.1f}x | {equal} |", flush=True)
    before, expected = _evaluate(specs, episodes, env_id, now=False)
    after, rows = _evaluate(specs, episodes, env_id, now=True)
    equal = "yes" if rows == expected else "NO"
    print(f"| **the table** | **{before:.1f}** | **{after:.1f}** | **{before / after:.1f}x** | {equal} |", flush=True)
    spread, rows = _evaluate(specs, episodes, env_id, now=True, workers=workers)
    equal = "yes" if rows == expected else "NO"
    print(f"| the table, `--workers {workers}` | {before:.1f} | {spread:.1f} | {before / spread:.1f}x | {equal} |\n")


def best_time(function: Callable[[], Any], seconds: float = 1.0, repeats: int = 3) -> float:
    """The best over ``repeats`` runs of the mean wall time of one ``function()`` call, seconds."""
    function()
    best = float("inf")
    for _ in range(repeats):
        calls, started = 0, time.perf_counter()
        while True:
            function()
            calls += 1
            elapsed = time.perf_counter() - started
            if elapsed >= seconds / repeats:
                break
        best = min(best, elapsed / calls)
    return best


def observations(env_id: str, count: int) -> list[dict[str, np.ndarray]]:
    """One observation per sub-env of ``count``, after 20 seeded random steps."""
    env = gym.make_vec(env_id, num_envs=count, exact_pose_nees=False)
    batch, _ = env.reset(seed=list(range(HELD_OUT_SEED, HELD_OUT_SEED + count)))
    rng = np.random.default_rng(0)
    for _ in range(20):
        batch, *_ = env.step(rng.uniform(-1.0, 1.0, size=(count, 2)))
    env.close()
    return [{key: value[e] for key, value in batch.items()} for e in range(count)]


def decision_rates(policy: str, env_id: str, count: int) -> None:
    """Measurement 2: decisions per second of ``policy``, batch 1 and one batch of ``count``."""
    env = make_evaluation_env(env_id, {})
    agent = load_agent(policy, env)
    assert isinstance(agent, SB3Agent)
    singles = observations(env_id, count)
    batch = {key: np.stack([o[key] for o in singles]) for key in singles[0]}
    starts = np.ones(count, dtype=bool)

    def one_by_one() -> None:
        for observation in singles:
            agent.predict(observation, episode_start=np.array([True]), deterministic=True)

    def batched() -> None:
        agent.predict(batch, episode_start=starts, deterministic=True)

    rates: dict[str, float] = {}
    agent.threads = DEFAULT_THREADS
    rates[f"batch 1, {DEFAULT_THREADS} threads (previous)"] = count / best_time(one_by_one)
    agent.threads = 1
    with limited_threads(1):
        rates["batch 1, 1 thread"] = count / best_time(one_by_one)
        rates[f"batch {count}, 1 thread, plain (rounds otherwise)"] = count / best_time(batched)
        with agent.exact_batches():
            batched()  # the first batched call checks each row alone
            rates[f"batch {count}, 1 thread, exact (the evaluation's)"] = count / best_time(batched)
        flops = decision_flops(agent, singles[0])
        gemm = gemm_rate()
    env.close()
    print(f"## Decisions per second of {policy} on {env_id} ({count} observations)\n")
    print("| how | decisions/s | ms/decision | vs previous | vs batch 1, 1 thread |")
    print("|---|--:|--:|--:|--:|")
    previous, single = list(rates.values())[:2]
    for how, rate in rates.items():
        print(f"| {how} | {rate:,.0f} | {1e3 / rate:.3f} | {rate / previous:.1f}x | {rate / single:.1f}x |")
    floor = flops / gemm  # seconds a decision's arithmetic takes at the speed of a large matrix product
    print(
        f"\nThe ceiling: one decision is {flops / 1e6:.2f} MFLOP of forward pass (torch's flop counter); this core "
        f"multiplies large float32 matrices at {gemm / 1e9:.1f} GFLOP/s on one thread, so a batch of {count} takes "
        f"at least {1e3 * count * floor:.2f} ms ({1e3 * floor:.4f} ms a decision): a batched call can reach at most "
        f"{1.0 / (floor * single):.1f}x batch 1's rate on one thread, whatever the implementation.\n"
    )


def decision_flops(agent: SB3Agent, observation: dict[str, np.ndarray]) -> float:
    """Floating-point operations of one batch-1 ``predict`` of ``agent`` (torch's flop counter)."""
    from torch.utils.flop_counter import FlopCounterMode

    counter = FlopCounterMode(display=False)
    with counter:
        agent.predict(observation, episode_start=np.array([True]), deterministic=True)
    return float(counter.get_total_flops())


def gemm_rate(size: int = 1024) -> float:
    """Floating-point operations per second of a large float32 matrix product on this process's threads."""
    generator = torch.Generator().manual_seed(0)
    a = torch.randn(size, size, generator=generator)
    b = torch.randn(size, size, generator=generator)
    return 2.0 * size**3 / best_time(lambda: a @ b)


def busy_processes(count: int) -> list[subprocess.Popen[bytes]]:
    """``count`` processes that spin on a core each until killed."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]


def under_load(policy: str, env_id: str, load: int) -> None:
    """Measurement 3: batch-1 decision times of ``policy`` and ``frontier`` with and without ``load`` busy processes."""
    env = make_evaluation_env(env_id, {})
    agent = load_agent(policy, env)
    frontier = load_agent("frontier", env)
    assert isinstance(agent, SB3Agent)
    observation, _ = env.reset(seed=HELD_OUT_SEED)
    for _ in range(20):
        observation, *_ = env.step(env.action_space.sample())

    def decide(who: Any) -> Callable[[], Any]:
        return lambda: who.predict(observation, episode_start=np.array([False]), deterministic=True)

    def measure() -> dict[str, float]:
        times = {}
        agent.threads = DEFAULT_THREADS
        times[f"{policy}, {DEFAULT_THREADS} threads (previous)"] = best_time(decide(agent), 2.0)
        agent.threads = 1
        times[f"{policy}, 1 thread"] = best_time(decide(agent), 2.0)
        times["frontier"] = best_time(decide(frontier), 2.0)
        return times

    idle = measure()
    workers = busy_processes(load)
    try:
        time.sleep(0.5)
        loaded = measure()
    finally:
        for worker in workers:
            worker.kill()
        for worker in workers:
            worker.wait()
    env.close()
    print(f"## A decision's time (batch 1) with {load} busy process(es) beside it\n")
    print("| who | idle (ms) | loaded (ms) | slow-down |")
    print("|---|--:|--:|--:|")
    for who in idle:
        print(f"| {who} | {1e3 * idle[who]:.3f} | {1e3 * loaded[who]:.3f} | {loaded[who] / idle[who]:.1f}x |")
    print()


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=20, help="held-out episodes of the table (default 20)")
    parser.add_argument("--env", default=LATEST_ID, help="registered env id (default %(default)s)")
    parser.add_argument("--policy", default="ppo", help="a shipped policy (default %(default)s)")
    parser.add_argument("--agents", default=None, help="the table's agents (default: the baselines and --policy)")
    parser.add_argument("--decisions", type=int, default=100, help="observations of the batched call (default 100)")
    parser.add_argument("--load", type=int, default=1, help="busy processes of the load test (default 1)")
    parser.add_argument("--skip-table", action="store_true", help="only the decision measurements")
    parser.add_argument("--per-agent", action="store_true", help="also each agent's share of the table, timed alone")
    parser.add_argument("--workers", type=int, default=2, help="processes of the table's spread run (default 2)")
    args = parser.parse_args(argv)
    if args.policy not in SHIPPED_POLICIES:
        parser.error(f"--policy must be a shipped policy ({', '.join(SHIPPED_POLICIES)}), got {args.policy!r}")
    for name, value in (("--episodes", args.episodes), ("--decisions", args.decisions), ("--load", args.load),
                        ("--workers", args.workers)):  # fmt: skip
        if value < 1:
            parser.error(f"{name} must be positive, got {value}")
    specs = args.agents.split(",") if args.agents else [*BASELINES, args.policy]
    print(f"# Evaluation speed ({platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"torch {torch.__version__}, default {DEFAULT_THREADS} torch threads)\n")  # fmt: skip
    if not args.skip_table:
        table_times(specs, args.episodes, args.env, per_agent=args.per_agent, workers=args.workers)
    decision_rates(args.policy, args.env, args.decisions)
    under_load(args.policy, args.env, args.load)


if __name__ == "__main__":
    main()
