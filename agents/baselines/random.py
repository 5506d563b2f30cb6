"""The ``random`` baseline: uniform actions from a seeded generator."""

from __future__ import annotations

from typing import Any

import numpy as np

from agents.base import Agent, Observation
from agents.baselines.geometry import Geometry

__all__ = ["RandomAgent"]


# -- random ----------------------------------------------------------------------------------------
class RandomAgent(Agent):
    """Uniform random actions in ``[-1, 1]^2``.

    Parameters
    ----------
    env : gymnasium.Env
        The ``SeifExplore`` env it acts in (checked, like every baseline's;
        its action space is ``[-1, 1]^2``).
    seed : int or None
        Seed of the agent's ``numpy.random.Generator``; the same seed gives
        the same action sequence.
    """

    name = "random"
    carries_over_episodes = True  # one generator for all episodes

    def __init__(self, env: Any, *, seed: int | None = None) -> None:
        super().__init__(env)
        self.geometry = Geometry.from_env(env)
        self.seed = seed
        self.rng = np.random.default_rng(seed)

    def _act(self, observation: Observation, index: int) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, 2)

    def __repr__(self) -> str:
        return f"RandomAgent(seed={self.seed})"
