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
``env.unwrapped`` and also reads its ``filter`` (deep-copied for the
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

import copy
import math
import time
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import uniform_filter

from seif_gym.observation import (
    DIAGONAL_OVER_HALF,
    BeliefEncoder,
    BeliefRaster,
    ObservationDecoder,
    landmark_rows,
    read_belief_map,
)
from seif_gym.slam.models import wrap_angle
from seif_gym.type_aliases import FloatArray

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
    "make_agent",
]

Observation = Mapping[str, np.ndarray]

# -- geometry --------------------------------------------------------------------------------------
#: The env attributes :meth:`Geometry.from_env` reads (configuration, never the world).
GEOMETRY_READS = ("encoder", "sensor", "robot_config")


@dataclass(frozen=True)
class Geometry:
    """What an agent needs to read the observation in metres: the env's own numbers.

    Attributes
    ----------
    decoder : seif_gym.observation.ObservationDecoder
        The inverse of the env's observation encoder (the arena's size, the
        belief map's extent, the standard deviations' scale).
    sensor_range : float
        Range of the sensor, metres.
    fov : float
        Full opening angle of the sensor, radians.
    step_length : float
        Distance of one step at full forward speed (``max_speed·dt``), metres.
    """

    decoder: ObservationDecoder
    sensor_range: float
    fov: float
    step_length: float

    @property
    def arena_size(self) -> float:
        """Side of the square arena, metres."""
        return self.decoder.arena_size

    @property
    def half(self) -> float:
        """``h``, half the arena side, metres."""
        return self.decoder.half_arena

    @property
    def map_extent(self) -> float:
        """Half-width of ``obs["belief_map"]``, metres."""
        return self.decoder.map_extent

    @property
    def std_scale(self) -> float:
        """Divisor of the standard deviations in the observation."""
        return self.decoder.std_scale

    @classmethod
    def of(cls, base: Any) -> Geometry:
        """The geometry of one ``SeifExplore`` env (``env.unwrapped``, or a view with its attributes).

        Raises
        ------
        TypeError
            If ``base`` lacks one of :data:`GEOMETRY_READS` or its encoder is
            not a :class:`~seif_gym.observation.BeliefEncoder`.
        """
        missing = [name for name in GEOMETRY_READS if getattr(base, name, None) is None]
        if missing:
            raise TypeError(f"env must be a SeifExplore env; {type(base).__name__} has no {', '.join(missing)}")
        encoder, sensor, robot = base.encoder, base.sensor, base.robot_config
        if not isinstance(encoder, BeliefEncoder):
            raise TypeError(f"env must be a SeifExplore env; its encoder is a {type(encoder).__name__}")
        return cls(encoder.decoder(), float(sensor.max_range), float(sensor.fov), float(robot.max_speed * robot.dt))

    @classmethod
    def from_env(cls, env: Any) -> Geometry:
        """Read the geometry from the env the agent acts in (its configuration, never its world).

        Parameters
        ----------
        env : gymnasium.Env, vector env or sequence of envs
            A ``SeifExplore`` env (any wrapper), a gymnasium or
            Stable-Baselines3 vector env of them, or a list of them; every
            sub-env must have the same geometry.

        Raises
        ------
        TypeError
            If ``env`` is ``None`` or not a ``SeifExplore`` env: reading its
            observations with another env's numbers would misplace everything.
        ValueError
            If the sub-envs of a vector env differ in geometry.
        """
        if env is None:
            raise TypeError("env must be the SeifExplore env the agent acts in (its geometry decodes the observation), "
                            "got None")  # fmt: skip
        geometries = [cls.of(base) for base in _geometry_sources(env)]
        if any(geometry != geometries[0] for geometry in geometries[1:]):
            raise ValueError(f"env: the sub-envs differ in geometry ({geometries[0]} and others); one agent reads one")
        return geometries[0]


