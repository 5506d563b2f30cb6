"""Belief -> observation: what an agent of ``SeifExplore-v0`` sees.

Everything here is computed from the filter's belief (its estimated pose and
map, and their uncertainty) and from what the robot itself knows (the arena's
size, its sensor). Nothing reads the true state: an encoder is never handed
the world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from gymnasium import spaces
from numba import njit, prange
from numpy.typing import NDArray

from seif_gym.slam._kernels import blanket_covariances, blanket_nodes, conditional_std
from seif_gym.slam.base import SlamFilter
from seif_gym.slam.models import RangeBearingSensor

__all__ = ["ObservationConfig", "BeliefEncoder", "POSE_FEATURES", "LANDMARK_FEATURES", "MAP_CHANNELS"]

FloatArray = NDArray[np.float64]

#: Entries of ``obs["pose"]``.
POSE_FEATURES = ("x", "y", "cos_theta", "sin_theta", "std_x", "std_y", "std_theta")
#: Columns of ``obs["landmarks"]``.
LANDMARK_FEATURES = ("forward", "left", "major_axis_95", "minor_axis_95")
#: Channels of ``obs["belief_map"]``.
MAP_CHANNELS = ("swept", "landmarks", "outside_arena")

#: 95% quantile of the chi-square distribution with 2 degrees of freedom.
CHI2_2DOF_95 = 5.991464547107979


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
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        for name in ("map_extent", "coverage_resolution", "std_scale"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be a positive number, got {value!r}")


@njit(cache=True)
def _sweep(coverage, resolution, half_arena, x, y, theta, max_range, half_fov):
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
def _belief_map(coverage, resolution, half_arena, x, y, theta, size, extent, landmarks, confidence):
    """The (3, size, size) uint8 egocentric raster (0..255); row 0 is ahead, column 0 is left."""
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
    return out


@njit(cache=True)
def _nearest(x, y, landmarks, k):
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
def _landmark_features(x, y, theta, landmarks, nearest, covs, k, diagonal, std_scale, chi2):
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

    def sweep(self, pose: FloatArray) -> None:
        """Add what the sensor sees from the *estimated* ``pose`` to the swept area."""
        half_fov = 0.5 * self.sensor.fov if self.sensor.fov < 2.0 * math.pi else math.pi
        _sweep(self.coverage, self.config.coverage_resolution, self.half_arena,
               float(pose[0]), float(pose[1]), float(pose[2]), self.sensor.max_range, half_fov)  # fmt: skip

    def nearest(self, pose: FloatArray, landmarks: FloatArray) -> NDArray[np.int64]:
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
        belief_map = _belief_map(
            self.coverage, config.coverage_resolution, self.half_arena,
            x, y, theta, config.map_size, config.map_extent, landmarks, confidence,
        )  # fmt: skip
        return {"pose": pose_obs, "landmarks": landmark_obs, "landmarks_mask": mask, "belief_map": belief_map}


@njit(cache=True, parallel=True)
def encode_many(coverage, resolution, half_arena, max_range, half_fov, map_size, map_extent, nearest_landmarks,
                diagonal, std_scale, robot_info, robot_links, landmark_info, neighbour_index, neighbour_info,
                neighbour_count, information_vector, mean, block_position, active, counters,
                pose_out, landmarks_out, mask_out, map_out, pose_covariance_out):  # fmt: skip
    """:meth:`BeliefEncoder.sweep` then :meth:`BeliefEncoder.encode` of a batch of SEIFs (``BatchedSEIF`` arrays).

    Writes each filter's observation into ``pose_out`` (N, 7), ``landmarks_out`` (N, 4K),
    ``mask_out`` (N, K), ``map_out`` (N, 3, H, W) and the Markov-blanket pose covariance
    it used into ``pose_covariance_out`` (N, 3, 3), with the same kernels and operations
    as the single encoder.
    """
    for e in prange(mean.shape[0]):
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
        map_out[e] = _belief_map(coverage[e], resolution, half_arena, x, y, theta, map_size, map_extent, landmarks,
                                 confidence)  # fmt: skip
