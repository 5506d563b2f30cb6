"""``SeifExploreVectorEnv``: N ``SeifExplore`` envs advanced by compiled kernels over arrays with an env axis.

A step of the single env (:class:`~seif_gym.envs.explore.SeifExploreEnv`)
spends most of its time in small Python calls around the filter
(``docs/performance_notes.md``). Here one ``step`` of N envs is a handful of compiled calls, each
looping over the envs (with ``num_threads > 1``, one parallel loop on numba's threads:
:mod:`seif_gym.threads`): the worlds
(:class:`~seif_gym.world.BatchedWorld`), the
SEIFs, ESEIFs or ConservativeSEIFs (:class:`~seif_gym.slam.batched.BatchedSEIF`, ``BatchedESEIF``,
``BatchedConservativeSEIF``), the observations
(:func:`~seif_gym.observation.encode_many`) and the rewards and infos
(:func:`_score_many`). No per-env Python object takes part in a step; an
episode's start (``reset``, and autoreset) runs the single env's own reset
and loads its state into the arrays, so the two cannot drift apart.

Supported in this compiled form: ``filter="seif"``, ``"eseif"`` or ``"cseif"`` (the last
with ``num_threads=1``; wavefront recovery), ``data_association="known"``, ``reward="map_error"``, Thrun's motion
model and a constant range noise (the defaults of every registered ``-v1`` id,
and their ESEIF variant). Any other configuration runs as a
:class:`gymnasium.vector.SyncVectorEnv` of single envs (``backend ==
"sync"``), with the same interface.

Equal to N single envs: with the same seeds, every observation, reward,
termination, truncation and info equals what a ``SyncVectorEnv`` of
``gym.make`` envs (time limit included) returns, bit for bit, in both
autoreset modes. ``info["pose_nees"]`` needs the exact pose marginal: a
compiled dense factorisation of Ω for maps of up to
:data:`~seif_gym.slam.seif.DENSE_MARGINALS_UP_TO` landmarks, the single env's
sparse LU above (:func:`~seif_gym.slam.seif.exact_marginal_covariance`), as
the single env does.
"""

from __future__ import annotations

import copy
import functools
import math
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, SyncVectorEnv, VectorEnv
from gymnasium.vector.utils import batch_space, concatenate, create_empty_array
from numba import njit, prange
from numpy.typing import ArrayLike

from seif_gym.envs.explore import Measurements, SeifExploreEnv
from seif_gym.metrics import map_error_kernel, nees_kernel
from seif_gym.observation import encode_env, encode_many
from seif_gym.slam import _kernels
from seif_gym.slam.base import SlamFilter
from seif_gym.slam.batched import BatchedConservativeSEIF, BatchedESEIF, BatchedSEIF
from seif_gym.slam.models import VelocityMotionModel, wrap_angle
from seif_gym.slam.seif import DENSE_MARGINALS_UP_TO, SEIF, exact_marginal_covariance
from seif_gym.threads import check_thread_count, numba_threads
from seif_gym.type_aliases import BoolArray, Float32Array, FloatArray, IntArray, UInt8Array
from seif_gym.validation import as_count
from seif_gym.world import BatchedWorld

__all__ = ["SeifExploreVectorEnv"]


def _as_actions(actions: Any, num_envs: int) -> FloatArray:
    """``actions`` as a float64 (num_envs, 2) array of finite real numbers, or a TypeError/ValueError naming it."""
    expected = f"one row of 2 real numbers per sub-env, shape ({num_envs}, 2)"
    if actions is None or isinstance(actions, (str, bytes)):
        raise TypeError(f"actions must be {expected}, got {type(actions).__name__}")
    try:
        array = np.asarray(actions)
    except (TypeError, ValueError):  # ragged nesting
        raise TypeError(f"actions must be {expected}, got {type(actions).__name__} that is not an array") from None
    if array.dtype.kind not in "iuf":
        raise TypeError(f"actions must be {expected}, got dtype {array.dtype}")
    if array.shape != (num_envs, 2):
        raise ValueError(f"actions must have shape {(num_envs, 2)}, got {array.shape}")
    array = np.asarray(array, dtype=np.float64)
    if not _all_finite(array):
        raise ValueError(
            f"actions must be finite, got non-finite rows {np.flatnonzero(~np.isfinite(array).all(1)).tolist()}"
        )
    return array


