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
from numba import njit
from numpy.typing import NDArray

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
        Side ``H = W`` of the egocentric ``belief_map`` raster, cells.
    map_extent : float
        Half-width of the raster, metres (the raster covers
        ``[-e, e]^2`` around the estimated pose, heading up).
    coverage_resolution : float
        Cell size of the swept-area grid kept over the arena, metres.
    std_scale : float
        Standard deviations are divided by this (and clipped to 1).
    """

    nearest_landmarks: int = 8
    map_size: int = 32
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
    """The (3, size, size) egocentric raster; row 0 is ahead, column 0 is left."""
    out = np.zeros((3, size, size), dtype=np.float32)
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
                out[2, i, j] = 1.0
                continue
            gi = min(int((wx + half_arena) / resolution), cells - 1)
            gj = min(int((wy + half_arena) / resolution), cells - 1)
            out[0, i, j] = coverage[gi, gj]
    for k in range(landmarks.shape[0]):
        dx = landmarks[k, 0] - x
        dy = landmarks[k, 1] - y
        forward = c * dx + s * dy
        left = -s * dx + c * dy
        i = int((extent - forward) / step)
        j = int((extent - left) / step)
        if 0 <= i < size and 0 <= j < size and forward <= extent and left <= extent:
            if confidence[k] > out[1, i, j]:
                out[1, i, j] = confidence[k]
    return out


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
                "landmarks": spaces.Box(-1.0, 1.0, (k, len(LANDMARK_FEATURES)), np.float32),
                "landmarks_mask": spaces.Box(0.0, 1.0, (k,), np.float32),
                "belief_map": spaces.Box(0.0, 1.0, (len(MAP_CHANNELS), size, size), np.float32),
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
        if len(landmarks) == 0:
            return np.empty(0, dtype=np.int64)
        d2 = np.einsum("ij,ij->i", landmarks - pose[:2], landmarks - pose[:2])
        k = self.config.nearest_landmarks
        if len(d2) > k:
            candidates = np.argpartition(d2, k - 1)[:k]
            return candidates[np.argsort(d2[candidates], kind="stable")]
        return np.argsort(d2, kind="stable")

    def encode(self, filt: SlamFilter) -> dict[str, np.ndarray]:
        """The observation of ``filt``'s current belief."""
        config = self.config
        pose = filt.pose
        landmarks = filt.landmarks
        nearest = self.nearest(pose, landmarks)
        pose_cov, landmark_covs = filt.local_marginals(nearest)
        scale = config.std_scale
        c, s = math.cos(pose[2]), math.sin(pose[2])
        pose_obs = np.array(
            [
                pose[0] / self.half_arena,
                pose[1] / self.half_arena,
                c,
                s,
                math.sqrt(max(pose_cov[0, 0], 0.0)) / scale,
                math.sqrt(max(pose_cov[1, 1], 0.0)) / scale,
                math.sqrt(max(pose_cov[2, 2], 0.0)) / math.pi,
            ],
            dtype=np.float32,
        )
        k = config.nearest_landmarks
        landmark_obs = np.zeros((k, len(LANDMARK_FEATURES)), dtype=np.float32)
        mask = np.zeros(k, dtype=np.float32)
        count = len(nearest)
        if count:
            d = landmarks[nearest] - pose[:2]
            diagonal = self.arena_size * math.sqrt(2.0)
            landmark_obs[:count, 0] = (c * d[:, 0] + s * d[:, 1]) / diagonal
            landmark_obs[:count, 1] = (-s * d[:, 0] + c * d[:, 1]) / diagonal
            eigenvalues = np.linalg.eigvalsh(landmark_covs)  # ascending
            axes = np.sqrt(CHI2_2DOF_95 * np.maximum(eigenvalues, 0.0)) / scale
            landmark_obs[:count, 2] = axes[:, 1]
            landmark_obs[:count, 3] = axes[:, 0]
            mask[:count] = 1.0
        confidence = 1.0 / (1.0 + filt.landmark_std() / scale) if len(landmarks) else np.empty(0)
        belief_map = _belief_map(
            self.coverage, config.coverage_resolution, self.half_arena,
            float(pose[0]), float(pose[1]), float(pose[2]), config.map_size, config.map_extent,
            landmarks, confidence,
        )  # fmt: skip
        return {
            "pose": np.clip(pose_obs, -1.0, 1.0),
            "landmarks": np.clip(landmark_obs, -1.0, 1.0),
            "landmarks_mask": mask,
            "belief_map": belief_map,
        }
