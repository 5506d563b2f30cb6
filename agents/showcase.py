"""The main job: the shipped policy against the baselines, and a GIF of it.

Usage::

    python -m agents.showcase [--episodes 100] [--seed 1000000] [--env SeifExplore-v1] [--out showcase]

Runs :func:`agents.evaluate.evaluate_agents` for ``random``, ``frontier``,
``revisit``, ``info_gain`` and the shipped PPO policy
(:data:`SHIPPED_POLICY`, trained on ``SeifExplore-v0``) on the same held-out
seeds of ``--env`` (default the newest, ``SeifExplore-v1``; training never
resets with these seeds), prints the
table (means with 95% confidence intervals), writes ``results.csv``,
``summary.json``, ``summary.md`` and ``map_error.png`` to ``--out``, and
records one episode of the shipped policy as ``episode.gif``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym

import seif_gym  # noqa: F401  (registers the envs)
from agents import BASELINES
from agents.evaluate import SB3Agent, evaluate_agents, markdown_table, write_outputs

SHIPPED_POLICY = Path(__file__).parent / "policies" / "ppo_seif_explore.zip"
#: The env the main job evaluates on (the shipped policy was trained on ``SeifExplore-v0``).
ENV_ID = "SeifExplore-v1"
#: First held-out seed: far from the seeds training and its evaluation callback draw.
HELD_OUT_SEED = 1_000_000


def record_gif(policy_path: Path, path: Path, seed: int, every: int = 4, size: int = 400, env_id: str = ENV_ID) -> Path:
    """One episode of the policy at ``policy_path`` on ``env_id`` as an animated GIF (every ``every``-th frame)."""
    from PIL import Image

    env = gym.make(env_id, render_mode="rgb_array")
    agent = SB3Agent(policy_path, env=env)
    observation, _ = env.reset(seed=seed)
    frames = [env.render()]
    done, step = False, 0
    while not done:
        action, _ = agent.predict(observation, deterministic=True)
        observation, _, terminated, truncated, _ = env.step(action)
        done = terminated or truncated
        step += 1
        if step % every == 0 or done:
            frames.append(env.render())
    env.close()
    images = [Image.fromarray(frame).resize((size, size), Image.LANCZOS) for frame in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=80, loop=0, optimize=True)
    return path


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=HELD_OUT_SEED)
    parser.add_argument("--policy", default=str(SHIPPED_POLICY), help="SB3 .zip of the policy to show")
    parser.add_argument("--env", default=ENV_ID, help="registered env id (default %(default)s)")
    parser.add_argument("--out", default="showcase")
    args = parser.parse_args(argv)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    specs = [*BASELINES, args.policy]
    started = time.perf_counter()
    rows, summary = evaluate_agents(specs, episodes=args.episodes, seed=args.seed, env_id=args.env, env_kwargs={})
    write_outputs(rows, summary, out)
    print(f"{args.env}, {args.episodes} episodes per agent on seeds {args.seed}..{args.seed + args.episodes - 1} "
          f"({time.perf_counter() - started:.0f} s)\n")  # fmt: skip
    print(markdown_table(summary))
    labels = list(summary["agents"])
    policy_label = labels[-1]
    errors = {label: summary["agents"][label]["final_map_error"]["mean"] for label in labels}
    best_baseline = min((label for label in labels if label != policy_label), key=errors.get)
    verdict = "beats" if errors[policy_label] < errors[best_baseline] else "does not beat"
    print(f"\n{policy_label} ({errors[policy_label]:.3f} m) {verdict} the best baseline, "
          f"{best_baseline} ({errors[best_baseline]:.3f} m), on mean final map error.")  # fmt: skip
    gif = record_gif(Path(args.policy), out / "episode.gif", seed=args.seed, env_id=args.env)
    print(f"\nwrote {', '.join(str(out / name) for name in ('results.csv', 'summary.json', 'map_error.png'))} and {gif}")


if __name__ == "__main__":
    main()
