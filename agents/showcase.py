"""The main job: a shipped policy against the baselines, and a GIF of it.

Usage::

    python -m agents.showcase [--policy ppo] [--env SeifExplore-v2] [--episodes N] [--seed 1000000]
        [--out showcase | --resume OUT] [--bootstrap N] [--no-batch] [--batch-size 100] [--threads 1]
        [--workers N | --ray auto|ADDRESS] [--quiet]

Runs :func:`agents.evaluate.evaluate_agents` for ``random``, ``frontier``,
``revisit``, ``info_gain`` and ``--policy`` (a shipped policy's name, default
``ppo``, or the path of a saved model) on the same held-out seeds of
``--env`` (default the newest task, :data:`seif_gym.LATEST_ID`; training never
resets with these seeds; ``--episodes`` default: the protocol's,
:func:`agents.protocol.held_out_episodes`), prints the table (means with 95%
confidence intervals) and the paired comparison with the best baseline (the
mean per-seed difference of the final map error with its 95% Student-t
interval, :func:`agents.evaluate.paired_comparison`; the policy *beats* the
best baseline only when that interval lies below zero), writes
``results.csv``, ``summary.json``, ``summary.md`` and ``map_error.png`` to
``--out``, and records one episode of the policy as ``episode.gif``; each file
whole or not at all, and ``manifest.json`` (every file's SHA-256) last. A
killed run continues with ``--resume OUT`` and the same arguments.
Progress goes to stderr (``--quiet``: none). ``--no-batch``, ``--batch-size``,
``--threads``, ``--workers`` and ``--ray`` are :func:`agents.evaluate.evaluate_agents`'
(the episodes run batched where they can, on one thread per process, spread
over as many processes as the machine has cores, at most 4, by default:
``--workers 1`` keeps them in this process; the rows are the same every way).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import seif_gym  # noqa: F401  (registers the envs)
from agents.baselines import BASELINES
from agents.cli import (
    add_resume_argument,
    check_seeds,
    model_digests,
    non_negative_int,
    positive_int,
    resume_folder,
    task,
    tasks_epilog,
    usage_errors,
)
from agents.cli import seed as seed_type
from agents.evaluate import evaluate_agents, limited_threads, markdown_table, paired_table, write_outputs
from agents.evaluate.cli import add_batch_arguments, check_batch_arguments
from agents.evaluate.journal import MANIFEST, journal_for_command_line, write_manifest
from agents.loading import SHIPPED_POLICIES, agent_labels, check_model_file
from agents.parallel import add_arguments as add_executor_arguments
from agents.parallel import available_cores
from agents.parallel import from_arguments as executor_from_arguments
from agents.protocol import HELD_OUT_SEED, held_out_episodes
from agents.sb3_agent import SB3Agent
from seif_gym import LATEST_ID
from seif_gym._atomic import atomic_write
from seif_gym.progress import Progress

__all__ = ["COMMAND", "ENV_ID", "SHIPPED_POLICY", "main", "record_gif", "verdict_sentence"]

#: The command's name in its journal and manifest.
COMMAND = "agents.showcase"

#: The ``.zip`` of the policy shown by default, the shipped policy ``ppo``.
SHIPPED_POLICY = SHIPPED_POLICIES["ppo"].path
#: The task the main job evaluates on by default: the newest.
ENV_ID = LATEST_ID


def record_gif(policy_path: Path, path: Path, seed: int, every: int = 4, size: int = 400, env_id: str = ENV_ID,
               *, verbose: bool = False, threads: int | None = 1) -> Path:  # fmt: skip
    """One episode of a saved policy on ``env_id`` as an animated GIF, deterministic actions.

    Parameters
    ----------
    policy_path : Path
        A saved SB3 / sb3-contrib model (:class:`~agents.sb3_agent.SB3Agent`); a recurrent policy's
        state is carried from step to step, as :func:`agents.evaluate.run_episode` does.
    path : Path
        The GIF written (whole or not at all).
    seed : int
        Seed of ``env.reset``.
    every : int
        Keep every ``every``-th frame (and the first and last).
    size : int
        Width and height of the frames, pixels.
    env_id : str
        A registered env id.
    verbose : bool
        A progress bar over the episode's steps on stderr.
    threads : int or None
        Torch threads of the policy's forward passes (:class:`~agents.sb3_agent.SB3Agent`'s).

    Returns
    -------
    Path
        ``path``.
    """
    from PIL import Image

    env = gym.make(env_id, render_mode="rgb_array")
    agent = SB3Agent(policy_path, env=env, threads=threads)
    observation, _ = env.reset(seed=seed)
    frames: list[Any] = [env.render()]
    done, step = False, 0
    state, start = None, True  # a recurrent policy's memory, carried as agents.evaluate.run_episode does
    limit = env.spec.max_episode_steps if env.spec is not None and env.spec.max_episode_steps else 1
    with Progress(int(limit), f"{path.name}", enabled=verbose, unit="steps") as progress:
        while not done:
            action, state = agent.predict(observation, state=state, episode_start=np.array([start]), deterministic=True)
            start = False
            observation, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
            step += 1
            progress.update(1)
            if step % every == 0 or done:
                frames.append(env.render())
    env.close()
    images = [Image.fromarray(frame).resize((size, size), Image.LANCZOS) for frame in frames]
    atomic_write(path, lambda temporary: images[0].save(temporary, format="GIF", save_all=True,
                                                         append_images=images[1:], duration=80, loop=0,
                                                         optimize=True))  # fmt: skip
    return Path(path)


def verdict_sentence(summary: Mapping[str, Any], label: str) -> str:
    """One sentence: whether agent ``label`` beats the best baseline by the paired comparison of ``summary``.

    Parameters
    ----------
    summary : mapping
        :func:`agents.evaluate.evaluate_agents`' summary.
    label : str
        An agent of it.

    Returns
    -------
    str
        Its mean final map error and, when there is a baseline to compare with, the verdict of
        :func:`agents.evaluate.paired_verdict` in words with the interval.
    """
    paired = summary["paired"]
    reference = paired["reference"]
    mean = summary["agents"][label]["final_map_error"]["mean"]
    if reference is None or label not in paired["agents"]:
        return f"{label}: final map error {mean:.3f} m (no baseline to compare with)."
    entry = paired["agents"][label]
    reference_mean = summary["agents"][reference]["final_map_error"]["mean"]
    interval = ("no interval (one seed)" if entry["ci95_low"] is None else
                f"95% t interval [{entry['ci95_low']:+.3f}, {entry['ci95_high']:+.3f}] m over {entry['n']} seeds")  # fmt: skip
    if entry["verdict"] == "beats":
        outcome = "beats"
    elif entry["verdict"] == "worse":
        outcome = "is worse than"
    else:
        outcome = "does not beat"
    reason = "" if entry["verdict"] in ("beats", "worse") else " (the interval holds 0)"
    return (f"{label} ({mean:.3f} m) {outcome} the best baseline, {reference} ({reference_mean:.3f} m){reason}: "
            f"paired per-seed difference of the final map error {entry['mean']:+.3f} m, {interval}.")  # fmt: skip


def main(argv: Sequence[str] | None = None) -> None:
    """Run ``python -m agents.showcase`` with ``argv`` (default ``sys.argv[1:]``).

    Every input is checked before any episode runs and before anything is written (:mod:`agents.cli`):
    a bad argument exits through ``argparse`` (status 2, one line). The files are written whole or not at
    all, ``manifest.json`` last; ``--resume OUT`` continues a killed run.
    """
    parser = argparse.ArgumentParser(
        prog="python -m agents.showcase",
        description=__doc__,
        epilog=f"shipped policies (--policy): {', '.join(SHIPPED_POLICIES)}\n\n{tasks_epilog()}",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--episodes", type=positive_int, default=None,
                        help="held-out episodes per agent (default: the protocol's for --env)")  # fmt: skip
    parser.add_argument("--seed", type=seed_type, default=HELD_OUT_SEED,
                        help="first held-out seed (default %(default)s)")  # fmt: skip
    parser.add_argument("--policy", default="ppo",
                        help="the policy to show: a shipped policy's name or the path of a saved model (default %(default)s)")  # fmt: skip
    parser.add_argument("--env", type=task, default=ENV_ID, metavar="TASK",
                        help="registered env id or family (default %(default)s)")  # fmt: skip
    parser.add_argument("--out", default=None, help="output folder (default showcase)")
    add_resume_argument(parser)
    parser.add_argument("--bootstrap", type=non_negative_int, default=0, metavar="N",
                        help="also a percentile bootstrap interval of the paired differences, N resamples")  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    add_batch_arguments(parser)
    add_executor_arguments(parser, workers=available_cores())  # the main job uses the machine's cores
    args = parser.parse_args(argv)
    executor = executor_from_arguments(args, parser)
    if args.episodes is None:
        try:
            args.episodes = held_out_episodes(args.env)
        except ValueError as error:
            parser.error(f"--env: {error}")
    check_batch_arguments(args, parser)
    policy = SHIPPED_POLICIES[args.policy].path if args.policy in SHIPPED_POLICIES else Path(args.policy)
    if not policy.is_file():
        parser.error(f"--policy: {args.policy!r} is neither a shipped policy ({', '.join(SHIPPED_POLICIES)}) "
                     "nor the path of a saved model")  # fmt: skip
    label = args.policy if args.policy in SHIPPED_POLICIES else None
    specs = [*BASELINES, str(policy) if label is None else f"{label}={policy}"]
    with usage_errors(parser):  # every input answered before any episode runs and anything is written
        try:
            check_model_file(policy)
        except (ValueError, FileNotFoundError) as error:
            raise ValueError(f"--policy: {error}") from None
        check_seeds(args.seed, args.episodes)
        out, resume = resume_folder(args, "showcase")
    config = {"env_id": args.env, "episodes": args.episodes, "seed": args.seed, "agents": specs,
              "models": model_digests(agent_labels(specs)), "bootstrap": args.bootstrap, "threads": args.threads}  # fmt: skip
    journal = journal_for_command_line(parser, out, COMMAND, config, resume)
    if journal is None:
        return
    started = time.perf_counter()
    with limited_threads(args.threads):
        rows, summary = evaluate_agents(specs, episodes=args.episodes, seed=args.seed, env_id=args.env, env_kwargs={},
                                        verbose=not args.quiet, bootstrap=args.bootstrap, executor=executor,
                                        batch=not args.no_batch,
                                        batch_size=args.batch_size, threads=args.threads, journal=journal)  # fmt: skip
        paths = write_outputs(rows, summary, out, manifest=False)
        print(f"{args.env}, {args.episodes} episodes per agent on seeds {args.seed}..{args.seed + args.episodes - 1} "
              f"({time.perf_counter() - started:.0f} s); mean ± 95% CI half-width\n")  # fmt: skip
        print(markdown_table(summary))
        paired = paired_table(summary)
        if paired:
            print(f"\n{paired}")
        print(f"\n{verdict_sentence(summary, list(summary['agents'])[-1])}")
        gif = record_gif(policy, out / "episode.gif", seed=args.seed, env_id=args.env, verbose=not args.quiet,
                         threads=args.threads)  # fmt: skip
    write_manifest(out, [*paths.values(), gif], COMMAND, config)
    journal.finish()
    print(f"\nwrote {', '.join(str(path) for path in paths.values())}, {gif} and {out / MANIFEST}")


if __name__ == "__main__":
    main()
