"""RecurrentPPO training throughput: sb3-contrib's step-by-step LSTM sequences against the fused ones.

Usage::

    python benchmarks/bench_recurrent.py [--env SeifExploreLoopBudget-v2] [--timesteps 16384]

Runs ``python -m agents.train --algo ppo_lstm`` with the task's entry of
``agents/hyperparams/ppo_lstm.yml`` (8 envs, 512-step rollouts, 5 epochs of
minibatches of 1024, the coverage shaping, an LSTM of 256 units), validation
and checkpoints off, once with ``fused_lstm=False`` (sb3-contrib's loop over
time steps wherever an episode begins inside a sequence) and once with
``fused_lstm=True`` (:func:`agents.networks.fused_lstm_sequence`), then fused
again with glibc's allocator left as it is (``--no-keep-freed-memory``:
:mod:`agents.allocator`), and prints the steps per second of ``model.learn``
(``train_time.json``). Each run is a fresh process on one BLAS thread and one
torch thread.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from bench_training import training_rate  # this folder is on sys.path when a benchmark runs as a script

from agents.hyperparams import load


def run(env_id: str, fused: bool, timesteps: int, folder: Path, keep_freed_memory: bool = True) -> float:
    """Steps per second of one training run."""
    policy_kwargs = str(load("ppo_lstm")[env_id]["policy_kwargs"]).strip()
    if not policy_kwargs.endswith(")"):
        raise ValueError(f"env: the entry's policy_kwargs is not a dict(...) string: {policy_kwargs!r}")
    policy_kwargs = policy_kwargs[:-1] + f", fused_lstm={fused})"
    arguments = ["--algo", "ppo_lstm", "--env", env_id, "--timesteps", str(timesteps),
                 "--hyperparams", f"policy_kwargs={policy_kwargs}"]  # fmt: skip
    if not keep_freed_memory:
        arguments.append("--no-keep-freed-memory")
    # torch on one thread too, as the recipes' runs are (two at a time on this 2-core machine)
    name = ("fused" if fused else "loop") + ("" if keep_freed_memory else "_plain_malloc")
    return training_rate(arguments, folder / name, {"OMP_NUM_THREADS": "1"})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="SeifExploreLoopBudget-v2", help="an entry of ppo_lstm.yml")
    parser.add_argument("--timesteps", type=int, default=16384)
    args = parser.parse_args(argv)
    if args.env not in load("ppo_lstm"):
        parser.error(f"--env: ppo_lstm.yml has no entry {args.env!r}")
    with tempfile.TemporaryDirectory() as folder:
        rates = {fused: run(args.env, fused, args.timesteps, Path(folder)) for fused in (False, True)}
        plain_malloc = run(args.env, True, args.timesteps, Path(folder), keep_freed_memory=False)
    print(f"RecurrentPPO on {args.env}, {args.timesteps} steps, {os.cpu_count()} CPUs")
    print()
    print("| LSTM sequences | training steps/s |")
    print("|---|---:|")
    print(f"| step by step (sb3-contrib; fused_lstm=False) | {rates[False]:,.0f} |")
    print(f"| fused (fused_lstm=True) | {rates[True]:,.0f} |")
    print(f"| fused, glibc's allocator as it is (--no-keep-freed-memory) | {plain_malloc:,.0f} |")
    print()
    print(f"fused / step by step: {rates[True] / rates[False]:.2f}x")
    print(f"freed memory kept / allocator as it is: {rates[True] / plain_malloc:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
