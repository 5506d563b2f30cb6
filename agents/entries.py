"""One entry added to a ``Dict`` observation space: the checks the policy-side wrappers share.

:class:`agents.time_feature.TimeLeftObservation`,
:class:`research.coverage_memory.CoverageMemoryObservation` and
:class:`research.residual.PlannerResidualAction` each add one entry that the
env does not have (:mod:`agents.memories`).

>>> import gymnasium as gym
>>> import numpy as np
>>> space = gym.spaces.Dict({"pose": gym.spaces.Box(-1.0, 1.0, (7,), np.float32)})
>>> sorted(with_entry(space, "time_left", gym.spaces.Box(0.0, 1.0, (1,), np.float32)).spaces)
['pose', 'time_left']
>>> holds_entry(space, "time_left"), holds_entry(space, "pose")
(False, True)
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

__all__ = ["holds_entry", "with_entry"]


def with_entry(space: Any, key: str, entry: gym.spaces.Space) -> gym.spaces.Dict:
    """``space`` (an env's observation space) with ``key`` added as ``entry``.

    Raises
    ------
    TypeError
        If ``space`` is not a ``Dict`` (the message names ``env``, whose space it is).
    ValueError
        If ``space`` already has ``key``.
    """
    if not isinstance(space, gym.spaces.Dict):
        raise TypeError(f"env: the observation space must be a Dict, got {type(space).__name__}")
    if key in space.spaces:
        raise ValueError(f"env: the observation already has {key!r}")
    return gym.spaces.Dict({**space.spaces, key: entry})


def holds_entry(space: Any, key: str) -> bool:
    """Whether ``space`` (a policy's observation space) is a ``Dict`` holding ``key``."""
    return isinstance(space, gym.spaces.Dict) and key in space.spaces
