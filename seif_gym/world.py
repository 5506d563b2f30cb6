"""The simulated world: a bounded arena, its landmarks and the true robot.

The world knows the truth and nothing of the filter. It moves the true
robot with :meth:`VelocityMotionModel.sample` and measures the landmarks with
:meth:`RangeBearingSensor.sample`, each from its own seeded generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from seif_gym.slam._kernels import _wrap_float
from seif_gym.slam.models import RangeBearingSensor, VelocityMotionModel, _visible_measurements, wrap_angle
from seif_gym.slam.noise_models import PerSecondVelocityMotionModel
from seif_gym.type_aliases import FloatArray
from seif_gym.validation import as_count

__all__ = ["LAYOUTS", "MAX_ARENA_SIZE", "WorldConfig", "World", "BatchedWorld", "make_landmarks"]


#: Landmark layouts that :func:`make_landmarks` generates; ``"fixed"`` (the given ``landmark_positions``) is the other.
LAYOUTS = ("uniform", "clustered", "loop")

#: Largest ``arena_size`` (metres) a :class:`WorldConfig` accepts: the env's coverage grid has
#: ``(arena_size / coverage_resolution)^2`` cells, so the side bounds its memory.
MAX_ARENA_SIZE = 1000.0


@dataclass(frozen=True)
class WorldConfig:
    """The arena and its landmarks.

    Attributes
    ----------
    arena_size : float
        Side of the square arena ``[-s/2, s/2]^2``, metres (the frame of the
        observation and the rendering).
    layout : {"uniform", "clustered", "loop", "fixed"}
        How landmarks are placed (see :func:`make_landmarks`).
    num_landmarks : int
        Number of landmarks.
    wall_margin : float
        Landmarks keep this distance from the walls.
    arena_extent : (float, float) or None
        ``(width, height)`` of the walled area, centred in the square, each
        at most ``arena_size``; ``None``: the walls are the square's.
    landmark_positions : tuple of (x, y) or None
        With ``layout="fixed"``: the landmarks, ``num_landmarks`` of them,
        inside the walls.
    """

    arena_size: float = 20.0
    layout: str = "uniform"
    num_landmarks: int = 30
    wall_margin: float = 1.0
    arena_extent: tuple[float, ...] | None = None
    landmark_positions: tuple[tuple[float, ...], ...] | None = None

    def __post_init__(self) -> None:
        if isinstance(self.arena_size, bool) or not isinstance(self.arena_size, (int, float, np.integer)):
            raise TypeError(f"arena_size must be a real number, got {type(self.arena_size).__name__}")
        if not (math.isfinite(self.arena_size) and 0 < self.arena_size <= MAX_ARENA_SIZE):
            raise ValueError(
                f"arena_size must be a positive number of at most {MAX_ARENA_SIZE} m, got {self.arena_size!r}"
            )
        if self.layout not in (*LAYOUTS, "fixed"):
            raise ValueError(f"layout must be one of {(*LAYOUTS, 'fixed')}, got {self.layout!r}")
        if isinstance(self.num_landmarks, bool) or not isinstance(self.num_landmarks, (int, np.integer)):
            raise TypeError(f"num_landmarks must be an int, got {type(self.num_landmarks).__name__}")
        if not 1 <= self.num_landmarks <= 10_000:
            raise ValueError(f"num_landmarks must be in [1, 10000], got {self.num_landmarks}")
        if not (
            isinstance(self.wall_margin, (int, float)) and math.isfinite(self.wall_margin) and self.wall_margin >= 0
        ):
            raise ValueError(f"wall_margin must be a non-negative number, got {self.wall_margin!r}")
        if not self.wall_margin < self.arena_size / 4:
            raise ValueError(
                f"arena_size must be more than 4 * wall_margin = {4 * self.wall_margin} m (the landmarks keep "
                f"wall_margin from each wall and the robot starts in the middle half), got {self.arena_size!r}"
            )
        if self.arena_extent is not None:
            extent = _float_tuple(self.arena_extent, "arena_extent")
            if len(extent) != 2 or not all(0 < side <= self.arena_size for side in extent):
                raise ValueError(
                    f"arena_extent must be (width, height), each in (0, arena_size], got {self.arena_extent!r}"
                )
            object.__setattr__(self, "arena_extent", extent)
            if self.layout in ("clustered", "loop"):
                raise ValueError(f"layout {self.layout!r} needs a square arena (arena_extent=None)")
        if (self.layout == "fixed") != (self.landmark_positions is not None):
            raise ValueError("landmark_positions must be given with layout='fixed', and only then")
        if self.landmark_positions is not None:
            try:
                points = np.array(self.landmark_positions, dtype=np.float64)
            except (TypeError, ValueError):
                points = np.empty(0)
            hx, hy = self.half_extent
            if points.shape != (self.num_landmarks, 2) or not np.all(np.isfinite(points)):
                raise ValueError(f"landmark_positions must be num_landmarks = {self.num_landmarks} pairs (x, y), "
                                 f"got shape {points.shape}")  # fmt: skip
            if np.any(np.abs(points[:, 0]) > hx) or np.any(np.abs(points[:, 1]) > hy):
                raise ValueError("landmark_positions must lie inside the walls")
            object.__setattr__(self, "landmark_positions", tuple(tuple(float(v) for v in p) for p in points))

    @property
    def half_size(self) -> float:
        """Half the side of the square frame."""
        return 0.5 * float(self.arena_size)

    @property
    def half_extent(self) -> tuple[float, float]:
        """``(half width, half height)`` of the walled area."""
        if self.arena_extent is None:
            return self.half_size, self.half_size
        return 0.5 * float(self.arena_extent[0]), 0.5 * float(self.arena_extent[1])


def _float_tuple(values: object, name: str) -> tuple[float, ...]:
    try:
        array = np.asarray(values, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be numbers, got {values!r}") from None
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite, got {values!r}")
    return tuple(float(v) for v in array)


def make_landmarks(config: WorldConfig, rng: np.random.Generator) -> FloatArray:
    """Landmark positions (n, 2) for ``config.layout``.

    * ``"uniform"``: uniform over the arena (inside the wall margin).
    * ``"clustered"``: 3 to 5 Gaussian clusters (std 1/12 of the arena),
      so that the space between clusters has nothing to see.
    * ``"loop"``: along a ring of radius 0.35 arena sizes with a radial
      jitter of 0.05 arena sizes; driving around it closes a loop.
    * ``"fixed"``: ``config.landmark_positions`` (no draw).

    With walls narrower than the square (``arena_extent``) ``"uniform"``
    fills the walled area; ``"clustered"`` and ``"loop"`` need the square.
    """
    n = config.num_landmarks
    if config.layout == "fixed":
        return np.array(config.landmark_positions, dtype=np.float64)
    if config.arena_extent is not None:
        if config.layout != "uniform":
            raise ValueError(f"layout {config.layout!r} needs a square arena (arena_extent=None)")
        hx, hy = (half - config.wall_margin for half in config.half_extent)
        return rng.uniform((-hx, -hy), (hx, hy), size=(n, 2))
    h = config.half_size - config.wall_margin
    if config.layout == "uniform":
        return rng.uniform(-h, h, size=(n, 2))
    if config.layout == "clustered":
        num_clusters = int(rng.integers(3, 6))
        centres = rng.uniform(-0.7 * h, 0.7 * h, size=(num_clusters, 2))
        members = rng.integers(0, num_clusters, size=n)
        points = centres[members] + rng.normal(0.0, config.arena_size / 12.0, size=(n, 2))
        return np.clip(points, -h, h)
    # loop
    angles = rng.uniform(0.0, 2.0 * math.pi, size=n)
    radii = 0.35 * config.arena_size + rng.normal(0.0, 0.05 * config.arena_size, size=n)
    points = np.column_stack([radii * np.cos(angles), radii * np.sin(angles)])
    return np.clip(points, -h, h)


class World:
    """True state of one episode: landmarks and robot pose in the arena.

    At the wall the robot's translation is blocked: a step whose noise-free
    motion would leave the arena is executed as a turn in place
    (``v = 0``, same ``omega``); the executed control is what odometry
    reports to the filter, and the step is flagged as a wall contact. Motion
    noise can still push the robot by a hair past the wall; its position is
    then clamped onto the wall.
    """

    def __init__(
        self,
        config: WorldConfig,
        motion: VelocityMotionModel | PerSecondVelocityMotionModel,
        sensor: RangeBearingSensor,
        landmarks: ArrayLike,
        initial_pose: ArrayLike,
        range_error_memory: float = 0.0,
    ) -> None:
        self.config = config
        self.motion = motion
        self.sensor = sensor
        self.landmarks = np.asarray(landmarks, dtype=np.float64)
        self.landmarks.setflags(write=False)
        self.pose = np.asarray(initial_pose, dtype=np.float64).copy()
        if not (isinstance(range_error_memory, (int, float)) and 0.0 <= range_error_memory < 1.0):
            raise ValueError(f"range_error_memory must be in [0, 1), got {range_error_memory!r}")
        # rho of each landmark's unit range error u_i (an AR(1) sampled once per measure(): an
        # Ornstein-Uhlenbeck process at the env's step); 0: white errors, drawn by the sensor
        self.range_error_memory = float(range_error_memory)
        self._unit_range_errors: FloatArray | None = None

    def inside(self, position: FloatArray) -> bool:
        hx, hy = self.config.half_extent
        x, y = float(position[0]), float(position[1])
        return -hx <= x <= hx and -hy <= y <= hy

    def step(self, control: ArrayLike, dt: float, rng: np.random.Generator) -> tuple[FloatArray, bool]:
        """Move the robot; returns the executed control and whether it hit the wall."""
        # inputs come validated from the env: the models' unchecked paths are used
        executed = np.asarray(control, dtype=np.float64)
        hit_wall = not self.inside(self.motion.predict_trusted(self.pose, executed, dt))
        if hit_wall:
            executed = np.array([0.0, executed[1]])
        pose = self.motion.sample_trusted(self.pose, executed, dt, rng)
        hx, hy = self.config.half_extent
        pose[0] = min(max(pose[0], -hx), hx)
        pose[1] = min(max(pose[1], -hy), hy)
        pose[2] = wrap_angle(float(pose[2]))
        self.pose = pose
        return executed, hit_wall

    def measure(self, rng: np.random.Generator) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
        """Noisy ``(ranges, bearings, ids)`` of the visible landmarks.

        With ``range_error_memory`` ``rho > 0`` each landmark's range error is
        ``sigma_r(r) u_i`` with ``u_i`` a stationary unit-variance AR(1)
        process advanced at every call (all landmarks, seen or not):
        ``u_i <- rho u_i + sqrt(1 - rho^2) xi_i``, started from ``N(0, 1)``.
        """
        if self.range_error_memory == 0.0:
            return self.sensor.sample_trusted(self.pose, self.landmarks, rng)
        count = len(self.landmarks)
        if self._unit_range_errors is None:
            self._unit_range_errors = rng.standard_normal(count)
        else:
            rho = self.range_error_memory
            self._unit_range_errors = rho * self._unit_range_errors + math.sqrt(1.0 - rho * rho) * rng.standard_normal(
                count
            )
        return self.sensor.sample_with_range_errors(self.pose, self.landmarks, self._unit_range_errors, rng)


# -- many worlds in one call (the native vector env) -------------------------------------------------
@njit(cache=True)
def _displacement(theta: float, v: float, w: float, dt: float) -> tuple[float, float, float]:
    """``VelocityMotionModel._displacement`` (same operations)."""
    half = 0.5 * w * dt
    if abs(half) < 1e-4:
        a2 = half * half
        sinc = 1.0 - a2 / 6.0 + a2 * a2 / 120.0
    else:
        sinc = np.sin(half) / half
    mid = theta + half
    return v * dt * np.cos(mid) * sinc, v * dt * np.sin(mid) * sinc, w * dt


@njit(cache=True)
def _any_at_least(values: NDArray[np.int64], bound: int) -> bool:
    """Whether some entry of ``values`` is ``>= bound`` (one call where numpy takes several)."""
    for value in values:
        if value >= bound:
            return True
    return False


@njit(cache=True)
def _step_worlds(
    poses: FloatArray,
    controls: FloatArray,
    dt: float,
    alphas: FloatArray,
    half_size: float,
    noise: FloatArray,
    cursor: NDArray[np.int64],
    executed: FloatArray,
    wall: NDArray[np.bool_],
) -> None:
    """:meth:`World.step` of every world ``e``, its motion noise read from ``noise[e, cursor[e]:]``."""
    for e in range(poses.shape[0]):
        x, y, theta = poses[e, 0], poses[e, 1], poses[e, 2]
        v, w = controls[e, 0], controls[e, 1]
        dx, dy, _ = _displacement(theta, v, w, dt)
        px, py = x + dx, y + dy
        hit = not (-half_size <= px <= half_size and -half_size <= py <= half_size)
        if hit:
            v = 0.0
        executed[e, 0], executed[e, 1] = v, w
        wall[e] = hit
        c = cursor[e]
        vv, ww = v * v, w * w
        v_hat = v + np.sqrt(alphas[0] * vv + alphas[1] * ww) * noise[e, c]
        w_hat = w + np.sqrt(alphas[2] * vv + alphas[3] * ww) * noise[e, c + 1]
        gamma = np.sqrt(alphas[4] * vv + alphas[5] * ww) * noise[e, c + 2]
        cursor[e] = c + 3
        dx, dy, dth = _displacement(theta, v_hat, w_hat, dt)
        heading = _wrap_float(theta + dth + gamma * dt)
        poses[e, 0] = min(max(x + dx, -half_size), half_size)
        poses[e, 1] = min(max(y + dy, -half_size), half_size)
        poses[e, 2] = _wrap_float(heading)


@njit(cache=True)
def _measure_worlds(poses: FloatArray, landmarks: FloatArray, max_range: float, half_fov: float, min_range: float,
                    sigma_range: float, sigma_bearing: float, noise: FloatArray, cursor: NDArray[np.int64],
                    ranges: FloatArray, bearings: FloatArray, ids: NDArray[np.int64],
                    counts: NDArray[np.int64]) -> None:  # fmt: skip
    """:meth:`World.measure` of every world, its sensor noise read from ``noise[e, cursor[e]:]``."""
    for e in range(poses.shape[0]):
        visible, z = _visible_measurements(poses[e, 0], poses[e, 1], poses[e, 2], landmarks[e], max_range, half_fov,
                                           min_range)  # fmt: skip
        c = cursor[e]
        m = visible.shape[0]
        for k in range(m):
            ranges[e, k] = abs(z[k, 0] + noise[e, c + 2 * k] * sigma_range)
            bearings[e, k] = (z[k, 1] + noise[e, c + 2 * k + 1] * sigma_bearing + np.pi) % (2.0 * np.pi) - np.pi
            ids[e, k] = visible[k]
        counts[e] = m
        cursor[e] = c + 2 * m


class _NormalStream:
    """Standard normals of one generator per world, drawn ahead into a buffer.

    A generator's normals do not depend on how the draws are chunked, so
    reading them from a buffer gives exactly what drawing them one call at a
    time gives; only the refill (once every ``size / need`` steps) calls the
    generators, one Python call per world that runs low.
    """

    def __init__(self, count: int, size: int) -> None:
        self.values = np.zeros((count, size))
        self.cursor = np.full(count, size, dtype=np.int64)
        self.generators: list[np.random.Generator | None] = [None] * count

    def reset(self, index: int, rng: np.random.Generator) -> None:
        self.generators[index] = rng
        self.values[index] = rng.standard_normal(self.values.shape[1])
        self.cursor[index] = 0

    def reserve(self, need: int) -> None:
        """Make sure every world has ``need`` unread normals."""
        size = self.values.shape[1]
        if not _any_at_least(self.cursor, size - need + 1):
            return  # the common case, checked in one compiled call
        for e in np.flatnonzero(self.cursor + need > size).tolist():
            rng = self.generators[e]
            if rng is None:
                raise RuntimeError(f"world {e} was not reset")
            left = size - int(self.cursor[e])
            self.values[e, :left] = self.values[e, size - left :]
            self.values[e, left:] = rng.standard_normal(size - left)
            self.cursor[e] = 0


class BatchedWorld:
    """:class:`World` times ``num_worlds``, stepped and measured by compiled kernels.

    Every world ``e`` computes exactly what a :class:`World` with the same
    landmarks, start and generators computes (``tests/env/test_world.py``). The
    motion and sensor noise come from each world's own generators, drawn
    ahead (:class:`_NormalStream`).

    Parameters
    ----------
    num_worlds : int
        Worlds in the batch.
    config : WorldConfig
        Arena and landmark count of every world.
    motion : VelocityMotionModel
        True motion model.
    sensor : RangeBearingSensor
        True sensor.
    buffer : int
        Normals drawn ahead per world and stream.
    """

    def __init__(self, num_worlds: int, config: WorldConfig, motion: VelocityMotionModel, sensor: RangeBearingSensor,
                 buffer: int = 4096) -> None:  # fmt: skip
        as_count(num_worlds, "num_worlds", minimum=1)
        as_count(buffer, "buffer", minimum=2 * config.num_landmarks + 3)
        self.config, self.motion, self.sensor = config, motion, sensor
        n, m = int(num_worlds), config.num_landmarks
        self.num_worlds = n
        self.poses = np.zeros((n, 3))
        self.landmarks = np.zeros((n, m, 2))
        self._alphas = np.array(motion.alphas, dtype=np.float64)
        self._motion_noise = _NormalStream(n, int(buffer))
        self._sensor_noise = _NormalStream(n, int(buffer))
        self.executed = np.zeros((n, 2))
        self.wall = np.zeros(n, dtype=bool)
        self.ranges = np.zeros((n, m))
        self.bearings = np.zeros((n, m))
        self.ids = np.zeros((n, m), dtype=np.int64)
        self.counts = np.zeros(n, dtype=np.int64)

    def reset(self, index: int, landmarks: ArrayLike, pose: ArrayLike, motion_rng: np.random.Generator,
              sensor_rng: np.random.Generator) -> None:  # fmt: skip
        """Start world ``index`` with these landmarks, true pose and noise generators."""
        self.landmarks[index] = landmarks
        self.poses[index] = pose
        self._motion_noise.reset(index, motion_rng)
        self._sensor_noise.reset(index, sensor_rng)

    def step(self, controls: ArrayLike, dt: float) -> tuple[FloatArray, NDArray[np.bool_]]:
        """Move every robot (valid ``controls``, shape (N, 2)); the executed controls and the wall contacts."""
        self._motion_noise.reserve(3)
        noise = self._motion_noise
        _step_worlds(self.poses, np.ascontiguousarray(controls, dtype=np.float64), float(dt), self._alphas,
                     self.config.half_size, noise.values, noise.cursor, self.executed, self.wall)  # fmt: skip
        return self.executed, self.wall

    def measure(self) -> tuple[FloatArray, FloatArray, NDArray[np.int64], NDArray[np.int64]]:
        """Noisy measurements of every world: ``ranges, bearings, ids`` (N, L), valid up to ``counts`` (N,)."""
        self._sensor_noise.reserve(2 * self.config.num_landmarks)
        noise, sensor = self._sensor_noise, self.sensor
        _measure_worlds(self.poses, self.landmarks, sensor.max_range, 0.5 * sensor.fov, sensor.min_range,
                        sensor.sigma_range, sensor.sigma_bearing, noise.values, noise.cursor, self.ranges, self.bearings, self.ids,
                        self.counts)  # fmt: skip
        return self.ranges, self.bearings, self.ids, self.counts
