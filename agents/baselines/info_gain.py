"""The ``info_gain`` baseline: plan constant-``(v, w)`` arcs through a copy of the filter."""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agents.base import Observation
from agents.baselines.frontier import FrontierAgent, _ExploreMemory
from agents.baselines.geometry import GEOMETRY_READS, Geometry, env_list, unwrapped_env
from seif_gym.envs.vector import SeifExploreVectorEnv
from seif_gym.observation import (
    read_belief_map,
)
from seif_gym.slam.rollout import Rollouts, expected_rollouts_trusted
from seif_gym.type_aliases import FloatArray

__all__ = ["INFO_GAIN_READS", "InfoGainAgent"]


# -- information gain ------------------------------------------------------------------------------
@dataclass
class _PlanMemory(_ExploreMemory):
    action: NDArray[np.float64] = field(default_factory=lambda: np.zeros(2))
    repeat: int = 0


#: Names of the env attributes :class:`InfoGainAgent` reads (nothing else).
INFO_GAIN_READS = ("filter", "motion", *GEOMETRY_READS)


class _SubEnv:
    """Sub-env ``index`` of a native vector env as :class:`InfoGainAgent` reads an env: its filter and models."""

    def __init__(self, vector: Any, index: int) -> None:
        self._vector, self._index = vector, index
        template = vector.envs[index]  # the single env that holds the sub-env's configuration
        for name in INFO_GAIN_READS:
            if name != "filter":
                setattr(self, name, getattr(template, name))

    @property
    def filter(self) -> Any:
        return self._vector.sub_filter(self._index)


def _belief_sources(env: Any) -> list[Any]:
    """What :class:`InfoGainAgent` reads per batch row: each env's unwrapped env, or a vector env's sub-envs."""
    base = unwrapped_env(env)
    if isinstance(base, SeifExploreVectorEnv):  # a type test: a single env is read for its belief alone
        return [_SubEnv(base, e) for e in range(base.num_envs)]
    return [unwrapped_env(e) for e in env_list(env)]


