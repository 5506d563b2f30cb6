"""PPO training throughput with each vector env: native (``gym.make_vec``), SB3's DummyVecEnv, SubprocVecEnv.

Usage::

    python benchmarks/bench_training.py [--env SeifExplore-v2] [--timesteps 16384] [--n-envs 8]

Runs ``python -m agents.train`` with the shipped hyperparameters
(``agents/hyperparams/ppo.yml``: 512 steps per env per rollout, 5 epochs of
minibatches of 1024) once per ``--vec-env``, without the entry's shaping
wrapper (a wrapper of single envs would turn ``native`` into ``dummy``),
validation and checkpoints off, and prints the steps per second of ``model.learn`` (what
``train_time.json`` records). Each run is a fresh process, so the numbers
include neither the other runs' warm caches nor their threads.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from seif_gym import LATEST_ID

VEC_ENVS = ("native", "dummy", "subproc")


def training_rate(train_arguments: list[str], out: Path, extra_environment: dict[str, str] | None = None) -> float:
    """Steps per second of ``model.learn`` in one ``python -m agents.train`` run, a fresh process on one BLAS thread.

    ``train_arguments`` are the run's own; the run writes to ``out``, validation and checkpoints off;
    ``extra_environment`` adds variables to the process's environment.
    """
    command = [sys.executable, "-m", "agents.train", *train_arguments, "--out", str(out), "--quiet",
               "--eval-freq", "-1", "--checkpoint-freq", "-1"]  # fmt: skip
    environment = {**os.environ, "OPENBLAS_NUM_THREADS": "1", **(extra_environment or {})}
    subprocess.run(command, check=True, capture_output=True, text=True, env=environment)
    record = json.loads((out / "train_time.json").read_text())
    return record["timesteps"] / record["seconds"]


def run(env_id: str, vec_env: str, timesteps: int, n_envs: int, folder: Path) -> float:
    """Steps per second of one training run."""
    # the shipped entry's shaping wrapper would turn native into dummy, and validation is not training:
    # both off, so that the three runs differ only in the vector env
    arguments = ["--algo", "ppo", "--env", env_id, "--timesteps", str(timesteps), "--n-envs", str(n_envs),
                 "--vec-env", vec_env, "--hyperparams", "env_wrapper=null"]  # fmt: skip
    return training_rate(arguments, folder / vec_env)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default=LATEST_ID)
    parser.add_argument("--timesteps", type=int, default=16384)
    parser.add_argument("--n-envs", type=int, default=8)
    parser.add_argument("--vec-envs", default=",".join(VEC_ENVS), help="comma-separated, of " + ", ".join(VEC_ENVS))
    args = parser.parse_args(argv)
    chosen = [name.strip() for name in args.vec_envs.split(",") if name.strip()]
    for name in chosen:
        if name not in VEC_ENVS:
            parser.error(f"--vec-envs: unknown {name!r}")
    with tempfile.TemporaryDirectory() as folder:
        rates = {name: run(args.env, name, args.timesteps, args.n_envs, Path(folder)) for name in chosen}
    print(f"PPO on {args.env}, {args.n_envs} envs, {args.timesteps} steps, {os.cpu_count()} CPUs")
    print()
    print("| vec env | training steps/s |")
    print("|---|---:|")
    for name, rate in rates.items():
        print(f"| {name} | {rate:,.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
