"""Exploration agents for the ``SeifExplore`` environments.

Every agent has Stable-Baselines3's ``predict(observation, state=None,
episode_start=None, deterministic=False) -> (action, state)``, so the
baselines and trained SB3 models are interchangeable.

>>> from agents import BASELINES, make_agent
>>> BASELINES
('random', 'frontier', 'revisit', 'info_gain')

``python -m agents.evaluate`` compares agents on the same seeds
(:mod:`agents.evaluate`).
"""

from agents.baselines import BASELINES, Agent, make_agent

__all__ = ["Agent", "BASELINES", "make_agent"]
