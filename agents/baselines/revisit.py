"""The ``revisit`` baseline: explore like ``frontier``; re-observe the most uncertain landmark when the pose gets uncertain."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from agents.base import Observation
from agents.baselines.frontier import FrontierAgent, _ExploreMemory
from agents.baselines.geometry import heading, to_robot_frame
from seif_gym.observation import (
    DIAGONAL_OVER_HALF,
    landmark_rows,
)
from seif_gym.type_aliases import FloatArray

__all__ = ["RevisitAgent"]


class _RevisitMemory(_ExploreMemory):
    mode: str = "explore"
    target: FloatArray | None = None  # normalised world position of the revisited landmark
    mode_steps: int = 0
    last_revisit: int = 0
    revisits: int = 0


# -- revisit ---------------------------------------------------------------------------------------
class RevisitAgent(FrontierAgent):
    """Explore like ``frontier``; now and then drive back to an uncertain landmark.

    A revisit starts when the pose's position standard deviation
    ``hypot(σx, σy)`` (from ``obs["pose"]``) exceeds ``pose_std_threshold``
    metres, or ``period`` steps after the last revisit, but not within
    ``cooldown`` steps of the last one. Its target is the landmark with the
    largest 95 % ellipse (``landmark_rows(obs)[:, 2]``) among the ``K`` listed
    (``target="least_uncertain"``: the smallest, an old well-mapped
    landmark that anchors the pose, a classic loop closure): its position is fixed in the arena frame at that moment (from the
    normalised offsets), and the robot drives to it until it is within
    ``reach`` metres or ``max_revisit_steps`` have passed, then explores
    again. Re-observing a landmark mapped earlier ties the current pose to
    the older part of the map (a loop closure) and shrinks both
    uncertainties.

    Deterministic; uses the observation only.

    Parameters
    ----------
    env : gymnasium.Env
        The env it acts in; only its :class:`Geometry` is read.
    pose_std_threshold : float
        Position standard deviation (metres) that triggers a revisit.
    period : int
        Steps after which a revisit starts anyway.
    cooldown : int
        Steps after a revisit during which no new one starts.
    reach : float
        Distance to the target landmark (metres) that ends a revisit.
    max_revisit_steps : int
        Longest revisit, steps.
    target : {"most_uncertain", "least_uncertain"}
        Which of the listed landmarks is revisited.
    **kwargs
        Passed to :class:`FrontierAgent`.
    """

    name = "revisit"

    def __init__(
        self,
        env: Any,
        *,
        pose_std_threshold: float = 0.25,
        period: int = 100,
        cooldown: int = 30,
        reach: float = 1.5,
        max_revisit_steps: int = 60,
        target: str = "most_uncertain",
        **kwargs: Any,
    ) -> None:
        super().__init__(env, **kwargs)
        if target not in ("most_uncertain", "least_uncertain"):
            raise ValueError(f"target must be 'most_uncertain' or 'least_uncertain', got {target!r}")
        self.target = target
        self.pose_std_threshold = float(pose_std_threshold)
        self.period = int(period)
        self.cooldown = int(cooldown)
        self.reach = float(reach)
        self.max_revisit_steps = int(max_revisit_steps)

    def _new_state(self) -> _RevisitMemory:
        return _RevisitMemory(visited=np.zeros((self.grid, self.grid), dtype=bool))

    def pose_std(self, observation: Observation) -> float:
        """Position standard deviation of the estimate, metres."""
        pose = np.asarray(observation["pose"], dtype=np.float64)
        return float(math.hypot(pose[4], pose[5]) * self.geometry.std_scale)

    def _choose_target(self, observation: Observation) -> FloatArray | None:
        mask = np.asarray(observation["landmarks_mask"]) > 0.5
        if not mask.any():
            return None
        rows = landmark_rows(observation)
        if self.target == "most_uncertain":
            row = rows[int(np.argmax(np.where(mask, rows[:, 2], -np.inf)))]
        else:
            row = rows[int(np.argmin(np.where(mask, rows[:, 2], np.inf)))]
        pose = np.asarray(observation["pose"], dtype=np.float64)
        theta = heading(pose)
        c, s = math.cos(theta), math.sin(theta)
        forward, left = row[0] * DIAGONAL_OVER_HALF, row[1] * DIAGONAL_OVER_HALF  # units of h
        return np.array([pose[0] + c * forward - s * left, pose[1] + s * forward + c * left])

    def _act(self, observation: Observation, index: int) -> np.ndarray:
        memory: _RevisitMemory = self._state(index)
        pose = np.asarray(observation["pose"], dtype=np.float64)
        if self._visit(memory, pose) and memory.mode == "revisit":
            # the target is behind a wall the drifted belief does not show: give it up
            memory.mode, memory.target, memory.last_revisit = "explore", None, memory.steps
        escape = self._escaping(memory)
        if escape is not None:
            return self._remember(memory, escape)
        since = memory.steps - memory.last_revisit
        if memory.mode == "explore" and since >= self.cooldown:
            if self.pose_std(observation) > self.pose_std_threshold or since >= self.period:
                target = self._choose_target(observation)
                if target is not None:
                    memory.mode, memory.target, memory.mode_steps = "revisit", target, 0
                    memory.revisits += 1
        if memory.mode == "revisit":
            memory.mode_steps += 1
            assert memory.target is not None  # chosen when the mode turned to revisit
            forward, left = to_robot_frame(
                memory.target[0] - pose[0], memory.target[1] - pose[1], heading(pose), self.geometry.half
            )
            if math.hypot(forward, left) > self.reach and memory.mode_steps <= self.max_revisit_steps:
                return self._remember(memory, self.steer(observation, forward, left))
            memory.mode, memory.target, memory.last_revisit = "explore", None, memory.steps
        return self._remember(memory, self.explore(observation, memory))
