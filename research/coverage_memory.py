"""Where the unswept arena lies: a memory the agent keeps of the area its sensor has swept.

The observation's belief map is egocentric and ``2·map_extent`` metres wide
(16 m): on ``SeifExploreLarge`` (a 40 m arena) it shows a sixth of the
arena, so a policy cannot see where the unexplored area is once it has left
the window, while ``info_gain`` reads the whole filter. An agent can keep
that memory itself from what it observes: :class:`CoverageMemory` marks, on
a coarse grid over the arena, the cells the sensor's field of view covered
from each *estimated* pose (``obs["pose"]``, the filter's belief, never the
truth), and summarises the cells still unswept by direction and distance in
the robot's frame (:data:`UNSWEPT`).

:class:`CoverageMemoryObservation` adds the entry for training (a
single-env wrapper, an ``env_wrapper`` of a config); evaluation on the
plain env computes the same entry on the agent's side
(:func:`agents.memories.policy_memories`).

>>> import gymnasium as gym
>>> import seif_gym
>>> from research.coverage_memory import UNSWEPT, CoverageMemoryObservation
>>> env = CoverageMemoryObservation(gym.make("SeifExploreLarge-v2"))
>>> observation, _ = env.reset(seed=0)
>>> observation[UNSWEPT].shape, observation[UNSWEPT].dtype.name
((16,), 'float32')
>>> bool(observation[UNSWEPT].max() <= 1.0)
True
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np

from agents.baselines import Geometry
from agents.entries import holds_entry, with_entry
from agents.memories import PolicyEntry, register_policy_entry
from seif_gym.validation import as_count, as_positive_scalar

__all__ = ["UNSWEPT", "CoverageMemory", "CoverageMemoryObservation", "uses_coverage_memory"]

#: The observation key of the unswept fractions: ``(2·sectors,)`` in [0, 1], near ring first.
UNSWEPT = "unswept_sectors"


def uses_coverage_memory(observation_space: Any) -> bool:
    """Whether ``observation_space`` (a policy's) holds the :data:`UNSWEPT` entry."""
    return holds_entry(observation_space, UNSWEPT)


class CoverageMemory:
    """The agent's memory of the swept arena, for one env or a batch of envs.

    Parameters
    ----------
    geometry : agents.baselines.Geometry
        The env's geometry (arena, sensor range and field of view).
    cell : float, default 2.0
        Side of a cell of the memory's grid, metres.
    sectors : int, default 8
        Bearing sectors around the robot.
    near : float, optional
        Radius of the near ring, metres; default twice the sensor range.

    Notes
    -----
    After each observation the cells whose centres lie within the sensor's
    range and field of view of the estimated pose ``(x, y, θ)`` are marked
    swept. Every cell is then binned by its bearing from the heading
    (``sectors`` equal sectors, the first starting behind the robot at
    ``−π``) and by its distance (inside ``near`` or beyond); the entry is the
    fraction of each bin's cells still unswept (0 for a bin without cells),
    the near ring's ``sectors`` values first.
    """

    def __init__(self, geometry: Geometry, *, cell: float = 2.0, sectors: int = 8, near: float | None = None) -> None:
        if not isinstance(geometry, Geometry):
            raise TypeError(f"geometry must be a Geometry, got {type(geometry).__name__}")
        as_positive_scalar(cell, "cell")
        as_count(sectors, "sectors", minimum=1)
        if near is not None:
            as_positive_scalar(near, "near")
        self.near = 2.0 * geometry.sensor_range if near is None else float(near)
        self.geometry, self.cell, self.sectors = geometry, float(cell), int(sectors)
        n = max(1, math.ceil(geometry.arena_size / cell))
        centres = (np.arange(n) + 0.5) * (geometry.arena_size / n) - geometry.half
        gx, gy = np.meshgrid(centres, centres, indexing="ij")
        self.cells = np.stack([gx.ravel(), gy.ravel()], axis=1)  # (n², 2), arena frame, metres
        self._swept = np.zeros((0, self.cells.shape[0]), dtype=bool)

    @property
    def size(self) -> int:
        """Length of the entry: ``2·sectors``."""
        return 2 * self.sectors

    def reset(self, index: int | None = None) -> None:
        """Env ``index`` (every env when ``None``) starts a new episode with nothing swept."""
        if index is None:
            self._swept = np.zeros((0, self.cells.shape[0]), dtype=bool)
        elif 0 <= int(index) < self._swept.shape[0]:
            self._swept[int(index)] = False

    def observe(self, observation: Mapping[str, np.ndarray], episode_start: Any = None) -> dict[str, np.ndarray]:
        """``observation`` (single or batched) with :data:`UNSWEPT` added, after sweeping from its pose."""
        if UNSWEPT in observation:
            return dict(observation)
        pose = np.asarray(observation["pose"], dtype=np.float64)
        batched = pose.ndim == 2
        poses = pose if batched else pose[None]
        n_envs = poses.shape[0]
        if poses.shape[1] < 4:
            raise ValueError(f"observation['pose'] must hold (x, y, cos θ, sin θ, ...), got shape {pose.shape}")
        starts = None
        if episode_start is not None:
            starts = np.asarray(episode_start, dtype=bool).reshape(-1)
            if starts.shape[0] != n_envs:
                raise ValueError(f"episode_start must have {n_envs} entries, got shape {np.shape(episode_start)}")
        # computed on a copy and stored last: a refused call leaves the memory as it was
        swept = self._swept.copy() if self._swept.shape[0] == n_envs else np.zeros((n_envs, len(self.cells)), bool)
        if starts is not None:
            swept[starts] = False
        half = self.geometry.half
        dx = self.cells[None, :, 0] - (poses[:, 0] * half)[:, None]
        dy = self.cells[None, :, 1] - (poses[:, 1] * half)[:, None]
        heading = np.arctan2(poses[:, 3], poses[:, 2])[:, None]
        distance = np.hypot(dx, dy)
        bearing = np.mod(np.arctan2(dy, dx) - heading + np.pi, 2.0 * np.pi) - np.pi
        swept |= (distance <= self.geometry.sensor_range) & (np.abs(bearing) <= 0.5 * self.geometry.fov)
        sector = np.minimum(((bearing + np.pi) * (self.sectors / (2.0 * np.pi))).astype(np.int64), self.sectors - 1)
        bins = sector + self.sectors * (distance >= self.near) + self.size * np.arange(n_envs)[:, None]
        total = np.bincount(bins.ravel(), minlength=n_envs * self.size).reshape(n_envs, self.size)
        unswept = np.bincount(bins.ravel(), weights=(~swept).ravel(), minlength=n_envs * self.size)
        fraction = (unswept.reshape(n_envs, self.size) / np.maximum(total, 1)).astype(np.float32)
        self._swept = swept
        return {**observation, UNSWEPT: fraction if batched else fraction[0]}


class CoverageMemoryObservation(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Add :data:`UNSWEPT` (:class:`CoverageMemory`) to a ``SeifExplore`` env's observation.

    Parameters
    ----------
    env : gymnasium.Env
        A ``SeifExplore`` env (any wrapper) with a ``Dict`` observation space.

    Notes
    -----
    The memory has :class:`CoverageMemory`'s default grid, sectors and ring,
    the ones the agent's side rebuilds from the env's geometry alone.
    """

    def __init__(self, env: gym.Env) -> None:
        memory = CoverageMemory(Geometry.from_env(env))
        entry = gym.spaces.Box(0.0, 1.0, shape=(memory.size,), dtype=np.float32)
        space = with_entry(env.observation_space, UNSWEPT, entry)
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        self.memory = memory
        self.observation_space = space

    def reset(self, **kwargs: Any):
        observation, info = self.env.reset(**kwargs)
        self.memory.reset()
        return self.memory.observe(observation), info

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        return self.memory.observe(observation), reward, terminated, truncated, info


# first (innermost): the memory checks everything the clock checks (and the pose) before it changes,
# so a refused observation changes neither
register_policy_entry(
    PolicyEntry(
        UNSWEPT,
        uses_coverage_memory,
        lambda env: CoverageMemory(Geometry.from_env(env)),
        CoverageMemoryObservation,
        order=-1.0,
    )  # fmt: skip
)