def _check_reset_options(options: Any) -> None:
    """Refuse reset ``options`` as the single env does: None or an empty mapping only."""
    if options is None:
        return
    if not isinstance(options, Mapping):
        raise TypeError(f"options must be a dict or None, got {type(options).__name__}")
    if options:
        raise ValueError(
            f"options has unknown key(s) {sorted(map(str, options))}: SeifExploreVectorEnv.reset accepts no options "
            "(pass None or {}); the episodes' set-up is fixed by the constructor's arguments"
        )


def _check_seeds(seed: Any, num_envs: int) -> list[int | None]:
    """One seed (a non-negative int or None) per sub-env, from ``reset``'s ``seed``."""
    if seed is None:
        return [None] * num_envs
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
        if seed < 0:
            raise ValueError(f"seed must be a non-negative int, got {seed!r}")
        return [int(seed) + e for e in range(num_envs)]
    if isinstance(seed, (list, tuple)) and len(seed) == num_envs:
        for entry in seed:
            if entry is not None and (isinstance(entry, bool) or not isinstance(entry, (int, np.integer)) or entry < 0):
                raise ValueError(f"seed must list a non-negative int or None per sub-env, got {seed!r}")
        return [None if entry is None else int(entry) for entry in seed]
    raise ValueError(f"seed must be an int, None or a list of {num_envs} seeds, got {seed!r}")


@njit(cache=True)
def _all_finite(values: FloatArray) -> bool:
    """Whether every entry of the 2-D ``values`` is finite (one compiled pass, no temporary arrays)."""
    for i in range(values.shape[0]):
        for j in range(values.shape[1]):
            if not np.isfinite(values[i, j]):
                return False
    return True


@njit(cache=True)
def _score_env(e: int, true_poses: FloatArray, truth: FloatArray, mean: FloatArray, counters: IntArray, ids: IntArray,
               robot_info: FloatArray, robot_links: FloatArray, landmark_info: FloatArray, neighbour_index: IntArray,
               neighbour_info: FloatArray, neighbour_count: IntArray, information_vector: FloatArray,
               block_position: IntArray, blanket_covariances: FloatArray, d_cap: float, previous_error: FloatArray,
               wall: BoolArray, wall_penalty: float, divergence_threshold: float, dense_up_to: int,
               reward: FloatArray, map_error: FloatArray, pose_error: FloatArray, diverged: BoolArray,
               pose_nees: FloatArray, pose_nees_blanket: FloatArray) -> None:  # fmt: skip
    """Reward, map error, pose error, divergence and the two pose NEES of env ``e`` (``SeifExploreEnv.step``).

    ``pose_nees[e]`` is left NaN for a map of more than ``dense_up_to`` landmarks: a dense factorisation
    of its Omega does not belong in a step, the caller solves those sparsely (``-1``: every map, for
    ``exact_pose_nees=False``).
    """
    error = np.empty(3)
    n = counters[e, 0]
    estimates = mean[e, 3 : 3 + 2 * n].reshape(n, 2)
    current = map_error_kernel(estimates, truth[e], ids[e, :n], d_cap)
    reward[e] = previous_error[e] - current
    if wall[e]:
        reward[e] -= wall_penalty
    map_error[e] = current
    previous_error[e] = current
    dx = true_poses[e, 0] - mean[e, 0]
    dy = true_poses[e, 1] - mean[e, 1]
    pose_error[e] = np.hypot(dx, dy)
    diverged[e] = pose_error[e] > divergence_threshold
    error[0] = dx
    error[1] = dy
    error[2] = _kernels._wrap_float(true_poses[e, 2] - mean[e, 2])
    pose_nees_blanket[e] = nees_kernel(error, blanket_covariances[e])
    if n > dense_up_to:
        pose_nees[e] = np.nan  # a large map: the caller's sparse factorisation, as the single env's
        return
    cov = _kernels.exact_marginal(robot_info[e], robot_links[e], landmark_info[e], neighbour_index[e],
                                  neighbour_info[e], neighbour_count[e], information_vector[e], mean[e],
                                  block_position[e], n, np.arange(3))  # fmt: skip
    pose_nees[e] = nees_kernel(error, 0.5 * (cov + cov.T))