class InfoGainAgent(FrontierAgent):
    """Pick the constant-``(v, w)`` arc with the largest expected information gain.

    Every ``replan_every`` steps, for each candidate arc (every ``(v, w)`` of
    ``speeds × turn_rates``, as actions in ``[-1, 1]``):

    1. a copy of the env's filter is rolled ``horizon`` steps forward:
       ``predict`` with the arc's control, then ``update`` with the
       *expected*, noise-free measurements (``sensor.predict`` of the
       estimated landmark positions) of the mapped landmarks inside the
       sensor's range and field of view from the predicted pose
       (:func:`~seif_gym.slam.rollout.expected_rollouts`: all arcs at once, in
       compiled code for a SEIF or an ESEIF; the env's filter is not changed);
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
    appended to :attr:`planning_times` (seconds). :meth:`_plan_reference` computes the same plan one arc
    at a time, with a deep copy of the filter each (the planner as first written): the same action and
    the same scores, bit for bit (``tests/agents/test_info_gain_planner.py``).

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
        envs = env_list(env)
        if not envs:
            raise TypeError(
                "env must be the SeifExplore env(s) info_gain acts in (it plans with their filter), got None"
            )
        super().__init__(envs[0], **kwargs)
        self.geometry = Geometry.from_env(env)  # every env's: one geometry
        self.envs = _belief_sources(env)
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
        #: The batch row of every plan in :attr:`planning_times`.
        self.planning_rows: list[int] = []
        #: Score terms of the last plan: candidates (c, 2), gain, explore, walls, score (c,).
        self.last_plan: dict[str, np.ndarray] = {}

    def _new_state(self) -> _PlanMemory:
        return _PlanMemory(visited=np.zeros((self.grid, self.grid), dtype=bool))

    def bind(self, env: Any) -> None:
        """Plan with the filter(s) of ``env`` from now on (its geometry must be this agent's); memories are reset.

        ``env`` is any env :class:`InfoGainAgent` takes, a native
        :class:`~seif_gym.envs.vector.SeifExploreVectorEnv` included: row ``e`` of a batch then plans
        with a copy of sub-env ``e``'s filter (:meth:`~seif_gym.envs.vector.SeifExploreVectorEnv.sub_filter`),
        which gives the plan a single env's filter gives.

        Raises
        ------
        TypeError
            If ``env`` is not a ``SeifExplore`` env (or several).
        ValueError
            If its geometry is not this agent's.
        """
        geometry = Geometry.from_env(env)
        if geometry != self.geometry:
            raise ValueError(f"env: its geometry {geometry} is not the agent's {self.geometry}")
        self.envs = _belief_sources(env)
        self.reset()

    def _env(self, index: int) -> Any:
        if index >= len(self.envs):
            raise ValueError(f"batch row {index} has no env: info_gain was given {len(self.envs)} env(s)")
        return self.envs[index]

    def uncertainty(self, filt: Any) -> float:
        """``sum(landmark_std) + pose_weight·sqrt(σx² + σy²)`` of ``filt``'s belief."""
        pose_cov, _ = filt.local_marginals(np.empty(0, dtype=np.int64))
        total = float(np.sum(filt.landmark_std())) if filt.num_landmarks else 0.0
        return total + self.pose_weight * math.sqrt(max(pose_cov[0, 0] + pose_cov[1, 1], 0.0))

    def _uncertainties(self, rollouts: Rollouts) -> FloatArray:
        """:meth:`uncertainty` of each rolled-out copy, from its marginals, shape (c,)."""
        out = np.empty(len(rollouts.poses))
        for k, (pose_cov, std) in enumerate(zip(rollouts.pose_covariances, rollouts.landmark_std)):
            total = float(np.sum(std)) if len(std) else 0.0
            out[k] = total + self.pose_weight * math.sqrt(max(pose_cov[0, 0] + pose_cov[1, 1], 0.0))
        return out

    def _swept_areas(self, observation: Observation, poses: FloatArray, start: FloatArray) -> FloatArray:
        """:meth:`_swept_area` of every candidate's poses (c, horizon, 3) at once, shape (c,).

        The same numbers: each cell and pose gets the same operations, but only the unswept in-arena
        cells are tested, and the field of view only where the range test passed.
        """
        count = len(poses)
        belief = read_belief_map(observation)
        raster = self.raster(belief.shape[1])
        candidate = (belief[0] < 0.5) & (belief[2] < 0.5)
        if not candidate.any():
            return np.zeros(count)
        c, s = math.cos(start[2]), math.sin(start[2])
        r2 = self.geometry.sensor_range**2
        half_fov = 0.5 * self.geometry.fov
        flat = poses.reshape(-1, 3)
        dx, dy = flat[:, 0] - start[0], flat[:, 1] - start[1]
        px, py = c * dx + s * dy, -s * dx + c * dy  # (forward, left) of each predicted pose
        # a cell farther than range + the farthest pose from the start is out of every pose's range
        reach = self.geometry.sensor_range + float(np.max(np.hypot(px, py))) + 1e-6
        cells = candidate & (raster.distance <= reach)
        if not cells.any():
            return np.zeros(count)
        forward, left = raster.forward[cells], raster.left[cells]
        df = forward - px[:, None]
        dl = left - py[:, None]
        seen = df * df + dl * dl <= r2  # (c·horizon, cells)
        if half_fov < math.pi:
            turn = np.broadcast_to((flat[:, 2] - start[2])[:, None], seen.shape)
            shifted = np.arctan2(dl[seen], df[seen]) - turn[seen] + np.pi
            # x % 2π is x itself on [0, 2π) (fmod is exact): the modulo only where it can change something
            outside = (shifted < 0.0) | (shifted >= 2.0 * np.pi)
            shifted[outside] %= 2.0 * np.pi
            seen[seen] = np.abs(shifted - np.pi) <= half_fov
        covered = np.count_nonzero(seen.reshape(count, -1, len(forward)).any(axis=1), axis=1)
        return covered.astype(np.float64) * raster.cell**2

    def _rollout(self, base: Any, belief: Any, control: FloatArray) -> tuple[Any, FloatArray]:
        """Copy of the filter after ``horizon`` steps of ``control``, and the predicted poses (horizon, 3).

        The reference planner's rollout (:meth:`_plan_reference`); :meth:`plan` rolls every candidate at
        once with :func:`~seif_gym.slam.rollout.expected_rollouts`, which gives the same numbers.
        """
        filt = copy.deepcopy(belief)
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
        """Score every candidate arc for env ``index`` and return the best action (2,).

        All candidates are rolled out together (:func:`~seif_gym.slam.rollout.expected_rollouts`) and
        their swept areas computed together; the scores are those of :meth:`_plan_reference`, bit for bit.
        """
        return self._plan(observation, index, reference=False)

    def _plan_reference(self, observation: Observation, index: int = 0) -> np.ndarray:
        """:meth:`plan` one candidate at a time: a deep copy of the filter each, its own steps, one raster each.

        The planner as it was written first, kept to check and time :meth:`plan` against
        (``tests/agents/test_info_gain_planner.py``, ``benchmarks/bench_planner.py``).
        """
        return self._plan(observation, index, reference=True)

    def _plan(self, observation: Observation, index: int, *, reference: bool) -> np.ndarray:
        started = time.perf_counter()
        base = self._env(index)
        belief = base.filter  # read once: a vector env's sub-env builds it from its arrays
        if belief is None:
            raise RuntimeError("the env has no filter yet: reset it before asking info_gain for an action")
        scale = np.array([base.robot_config.max_speed, base.robot_config.max_turn_rate], dtype=np.float64)
        half = self.geometry.half
        start = np.array(belief.pose, dtype=np.float64)
        before = self.uncertainty(belief)
        memory = self._state(index)
        target = self.frontier_target(observation)
        if target is None:
            target = self.grid_target(memory, np.asarray(observation["pose"]))
        c, s = math.cos(start[2]), math.sin(start[2])
        target_world = start[:2] + np.array([c * target[0] - s * target[1], s * target[0] + c * target[1]])
        distance0 = float(np.hypot(*(target_world - start[:2])))
        count = len(self.candidates)
        gain, explore, walls = np.zeros(count), np.zeros(count), np.zeros(count)
        if reference:
            for k, action in enumerate(self.candidates):
                filt, poses = self._rollout(base, belief, action * scale)
                gain[k] = before - self.uncertainty(filt)
                progress = distance0 - float(np.hypot(*(target_world - poses[-1, :2])))
                explore[k] = self._swept_area(observation, poses, start) + self.progress_weight * progress
                walls[k] = np.count_nonzero(np.any(np.abs(poses[:, :2]) > half - self.wall_margin, axis=1))
        else:
            rollouts = expected_rollouts_trusted(belief, self.candidates * scale, float(base.robot_config.dt),
                                                 self.horizon)  # fmt: skip
            gain[:] = before - self._uncertainties(rollouts)
            swept = self._swept_areas(observation, rollouts.poses, start)
            for k, poses in enumerate(rollouts.poses):
                progress = distance0 - float(np.hypot(*(target_world - poses[-1, :2])))
                explore[k] = float(swept[k]) + self.progress_weight * progress
            walls[:] = np.count_nonzero(np.any(np.abs(rollouts.poses[:, :, :2]) > half - self.wall_margin, axis=2),
                                        axis=1)  # fmt: skip
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
        self.planning_rows.append(index)
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
