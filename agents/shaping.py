"""Potential-based reward shaping for ``SeifExplore`` training.

:class:`CoverageShaping` adds to the env's reward the potential-based term
(Ng, Harada & Russell, ICML 1999)::

    F_t = coef * (gamma * Phi(s_t) - Phi(s_{t-1})),    Phi = swept fraction of the arena

where the swept fraction is the share of the env's swept-area grid cells
(``belief_map`` channel 0: what the sensor has covered, from the *estimated*
poses) that are marked. Potential-based shaping leaves the optimal policies of
the discounted task unchanged; it only pays sooner for what the map-error
reward pays later: the corners and far edges of the arena, where the last
unmapped landmarks tend to be, lie outside the egocentric map window most of
the time. The wrapper changes the reward only; the observation and the episode are the
env's. Evaluation (``python -m agents.evaluate``) always runs unwrapped envs.

>>> import gymnasium as gym
>>> import seif_gym
>>> from agents.shaping import CoverageShaping
>>> env = CoverageShaping(gym.make("SeifExplore-v2", max_episode_steps=3), coef=1.0)
>>> _, info = env.reset(seed=0)
>>> _, reward, _, _, info = env.step(env.action_space.sample())
>>> 0.0 < info["swept_fraction"] < 1.0
True
"""

from __future__ import annotations

from typing import Any, cast

import gymnasium as gym
import numpy as np

from seif_gym.envs.explore import SeifExploreEnv
from seif_gym.validation import as_nonnegative_scalar

__all__ = ["CoverageShaping"]


class CoverageShaping(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Add ``coef * (gamma * Phi' - Phi)`` with ``Phi`` the swept fraction of the arena.

    Parameters
    ----------
    env : gymnasium.Env
        An env whose ``unwrapped`` is a ``SeifExploreEnv``.
    coef : float, default 1.0
        Weight of the potential (the whole arena swept is worth ``coef``).
    gamma : float, default 0.995
        The discount of the training algorithm (``F`` is policy-invariant for it).

    Raises
    ------
    TypeError
        If ``env.unwrapped`` is not a ``SeifExploreEnv``.
    ValueError
        If ``coef`` or ``gamma`` is negative or not finite, or ``gamma`` exceeds 1.

    Notes
    -----
    Extra ``info`` key: ``swept_fraction`` (``Phi`` after the step). At the end of an episode
    (``terminated``) the next potential is 0, so ``F_T = -coef * Phi(s_{T-1})``.
    """

    def __init__(self, env: gym.Env, coef: float = 1.0, gamma: float = 0.995) -> None:
        for name, value in (("coef", coef), ("gamma", gamma)):
            as_nonnegative_scalar(value, name)
        if gamma > 1:
            raise ValueError(f"gamma must be at most 1, got {gamma!r}")
        if not isinstance(env.unwrapped, SeifExploreEnv):
            raise TypeError(f"env must wrap a SeifExploreEnv, got {type(env.unwrapped).__name__}")
        gym.utils.RecordConstructorArgs.__init__(self, coef=coef, gamma=gamma)
        gym.Wrapper.__init__(self, env)
        self.coef = float(coef)
        self.gamma = float(gamma)
        self._potential = 0.0

    def _swept_fraction(self) -> float:
        coverage = cast(SeifExploreEnv, self.env.unwrapped).encoder.coverage
        return float(np.count_nonzero(coverage)) / coverage.size

    def reset(self, **kwargs: Any):
        observation, info = self.env.reset(**kwargs)
        self._potential = self._swept_fraction()
        info["swept_fraction"] = self._potential
        return observation, info

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        potential = self._swept_fraction()
        # at the episode's end the next state's potential is 0 (no future), as the theory requires
        next_potential = 0.0 if terminated else potential
        reward = float(reward) + self.coef * (self.gamma * next_potential - self._potential)
        self._potential = potential
        info["swept_fraction"] = potential
        return observation, reward, terminated, truncated, info
