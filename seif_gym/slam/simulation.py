"""Simulated SLAM runs for tests, examples and benchmarks.

A :class:`SimulatedRun` holds everything a filter needs to be driven and
scored: the true landmarks and poses, the controls, and the measurement taken
after each motion step. :func:`simulate_run` makes one from a motion model and
a sensor; :func:`loop_controls`, :func:`loop_start_pose` and
:func:`ring_landmarks` build the standard loop-closing scenario (a circle
driven a little more than once, with landmarks on a ring around it);
:func:`run_filter` feeds a run through a filter and :func:`pose_nees` scores
the result.

Examples
--------
>>> import numpy as np
>>> from seif_gym.slam import EKF, RangeBearingSensor, VelocityMotionModel
>>> from seif_gym.slam.simulation import (
...     loop_controls, loop_start_pose, ring_landmarks, run_filter, simulate_run)
>>> rng = np.random.default_rng(0)
>>> motion, sensor = VelocityMotionModel(), RangeBearingSensor(max_range=5.0)
>>> landmarks = ring_landmarks(30, 7.0, 13.0, rng)
>>> run = simulate_run(motion, sensor, landmarks, loop_controls(200, 0.1, 10.0), 0.1,
...                    loop_start_pose(10.0), rng)
>>> result = run_filter(EKF(motion, sensor, run.initial_pose), run)
>>> result["poses"].shape, result["pose_covariances"].shape
((201, 3), (201, 3, 3))
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

# the metric has one home, seif_gym.metrics; re-exported here, where it was first defined
from seif_gym.metrics import pose_nees  # noqa: F401  (after the slam imports: metrics imports slam.models)
from seif_gym.slam.models import wrap_angle
from seif_gym.type_aliases import FloatArray, IntArray
from seif_gym.validation import as_count, as_finite_array, as_finite_vector, as_positive_scalar

if TYPE_CHECKING:  # imported for annotations only: no import cycle at run time
    from seif_gym.slam.base import SlamFilter
    from seif_gym.slam.models import MotionModel, RangeBearingSensor

__all__ = [
    "SimulatedRun",
    "simulate_run",
    "loop_controls",
    "loop_start_pose",
    "ring_landmarks",
    "run_filter",
    "pose_nees",
]


def _read_only(array: NDArray) -> NDArray:
    array = np.array(array, copy=True)
    array.setflags(write=False)
    return array


@dataclass(frozen=True)
class SimulatedRun:
    """One simulated run: ground truth, controls and measurements.

    All arrays are read-only copies.

    Attributes
    ----------
    landmarks : ndarray, shape (n, 2)
        True landmark positions; a landmark's id is its row index.
    true_poses : ndarray, shape (T + 1, 3)
        True poses ``(x, y, theta)``; row 0 is :attr:`initial_pose`, row
        ``t + 1`` the pose after control ``t``.
    controls : ndarray, shape (T, 2)
        Commanded ``(v, omega)``, each applied for :attr:`dt` seconds.
    dt : float
        Duration of one step, seconds.
    ranges, bearings, ids : tuple of T one-dimensional arrays
        The measurement taken at ``true_poses[t + 1]``, after motion step ``t``:
        ranges (m), bearings (rad, robot frame) and landmark ids (int64).
    initial_pose : ndarray, shape (3,)
        The true (and known) starting pose.
    """

    landmarks: FloatArray
    true_poses: FloatArray
    controls: FloatArray
    dt: float
    ranges: tuple[FloatArray, ...]
    bearings: tuple[FloatArray, ...]
    ids: tuple[IntArray, ...]
    initial_pose: FloatArray

    @property
    def steps(self) -> int:
        """Number of motion steps ``T``."""
        return len(self.controls)

    @property
    def measurement_counts(self) -> IntArray:
        """Number of landmarks seen after each step, shape (T,)."""
        return np.array([len(ids) for ids in self.ids], dtype=np.int64)


def simulate_run(
    motion: MotionModel,
    sensor: RangeBearingSensor,
    landmarks: ArrayLike,
    controls: ArrayLike,
    dt: float,
    initial_pose: ArrayLike,
    rng: np.random.Generator | None = None,
    *,
    noise_free: bool = False,
) -> SimulatedRun:
    """Drive the robot through ``controls`` and record what the sensor sees.

    Parameters
    ----------
    motion : MotionModel
        Its ``sample`` (or, with ``noise_free``, ``predict``) moves the true robot.
    sensor : RangeBearingSensor
        Its ``sample`` (or, with ``noise_free``, ``visible`` and ``predict``)
        makes the measurements.
    landmarks : array_like, shape (n, 2)
        True landmark positions; ids are row indices.
    controls : array_like, shape (T, 2)
        ``(v, omega)`` per step.
    dt : float
        Step duration, seconds (positive).
    initial_pose : array_like, shape (3,)
        True starting pose; its heading is wrapped.
    rng : numpy.random.Generator, optional
        Source of all noise; required unless ``noise_free``.
    noise_free : bool
        Use the noise-free models: the true poses follow ``motion.predict`` and
        each measurement is ``sensor.predict`` of the visible landmarks. Useful
        for checks where the filter's linearization error alone should remain.

    Returns
    -------
    SimulatedRun
    """
    landmarks = as_finite_array(landmarks, "landmarks", (None, 2))
    controls = as_finite_array(controls, "controls", (None, 2))
    dt = as_positive_scalar(dt, "dt")
    pose = as_finite_vector(initial_pose, "initial_pose", 3).copy()
    pose[2] = wrap_angle(float(pose[2]))
    if not noise_free and not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator unless noise_free=True, got {type(rng).__name__}")
    all_ids = np.arange(len(landmarks), dtype=np.int64)
    poses = np.empty((len(controls) + 1, 3))
    poses[0] = pose
    ranges: list[FloatArray] = []
    bearings: list[FloatArray] = []
    ids: list[IntArray] = []
    for t, control in enumerate(controls):
        if noise_free:
            pose = motion.predict(pose, control, dt)
            visible = sensor.visible(pose, landmarks)
            z = sensor.predict(pose, landmarks[visible])
            step_ranges, step_bearings, step_ids = z[:, 0], z[:, 1], all_ids[visible]
        else:
            assert rng is not None  # checked above
            pose = motion.sample(pose, control, dt, rng)
            step_ranges, step_bearings, step_ids = sensor.sample(pose, landmarks, rng)
        poses[t + 1] = pose
        ranges.append(_read_only(step_ranges))
        bearings.append(_read_only(step_bearings))
        ids.append(_read_only(np.asarray(step_ids, dtype=np.int64)))
    return SimulatedRun(
        landmarks=_read_only(landmarks),
        true_poses=_read_only(poses),
        controls=_read_only(controls),
        dt=dt,
        ranges=tuple(ranges),
        bearings=tuple(bearings),
        ids=tuple(ids),
        initial_pose=_read_only(poses[0]),
    )


def loop_controls(
    steps: int,
    dt: float,
    radius: float,
    speed: float | None = None,
    turns: float | None = None,
) -> FloatArray:
    """Constant controls that drive a circle of ``radius`` counter-clockwise.

    The turn rate is ``omega = v / radius``. Give at most one of ``speed`` and
    ``turns``: with ``turns`` (default 1.2, so that the loop closes and the
    start is seen again) the speed is ``v = 2 pi radius turns / (steps dt)``;
    with ``speed`` the run covers ``speed steps dt / (2 pi radius)`` turns.

    Parameters
    ----------
    steps : int
        Number of steps (positive).
    dt : float
        Step duration, seconds.
    radius : float
        Radius of the circle, metres.
    speed : float, optional
        Forward speed ``v``, m/s.
    turns : float, optional
        Number of full turns driven in ``steps`` steps.

    Returns
    -------
    ndarray, shape (steps, 2)
        ``(v, omega)`` per step. Start the robot at :func:`loop_start_pose` to
        drive the circle centred on the origin.
    """
    as_count(steps, "steps", minimum=1)
    dt = as_positive_scalar(dt, "dt")
    radius = as_positive_scalar(radius, "radius")
    if speed is not None and turns is not None:
        raise ValueError("give at most one of speed and turns")
    if speed is None:
        turns = 1.2 if turns is None else as_positive_scalar(turns, "turns")
        speed = 2.0 * math.pi * radius * turns / (steps * dt)
    else:
        speed = as_positive_scalar(speed, "speed")
    controls = np.empty((int(steps), 2))
    controls[:, 0] = speed
    controls[:, 1] = speed / radius
    return controls


def loop_start_pose(radius: float) -> FloatArray:
    """Pose ``(radius, 0, pi/2)``: with :func:`loop_controls` the circle is centred on the origin."""
    radius = as_positive_scalar(radius, "radius")
    return np.array([radius, 0.0, 0.5 * math.pi])


def ring_landmarks(n: int, radius_inner: float, radius_outer: float, rng: np.random.Generator) -> FloatArray:
    """``n`` landmarks spread around the origin between two radii.

    The angles are evenly spaced with a random jitter of up to a quarter of the
    spacing (so that the robot always has landmarks nearby, but the layout is
    not perfectly regular); the radii are uniform in
    ``[radius_inner, radius_outer]``. Put the loop's radius between the two.

    Parameters
    ----------
    n : int
        Number of landmarks (positive).
    radius_inner, radius_outer : float
        Ring bounds, ``0 <= radius_inner <= radius_outer``.
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (n, 2)
    """
    as_count(n, "n", minimum=1)
    radius_outer = as_positive_scalar(radius_outer, "radius_outer")
    radius_inner = float(radius_inner)
    if not 0.0 <= radius_inner <= radius_outer:
        raise ValueError(f"radius_inner must lie in [0, radius_outer], got {radius_inner}")
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    spacing = 2.0 * math.pi / n
    angles = spacing * np.arange(n) + rng.uniform(-0.25, 0.25, n) * spacing
    radii = rng.uniform(radius_inner, radius_outer, n)
    return np.column_stack([radii * np.cos(angles), radii * np.sin(angles)])


def run_filter(filt: SlamFilter, run: SimulatedRun) -> dict[str, NDArray]:
    """Feed ``run`` through ``filt``: per step, ``predict`` then ``update``.

    Parameters
    ----------
    filt : SlamFilter
        A filter constructed at ``run.initial_pose``; it is modified in place.
    run : SimulatedRun

    Returns
    -------
    dict
        ``"poses"`` (T + 1, 3): estimated pose, row 0 before the first step;
        ``"pose_covariances"`` (T + 1, 3, 3): their marginal covariances;
        ``"step_seconds"`` (T,): wall time of each predict + update (the
        covariance queries are not timed).
    """
    steps = run.steps
    poses = np.empty((steps + 1, 3))
    covariances = np.empty((steps + 1, 3, 3))
    seconds = np.empty(steps)
    poses[0], covariances[0] = filt.pose, filt.pose_covariance
    for t in range(steps):
        start = time.perf_counter()
        filt.predict(run.controls[t], run.dt)
        filt.update(run.ranges[t], run.bearings[t], run.ids[t])
        seconds[t] = time.perf_counter() - start
        poses[t + 1], covariances[t + 1] = filt.pose, filt.pose_covariance
    return {"poses": poses, "pose_covariances": covariances, "step_seconds": seconds}
