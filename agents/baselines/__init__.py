"""Baseline exploration agents for the ``SeifExplore`` environments.

Every agent is an :class:`Agent` and has Stable-Baselines3's
``predict(observation, state=None, episode_start=None, deterministic=False)
-> (action, state)``, so a baseline and a trained SB3 model are used the same
way. Build one by name with :func:`make_agent`; :data:`BASELINES` lists the
names.

============= ======================= =================================================
name          reads                   what it does
============= ======================= =================================================
``random``    nothing                 uniform actions in ``[-1, 1]^2`` from a seeded
                                      ``numpy.random.Generator``
``frontier``  the observation         drives to the nearest / largest unswept region
                                      of ``obs["belief_map"]`` inside the arena, slows
                                      down in front of the arena's outside
``revisit``   the observation         explores like ``frontier``; when the pose gets
                                      uncertain (or every ``period`` steps) drives back
                                      to the most uncertain of the ``K`` listed
                                      landmarks to re-observe it (close a loop)
``info_gain`` the filter (belief)     rolls constant-``(v, w)`` arcs through a copy of
                                      the filter with the expected measurements and
                                      picks the largest uncertainty reduction plus an
                                      exploration term
============= ======================= =================================================

No agent reads the ground truth. Every baseline is built for the env it acts
in (``make_agent(name, env)``; ``None`` or an object that is not a
``SeifExplore`` env raises ``TypeError``) and reads the observation through
that env's own geometry (:class:`Geometry`: the inverse of the env's
observation encoder, :class:`seif_gym.observation.ObservationDecoder`, and
the sensor's range and field of view): the observation is normalised by the
arena's size, so reading ``SeifExploreLarge``'s with another env's numbers
would misplace everything. The observation-only agents read nothing else of
the env (:data:`GEOMETRY_READS`). ``info_gain`` keeps a reference to
``env.unwrapped`` and also reads its ``filter`` (its arrays copied for the
rollouts) and ``motion`` (:data:`INFO_GAIN_READS`) -- never ``world``.

Observation geometry (see ``seif_gym.observation``): ``obs["pose"]`` is
``(x/h, y/h, cos θ, sin θ, σx/s, σy/s, σθ/π)`` with ``h`` half the arena side;
``obs["landmarks"]`` is flat, ``(4K,)``: :func:`landmark_rows` reshapes it to
``K`` rows ``(forward, left)`` in the robot frame divided by the arena diagonal
``2√2·h``, then the 95 % ellipse semi-axes divided by ``s``;
``obs["belief_map"]`` is a ``uint8`` heading-up raster (``0..255``) of
``±map_extent`` metres, row 0 ahead and column 0 to the left, channels
(swept, landmark certainty, outside the arena), which :func:`read_belief_map`
reads as floats in ``[0, 1]``. Cell ``(i, j)`` has its centre
``forward = e − (i + ½)·c``, ``left = e − (j + ½)·c`` metres from the robot
(``c = 2e/H``).

>>> import gymnasium as gym
>>> import seif_gym
>>> from agents import make_agent
>>> env = gym.make("SeifExplore-v2", max_episode_steps=5)
>>> agent = make_agent("frontier", env)
>>> obs, info = env.reset(seed=0)
>>> action, state = agent.predict(obs, episode_start=True)
>>> action.shape, action.dtype.name
((2,), 'float32')
"""

from __future__ import annotations

from typing import Any

from agents.base import Agent
from agents.baselines.frontier import FrontierAgent
from agents.baselines.geometry import GEOMETRY_READS, Geometry
from agents.baselines.info_gain import INFO_GAIN_READS, InfoGainAgent
from agents.baselines.random import RandomAgent
from agents.baselines.revisit import RevisitAgent
from seif_gym.observation import landmark_rows, read_belief_map

__all__ = [
    "Agent",
    "RandomAgent",
    "FrontierAgent",
    "RevisitAgent",
    "InfoGainAgent",
    "Geometry",
    "GEOMETRY_READS",
    "INFO_GAIN_READS",
    "read_belief_map",
    "landmark_rows",
    "BASELINES",
    "baseline_class",
    "make_agent",
]

# -- factory ---------------------------------------------------------------------------------------
_REGISTRY: dict[str, type[Agent]] = {cls.name: cls for cls in (RandomAgent, FrontierAgent, RevisitAgent, InfoGainAgent)}

#: Names accepted by :func:`make_agent`.
BASELINES: tuple[str, ...] = tuple(_REGISTRY)


def baseline_class(name: str) -> type[Agent]:
    """The class of the baseline ``name`` (one of :data:`BASELINES`; ``ValueError`` otherwise)."""
    try:
        return _REGISTRY[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown agent {name!r}; baselines: {', '.join(BASELINES)}") from None


def make_agent(name: str, env: Any, **kwargs: Any) -> Agent:
    """Build the baseline ``name``.

    Parameters
    ----------
    name : str
        One of :data:`BASELINES`.
    env : gymnasium.Env, vector env or sequence of envs
        The ``SeifExplore`` env(s) the agent will act in: every baseline
        reads the observation with their :class:`Geometry`, and
        ``info_gain`` plans with their filter.
    **kwargs
        Options of the agent's class (for example ``seed`` for ``random``).

    Returns
    -------
    Agent

    Raises
    ------
    ValueError
        If ``name`` is not a baseline (:func:`agents.load_agent` also builds shipped policies, saved
        models and RLlib checkpoints).
    TypeError
        If ``env`` is not a ``SeifExplore`` env.
    """
    return baseline_class(name)(env, **kwargs)
