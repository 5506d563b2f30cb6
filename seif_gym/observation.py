"""Belief -> observation: what an agent of ``SeifExplore-v0`` sees, and back.

Everything here is computed from the filter's belief (its estimated pose and
map, and their uncertainty) and from what the robot itself knows (the arena's
size, its sensor). Nothing reads the true state: an encoder is never handed
the world.

:class:`BeliefEncoder` makes the observation; :class:`ObservationDecoder`
(``encoder.decoder()``, or ``ObservationDecoder.from_env(env)``) is its
inverse, which agents use to read the observation in metres with the numbers
of the env that made it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces
from numba import njit
from numpy.typing import ArrayLike, NDArray

from seif_gym.metrics import CHI2_95_2DOF
from seif_gym.slam._kernels import blanket_covariances, blanket_nodes, conditional_std
from seif_gym.slam.base import SlamFilter
from seif_gym.slam.models import RangeBearingSensor
from seif_gym.type_aliases import Float32Array, FloatArray, IntArray, UInt8Array
from seif_gym.validation import as_count, as_positive_scalar

__all__ = [
    "ObservationConfig", "BeliefEncoder", "ObservationDecoder", "BeliefRaster", "read_belief_map", "landmark_rows",
    "POSE_FEATURES", "LANDMARK_FEATURES", "MAP_CHANNELS", "DIAGONAL_OVER_HALF",
]  # fmt: skip


#: Entries of ``obs["pose"]``.
POSE_FEATURES = ("x", "y", "cos_theta", "sin_theta", "std_x", "std_y", "std_theta")
#: Columns of ``obs["landmarks"]``.
LANDMARK_FEATURES = ("forward", "left", "major_axis_95", "minor_axis_95")
#: Channels of ``obs["belief_map"]``.
MAP_CHANNELS = ("swept", "landmarks", "outside_arena")

#: 95% quantile of the chi-square distribution with 2 degrees of freedom (home: :mod:`seif_gym.metrics`).
CHI2_2DOF_95 = CHI2_95_2DOF


@dataclass(frozen=True)
class ObservationConfig:
    """Shape of the observation.

    Attributes
    ----------
    nearest_landmarks : int
        ``K``, the number of mapped landmarks listed in ``obs["landmarks"]``.
    map_size : int
        Side ``H = W`` of the egocentric ``belief_map`` raster, cells (at
        least 36 for stable-baselines3's image checks).
    map_extent : float
        Half-width of the raster, metres (the raster covers
        ``[-e, e]^2`` around the estimated pose, heading up).
    coverage_resolution : float
        Cell size of the swept-area grid kept over the arena, metres.
    std_scale : float
        Standard deviations are divided by this (and clipped to 1).
    """

    nearest_landmarks: int = 8
    map_size: int = 40
    map_extent: float = 8.0
    coverage_resolution: float = 0.5
    std_scale: float = 1.0

    def __post_init__(self) -> None:
        for name in ("nearest_landmarks", "map_size"):
            as_count(getattr(self, name), name, minimum=1)
        for name in ("map_extent", "coverage_resolution", "std_scale"):  # kept as the checked float
            object.__setattr__(self, name, as_positive_scalar(getattr(self, name), name))


@njit(cache=True)
def _sweep(
    coverage: UInt8Array,
    resolution: float,
    half_arena: float,
    x: float,
    y: float,
    theta: float,
    max_range: float,
    half_fov: float,
) -> None:
    """Mark the coverage cells whose centres the sensor sees from ``(x, y, theta)``."""
    cells = coverage.shape[0]
    lo_i = max(int((x - max_range + half_arena) / resolution), 0)
    hi_i = min(int((x + max_range + half_arena) / resolution) + 1, cells)
    lo_j = max(int((y - max_range + half_arena) / resolution), 0)
    hi_j = min(int((y + max_range + half_arena) / resolution) + 1, cells)
    r2 = max_range * max_range
    for i in range(lo_i, hi_i):
        cx = (i + 0.5) * resolution - half_arena - x
        for j in range(lo_j, hi_j):
            if coverage[i, j]:
                continue  # already swept: nothing to decide
            cy = (j + 0.5) * resolution - half_arena - y
            if cx * cx + cy * cy > r2:
                continue
            if half_fov < np.pi:
                bearing = (np.arctan2(cy, cx) - theta + np.pi) % (2.0 * np.pi) - np.pi
                if abs(bearing) > half_fov:
                    continue
            coverage[i, j] = 1


@njit(cache=True)
def _mark_landmarks(out: UInt8Array, x: float, y: float, c: float, s: float, step: float, extent: float, size: int,
                    landmarks: FloatArray, confidence: FloatArray) -> None:  # fmt: skip
    """Channel 1 of the raster: each landmark's cell gets ``round(255 confidence)`` (at least 1; the largest wins)."""
    for k in range(landmarks.shape[0]):
        dx = landmarks[k, 0] - x
        dy = landmarks[k, 1] - y
        forward = c * dx + s * dy
        left = -s * dx + c * dy
        i = int((extent - forward) / step)
        j = int((extent - left) / step)
        if 0 <= i < size and 0 <= j < size and forward <= extent and left <= extent:
            value = np.uint8(min(max(round(255.0 * confidence[k]), 1.0), 255.0))
            if value > out[1, i, j]:
                out[1, i, j] = value


@njit(cache=True)
def _belief_map(
    coverage: UInt8Array,
    resolution: float,
    half_arena: float,
    x: float,
    y: float,
    theta: float,
    size: int,
    extent: float,
    landmarks: FloatArray,
    confidence: FloatArray,
) -> UInt8Array:
    """The (3, size, size) uint8 egocentric raster (0..255); row 0 is ahead, column 0 is left.

    The readable reference: the encoders call :func:`_fill_belief_map`, which computes the same
    bits with the per-row and per-column products hoisted (``tests/env/test_world.py`` compares them).
    """
    out = np.zeros((3, size, size), dtype=np.uint8)
    cells = coverage.shape[0]
    c, s = np.cos(theta), np.sin(theta)
    step = 2.0 * extent / size
    for i in range(size):
        forward = extent - (i + 0.5) * step
        for j in range(size):
            left = extent - (j + 0.5) * step
            wx = x + c * forward - s * left
            wy = y + s * forward + c * left
            if wx < -half_arena or wx > half_arena or wy < -half_arena or wy > half_arena:
                out[2, i, j] = 255
                continue
            gi = min(int((wx + half_arena) / resolution), cells - 1)
            gj = min(int((wy + half_arena) / resolution), cells - 1)
            out[0, i, j] = 255 * coverage[gi, gj]
    _mark_landmarks(out, x, y, c, s, step, extent, size, landmarks, confidence)
    return out


@njit(cache=True)
def _fill_belief_map(out: UInt8Array, coverage: UInt8Array, resolution: float, half_arena: float, x: float, y: float,
                     theta: float, size: int, extent: float, landmarks: FloatArray, confidence: FloatArray) -> None:  # fmt: skip
    """:func:`_belief_map` written into ``out`` (3, size, size), the same bits with the row and column terms hoisted.

    A cell's world point ``(x + c f − s l, y + s f + c l)`` is evaluated as ``(x + c f) − (s l)`` and
    ``(y + s f) + (c l)``, the order of :func:`_belief_map`'s expression, with the row terms computed
    once per row and the column terms once per column; each row first computes every cell's grid
    indices in a loop without branches (which the compiler vectorises), then reads the coverage.
    """
    cells = coverage.shape[0]
    last = cells - 1
    c, s = np.cos(theta), np.sin(theta)
    step = 2.0 * extent / size
    s_left = np.empty(size)
    c_left = np.empty(size)
    for j in range(size):
        left = extent - (j + 0.5) * step
        s_left[j] = s * left
        c_left[j] = c * left
    grid_i = np.empty(size, dtype=np.int64)
    grid_j = np.empty(size, dtype=np.int64)
    inside = np.empty(size, dtype=np.bool_)
    for i in range(size):
        forward = extent - (i + 0.5) * step
        row_x = x + c * forward
        row_y = y + s * forward
        for j in range(size):
            wx = row_x - s_left[j]
            wy = row_y + c_left[j]
            inside[j] = (wx >= -half_arena) & (wx <= half_arena) & (wy >= -half_arena) & (wy <= half_arena)
            # clamped below too: the index of a cell outside the arena is computed, never read
            grid_i[j] = min(max(int((wx + half_arena) / resolution), 0), last)
            grid_j[j] = min(max(int((wy + half_arena) / resolution), 0), last)
        for j in range(size):
            out[1, i, j] = 0
            if inside[j]:
                out[0, i, j] = 255 * coverage[grid_i[j], grid_j[j]]
                out[2, i, j] = 0
            else:
                out[0, i, j] = 0
                out[2, i, j] = 255
    _mark_landmarks(out, x, y, c, s, step, extent, size, landmarks, confidence)


@njit(cache=True)
def _nearest(x: float, y: float, landmarks: FloatArray, k: int) -> IntArray:
    """Indices of the ``k`` landmarks nearest to ``(x, y)``, nearest first (ties: lower index)."""
    n = landmarks.shape[0]
    count = min(k, n)
    best = np.empty(count, dtype=np.int64)
    best_d2 = np.empty(count)
    filled = 0
    for i in range(n):
        dx = landmarks[i, 0] - x
        dy = landmarks[i, 1] - y
        d2 = dx * dx + dy * dy
        if filled < count:
            pos = filled
            filled += 1
        elif d2 < best_d2[count - 1]:
            pos = count - 1
        else:
            continue
        while pos > 0 and best_d2[pos - 1] > d2:
            best_d2[pos] = best_d2[pos - 1]
            best[pos] = best[pos - 1]
            pos -= 1
        best_d2[pos] = d2
        best[pos] = i
    return best


@njit(cache=True)
def _landmark_features(
    x: float,
    y: float,
    theta: float,
    landmarks: FloatArray,
    nearest: IntArray,
    covs: FloatArray,
    k: int,
    diagonal: float,
    std_scale: float,
    chi2: float,
) -> tuple[Float32Array, Float32Array]:
    """``obs["landmarks"]`` (``k`` rows ``(forward, left, major, minor)``, flattened) and the mask."""
    features = np.zeros((k, 4), dtype=np.float32)
    mask = np.zeros(k, dtype=np.float32)
    c, s = np.cos(theta), np.sin(theta)
    for row in range(nearest.shape[0]):
        i = nearest[row]
        dx = landmarks[i, 0] - x
        dy = landmarks[i, 1] - y
        features[row, 0] = min(max((c * dx + s * dy) / diagonal, -1.0), 1.0)
        features[row, 1] = min(max((-s * dx + c * dy) / diagonal, -1.0), 1.0)
        # eigenvalues of the symmetric 2x2 covariance, closed form
        a, b, d = covs[row, 0, 0], covs[row, 0, 1], covs[row, 1, 1]
        mid = 0.5 * (a + d)
        radius = np.sqrt(max(0.25 * (a - d) * (a - d) + b * b, 0.0))
        features[row, 2] = min(np.sqrt(chi2 * max(mid + radius, 0.0)) / std_scale, 1.0)
        features[row, 3] = min(np.sqrt(chi2 * max(mid - radius, 0.0)) / std_scale, 1.0)
        mask[row] = 1.0
    return features.reshape(k * 4), mask


class BeliefEncoder:
    """Turns a filter's belief into the observation dictionary.

    Parameters
    ----------
    arena_size : float
        Side of the square arena (known to the robot), metres.
    sensor : RangeBearingSensor
        The robot's sensor (its range and field of view define the swept area).
    config : ObservationConfig
    """

    def __init__(self, arena_size: float, sensor: RangeBearingSensor, config: ObservationConfig) -> None:
        self.arena_size = float(arena_size)
        self.half_arena = 0.5 * self.arena_size
        self.sensor = sensor
        self.config = config
        cells = int(math.ceil(self.arena_size / config.coverage_resolution))
        self.coverage = np.zeros((cells, cells), dtype=np.uint8)
        k, size = config.nearest_landmarks, config.map_size
        self.observation_space = spaces.Dict(
            {
                "pose": spaces.Box(-1.0, 1.0, (len(POSE_FEATURES),), np.float32),
                # flat (K * 4,): stable-baselines3 expects 1-D vectors
                "landmarks": spaces.Box(-1.0, 1.0, (k * len(LANDMARK_FEATURES),), np.float32),
                "landmarks_mask": spaces.Box(0.0, 1.0, (k,), np.float32),
                # uint8 channel-first image, as stable-baselines3 expects of an image
                "belief_map": spaces.Box(0, 255, (len(MAP_CHANNELS), size, size), np.uint8),
            }
        )

    def reset(self) -> None:
        self.coverage[:] = 0

    def decoder(self) -> ObservationDecoder:
        """The inverse of this encoder: reads its observations in metres and radians."""
        return ObservationDecoder(self.arena_size, self.config)

    def sweep(self, pose: FloatArray) -> None:
        """Add what the sensor sees from the *estimated* ``pose`` to the swept area."""
        half_fov = 0.5 * self.sensor.fov if self.sensor.fov < 2.0 * math.pi else math.pi
        _sweep(self.coverage, self.config.coverage_resolution, self.half_arena,
               float(pose[0]), float(pose[1]), float(pose[2]), self.sensor.max_range, half_fov)  # fmt: skip

    def nearest(self, pose: FloatArray, landmarks: ArrayLike) -> NDArray[np.int64]:
        """State orders of the ``K`` mapped landmarks nearest to ``pose``, nearest first."""
        return _nearest(float(pose[0]), float(pose[1]), np.ascontiguousarray(landmarks), self.config.nearest_landmarks)

    def encode(self, filt: SlamFilter) -> dict[str, np.ndarray]:
        """The observation of ``filt``'s current belief.

        Also keeps the pose covariance it used in :attr:`pose_covariance`
        (the env's ``info["pose_nees_blanket"]`` reuses it).
        """
        config = self.config
        pose = filt.pose
        x, y, theta = float(pose[0]), float(pose[1]), float(pose[2])
        landmarks = filt.landmarks
        nearest = self.nearest(pose, landmarks)
        pose_cov, landmark_covs = filt.local_marginals_trusted(nearest)
        self.pose_covariance = pose_cov
        scale = config.std_scale
        pose_obs = np.empty(len(POSE_FEATURES), dtype=np.float32)
        pose_obs[0] = x / self.half_arena
        pose_obs[1] = y / self.half_arena
        pose_obs[2] = math.cos(theta)
        pose_obs[3] = math.sin(theta)
        pose_obs[4] = math.sqrt(max(pose_cov[0, 0], 0.0)) / scale
        pose_obs[5] = math.sqrt(max(pose_cov[1, 1], 0.0)) / scale
        pose_obs[6] = math.sqrt(max(pose_cov[2, 2], 0.0)) / math.pi
        np.clip(pose_obs, -1.0, 1.0, out=pose_obs)
        landmark_obs, mask = _landmark_features(
            x, y, theta, landmarks, nearest, landmark_covs, config.nearest_landmarks,
            self.arena_size * math.sqrt(2.0), scale, CHI2_2DOF_95,
        )  # fmt: skip
        confidence = 1.0 / (1.0 + filt.landmark_std() / scale)
        belief_map = np.empty((len(MAP_CHANNELS), config.map_size, config.map_size), dtype=np.uint8)
        _fill_belief_map(
            belief_map, self.coverage, config.coverage_resolution, self.half_arena,
            x, y, theta, config.map_size, config.map_extent, landmarks, confidence,
        )  # fmt: skip
        return {"pose": pose_obs, "landmarks": landmark_obs, "landmarks_mask": mask, "belief_map": belief_map}


# -- decoding: the inverse of BeliefEncoder -----------------------------------------------------------
#: ``diagonal / h`` of a square arena: the landmark offsets of ``obs["landmarks"]`` times this are in
#: units of ``h`` (half the arena side), like the position in ``obs["pose"]``.
DIAGONAL_OVER_HALF = 2.0 * math.sqrt(2.0)


def read_belief_map(observation: Mapping[str, np.ndarray] | np.ndarray) -> FloatArray:
    """``obs["belief_map"]`` as ``float64`` in ``[0, 1]``.

    Parameters
    ----------
    observation : dict or ndarray
        The observation dict or the map itself, single ``(3, H, H)`` or
        batched ``(n_envs, 3, H, H)``.

    Returns
    -------
    ndarray
        The ``uint8`` map divided by 255; a float map (already in ``[0, 1]``,
        the format before ``uint8``) only converted to ``float64``.
    """
    raw = np.asarray(observation["belief_map"] if isinstance(observation, Mapping) else observation)
    belief = np.asarray(raw, dtype=np.float64)
    if raw.dtype == np.uint8:
        belief /= 255.0
    return belief


def landmark_rows(observation: Mapping[str, np.ndarray] | np.ndarray, batched: bool = False) -> FloatArray:
    """``obs["landmarks"]`` as ``float64`` rows ``(forward, left, major, minor)``, still normalised.

    Parameters
    ----------
    observation : dict or ndarray
        The observation dict or the entry itself: flat ``(4K,)``, or with
        ``batched=True`` ``(n_envs, 4K)``; already-shaped rows come back
        unchanged.
    batched : bool
        Whether there is a leading ``n_envs`` axis.

    Returns
    -------
    ndarray
        ``(K, 4)``, or ``(n_envs, K, 4)``.
    """
    raw = observation["landmarks"] if isinstance(observation, Mapping) else observation
    rows = np.asarray(raw, dtype=np.float64)
    if batched:
        return rows.reshape(rows.shape[0], -1, 4)
    return rows.reshape(-1, 4)


@dataclass(frozen=True, eq=False)
class BeliefRaster:
    """Cell centres of ``obs["belief_map"]`` in metres, robot frame (heading up).

    Cell ``(i, j)`` has its centre ``forward = e − (i + ½)·c`` ahead of the
    robot and ``left = e − (j + ½)·c`` to its left (``e`` the map's
    half-width, ``c = 2e/H`` the cell size): row 0 is ahead, column 0 left.

    Attributes
    ----------
    size : int
        ``H``.
    extent : float
        ``e``, metres.
    cell : float
        ``c``, metres.
    forward, left, distance, bearing : ndarray, shape (H, H)
        Per cell: metres ahead, metres to the left, distance (m) and bearing
        (rad, left positive) of its centre.
    """

    size: int
    extent: float
    cell: float
    forward: FloatArray
    left: FloatArray
    distance: FloatArray
    bearing: FloatArray

    @classmethod
    def build(cls, size: int, extent: float) -> BeliefRaster:
        """The raster of a ``size × size`` map of half-width ``extent`` metres."""
        cell = 2.0 * extent / size
        centres = extent - (np.arange(size) + 0.5) * cell
        forward, left = np.meshgrid(centres, centres, indexing="ij")  # forward along rows, left along columns
        return cls(size, extent, cell, forward, left, np.hypot(forward, left), np.arctan2(left, forward))


@dataclass(frozen=True)
class ObservationDecoder:
    """The inverse of :class:`BeliefEncoder`: an observation read back in metres and radians.

    Build it from the encoder that made the observations
    (:meth:`BeliefEncoder.decoder`, or :meth:`from_env` for an env): the
    observation is normalised by the arena's size and the observation's
    configuration, so reading it with another env's numbers misplaces
    everything without an error.

    Parameters
    ----------
    arena_size : float
        Side of the square arena, metres.
    config : ObservationConfig
        The encoder's configuration.

    Notes
    -----
    The encoder clips to ``[-1, 1]`` (standard deviations and ellipse axes
    to ``[0, 1]``): a clipped entry decodes to its bound, the rest exactly
    up to ``float32`` rounding. Positions come in two units: metres
    (:meth:`pose`, :meth:`landmarks`) and the observation's own units of
    ``h``, half the arena side (``obs["pose"][:2]``, and
    :data:`DIAGONAL_OVER_HALF` times the landmark offsets).
    """

    arena_size: float
    config: ObservationConfig = ObservationConfig()

    def __post_init__(self) -> None:
        size = as_positive_scalar(self.arena_size, "arena_size")
        if not isinstance(self.config, ObservationConfig):
            raise TypeError(f"config must be an ObservationConfig, got {type(self.config).__name__}")
        object.__setattr__(self, "arena_size", size)

    @classmethod
    def from_env(cls, env: object) -> ObservationDecoder:
        """The decoder of ``env``'s encoder (``env.unwrapped.encoder``).

        Raises
        ------
        TypeError
            If ``env`` is ``None`` or has no :class:`BeliefEncoder` (not a
            ``SeifExplore`` env).
        """
        if env is None:
            raise TypeError("env must be a SeifExplore env, got None")
        encoder = getattr(getattr(env, "unwrapped", env), "encoder", None)
        if not isinstance(encoder, BeliefEncoder):
            raise TypeError(f"env must be a SeifExplore env (with a BeliefEncoder), got {type(env).__name__}")
        return encoder.decoder()

    # -- geometry --------------------------------------------------------------------------------
    @property
    def half_arena(self) -> float:
        """``h``, half the arena side, metres."""
        return 0.5 * self.arena_size

    @property
    def diagonal(self) -> float:
        """The arena's diagonal, metres: the landmark offsets' divisor."""
        return self.arena_size * math.sqrt(2.0)

    @property
    def map_extent(self) -> float:
        """Half-width of ``obs["belief_map"]``, metres."""
        return float(self.config.map_extent)

    @property
    def std_scale(self) -> float:
        """Divisor of the standard deviations and ellipse axes."""
        return float(self.config.std_scale)

    def raster(self) -> BeliefRaster:
        """Cell centres of this encoder's belief map."""
        return BeliefRaster.build(self.config.map_size, self.map_extent)

    # -- reading -----------------------------------------------------------------------------------
    def check(self, observation: Mapping[str, np.ndarray], batched: bool = False) -> None:
        """Raise ``ValueError`` naming the entry whose shape this encoder does not make.

        Parameters
        ----------
        observation : dict
            One observation (or a batch, with ``batched=True``).
        batched : bool
            Whether the entries have a leading ``n_envs`` axis.
        """
        if not isinstance(observation, Mapping):
            raise TypeError(f"observation must be the env's dict observation, got {type(observation).__name__}")
        k, size = self.config.nearest_landmarks, self.config.map_size
        expected = {"pose": (len(POSE_FEATURES),), "landmarks": (len(LANDMARK_FEATURES) * k,),
                    "landmarks_mask": (k,), "belief_map": (len(MAP_CHANNELS), size, size)}  # fmt: skip
        for key, shape in expected.items():
            if key not in observation:
                raise ValueError(f"observation has no {key!r} entry")
            actual = np.shape(observation[key])[1:] if batched else np.shape(observation[key])
            if tuple(actual) != shape:
                raise ValueError(f"observation[{key!r}] has shape {tuple(actual)}, but this encoder makes {shape}: "
                                 "an observation of another env?")  # fmt: skip

    def pose(self, observation: Mapping[str, np.ndarray]) -> FloatArray:
        """``(x, y, theta, σx, σy, σθ)`` of the estimated pose: metres and radians (shape (6,)).

        ``theta`` is ``atan2(sin θ, cos θ)``, in ``[-π, π]``.
        """
        self.check(observation)
        p = np.asarray(observation["pose"], dtype=np.float64)
        half, scale = self.half_arena, self.std_scale
        return np.array([p[0] * half, p[1] * half, math.atan2(p[3], p[2]), p[4] * scale, p[5] * scale, p[6] * math.pi])

    def landmarks(self, observation: Mapping[str, np.ndarray]) -> tuple[FloatArray, NDArray[np.bool_]]:
        """The ``K`` listed landmarks in metres, and which rows hold one.

        Returns
        -------
        rows : ndarray, shape (K, 4)
            ``(forward, left, major, minor)``: the offset in the robot frame
            and the semi-axes of the 95 % ellipse (``sqrt(χ²₀.₉₅ · λ)`` of
            the covariance's eigenvalues ``λ``), metres; zeros in empty rows.
        mask : ndarray of bool, shape (K,)
        """
        self.check(observation)
        rows = landmark_rows(observation)
        metres = np.empty_like(rows)
        metres[:, :2] = rows[:, :2] * self.diagonal
        metres[:, 2:] = rows[:, 2:] * self.std_scale
        return metres, np.asarray(observation["landmarks_mask"]) > 0.5

    def landmark_positions(self, observation: Mapping[str, np.ndarray]) -> FloatArray:
        """World positions (metres) of the listed landmarks, from the estimated pose: shape (m, 2), nearest first."""
        x, y, theta = self.pose(observation)[:3]
        rows, mask = self.landmarks(observation)
        c, s = math.cos(theta), math.sin(theta)
        forward, left = rows[mask, 0], rows[mask, 1]
        return np.stack([x + c * forward - s * left, y + s * forward + c * left], axis=1)

    def belief_map(self, observation: Mapping[str, np.ndarray]) -> FloatArray:
        """``obs["belief_map"]`` as floats in ``[0, 1]`` (:func:`read_belief_map`), shape checked."""
        self.check(observation)
        return read_belief_map(observation)


@njit(cache=True)
def encode_env(e: int, coverage: UInt8Array, resolution: float, half_arena: float, max_range: float, half_fov: float,
               map_size: int, map_extent: float, nearest_landmarks: int, diagonal: float, std_scale: float,
               robot_info: FloatArray, robot_links: FloatArray, landmark_info: FloatArray, neighbour_index: IntArray,
               neighbour_info: FloatArray, neighbour_count: IntArray, information_vector: FloatArray,
               mean: FloatArray, block_position: IntArray, active: IntArray, counters: IntArray,
               pose_out: Float32Array, landmarks_out: Float32Array, mask_out: Float32Array, map_out: UInt8Array,
               pose_covariance_out: FloatArray) -> None:  # fmt: skip
    """:meth:`BeliefEncoder.sweep` then :meth:`BeliefEncoder.encode` of SEIF ``e`` of a batch (``BatchedSEIF`` arrays).

    Writes its observation into row ``e`` of ``pose_out`` (N, 7), ``landmarks_out`` (N, 4K),
    ``mask_out`` (N, K), ``map_out`` (N, 3, H, W) and the Markov-blanket pose covariance
    it used into ``pose_covariance_out[e]`` (3, 3), with the same kernels and operations
    as the single encoder.
    """
    x = mean[e, 0]
    y = mean[e, 1]
    theta = mean[e, 2]
    _sweep(coverage[e], resolution, half_arena, x, y, theta, max_range, half_fov)
    n = counters[e, 0]
    landmarks = mean[e, 3 : 3 + 2 * n].reshape(n, 2)
    nearest = _nearest(x, y, landmarks, nearest_landmarks)
    act = active[e, : counters[e, 1]]
    nodes = blanket_nodes(act, nearest, block_position[e])
    pose_cov, covs = blanket_covariances(robot_info[e], robot_links[e], landmark_info[e], neighbour_index[e],
                                         neighbour_info[e], neighbour_count[e], information_vector[e], mean[e],
                                         block_position[e], nodes, nearest)  # fmt: skip
    pose_covariance_out[e] = pose_cov
    pose_out[e, 0] = x / half_arena
    pose_out[e, 1] = y / half_arena
    pose_out[e, 2] = np.cos(theta)
    pose_out[e, 3] = np.sin(theta)
    pose_out[e, 4] = np.sqrt(max(pose_cov[0, 0], 0.0)) / std_scale
    pose_out[e, 5] = np.sqrt(max(pose_cov[1, 1], 0.0)) / std_scale
    pose_out[e, 6] = np.sqrt(max(pose_cov[2, 2], 0.0)) / np.pi
    for a in range(7):
        pose_out[e, a] = min(max(pose_out[e, a], np.float32(-1.0)), np.float32(1.0))
    features, mask = _landmark_features(x, y, theta, landmarks, nearest, covs, nearest_landmarks, diagonal,
                                        std_scale, CHI2_2DOF_95)  # fmt: skip
    landmarks_out[e] = features
    mask_out[e] = mask
    std = conditional_std(landmark_info[e], n)
    confidence = np.empty(n)
    for i in range(n):
        confidence[i] = 1.0 / (1.0 + std[i] / std_scale)
    _fill_belief_map(map_out[e], coverage[e], resolution, half_arena, x, y, theta, map_size, map_extent, landmarks,
                     confidence)  # fmt: skip


@njit(cache=True)
def encode_many(*arguments: Any) -> None:
    """:func:`encode_env` of every SEIF of a batch, one after another.

    ``arguments``: those of :func:`encode_env` after ``e`` (the first one has the env axis).
    """
    for e in range(arguments[0].shape[0]):
        encode_env(e, *arguments)