@njit(cache=True)
def _score_many(*arguments: Any) -> None:
    """:func:`_score_env` of every env, one after another.

    ``arguments``: those of :func:`_score_env` after ``e`` (the first one has the env axis).
    """
    for e in range(arguments[0].shape[0]):
        _score_env(e, *arguments)


@njit(cache=True, parallel=True)
def _filter_and_score_parallel(
    robot_info: FloatArray, robot_links: FloatArray, landmark_info: FloatArray, neighbour_index: IntArray,
    neighbour_info: FloatArray, neighbour_count: IntArray, information_vector: FloatArray, mean: FloatArray,
    block_position: IntArray, active: IntArray, counters: IntArray, is_active: BoolArray, last_observed: IntArray,
    id_to_index: IntArray, ids: IntArray, queue: IntArray, queued: BoolArray, queue_state: IntArray,
    controls: FloatArray, dt: float, alphas: FloatArray, floor: float, ranges: FloatArray, bearings: FloatArray,
    measured: IntArray, measured_count: IntArray, noise_info: FloatArray, noise_cov: FloatArray, max_active: int,
    relocalization_landmarks: int, split_weight: float, rcond: float, recovery_landmarks: int, budget: int,
    relaxation: float, tolerance: float, eseif_counters: IntArray,
    coverage: UInt8Array, resolution: float, half_arena: float, max_range: float, half_fov: float, map_size: int,
    map_extent: float, nearest_landmarks: int, diagonal: float, std_scale: float, pose_out: Float32Array,
    landmarks_out: Float32Array, mask_out: Float32Array, map_out: UInt8Array, blanket_covariances: FloatArray,
    true_poses: FloatArray, truth: FloatArray, d_cap: float, previous_error: FloatArray, wall: BoolArray,
    wall_penalty: float, divergence_threshold: float, dense_up_to: int, reward: FloatArray, map_error: FloatArray,
    pose_error: FloatArray, diverged: BoolArray, pose_nees: FloatArray, pose_nees_blanket: FloatArray,
) -> None:  # fmt: skip
    """Motion update, measurement update, observation and score of every env, the envs on numba's threads.

    Per env exactly the kernels, in the order, that the one-thread path calls for all envs in turn
    (``BatchedSEIF.predict`` and ``update_trusted``, :func:`~seif_gym.observation.encode_many`,
    :func:`_score_many`): the envs are independent, so the results are the same bits.
    ``relocalization_landmarks > 0`` runs the ESEIF's update (``BatchedESEIF``), 0 the SEIF's.
    """
    active_count = counters[:, 1].copy()
    for e in prange(mean.shape[0]):
        # fmt: off
        _kernels.seif_predict_env(e, robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                                  neighbour_count, information_vector, mean, block_position, active, active_count,
                                  controls, dt, alphas, floor)
        if relocalization_landmarks > 0:
            _kernels.eseif_update_env(e, robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                                      neighbour_count, information_vector, mean, block_position, active, counters,
                                      is_active, last_observed, id_to_index, ids, queue, queued, queue_state, ranges,
                                      bearings, measured, measured_count, noise_info, noise_cov, max_active,
                                      relocalization_landmarks, split_weight, rcond, recovery_landmarks, budget,
                                      relaxation, tolerance, eseif_counters)
        else:
            _kernels.seif_update_env(e, robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                                     neighbour_count, information_vector, mean, block_position, active, counters,
                                     is_active, last_observed, id_to_index, ids, queue, queued, queue_state, ranges,
                                     bearings, measured, measured_count, noise_info, max_active, recovery_landmarks,
                                     budget, relaxation, tolerance)
        encode_env(e, coverage, resolution, half_arena, max_range, half_fov, map_size, map_extent, nearest_landmarks,
                   diagonal, std_scale, robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                   neighbour_count, information_vector, mean, block_position, active, counters, pose_out,
                   landmarks_out, mask_out, map_out, blanket_covariances)
        _score_env(e, true_poses, truth, mean, counters, ids, robot_info, robot_links, landmark_info, neighbour_index,
                   neighbour_info, neighbour_count, information_vector, block_position, blanket_covariances, d_cap,
                   previous_error, wall, wall_penalty, divergence_threshold, dense_up_to, reward, map_error,
                   pose_error, diverged, pose_nees, pose_nees_blanket)
        # fmt: on


