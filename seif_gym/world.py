"""The simulated world: a bounded arena, its landmarks and the true robot.

The world knows the truth and nothing of the filter. It moves the true
robot with :meth:`VelocityMotionModel.sample` and measures the landmarks with
:meth:`RangeBearingSensor.sample`, each from its own seeded generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from seif_gym.slam.models import RangeBearingSensor, VelocityMotionModel, wrap_angle

__all__ = ["LAYOUTS", "WorldConfig", "World", "make_landmarks"]

FloatArray = NDArray[np.float64]

#: Landmark layouts understood by :func:`make_landmarks`.
LAYOUTS = ("uniform", "clustered", "loop")


@dataclass(frozen=True)
class WorldConfig:
    """The arena and its landmarks.

    Attributes
    ----------
    arena_size : float
        Side of the square arena ``[-s/2, s/2]^2``, metres.
    layout : {"uniform", "clustered", "loop"}
        How landmarks are placed (see :func:`make_landmarks`).
    num_landmarks : int
        Number of landmarks.
    wall_margin : float
        Landmarks keep this distance from the walls.
    """

    arena_size: float = 20.0
    layout: str = "uniform"
    num_landmarks: int = 30
    wall_margin: float = 1.0

    def __post_init__(self) -> None:
        if not (isinstance(self.arena_size, (int, float)) and math.isfinite(self.arena_size) and self.arena_size > 0):
            raise ValueError(f"arena_size must be a positive number, got {self.arena_size!r}")
        if self.layout not in LAYOUTS:
            raise ValueError(f"layout must be one of {LAYOUTS}, got {self.layout!r}")
        if isinstance(self.num_landmarks, bool) or not isinstance(self.num_landmarks, (int, np.integer)):
            raise TypeError(f"num_landmarks must be an int, got {type(self.num_landmarks).__name__}")
        if not 1 <= self.num_landmarks <= 10_000:
            raise ValueError(f"num_landmarks must be in [1, 10000], got {self.num_landmarks}")
        if not (isinstance(self.wall_margin, (int, float)) and 0 <= self.wall_margin < self.arena_size / 4):
            raise ValueError(f"wall_margin must be in [0, arena_size/4), got {self.wall_margin!r}")

    @property
    def half_size(self) -> float:
        return 0.5 * float(self.arena_size)


def make_landmarks(config: WorldConfig, rng: np.random.Generator) -> FloatArray:
    """Landmark positions (n, 2) for ``config.layout``.

    * ``"uniform"``: uniform over the arena (inside the wall margin).
    * ``"clustered"``: 3 to 5 Gaussian clusters (std 1/12 of the arena),
      so that the space between clusters has nothing to see.
    * ``"loop"``: along a ring of radius 0.35 arena sizes with a radial
      jitter of 0.05 arena sizes; driving around it closes a loop.
    """
    h = config.half_size - config.wall_margin
    n = config.num_landmarks
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
        motion: VelocityMotionModel,
        sensor: RangeBearingSensor,
        landmarks: FloatArray,
        initial_pose: FloatArray,
    ) -> None:
        self.config = config
        self.motion = motion
        self.sensor = sensor
        self.landmarks = np.asarray(landmarks, dtype=np.float64)
        self.landmarks.setflags(write=False)
        self.pose = np.asarray(initial_pose, dtype=np.float64).copy()

    def inside(self, position: FloatArray) -> bool:
        h = self.config.half_size
        x, y = float(position[0]), float(position[1])
        return -h <= x <= h and -h <= y <= h

    def step(self, control: FloatArray, dt: float, rng: np.random.Generator) -> tuple[FloatArray, bool]:
        """Move the robot; returns the executed control and whether it hit the wall."""
        # inputs come validated from the env: the models' unchecked paths are used
        executed = np.asarray(control, dtype=np.float64)
        hit_wall = not self.inside(self.motion.predict_trusted(self.pose, executed, dt))
        if hit_wall:
            executed = np.array([0.0, executed[1]])
        pose = self.motion.sample_trusted(self.pose, executed, dt, rng)
        h = self.config.half_size
        pose[0] = min(max(pose[0], -h), h)
        pose[1] = min(max(pose[1], -h), h)
        pose[2] = wrap_angle(float(pose[2]))
        self.pose = pose
        return executed, hit_wall

    def measure(self, rng: np.random.Generator) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
        """Noisy ``(ranges, bearings, ids)`` of the visible landmarks."""
        return self.sensor.sample_trusted(self.pose, self.landmarks, rng)