def _geometry_sources(env: Any) -> list[Any]:
    """The base env(s) of ``env`` whose configuration the agent reads."""
    base = _unwrapped(env)
    if all(getattr(base, name, None) is not None for name in GEOMETRY_READS):
        return [base]
    if callable(getattr(env, "get_attr", None)) and isinstance(getattr(env, "num_envs", None), int):
        # a Stable-Baselines3 VecEnv: the sub-envs' attributes, one namespace per sub-env
        values = {name: env.get_attr(name) for name in GEOMETRY_READS}
        return [SimpleNamespace(**{name: values[name][i] for name in GEOMETRY_READS}) for i in range(env.num_envs)]
    envs = _env_list(env)
    if len(envs) > 1 or (envs and envs[0] is not env):
        return [_unwrapped(e) for e in envs]
    raise TypeError(f"env must be a SeifExplore env (with {', '.join(GEOMETRY_READS)}), got {type(base).__name__}")


def _unwrapped(env: Any | None) -> Any | None:
    """``env.unwrapped`` if ``env`` is a gymnasium env, else ``env`` (or ``None``)."""
    if env is None:
        return None
    return getattr(env, "unwrapped", env)


def _heading(pose: np.ndarray) -> float:
    return math.atan2(float(pose[3]), float(pose[2]))


# -- the interface ---------------------------------------------------------------------------------
class Agent(ABC):
    """Base class of the baselines: SB3's ``predict`` over per-env ``_act``.

    Subclasses implement :meth:`_act` for one (unbatched) observation and,
    if they keep memory, :meth:`_new_state`. :meth:`predict` accepts a single
    observation dict (arrays of the observation space's shapes) or a batched
    one (a leading ``n_envs`` axis, as a ``VecEnv`` returns), like an SB3
    model, and keeps one memory per env index.

    Parameters
    ----------
    env : gymnasium.Env or None
        The env the agent acts in. The baselines require it (they read the
        observation with its :class:`Geometry`); a trained model may not
        need it.
    """

    #: Name under which :func:`make_agent` builds the agent.
    name: ClassVar[str] = "agent"
    #: Whether the agent needs the env's filter (``env`` may not be ``None``).
    needs_filter: ClassVar[bool] = False
    #: Whether state carries from one episode into the next (beyond what ``reset`` clears), so that an
    #: episode's actions depend on the episodes before it: a harness must then run them in order.
    carries_over_episodes: ClassVar[bool] = False

    def __init__(self, env: Any | None = None) -> None:
        self.env = env
        self._states: dict[int, Any] = {}

    # -- for subclasses ----------------------------------------------------------------------------
    def _new_state(self) -> Any:
        """Fresh memory of one env at an episode start (``None``: memoryless)."""
        return None

    @abstractmethod
    def _act(self, observation: Observation, index: int) -> np.ndarray:
        """Action ``(2,)`` in ``[-1, 1]`` for the unbatched ``observation`` of env ``index``."""

    def _state(self, index: int) -> Any:
        if index not in self._states:
            self._states[index] = self._new_state()
        return self._states[index]

    # -- public ------------------------------------------------------------------------------------
    def reset(self, index: int | None = None) -> None:
        """Forget the memory of env ``index`` (all envs when ``None``): a new episode starts."""
        if index is None:
            self._states.clear()
        else:
            self._states.pop(int(index), None)

    def predict(
        self,
        observation: Observation,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, Any]:
        """Actions for ``observation``, with SB3's signature.

        Parameters
        ----------
        observation : dict of numpy.ndarray
            One observation of the env's ``Dict`` space, or a batch of them
            (every entry with a leading ``n_envs`` axis).
        state : Any, optional
            Returned unchanged (the recurrent state of SB3; the baselines
            keep their memory inside, per env index).
        episode_start : bool or array_like of bool, optional
            ``True`` for the envs whose episode has just started: their
            memory is reset first. Shape ``(n_envs,)`` for a batch.
        deterministic : bool, optional
            Ignored: ``random`` always samples (that is its point), the
            other baselines are deterministic.

        Returns
        -------
        action : numpy.ndarray of float32
            Shape ``(2,)`` for a single observation, ``(n_envs, 2)`` for a
            batch; values in ``[-1, 1]``.
        state : Any
            ``state``, unchanged.
        """
        if not isinstance(observation, Mapping) or "pose" not in observation:
            raise TypeError(f"observation must be the env's dict observation, got {type(observation).__name__}")
        pose = np.asarray(observation["pose"])
        if pose.ndim not in (1, 2) or pose.shape[-1] != 7:
            raise ValueError(f'observation["pose"] must have shape (7,) or (n_envs, 7), got {pose.shape}')
        batched = pose.ndim == 2
        count = pose.shape[0] if batched else 1
        if episode_start is not None:
            starts = np.broadcast_to(np.asarray(episode_start, dtype=bool).reshape(-1), (count,))
            for started in np.flatnonzero(starts):
                self.reset(int(started))
        actions = np.empty((count, 2), dtype=np.float32)
        for index in range(count):
            single = {
                key: np.asarray(value)[index] if batched else np.asarray(value) for key, value in observation.items()
            }
            actions[index] = np.clip(self._act(single, index), -1.0, 1.0)
        return (actions if batched else actions[0]), state

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