def _same(env: gym.Env) -> gym.Env:
    """``env`` itself (SyncVectorEnv takes env factories; the fallback hands it the envs it already has)."""
    return env


class SeifExploreVectorEnv(VectorEnv):
    """N ``SeifExplore`` envs in one: ``gym.make_vec(id, num_envs=N)`` builds it for every registered id.

    Parameters
    ----------
    num_envs : int
        Number of sub-envs.
    max_episode_steps : int or None
        Time limit of each sub-env's episodes (the registered one when made by ``gym.make_vec``).
    autoreset_mode : AutoresetMode or str
        ``"NextStep"`` (default: the step after an episode ends resets that sub-env) or ``"SameStep"``
        (the step that ends it returns the next episode's first observation, the last one in
        ``info["final_obs"]``).
    render_mode : {"rgb_array"} or None
        ``render()`` draws sub-env 0.
    num_threads : int
        Threads the compiled kernels share the envs out to (numba's threads, at most
        ``NUMBA_NUM_THREADS``, the cores; each env's arithmetic is the same on any number;
        :func:`seif_gym.threads.numba_threads`). Default 1: numba's thread pool is not started. More
        pay with many envs on cores nobody else wants, and not where other busy processes share them;
        with numba's OpenMP layer, a process that has started the pool must not ``fork`` children that
        run numba's parallel code (``NUMBA_THREADING_LAYER=forksafe`` avoids it, at some speed).
    **kwargs
        The keyword arguments of :class:`~seif_gym.envs.explore.SeifExploreEnv`.
    """

    metadata = {"render_modes": ["rgb_array"], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, *, max_episode_steps: int | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP, render_mode: str | None = None,
                 num_threads: int = 1, **kwargs: Any) -> None:  # fmt: skip
        as_count(num_envs, "num_envs", minimum=1)
        if max_episode_steps is not None:
            as_count(max_episode_steps, "max_episode_steps", minimum=1)
        try:
            mode = AutoresetMode(autoreset_mode)
        except ValueError as error:
            choices = [m.value for m in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)]
            raise ValueError(f"autoreset_mode must be one of {choices}, got {autoreset_mode!r}") from error
        if mode not in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP):
            raise ValueError(f"autoreset_mode must be NextStep or SameStep, got {mode.value!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be 'rgb_array' or None, got {render_mode!r}")
        #: threads of the compiled kernels
        self.num_threads = check_thread_count(num_threads, "num_threads")
        self.num_envs = int(num_envs)
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        self.autoreset_mode = mode
        self.metadata = {**self.metadata, "autoreset_mode": mode}
        self.render_mode = render_mode
        # the single envs: the configuration, the spaces, and every episode's start
        self.envs = [
            SeifExploreEnv(render_mode=render_mode if e == 0 else None, **kwargs) for e in range(self.num_envs)
        ]
        template = self.envs[0]
        config = template.filter_config
        # the ConservativeSEIF's batched update runs on one thread only (the parallel loop runs the SEIF's or the ESEIF's)
        compiled = ((config.filter in ("seif", "eseif") or (config.filter == "cseif" and self.num_threads == 1))
                    and config.data_association == "known" and config.mean_recovery == "wavefront"
                    and template.reward_config.reward == "map_error" and not template.measure_time
                    and config.innovation_gate is None and isinstance(template.motion, VelocityMotionModel)
                    and template.world_config.arena_extent is None and template.sensor_config.range_error_time is None
                    and not getattr(template.sensor, "range_dependent", False))  # fmt: skip
        #: ``"compiled"`` (batched kernels) or ``"sync"`` (a SyncVectorEnv of single envs, for other configurations)
        self.backend = "compiled" if compiled else "sync"
        self.single_observation_space = template.observation_space
        self.single_action_space = template.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._sync: SyncVectorEnv | None = None
        if not compiled:
            limited: list[gym.Env] = [gym.wrappers.TimeLimit(env, self.max_episode_steps) if self.max_episode_steps
                                      else env for env in self.envs]  # fmt: skip
            self._sync = SyncVectorEnv([functools.partial(_same, env) for env in limited], autoreset_mode=mode)
            return
        n = self.num_envs
        motion = template.motion
        assert isinstance(motion, VelocityMotionModel)  # the compiled kernels are Thrun's model (checked above)
        self._world = BatchedWorld(n, template.world_config, motion, template.sensor)
        batch = {"eseif": BatchedESEIF, "cseif": BatchedConservativeSEIF}.get(config.filter, BatchedSEIF)
        self._filters = batch(n, template.world_config.num_landmarks, motion, template.sensor,
                              max_active=config.max_active)  # fmt: skip
        cells = template.encoder.coverage.shape[0]
        self._coverage = np.zeros((n, cells, cells), dtype=np.uint8)
        self._truth = np.zeros((n, template.world_config.num_landmarks, 2))
        self._observations: dict[str, np.ndarray] = create_empty_array(self.single_observation_space, n)  # type: ignore[assignment]
        self._blanket_covariances = np.zeros((n, 3, 3))
        self._previous_error = np.zeros(n)
        self._elapsed = np.zeros(n, dtype=np.int64)
        self._autoreset = np.zeros(n, dtype=bool)
        self._scale = template._action_scale
        #: whether a map can outgrow the compiled dense pose marginal and the NEES is asked (then the sparse one runs)
        self._sparse_nees = template.exact_pose_nees and template.world_config.num_landmarks > DENSE_MARGINALS_UP_TO
        # exact_pose_nees=False: no env's pose marginal is factorised (the kernels leave NaN above this many landmarks)
        self._nees_up_to = DENSE_MARGINALS_UP_TO if template.exact_pose_nees else -1
        self._env_rows = np.arange(n)[:, None]
        self._landmarks_total = np.full(n, template.world_config.num_landmarks, dtype=np.int64)
        self._info_template: dict[str, Any] | None = None

    # -- episodes ---------------------------------------------------------------------------------
    def _load(self, e: int) -> None:
        """Copy sub-env ``e``'s state after its reset into the arrays."""
        env = self.envs[e]
        world, filt = env.world, env.filter
        assert isinstance(filt, SEIF) and world is not None
        motion_rng, sensor_rng = env._motion_rng, env._sensor_rng
        if e == 0 and self.render_mode is not None:
            # sub-env 0 also steps as a single env, to be drawn: it keeps its generators, the arrays get copies
            motion_rng, sensor_rng = copy.deepcopy(motion_rng), copy.deepcopy(sensor_rng)
        self._world.reset(e, world.landmarks, world.pose, motion_rng, sensor_rng)
        self._truth[e] = world.landmarks
        self._filters.load(e, filt)
        self._coverage[e] = env.encoder.coverage
        self._previous_error[e] = env._map_error
        self._elapsed[e] = 0

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Reset every sub-env (``seed``: an int seeds sub-env ``e`` with ``seed + e``; or a list).

        Raises
        ------
        TypeError
            If ``options`` is not a mapping.
        ValueError
            If ``options`` has any key (the env accepts no reset options), or ``seed`` is not a
            non-negative int, None or a list of one per sub-env; nothing is reset then.
        """
        _check_reset_options(options)
        seeds = _check_seeds(seed, self.num_envs)
        if self._sync is not None:
            return self._sync.reset(seed=seed, options=options)
        observations: list[dict[str, np.ndarray]] = []
        infos: dict[str, Any] = {}
        for e, env_seed in enumerate(seeds):
            observation, info = self.envs[e].reset(seed=env_seed, options=options)
            self._load(e)
            observations.append(observation)
            infos = self._add_info(infos, info, e)
        self._observations = concatenate(self.single_observation_space, observations, self._observations)  # type: ignore[assignment]
        self._autoreset[:] = False
        return self._copy_observations(), infos

    def _copy_observations(self) -> dict[str, np.ndarray]:
        return {key: value.copy() for key, value in self._observations.items()}

    # -- steps ----------------------------------------------------------------------------------
    def step(
        self, actions: ArrayLike
    ) -> tuple[dict[str, np.ndarray], FloatArray, BoolArray, BoolArray, dict[str, Any]]:
        """Advance every sub-env by one step (``actions``: shape (N, 2), finite real numbers).

        Raises
        ------
        TypeError
            If ``actions`` is not an array of real numbers (a string, None, ragged rows, a bool, complex or
            object dtype).
        ValueError
            If ``actions`` has not the shape (N, 2) or is not finite; no sub-env steps then.
        """
        actions = _as_actions(actions, self.num_envs)
        if self._sync is not None:
            return self._sync.step(actions)
        n = self.num_envs
        template = self.envs[0]
        if self.render_mode is not None and not self._autoreset[0]:
            template.step(actions[0])  # the drawn copy of sub-env 0 (its own generators: the same draws)
        dt = template.robot_config.dt
        controls = np.minimum(np.maximum(actions, -1.0), 1.0) * self._scale  # np.clip's values, without its wrapper
        world, filters = self._world, self._filters
        executed, wall = world.step(controls, dt)
        ranges, bearings, ids, counts = world.measure()
        obs = self._observations
        config, sensor, reward_config = template.observation_config, template.sensor, template.reward_config
        half_fov = 0.5 * sensor.fov if sensor.fov < 2.0 * math.pi else math.pi
        diagonal = template.world_config.arena_size * math.sqrt(2.0)
        rewards, map_error, pose_error, pose_nees, pose_nees_blanket = np.zeros((5, n))
        diverged = np.zeros(n, dtype=bool)
        # one thread: a plain loop per kernel, which never starts numba's thread pool (seif_gym.threads says
        # why that matters); more: one prange loop over the envs for the filters, observations and scores
        if self.num_threads == 1:
            filters.predict_trusted(executed, dt)  # the worlds' own executed controls: valid
            filters.update_trusted(ranges, bearings, ids, counts)  # the worlds' own measurements: valid
            encode_many(self._coverage, config.coverage_resolution, template.encoder.half_arena, sensor.max_range,
                        half_fov, config.map_size, config.map_extent, config.nearest_landmarks, diagonal,
                        config.std_scale, *filters.kernel_arrays(), filters.active, filters.counters, obs["pose"],
                        obs["landmarks"], obs["landmarks_mask"], obs["belief_map"], self._blanket_covariances)  # fmt: skip
            _score_many(world.poses, self._truth, filters.mean, filters.counters, filters.ids, filters.robot_info,
                        filters.robot_links, filters.landmark_info, filters.neighbour_index, filters.neighbour_info,
                        filters.neighbour_count, filters.information_vector, filters.block_position,
                        self._blanket_covariances, reward_config.d_cap, self._previous_error, wall,
                        reward_config.wall_penalty, reward_config.divergence_threshold, self._nees_up_to, rewards,
                        map_error, pose_error, diverged, pose_nees, pose_nees_blanket)  # fmt: skip
        else:
            with numba_threads(self.num_threads):
                _filter_and_score_parallel(
                    *filters.kernel_arrays(), *filters.bookkeeping_arrays(), executed, dt,
                    filters._alphas, filters._floor, ranges, bearings, ids, counts, *filters.update_arguments(),
                    self._coverage, config.coverage_resolution, template.encoder.half_arena, sensor.max_range,
                    half_fov, config.map_size, config.map_extent, config.nearest_landmarks, diagonal,
                    config.std_scale, obs["pose"], obs["landmarks"], obs["landmarks_mask"], obs["belief_map"],
                    self._blanket_covariances,
                    world.poses, self._truth, reward_config.d_cap, self._previous_error, wall,
                    reward_config.wall_penalty, reward_config.divergence_threshold, self._nees_up_to, rewards,
                    map_error, pose_error, diverged, pose_nees, pose_nees_blanket,
                )  # fmt: skip
        large = (np.flatnonzero(filters.counters[:, 0] > DENSE_MARGINALS_UP_TO).tolist() if self._sparse_nees
                 else ())  # fmt: skip
        for e in large:
            # large maps: the single env's sparse LU on this env's arrays (exactly what it computes)
            error = world.poses[e] - filters.mean[e, :3]
            error[2] = wrap_angle(float(error[2]))
            cov = exact_marginal_covariance(filters.store(e), np.arange(3), DENSE_MARGINALS_UP_TO)
            pose_nees[e] = nees_kernel(error, cov)
        self._elapsed += 1
        terminated = diverged.copy()
        truncated = (self._elapsed >= self.max_episode_steps if self.max_episode_steps is not None
                     else np.zeros(n, dtype=bool))  # fmt: skip
        infos = self._step_infos(controls, executed, wall, ranges, bearings, ids, counts, map_error, pose_error,
                                 diverged, pose_nees, pose_nees_blanket)  # fmt: skip
        observations = self._copy_observations()
        if self.autoreset_mode == AutoresetMode.NEXT_STEP:
            # a sub-env whose previous step ended its episode starts a new one instead of stepping
            for e in np.flatnonzero(self._autoreset).tolist() if self._autoreset.any() else ():
                observation, info = self.envs[e].reset()
                self._load(e)
                for key, value in observation.items():
                    observations[key][e] = value
                    self._observations[key][e] = value
                rewards[e], terminated[e], truncated[e] = 0.0, False, False
                infos = self._replace_info(infos, info, e)
            self._autoreset = terminated | truncated
        else:
            ended = terminated | truncated
            for e in np.flatnonzero(ended).tolist() if ended.any() else ():
                # as SyncVectorEnv: the ending step's observation and info go under final_obs / final_info
                final = {key: value[e].copy() for key, value in observations.items()}
                infos = self._add_info(infos, {"final_obs": final, "final_info": self._info_of(infos, e)}, e)
                observation, info = self.envs[e].reset()
                self._load(e)
                for key, value in observation.items():
                    observations[key][e] = value
                    self._observations[key][e] = value
                infos = self._replace_info(infos, info, e)
        return observations, rewards, terminated, truncated, infos

    def _step_infos(self, controls: FloatArray, executed: FloatArray, wall: BoolArray, ranges: FloatArray,
                    bearings: FloatArray, ids: IntArray, counts: IntArray, map_error: FloatArray, pose_error: FloatArray,
                    diverged: BoolArray, pose_nees: FloatArray, pose_nees_blanket: FloatArray) -> dict[str, Any]:  # fmt: skip
        """The batched infos of a step: the single env's keys, each with its ``_key`` mask."""
        n = self.num_envs
        filters, world = self._filters, self._world
        active = np.empty(n, dtype=object)
        measurements = np.empty(n, dtype=object)
        # one gather and one copy for all envs, then per env a tuple and views of the copies
        active_ids = filters.ids[self._env_rows, filters.active].tolist()
        active_counts = filters.counters[:, 1].tolist()
        ranges, bearings, ids = ranges.copy(), bearings.copy(), ids.copy()
        for e, m in enumerate(counts.tolist()):
            active[e] = tuple(active_ids[e][: active_counts[e]])
            measurements[e] = Measurements(ranges[e, :m], bearings[e, :m], ids[e, :m])
        # the single env's info uses math.hypot (CPython's own algorithm, not libm's hypot, which the
        # divergence test uses): the same function here, so that the values agree to the last bit
        error = world.poses[:, :2] - filters.mean[:, :2]
        pose_error = np.array([math.hypot(dx, dy) for dx, dy in error.tolist()])
        values: dict[str, Any] = {
            "true_pose": world.poses.copy(),
            "pose_estimate": filters.mean[:, :3].copy(),
            "pose_error": pose_error,
            "map_error": map_error,
            "pose_nees": pose_nees,
            "pose_nees_blanket": pose_nees_blanket,
            "landmarks_mapped": filters.counters[:, 0].copy(),
            "landmarks_total": self._landmarks_total.copy(),
            "active_landmarks": active,
            "control": controls.copy(),
            "executed_control": executed.copy(),
            "measurements": measurements,
            "step_time": np.zeros(n),
            "wall_contact": wall.copy(),
            "diverged": diverged,
            "association_errors": np.zeros(n, dtype=np.int64),
        }
        infos: dict[str, Any] = {}
        masks = np.ones((len(values), n), dtype=bool)  # one allocation; each key's mask is its own row
        for (key, value), mask in zip(values.items(), masks):
            infos[key] = value
            infos["_" + key] = mask
        return infos

    @staticmethod
    def _info_of(infos: dict[str, Any], e: int) -> dict[str, Any]:
        """Sub-env ``e``'s own info out of batched ``infos`` (as the single env returned it)."""
        single: dict[str, Any] = {}
        for key, value in infos.items():
            mask = infos.get(f"_{key}")
            if key.startswith("_") or key in ("final_obs", "final_info") or mask is None or not mask[e]:
                continue
            item = value[e]
            single[key] = item.item() if isinstance(item, np.generic) else item
        return single

    def _replace_info(self, infos: dict[str, Any], info: dict[str, Any], e: int) -> dict[str, Any]:
        """Put sub-env ``e``'s reset ``info`` in place of its step info."""
        for key in [k for k in infos if not k.startswith("_") and k not in ("final_obs", "final_info")]:
            infos[f"_{key}"][e] = False
        return self._add_info(infos, info, e)

    # -- the rest of the API ---------------------------------------------------------------------------
    def sub_filter(self, index: int) -> SlamFilter:
        """A copy of sub-env ``index``'s filter as it is now: the belief a planner reads and may roll forward.

        The copy computes what the sub-env's filter computes, bit for bit, and stepping it leaves the
        vector env as it was. With the compiled backend it is rebuilt from the batched arrays
        (:meth:`~seif_gym.slam.batched.BatchedSEIF.to_filter`), with the sync one a deep copy of the
        single env's filter.

        Raises
        ------
        ValueError
            If ``index`` is not a sub-env.
        RuntimeError
            Before the first :meth:`reset`.
        """
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < self.num_envs:
            raise ValueError(f"index must be a sub-env in [0, {self.num_envs}), got {index!r}")
        if self._sync is not None:
            filt = self.envs[int(index)].filter
            if filt is None:
                raise RuntimeError("reset() the vector env before asking for a sub-env's filter")
            return copy.deepcopy(filt)
        return self._filters.to_filter(int(index))

    def render(self) -> Any:  # one frame (uint8) or None, where VectorEnv declares a tuple of frames
        """The frame of sub-env 0 (``render_mode="rgb_array"``), drawn by the single env that runs beside it.

        The same for both backends (the sync one steps these same single envs).
        """
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' to make_vec()")
            return None
        single = self.envs[0]
        if single.spec is None and self.spec is not None and self.spec.id in gym.registry:
            single.spec = gym.spec(self.spec.id)  # the frame's header names the env id, as the single env's does
        return single.render()

    def close_extras(self, **kwargs: Any) -> None:
        # also after a constructor that failed before these attributes existed (close() runs on collection)
        sync = getattr(self, "_sync", None)
        if sync is not None:
            sync.close()
        for env in getattr(self, "envs", ()):
            env.close()
