"""Training that starts from a clone of a teacher: ``python -m research.kickstart``.

``agents.train``'s command line and three more options: ``--kickstart TEACHER``
clones a baseline (``info_gain``) or the privileged ``coverage_oracle``
(:mod:`research.oracle`) into the policy before PPO learns, on the teacher's
own episodes and then ``--dagger-rounds`` DAgger rounds,
``--kickstart-episodes`` episodes in all on training seeds drawn from
``--seed`` (:mod:`research.imitation`). The research log's E13–E16 ran this
as ``python -m agents.train --kickstart ...`` (before seif_gym 1.0).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from agents import train as agents_train
from agents.protocol import VALIDATION_SEED

__all__ = ["build_parser", "check_kickstart", "kickstart_seeds", "main"]


def build_parser() -> argparse.ArgumentParser:
    """``agents.train``'s parser with ``--kickstart``, ``--kickstart-episodes`` and ``--dagger-rounds``."""
    parser = agents_train.build_parser()
    parser.prog = "python -m research.kickstart"
    parser.add_argument(
        "--kickstart",
        default=None,
        metavar="TEACHER",
        help="before learning, clone this teacher into the policy: a baseline (e.g. info_gain) or "
        "coverage_oracle (privileged: reads the true state); its episodes, then DAgger rounds (research.imitation)",
    )
    parser.add_argument(
        "--kickstart-episodes",
        type=int,
        default=48,
        help="episodes of the cloning, split between the baseline's own and the DAgger rounds' (training seeds "
        "drawn from --seed)",
    )
    parser.add_argument("--dagger-rounds", type=int, default=2, help="DAgger rounds of the cloning")
    return parser


def kickstart_seeds(seed: int, episodes: int) -> list[int]:
    """The cloning's episode seeds of training seed ``seed``: ``episodes`` distinct seeds of the training split."""
    if episodes < 1:
        raise ValueError(f"--kickstart-episodes must be at least 1, got {episodes}")
    return sorted(int(s) for s in np.random.default_rng(seed).choice(VALIDATION_SEED, size=episodes, replace=False))


def check_kickstart(args: argparse.Namespace) -> None:
    """``ValueError`` for ``--kickstart`` arguments that cannot work, before anything is built."""
    from research.imitation import TEACHERS, round_seeds

    if args.kickstart not in TEACHERS:
        raise ValueError(f"--kickstart: unknown teacher {args.kickstart!r}; teachers: {', '.join(TEACHERS)}")
    if args.algo != "ppo":
        raise ValueError(f"--kickstart: clones into PPO's actor-critic policy, got --algo {args.algo}")
    if args.init_from:
        raise ValueError("--kickstart and --init-from both choose the starting weights: pass one of them")
    try:
        round_seeds(kickstart_seeds(args.seed, args.kickstart_episodes), args.dagger_rounds)
    except ValueError as error:
        raise ValueError(f"--kickstart-episodes/--dagger-rounds: {error}") from error


def _kickstart(args: argparse.Namespace, experiment: Any, model: Any) -> None:
    """Clone ``--kickstart`` into ``model`` on the training envs' wrapped single env (research.imitation)."""
    if not args.kickstart:
        return
    check_kickstart(args)
    from research.imitation import kickstart

    seeds = kickstart_seeds(args.seed, args.kickstart_episodes)
    env_id, env_kwargs, wrapper = experiment.env_name.gym_id, dict(experiment.env_kwargs), experiment.env_wrapper

    def make_env() -> gym.Env:
        env = gym.make(env_id, **env_kwargs)
        return wrapper(env) if wrapper is not None else env

    def say(line: str) -> None:
        if not args.quiet:
            print(f"research.kickstart: {line}", file=sys.stderr)

    started = time.perf_counter()
    kickstart(model, make_env, args.kickstart, seeds=seeds, dagger_rounds=args.dagger_rounds, log=say)
    say(f"kickstart: {time.perf_counter() - started:.0f} s")


def prepare(args: argparse.Namespace) -> tuple[Any, Any]:
    """:func:`agents.train.prepare` with the kickstart (its arguments checked before anything is built)."""
    if args.kickstart:
        check_kickstart(args)
    return agents_train.prepare(args, before_learn=_kickstart)


def main(argv: Sequence[str] | None = None) -> int:
    """The command line (``agents.train``'s, with the kickstart checked before anything is built)."""
    args = build_parser().parse_args(argv)
    if args.kickstart:
        try:
            check_kickstart(args)
        except ValueError as error:
            raise SystemExit(f"research.kickstart: {error}") from error
    return agents_train.run(args, before_learn=_kickstart)


if __name__ == "__main__":
    sys.exit(main())