# -- random ----------------------------------------------------------------------------------------
class RandomAgent(Agent):
    """Uniform random actions in ``[-1, 1]^2``.

    Parameters
    ----------
    env : gymnasium.Env
        The ``SeifExplore`` env it acts in (checked, like every baseline's;
        its action space is ``[-1, 1]^2``).
    seed : int or None
        Seed of the agent's ``numpy.random.Generator``; the same seed gives
        the same action sequence.
    """

    name = "random"
    carries_over_episodes = True  # one generator for all episodes

    def __init__(self, env: Any, *, seed: int | None = None) -> None:
        super().__init__(env)
        self.geometry = Geometry.from_env(env)
        self.seed = seed
        self.rng = np.random.default_rng(seed)

    def _act(self, observation: Observation, index: int) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, 2)

    def __repr__(self) -> str:
        return f"RandomAgent(seed={self.seed})"


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
class _RevisitMemory(_ExploreMemory):
    mode: str = "explore"
    target: FloatArray | None = None  # normalised world position of the revisited landmark
    mode_steps: int = 0
    last_revisit: int = 0
    revisits: int = 0


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
        :mod:`agents.residual`): the bump check of the next step compares the
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
        theta = _heading(pose)
        bearing = np.abs(wrap_angle(np.arctan2(dy, dx) - theta))
        cost = np.hypot(dx, dy) * self.geometry.half + self.turn_cost * bearing
        cost[memory.visited] = np.inf
        i, j = np.unravel_index(int(np.argmin(cost)), cost.shape)
        return _to_robot_frame(gx[i, j] - float(pose[0]), gy[i, j] - float(pose[1]), theta, self.geometry.half)

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


def _to_robot_frame(dx_h: float, dy_h: float, theta: float, half: float) -> tuple[float, float]:
    """World offset in units of ``h`` -> ``(forward, left)`` metres."""
    c, s = math.cos(theta), math.sin(theta)
    return (c * dx_h + s * dy_h) * half, (-s * dx_h + c * dy_h) * half


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
        theta = _heading(pose)
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
            forward, left = _to_robot_frame(
                memory.target[0] - pose[0], memory.target[1] - pose[1], _heading(pose), self.geometry.half
            )
            if math.hypot(forward, left) > self.reach and memory.mode_steps <= self.max_revisit_steps:
                return self._remember(memory, self.steer(observation, forward, left))
            memory.mode, memory.target, memory.last_revisit = "explore", None, memory.steps
        return self._remember(memory, self.explore(observation, memory))


# -- information gain ------------------------------------------------------------------------------
@dataclass
class _PlanMemory(_ExploreMemory):
    action: NDArray[np.float64] = field(default_factory=lambda: np.zeros(2))
    repeat: int = 0


