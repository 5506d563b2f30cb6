"""The coverage oracle: a cheating explorer, a yardstick for the tasks and a privileged teacher.

The oracle reads what no agent of the leaderboard may read: the true
landmarks and the true pose (``env.unwrapped.world``), and the ids the filter
has mapped. It drives greedily to the unmapped landmark that is nearest,
counting one metre of path per radian of turn, until every landmark is
mapped. It plans no revisits and no loop closures.

Two uses, neither of them as a leaderboard agent:

* a yardstick of how much room a task leaves to coverage
  (``research/coverage_oracle.py``, docs/benchmark/protocol.md "Tasks");
* a *privileged teacher* for kickstarting (``python -m research.kickstart --kickstart
  coverage_oracle``): its action is a function of the true state alone, so
  it labels any state a learner drives into (DAgger), and the learner, which
  sees only the belief, fits what the oracle does on average given what the
  belief shows (Chen et al., CoRL 2019, "Learning by cheating").

It needs the registered ids' known association: under maximum-likelihood
association the filter's ids are not the true landmarks' indices.

>>> import numpy as np
>>> oracle_action(np.zeros(3), np.array([[4.0, 0.0], [0.0, 3.0]]), mapped={0}).tolist()
[0.30000001192092896, 1.0]
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from agents.base import Agent, Observation
from agents.baselines.geometry import unwrapped_env
from seif_gym.slam import wrap_angle

__all__ = ["STEERING_GAIN", "TURN_COST", "CoverageOracle", "oracle_action"]

#: Metres of path one radian of turn is worth when the oracle picks its next landmark.
TURN_COST = 1.0
#: Steering gain: the turn-rate action per radian of heading error (clipped to the action's bound).
STEERING_GAIN = 2.0


def oracle_action(pose: np.ndarray, landmarks: np.ndarray, mapped: set[int]) -> np.ndarray:
    """The oracle's action: full speed towards the cheapest unmapped landmark, slower while it turns.

    Parameters
    ----------
    pose : ndarray, shape (3,)
        The true pose ``(x, y, θ)``.
    landmarks : ndarray, shape (n, 2)
        The true landmark positions; landmark ``i`` has id ``i``.
    mapped : set of int
        The ids the filter has mapped.

    Returns
    -------
    ndarray, shape (2,)
        ``(v, ω)`` in the env's action units; ``(0, 0)`` once every landmark is mapped.

    Raises
    ------
    ValueError
        If ``pose`` is not of shape (3,) or ``landmarks`` not of shape (n, 2).
    """
    pose, landmarks = np.asarray(pose, dtype=float), np.asarray(landmarks, dtype=float)
    if pose.shape != (3,):
        raise ValueError(f"pose must have shape (3,), got {pose.shape}")
    if landmarks.ndim != 2 or landmarks.shape[1] != 2:
        raise ValueError(f"landmarks must have shape (n, 2), got {landmarks.shape}")
    todo = np.array([i for i in range(len(landmarks)) if i not in mapped], dtype=np.int64)
    if todo.size == 0:
        return np.zeros(2, dtype=np.float32)
    dx, dy = landmarks[todo, 0] - pose[0], landmarks[todo, 1] - pose[1]
    heading_error = wrap_angle(np.arctan2(dy, dx) - pose[2])
    k = int(np.argmin(np.hypot(dx, dy) + TURN_COST * np.abs(heading_error)))
    speed = 1.0 if abs(heading_error[k]) < 1.2 else 0.3
    turn = float(np.clip(STEERING_GAIN * heading_error[k], -1.0, 1.0))
    return np.array([speed, turn], dtype=np.float32)


class CoverageOracle(Agent):
    """:func:`oracle_action` on the true state of the env it is bound to (one env, known association).

    Parameters
    ----------
    env : gymnasium.Env
        A single ``SeifExplore`` env (wrappers allowed) with ``data_association="known"``; the
        observation passed to :meth:`predict` is ignored beyond its shape checks.

    Raises
    ------
    TypeError
        If ``env`` is not a ``SeifExplore`` env.
    ValueError
        If the env associates by maximum likelihood.
    """

    name: ClassVar[str] = "coverage_oracle"

    def __init__(self, env: Any) -> None:
        base: Any = unwrapped_env(env)
        if not hasattr(base, "world") or getattr(base, "filter_config", None) is None:
            raise TypeError(f"env must be a single SeifExplore env, got {type(base).__name__}")
        if base.filter_config.data_association != "known":
            raise ValueError("env: associates by maximum likelihood; the oracle needs the true ids")
        super().__init__(env)
        self._base = base

    def _act(self, observation: Observation, index: int) -> np.ndarray:
        if index != 0:
            raise ValueError(f"batch row {index} has no env: the coverage oracle reads one env")
        world = self._base.world
        mapped = {int(i) for i in self._base.filter.landmark_ids}
        return oracle_action(world.pose, world.landmarks, mapped)

    def __repr__(self) -> str:
        return "CoverageOracle()"
