"""Agents for the ``SeifExplore`` environments: baselines, shipped policies, training and evaluation.

Every agent has Stable-Baselines3's ``predict(observation, state=None,
episode_start=None, deterministic=False) -> (action, state)``
(:class:`~agents.base.Agent`), so the baselines and trained models are
interchangeable.

>>> from agents import BASELINES
>>> BASELINES
('random', 'frontier', 'revisit', 'info_gain')

- :func:`pretrained` gives a shipped policy for a task or by name,
  :func:`list_pretrained` lists them;
- :func:`load_agent` builds any agent spec (a baseline, a shipped policy, an
  SB3 ``.zip``, ``rllib:CHECKPOINT``) for the env it acts in;
- ``python -m agents.showcase`` (the main job), ``agents.evaluate``,
  ``agents.benchmark`` (the leaderboard), ``agents.train`` and
  ``agents.robustness`` are the commands.
"""

from agents.base import Agent
from agents.baselines import BASELINES, make_agent
from agents.loading import PretrainedInfo, list_pretrained, load_agent, pretrained

__all__ = ["Agent", "BASELINES", "PretrainedInfo", "list_pretrained", "load_agent", "make_agent", "pretrained"]