#: Names of the env attributes :class:`InfoGainAgent` reads (nothing else).
INFO_GAIN_READS = ("filter", "motion", *GEOMETRY_READS)


class InfoGainAgent(FrontierAgent):
    """Pick the constant-``(v, w)`` arc with the largest expected information gain.

    Every ``replan_every`` steps, for each candidate arc (every ``(v, w)`` of
    ``speeds × turn_rates``, as actions in ``[-1, 1]``):

    1. a deep copy of the env's filter is rolled ``horizon`` steps forward:
       ``predict`` with the arc's control, then ``update`` with the
       *expected*, noise-free measurements (``sensor.predict`` of the
       estimated landmark positions) of the mapped landmarks inside the
       sensor's range and field of view from the predicted pose;
    2. ``gain`` = decrease of ``sum(landmark_std) + pose_weight·sqrt(σx² + σy²)``
       (the pose from ``local_marginals``) from now to the horizon's end;
    3. ``explore`` = area (m²) of the unswept, in-arena cells of
       ``obs["belief_map"]`` that the sensor would sweep from the predicted
       poses, plus ``progress_weight`` times the progress (metres) towards
       the ``frontier`` agent's target, which pulls the robot to unswept
       space beyond the horizon;
    4. ``walls`` = number of predicted poses closer than ``wall_margin`` to
       the arena's side (from the estimate and the geometry's arena size).

    Score ``gain + exploration_weight·explore − wall_penalty·walls``; the best
    arc is executed ``replan_every`` times (a bump, detected as by
    ``frontier``, interrupts it with a turn in place and a new plan). The wall time of each plan is
    appended to :attr:`planning_times` (seconds).

    New landmarks are not predicted (the planner does not know where they
    are); the exploration term stands for them.

    Parameters
    ----------
    env : gymnasium.Env, sequence of them, or a ``DummyVecEnv``
        The env(s) whose filter is the belief; env ``i`` serves batch row
        ``i``. Reads only :data:`INFO_GAIN_READS` of ``env.unwrapped``.
    horizon : int
        Steps of each rollout.
    replan_every : int
        Steps between plans (the chosen action is repeated in between).
    speeds, turn_rates : sequence of float
        Candidate forward-speed and turn-rate actions; ``(0, ±1)`` (turning
        in place) is always added.
    exploration_weight : float
        Weight of a square metre of newly swept area (metres of standard
        deviation per m²).
    progress_weight : float
        Square metres one metre of progress to the frontier target is worth.
    pose_weight : float
        Weight of the pose's position standard deviation in the uncertainty.
    wall_margin, wall_penalty : float
        Distance to the arena's side counted as a wall contact (metres),
        and the penalty of one.
    **kwargs
        Passed to :class:`FrontierAgent` (the frontier target's options).
    """

    name = "info_gain"
    needs_filter = True

    def __init__(
        self,
        env: Any,
        *,
        horizon: int = 8,
        replan_every: int = 4,
        speeds: Sequence[float] = (0.5, 1.0),
        turn_rates: Sequence[float] = (-1.0, -0.5, 0.0, 0.5, 1.0),
        exploration_weight: float = 0.01,
        progress_weight: float = 5.0,
        pose_weight: float = 1.0,
        wall_margin: float = 0.5,
        wall_penalty: float = 1.0,
        **kwargs: Any,
    ) -> None:
        envs = _env_list(env)
        if not envs:
            raise TypeError(
                "env must be the SeifExplore env(s) info_gain acts in (it plans with their filter), got None"
            )
        super().__init__(envs[0], **kwargs)
        self.geometry = Geometry.from_env(env)  # every env's: one geometry
        self.envs = [_unwrapped(e) for e in envs]
        if int(horizon) < 1 or int(replan_every) < 1:
            raise ValueError(f"horizon and replan_every must be positive, got {horizon}, {replan_every}")
        self.horizon = int(horizon)
        self.replan_every = int(replan_every)
        arcs = {(float(v), float(w)) for v in speeds for w in turn_rates} | {(0.0, 1.0), (0.0, -1.0)}
        self.candidates = np.array(sorted(arcs), dtype=np.float64)
        if np.any(np.abs(self.candidates) > 1.0):
            raise ValueError("speeds and turn_rates are actions and must lie in [-1, 1]")
        self.exploration_weight = float(exploration_weight)
        self.progress_weight = float(progress_weight)
        self.pose_weight = float(pose_weight)
        self.wall_margin = float(wall_margin)
        self.wall_penalty = float(wall_penalty)
        #: Wall time of every plan, seconds.
        self.planning_times: list[float] = []
        #: Score terms of the last plan: candidates (c, 2), gain, explore, walls, score (c,).
        self.last_plan: dict[str, np.ndarray] = {}

    def _new_state(self) -> _PlanMemory:
        return _PlanMemory(visited=np.zeros((self.grid, self.grid), dtype=bool))

    def _env(self, index: int) -> Any:
        if index >= len(self.envs):
            raise ValueError(f"batch row {index} has no env: info_gain was given {len(self.envs)} env(s)")
        return self.envs[index]

    def uncertainty(self, filt: Any) -> float:
        """``sum(landmark_std) + pose_weight·sqrt(σx² + σy²)`` of ``filt``'s belief."""
        pose_cov, _ = filt.local_marginals(np.empty(0, dtype=np.int64))
        total = float(np.sum(filt.landmark_std())) if filt.num_landmarks else 0.0
        return total + self.pose_weight * math.sqrt(max(pose_cov[0, 0] + pose_cov[1, 1], 0.0))

    def _rollout(self, base: Any, control: FloatArray) -> tuple[Any, FloatArray]:
        """Copy of the filter after ``horizon`` steps of ``control``, and the predicted poses (horizon, 3)."""
        filt = copy.deepcopy(base.filter)
        dt = float(base.robot_config.dt)
        sensor = base.sensor
        ids = np.array(filt.landmark_ids, dtype=np.int64)
        landmarks = np.array(filt.landmarks, dtype=np.float64)
        half_fov = 0.5 * float(sensor.fov)
        poses = np.empty((self.horizon, 3))
        empty_f, empty_i = np.empty(0), np.empty(0, dtype=np.int64)
        for t in range(self.horizon):
            filt.predict_trusted(control, dt)
            pose = np.array(filt.pose, dtype=np.float64)
            poses[t] = pose
            if len(ids):
                z = sensor.predict_trusted(pose, landmarks)
                visible = (z[:, 0] > 0.0) & (z[:, 0] <= sensor.max_range)
                if half_fov < math.pi:
                    visible &= np.abs(z[:, 1]) <= half_fov
                if visible.any():
                    filt.update_trusted(z[visible, 0].copy(), z[visible, 1].copy(), ids[visible])
                    continue
            filt.update_trusted(empty_f, empty_f, empty_i)
        return filt, poses

    def _swept_area(self, observation: Observation, poses: FloatArray, start: FloatArray) -> float:
        """Area (m²) of unswept in-arena cells of the belief map the sensor sweeps from ``poses``."""
        belief = read_belief_map(observation)
        raster = self.raster(belief.shape[1])
        candidate = (belief[0] < 0.5) & (belief[2] < 0.5)
        if not candidate.any():
            return 0.0
        c, s = math.cos(start[2]), math.sin(start[2])
        r2 = self.geometry.sensor_range**2
        half_fov = 0.5 * self.geometry.fov
        covered = np.zeros_like(candidate)
        for pose in poses:
            dx, dy = pose[0] - start[0], pose[1] - start[1]
            px, py = c * dx + s * dy, -s * dx + c * dy  # (forward, left) of the predicted pose
            df, dl = raster.forward - px, raster.left - py
            seen = df * df + dl * dl <= r2
            if half_fov < math.pi:
                bearing = np.arctan2(dl, df) - (pose[2] - start[2])
                seen &= np.abs((bearing + np.pi) % (2.0 * np.pi) - np.pi) <= half_fov
            covered |= seen
        return float(np.count_nonzero(covered & candidate)) * raster.cell**2

    def plan(self, observation: Observation, index: int = 0) -> np.ndarray:
        """Score every candidate arc for env ``index`` and return the best action (2,)."""
        started = time.perf_counter()
        base = self._env(index)
        if base.filter is None:
            raise RuntimeError("the env has no filter yet: reset it before asking info_gain for an action")
        scale = np.array([base.robot_config.max_speed, base.robot_config.max_turn_rate], dtype=np.float64)
        half = self.geometry.half
        start = np.array(base.filter.pose, dtype=np.float64)
        before = self.uncertainty(base.filter)
        memory = self._state(index)
        target = self.frontier_target(observation)
        if target is None:
            target = self.grid_target(memory, np.asarray(observation["pose"]))
        c, s = math.cos(start[2]), math.sin(start[2])
        target_world = start[:2] + np.array([c * target[0] - s * target[1], s * target[0] + c * target[1]])
        distance0 = float(np.hypot(*(target_world - start[:2])))
        count = len(self.candidates)
        gain, explore, walls = np.zeros(count), np.zeros(count), np.zeros(count)
        for k, action in enumerate(self.candidates):
            filt, poses = self._rollout(base, action * scale)
            gain[k] = before - self.uncertainty(filt)
            progress = distance0 - float(np.hypot(*(target_world - poses[-1, :2])))
            explore[k] = self._swept_area(observation, poses, start) + self.progress_weight * progress
            walls[k] = np.count_nonzero(np.any(np.abs(poses[:, :2]) > half - self.wall_margin, axis=1))
        score = gain + self.exploration_weight * explore - self.wall_penalty * walls
        best = int(np.argmax(score))
        self.last_plan = {
            "candidates": self.candidates,
            "gain": gain,
            "explore": explore,
            "walls": walls,
            "score": score,
        }
        self.planning_times.append(time.perf_counter() - started)
        return self.candidates[best].copy()

    def _act(self, observation: Observation, index: int) -> np.ndarray:
        memory: _PlanMemory = self._state(index)
        self._visit(memory, np.asarray(observation["pose"]))
        escape = self._escaping(memory)
        if escape is not None:  # bumped into a wall the belief does not show: turn, then plan afresh
            memory.repeat = 0
            return self._remember(memory, escape)
        if memory.repeat <= 0:
            memory.action = self.plan(observation, index)
            memory.repeat = self.replan_every
        memory.repeat -= 1
        return self._remember(memory, memory.action)

    @property
    def mean_planning_time(self) -> float:
        """Mean wall time of one plan, seconds (``nan`` before the first)."""
        return float(np.mean(self.planning_times)) if self.planning_times else math.nan


def _env_list(env: Any) -> list[Any]:
    """``env`` as a list of envs: a single env, a sequence of envs, or a ``DummyVecEnv``'s ``envs``."""
    if env is None:
        return []
    if isinstance(env, gym.Env):
        return [env]
    if "envs" in getattr(env, "__dict__", {}):  # a DummyVecEnv (looked up without probing other envs)
        return list(env.envs)
    if isinstance(env, Sequence) and not isinstance(env, (str, bytes)):
        return list(env)
    return [env]


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
        One of :data:`BASELINES`, or ``"rllib:PATH"``: a checkpoint of
        ``python -m agents.rllib_train`` (:class:`agents.rllib_agent.RLlibAgent`).
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
        If ``name`` is unknown.
    TypeError
        If ``env`` is not a ``SeifExplore`` env.
    """
    if isinstance(name, str) and name.startswith("rllib:"):  # an RLlib checkpoint (needs the optional ray extra)
        from agents.rllib_agent import RLlibAgent

        return RLlibAgent(name[len("rllib:") :], env, **kwargs)
    return baseline_class(name)(env, **kwargs)
