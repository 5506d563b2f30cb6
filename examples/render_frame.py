"""Render one frame of an episode to a PNG: the picture at the top of the README and the docs.

python examples/render_frame.py --env SeifExplore-v2 --agent frontier --seed 3 --steps 150 --out frame.png
"""

from __future__ import annotations

import argparse

import gymnasium as gym
from PIL import Image

import seif_gym  # noqa: F401  (registers the envs)
from agents import load_agent


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="SeifExplore-v2")
    parser.add_argument("--agent", default="frontier", help="a baseline or a shipped policy")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--out", default="frame.png")
    args = parser.parse_args()
    env = gym.make(args.env, render_mode="rgb_array")
    agent = load_agent(args.agent, env, seed=args.seed)
    observation, _ = env.reset(seed=args.seed)
    for _ in range(args.steps):
        action, _ = agent.predict(observation, deterministic=True)
        observation, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            break
    Image.fromarray(env.render()).save(args.out, optimize=True)


if __name__ == "__main__":
    main()
