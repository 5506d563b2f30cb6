"""Exploration agents for the ``SeifExplore`` environments.

Every agent has Stable-Baselines3's ``predict(observation, state=None,
episode_start=None, deterministic=False) -> (action, state)``, so the
baselines and trained SB3 models are interchangeable.

>>> from agents import BASELINES, make_agent
>>> BASELINES
('random', 'frontier', 'revisit', 'info_gain')

``python -m agents.evaluate`` compares agents on the same seeds, with paired
per-seed differences to the best baseline (:mod:`agents.evaluate`);
``python -m agents.robustness`` records episodes with them for the filter
robustness harness (:mod:`seif_gym.evaluate`, which replays and scores
episodes and never imports this package). Every baseline is built for the env
it acts in, ``make_agent(name, env)``, and reads the observation with that
env's geometry.
"""

from agents.baselines import BASELINES, Agent, make_agent

__all__ = ["Agent", "BASELINES", "make_agent"]
