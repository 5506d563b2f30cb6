"""The ``frontier`` baseline: drive to the nearest or largest unswept region of the belief map."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import uniform_filter

from agents.base import Agent, Observation
from agents.baselines.geometry import Geometry, heading, to_robot_frame
from seif_gym.observation import (
    BeliefRaster,
    read_belief_map,
)
from seif_gym.slam.models import wrap_angle
from seif_gym.type_aliases import FloatArray

__all__ = ["FrontierAgent"]


# -- frontier --------------------------------------------------------------------------------------
@dataclass
class _ExploreMemory:
    """Memory of the exploring agents.

    ``visited`` is a coarse visit grid over the arena in units of ``h``
    (``[-1, 1]^2``); ``last_position`` (units of ``h``) and ``last_speed``
    (action) detect a bump into the wall; ``escape`` counts the steps left
    turning away after one.
    """

    visited: NDArray[np.bool_]
    steps: int = 0
    last_position: FloatArray | None = None
    last_speed: float = 0.0
    escape: int = 0
    bumps: int = 0


@dataclass
class FrontierAgent(Agent):
    """Drive to the nearest / largest unswept region of the belief map.

    Each step:

    1. Candidate cells of ``obs["belief_map"]`` (read as floats in
       ``[0, 1]`` by :func:`read_belief_map`) are those *unswept*
       (channel 0 < ½) and *inside the arena* (channel 2 < ½).
    2. Each candidate scores ``density / (1 + cost / cost_scale)``:
       ``density`` is the fraction of candidates in its ``window × window``
       neighbourhood (large unswept regions first), ``cost = distance +
       turn_cost·|bearing|`` in metres (near regions, and regions ahead,
       first). The best cell is the target.
    3. If the raster holds no candidate (all around is swept), the target is
       the nearest cell of a coarse ``grid × grid`` visit map of the arena
       (kept from ``obs["pose"]``) that the robot has not been in.
    4. Steering: turn rate ``clip(gain·bearing)``, forward speed
       ``max(cos bearing, 0)`` times a slow-down ``clip((d − stop)/slow)``,
       ``d`` the distance to the nearest outside-arena cell in a corridor of
       half-width ``corridor`` ahead.
    5. Bump: the env turns a step that would leave the arena into a turn in
       place and tells the filter, so an estimated position that barely
       moves (less than ``bump_fraction`` of the commanded step) after a
       commanded forward speed above ``0.3`` means the robot is at a wall
       the (drifted) belief map does not show yet. It then turns in place
       for ``escape_steps`` steps.

    Deterministic; uses the observation only.

    Parameters
    ----------
    env : gymnasium.Env
        The env it acts in; only its :class:`Geometry` is read.
    turn_cost : float
        Metres of travel one radian of turning is worth.
    cost_scale : float
        Metres at which the score of a region has halved.
    window : int
        Side of the neighbourhood measuring the size of a region, cells.
    gain : float
        Turn-rate action per radian of bearing to the target.
    corridor, stop, slow : float
        Half-width of the corridor checked for the wall, the distance at
        which the robot stops in front of it and the distance over which it
        slows down, metres.
    grid : int
        Side of the coarse visit map.
    bump_fraction : float
        Fraction of the commanded step below which a step counts as a bump.
    escape_steps : int
        Steps of turning in place after a bump.
    """

    name = "frontier"

    def __init__(
        self,
        env: Any,
        *,
        turn_cost: float = 1.5,
        cost_scale: float = 3.0,
        window: int = 5,
        gain: float = 1.5,
        corridor: float = 0.75,
        stop: float = 0.6,
        slow: float = 1.5,
        grid: int = 8,
        bump_fraction: float = 0.2,
        escape_steps: int = 6,
    ) -> None:
        super().__init__(env)
        self.geometry = Geometry.from_env(env)
        self.turn_cost = float(turn_cost)
        self.cost_scale = float(cost_scale)
        self.window = int(window)
        self.gain = float(gain)
        self.corridor = float(corridor)
        self.stop = float(stop)
        self.slow = float(slow)
        self.grid = int(grid)
        self.bump_fraction = float(bump_fraction)
        self.escape_steps = int(escape_steps)
        self._raster: BeliefRaster | None = None

    def _new_state(self) -> _ExploreMemory:
        return _ExploreMemory(visited=np.zeros((self.grid, self.grid), dtype=bool))

    def raster(self, size: int) -> BeliefRaster:
        """Cell geometry of the env's ``size × size`` belief map (cached).

        Raises
        ------
        ValueError
            If ``size`` is not the side of the env's belief map (an
            observation of another env).
        """
        if self._raster is None:
            self._raster = self.geometry.decoder.raster()
        if size != self._raster.size:
            raise ValueError(f"observation['belief_map'] is {size} cells wide, but the env's encoder makes "
                             f"{self._raster.size}: an observation of another env?")  # fmt: skip
        return self._raster

    # -- pieces shared with revisit and info_gain ---------------------------------------------------
    def _visit(self, memory: _ExploreMemory, pose: np.ndarray) -> bool:
        """Record ``pose`` in the memory; ``True`` if the last step was a bump (step 5)."""
        position = np.asarray(pose[:2], dtype=np.float64)
        cell = np.clip(((position + 1.0) * 0.5 * self.grid).astype(int), 0, self.grid - 1)
        memory.visited[cell[0], cell[1]] = True
        memory.steps += 1
        bumped = False
        if memory.last_position is not None and memory.last_speed > 0.3:
            moved = float(np.hypot(*(position - memory.last_position))) * self.geometry.half
            bumped = moved < self.bump_fraction * memory.last_speed * self.geometry.step_length
        memory.last_position = position
        if bumped:
            memory.escape = self.escape_steps
            memory.bumps += 1
        return bumped

    def _escaping(self, memory: _ExploreMemory) -> np.ndarray | None:
        """The turn-in-place action while escaping from a bump, else ``None``."""
        if memory.escape <= 0:
            return None
        memory.escape -= 1
        return np.array([0.0, 1.0])

    @staticmethod
    def _remember(memory: _ExploreMemory, action: np.ndarray) -> np.ndarray:
        memory.last_speed = float(action[0])
        return action

    def executed(self, action: np.ndarray, index: int = 0) -> None:
        """Tell the agent that env ``index`` executed ``action`` (2,), not the action it chose.

        For a controller built on this agent (a residual policy,
        :mod:`research.residual`): the bump check of the next step compares the
        motion with the speed actually commanded.
        """
        self._remember(self._state(index), np.asarray(action))

    def frontier_target(self, observation: Observation) -> tuple[float, float] | None:
        """``(forward, left)`` metres of the chosen unswept cell, or ``None`` if there is none."""
        belief = read_belief_map(observation)
        raster = self.raster(belief.shape[1])
        candidate = (belief[0] < 0.5) & (belief[2] < 0.5)
        if not candidate.any():
            return None
        density = uniform_filter(candidate.astype(np.float64), size=self.window, mode="constant")
        cost = raster.distance + self.turn_cost * np.abs(raster.bearing)
        score = np.where(candidate, density / (1.0 + cost / self.cost_scale), -np.inf)
        i, j = np.unravel_index(int(np.argmax(score)), score.shape)
        return float(raster.forward[i, j]), float(raster.left[i, j])

    def grid_target(self, memory: _ExploreMemory, pose: np.ndarray) -> tuple[float, float]:
        """``(forward, left)`` metres to the nearest unvisited cell of the visit map."""
        if memory.visited.all():
            memory.visited[:] = False
        centres = (np.arange(self.grid) + 0.5) / self.grid * 2.0 - 1.0
        gx, gy = np.meshgrid(centres, centres, indexing="ij")
        dx, dy = gx - float(pose[0]), gy - float(pose[1])
        theta = heading(pose)
        bearing = np.abs(wrap_angle(np.arctan2(dy, dx) - theta))
        cost = np.hypot(dx, dy) * self.geometry.half + self.turn_cost * bearing
        cost[memory.visited] = np.inf
        i, j = np.unravel_index(int(np.argmin(cost)), cost.shape)
        return to_robot_frame(gx[i, j] - float(pose[0]), gy[i, j] - float(pose[1]), theta, self.geometry.half)

    def wall_clearance(self, observation: Observation) -> float:
        """Distance ahead to the nearest outside-arena cell in the corridor, metres (``inf`` if none)."""
        belief = read_belief_map(observation)
        raster = self.raster(belief.shape[1])
        blocked = (
            (belief[2] >= 0.5) & (raster.forward > 0.0) & (np.abs(raster.left) <= self.corridor + 0.5 * raster.cell)
        )
        if not blocked.any():
            return math.inf
        return float(raster.forward[blocked].min() - 0.5 * raster.cell)

    def steer(self, observation: Observation, forward: float, left: float) -> np.ndarray:
        """Action towards the point ``(forward, left)`` (metres, robot frame), slowing at the wall."""
        bearing = math.atan2(left, forward)
        turn = float(np.clip(self.gain * bearing, -1.0, 1.0))
        speed = max(math.cos(bearing), 0.0)
        clearance = self.wall_clearance(observation)
        speed *= float(np.clip((clearance - self.stop) / self.slow, 0.0, 1.0))
        return np.array([speed, turn])

    def explore(self, observation: Observation, memory: _ExploreMemory) -> np.ndarray:
        """The frontier action (steps 1-4 of the class docstring)."""
        target = self.frontier_target(observation)
        if target is None:
            target = self.grid_target(memory, np.asarray(observation["pose"]))
        return self.steer(observation, *target)

    def _act(self, observation: Observation, index: int) -> np.ndarray:
        memory = self._state(index)
        self._visit(memory, np.asarray(observation["pose"]))
        escape = self._escaping(memory)
        return self._remember(memory, escape if escape is not None else self.explore(observation, memory))

    def __repr__(self) -> str:
        return f"{type(self).__name__}(geometry={self.geometry})"
