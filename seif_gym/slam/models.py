"""Motion and sensor models (Thrun, Burgard & Fox, *Probabilistic Robotics*).

Every filter of :mod:`seif_gym.slam` takes a *motion model* and a *sensor*.
A motion model is any object with the methods of :class:`MotionModel`; the
filters only call :meth:`MotionModel.linearize`, which returns the pose
increment, its Jacobian and the state-space noise in one call (one call keeps
the per-step Python overhead small). The simulator calls ``sample``.

Equations: Thrun, Burgard & Fox, *Probabilistic Robotics*, Table 5.3 (the
velocity motion model) and the range-bearing measurement model of chapters 6
and 10; each class's Notes write them out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol, overload, runtime_checkable

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from seif_gym.type_aliases import FloatArray
from seif_gym.validation import (
    as_finite_array,
    as_finite_vector,
    as_positive_scalar,
)

__all__ = [
    "wrap_angle",
    "MotionModel",
    "VelocityMotionModel",
    "RangeBearingSensor",
]


@overload
def wrap_angle(angle: float) -> float: ...


@overload
def wrap_angle(angle: ArrayLike) -> FloatArray: ...


def wrap_angle(angle: ArrayLike) -> float | FloatArray:
    """Wrap angles to ``[-pi, pi)``; a float gives a float, anything else an array.

    (An ``int`` is typed as a float, but gives a 0-d array.)
    """
    # the modulo can round up to exactly 2 pi for inputs a hair below -pi: fold that back
    if isinstance(angle, float):
        folded = (angle + math.pi) % (2.0 * math.pi) - math.pi
        return folded - 2.0 * math.pi if folded >= math.pi else folded
    wrapped = (np.asarray(angle, dtype=np.float64) + np.pi) % (2.0 * np.pi) - np.pi
    return np.where(wrapped >= np.pi, wrapped - 2.0 * np.pi, wrapped)


@runtime_checkable
class MotionModel(Protocol):
    """What a filter needs from a motion model.

    ``linearize(pose, control, dt)`` returns ``(delta, G, R)``: the pose
    increment ``delta`` (3,) so that the predicted pose is ``pose + delta``
    (angle wrapped afterwards), the Jacobian ``G = d g / d pose`` (3, 3) and the
    state-space motion noise ``R`` (3, 3), symmetric positive definite.

    A model may also provide ``linearize_trusted`` with the same signature
    and result but no input checks; the filters call it when present, since
    they have validated ``control`` and ``dt`` already (the checks cost more
    than the model itself).
    """

    def linearize(
        self, pose: ArrayLike, control: ArrayLike, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]: ...

    def predict(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray: ...

    def sample(self, pose: ArrayLike, control: ArrayLike, dt: float, rng: np.random.Generator) -> FloatArray: ...

    def validate_control(self, control: ArrayLike) -> FloatArray: ...


def _sinc_and_derivative(a: float) -> tuple[float, float]:
    """``sin(a)/a`` and its derivative, accurate also for ``a`` near zero."""
    if abs(a) < 1e-4:
        a2 = a * a
        return 1.0 - a2 / 6.0 + a2 * a2 / 120.0, -a / 3.0 + a * a2 / 30.0
    s, c = math.sin(a), math.cos(a)
    return s / a, (a * c - s) / (a * a)


class VelocityMotionModel:
    r"""Thrun's velocity motion model with controls ``(v, omega)``.

    Parameters
    ----------
    alphas : sequence of 6 floats
        Noise parameters ``(a1, ..., a6)`` of Thrun Table 5.3: the executed
        controls are ``v + N(0, a1 v^2 + a2 w^2)``, ``w + N(0, a3 v^2 + a4 w^2)``
        and a final rotation rate ``N(0, a5 v^2 + a6 w^2)``.
    noise_floor : float
        Variance added to each diagonal entry of ``R`` so that the filters'
        information matrices stay well conditioned when the robot stands still.

    Notes
    -----
    Thrun Table 5.3 (the velocity motion model). The arc is written as

    .. math:: \delta = (v\Delta t\,\cos(\theta+\omega\Delta t/2)\,\mathrm{sinc}(\omega\Delta t/2),
              v\Delta t\,\sin(\theta+\omega\Delta t/2)\,\mathrm{sinc}(\omega\Delta t/2), \omega\Delta t)

    which equals the ``v/w (sin(theta + w dt) - sin theta)`` form of the book
    exactly (a product-to-sum identity) and is continuous at ``w = 0``, where
    it becomes the straight-line limit ``(v dt cos theta, v dt sin theta, 0)``.
    There is no threshold and no cancellation for small ``w``.
    """

    def __init__(
        self,
        alphas: Sequence[float] = (0.01, 0.001, 0.001, 0.01, 0.0005, 0.0005),
        noise_floor: float = 1e-9,
    ) -> None:
        alphas_array = as_finite_vector(alphas, "alphas", 6)
        if np.any(alphas_array < 0):
            raise ValueError(f"alphas must be non-negative, got {tuple(alphas_array)}")
        self.alphas: tuple[float, ...] = tuple(float(a) for a in alphas_array)
        self.noise_floor = as_positive_scalar(noise_floor, "noise_floor")

    def __repr__(self) -> str:
        return f"VelocityMotionModel(alphas={self.alphas}, noise_floor={self.noise_floor})"

    # -- validation ---------------------------------------------------------
    def validate_control(self, control: ArrayLike) -> FloatArray:
        """Return ``control`` as a finite ``(v, omega)`` array or raise."""
        return as_finite_vector(control, "control", 2)

    def _check(self, pose: ArrayLike, control: ArrayLike, dt: float) -> tuple[FloatArray, FloatArray, float]:
        return (
            as_finite_vector(pose, "pose", 3),
            self.validate_control(control),
            as_positive_scalar(dt, "dt"),
        )

    # -- deterministic model ------------------------------------------------
    @staticmethod
    def _displacement(theta: float, v: float, w: float, dt: float) -> tuple[float, float, float]:
        half = 0.5 * w * dt
        sinc, _ = _sinc_and_derivative(half)
        mid = theta + half
        return v * dt * math.cos(mid) * sinc, v * dt * math.sin(mid) * sinc, w * dt

    def displacement(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """Pose increment ``delta`` of the class Notes (angle not wrapped)."""
        pose, control, dt = self._check(pose, control, dt)
        return np.array(self._displacement(pose[2], control[0], control[1], dt))

    def predict(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """Noise-free next pose ``g(u, x)`` with the heading wrapped."""
        pose, control, dt = self._check(pose, control, dt)
        return self.predict_trusted(pose, control, dt)

    def jacobian_state(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """``G = I + Delta``, the Jacobian of ``g`` with respect to the pose (3, 3)."""
        pose, control, dt = self._check(pose, control, dt)
        dx, dy, _ = self._displacement(pose[2], control[0], control[1], dt)
        return np.array([[1.0, 0.0, -dy], [0.0, 1.0, dx], [0.0, 0.0, 1.0]])

    @staticmethod
    def _jacobian_control(theta: float, v: float, w: float, dt: float) -> FloatArray:
        half = 0.5 * w * dt
        sinc, dsinc = _sinc_and_derivative(half)
        mid = theta + half
        c, s = math.cos(mid), math.sin(mid)
        # d/dw of (v dt cos(mid) sinc(half)), with d mid/dw = d half/dw = dt/2
        return np.array(
            [
                [dt * c * sinc, v * dt * 0.5 * dt * (-s * sinc + c * dsinc)],
                [dt * s * sinc, v * dt * 0.5 * dt * (c * sinc + s * dsinc)],
                [0.0, dt],
            ]
        )

    def jacobian_control(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """``V = d g / d (v, omega)`` (3, 2), Thrun eq. 7.11."""
        pose, control, dt = self._check(pose, control, dt)
        return self._jacobian_control(pose[2], control[0], control[1], dt)

    def control_covariance(self, control: ArrayLike) -> FloatArray:
        """``M = diag(a1 v^2 + a2 w^2, a3 v^2 + a4 w^2)`` (2, 2)."""
        v, w = self.validate_control(control)
        a1, a2, a3, a4, _, _ = self.alphas
        return np.diag([a1 * v * v + a2 * w * w, a3 * v * v + a4 * w * w])

    def noise_covariance(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """State-space noise ``R = V M V^T + gamma term + floor`` (3, 3)."""
        return self.linearize(pose, control, dt)[2]

    def linearize(self, pose: ArrayLike, control: ArrayLike, dt: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(delta, G, R)`` at ``pose`` for ``control`` over ``dt``.

        Notes
        -----
        ``R = V M V^T + diag(0, 0, (a5 v^2 + a6 w^2) dt^2) + floor I``; the
        last-but-one term is the final rotation of Thrun Table 5.3 integrated
        over the step.
        """
        pose, control, dt = self._check(pose, control, dt)
        return self.linearize_trusted(pose, control, dt)

    def linearize_trusted(
        self, pose: FloatArray, control: FloatArray, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """:meth:`linearize` without input checks, for callers that validated them."""
        theta, v, w, dt = float(pose[2]), float(control[0]), float(control[1]), float(dt)
        half = 0.5 * w * dt
        sinc, dsinc = _sinc_and_derivative(half)
        mid = theta + half
        c, s = math.cos(mid), math.sin(mid)
        dx, dy = v * dt * c * sinc, v * dt * s * sinc
        delta = np.array([dx, dy, w * dt])
        jacobian = np.array([[1.0, 0.0, -dy], [0.0, 1.0, dx], [0.0, 0.0, 1.0]])
        # V = d g / d(v, w) (Thrun eq. 7.11), and R = V M V^T + gamma term + floor, written out
        v0, v1 = dt * c * sinc, v * dt * 0.5 * dt * (-s * sinc + c * dsinc)
        u0, u1 = dt * s * sinc, v * dt * 0.5 * dt * (c * sinc + s * dsinc)
        a1, a2, a3, a4, a5, a6 = self.alphas
        vv, ww = v * v, w * w
        m_v, m_w = a1 * vv + a2 * ww, a3 * vv + a4 * ww
        floor = self.noise_floor
        r01 = v0 * m_v * u0 + v1 * m_w * u1
        r02 = v1 * m_w * dt
        r12 = u1 * m_w * dt
        noise = np.array(
            [
                [v0 * m_v * v0 + v1 * m_w * v1 + floor, r01, r02],
                [r01, u0 * m_v * u0 + u1 * m_w * u1 + floor, r12],
                [r02, r12, dt * m_w * dt + (a5 * vv + a6 * ww) * dt * dt + floor],
            ]
        )
        return delta, jacobian, noise

    # -- stochastic model ---------------------------------------------------
    def sample(self, pose: ArrayLike, control: ArrayLike, dt: float, rng: np.random.Generator) -> FloatArray:
        """Draw the next true pose (Thrun Table 5.3, ``sample_motion_model_velocity``)."""
        pose, control, dt = self._check(pose, control, dt)
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        return self.sample_trusted(pose, control, dt, rng)

    def sample_trusted(self, pose: FloatArray, control: FloatArray, dt: float, rng: np.random.Generator) -> FloatArray:
        """:meth:`sample` without input checks, for the simulator's inner loop."""
        v, w = float(control[0]), float(control[1])
        a1, a2, a3, a4, a5, a6 = self.alphas
        vv, ww = v * v, w * w
        noise = rng.standard_normal(3)
        v_hat = v + math.sqrt(a1 * vv + a2 * ww) * noise[0]
        w_hat = w + math.sqrt(a3 * vv + a4 * ww) * noise[1]
        gamma = math.sqrt(a5 * vv + a6 * ww) * noise[2]
        dx, dy, dth = self._displacement(float(pose[2]), v_hat, w_hat, dt)
        return np.array([pose[0] + dx, pose[1] + dy, wrap_angle(float(pose[2] + dth + gamma * dt))])

    def predict_trusted(self, pose: FloatArray, control: FloatArray, dt: float) -> FloatArray:
        """:meth:`predict` without input checks."""
        dx, dy, dth = self._displacement(float(pose[2]), float(control[0]), float(control[1]), float(dt))
        return np.array([pose[0] + dx, pose[1] + dy, wrap_angle(float(pose[2] + dth))])


@njit(cache=True)
def _visible_measurements(
    x: float, y: float, theta: float, landmarks: FloatArray, max_range: float, half_fov: float, min_range: float
) -> tuple[NDArray[np.int64], FloatArray]:
    """Indices and noise-free ``(range, bearing)`` of the visible landmarks (``sample``'s inner loop).

    Visible: ``min_range < r <= max_range`` and within the field of view.
    """
    n = landmarks.shape[0]
    indices = np.empty(n, dtype=np.int64)
    z = np.empty((n, 2))
    count = 0
    limited = half_fov < np.pi
    for i in range(n):
        dx = landmarks[i, 0] - x
        dy = landmarks[i, 1] - y
        r = np.sqrt(dx * dx + dy * dy)
        if r > max_range or r <= min_range:
            continue
        bearing = (np.arctan2(dy, dx) - theta + np.pi) % (2.0 * np.pi) - np.pi
        if limited and abs(bearing) > half_fov:
            continue
        indices[count] = i
        z[count, 0] = r
        z[count, 1] = bearing
        count += 1
    return indices[:count], z[:count]


class RangeBearingSensor:
    """Range-bearing landmark sensor with a limited range and field of view.

    Parameters
    ----------
    sigma_range : float
        Standard deviation of the range noise, metres.
    sigma_bearing : float
        Standard deviation of the bearing noise, radians.
    max_range : float
        Landmarks farther than this are not seen.
    fov : float
        Full opening angle of the sensor, radians, centred on the heading;
        ``2 pi`` sees all around.
    min_range : float
        Landmarks at this distance or closer are not seen (a real sensor's
        blind zone; it also keeps the bearing's ``1/r`` Jacobian bounded, whose
        information grows as ``1/r^2`` when the robot stands on a landmark).

    Notes
    -----
    With ``d = m - (x, y)`` and ``q = d^T d``, a landmark ``m`` is measured
    as ``z = (sqrt(q), atan2(d_y, d_x) - theta)`` (bearing wrapped), with the
    Jacobian over ``(x, y, theta, m_x, m_y)`` (:meth:`jacobian`)::

        H = 1/q [[-sqrt(q) d_x, -sqrt(q) d_y,  0,  sqrt(q) d_x,  sqrt(q) d_y],
                 [        d_y,          -d_x, -q,         -d_y,          d_x]]

    A landmark seen for the first time is placed by the inverse model
    ``m = (x + r cos(phi + theta), y + r sin(phi + theta))`` (:meth:`inverse`).
    """

    def __init__(
        self,
        sigma_range: float = 0.1,
        sigma_bearing: float = math.radians(2.0),
        max_range: float = 8.0,
        fov: float = 2.0 * math.pi,
        min_range: float = 0.0,
    ) -> None:
        self.sigma_range = as_positive_scalar(sigma_range, "sigma_range")
        self.sigma_bearing = as_positive_scalar(sigma_bearing, "sigma_bearing")
        self.max_range = as_positive_scalar(max_range, "max_range")
        if isinstance(min_range, bool) or not isinstance(min_range, (int, float, np.integer, np.floating)):
            raise TypeError(f"min_range must be a real number, got {type(min_range).__name__}")
        if not 0.0 <= float(min_range) < self.max_range:
            raise ValueError(f"min_range must lie in [0, max_range), got {min_range!r}")
        self.min_range = float(min_range)
        self.fov = as_positive_scalar(fov, "fov")
        if self.fov > 2.0 * math.pi + 1e-12:
            raise ValueError(f"fov must be at most 2*pi, got {self.fov}")
        self.noise_covariance: FloatArray = np.diag([self.sigma_range**2, self.sigma_bearing**2])
        self.noise_covariance.setflags(write=False)

    #: One noise for every measurement (``noise_covariance``); a sensor whose noise depends on the
    #: measurement sets this True and the filters call :meth:`measurement_covariances` instead.
    range_dependent = False

    def __repr__(self) -> str:
        return (
            f"RangeBearingSensor(sigma_range={self.sigma_range}, sigma_bearing={self.sigma_bearing}, "
            f"max_range={self.max_range}, fov={self.fov}, min_range={self.min_range})"
        )

    def measurement_covariances(self, ranges: ArrayLike) -> FloatArray:
        """Noise covariance ``Q`` of each measurement, shape (m, 2, 2): ``noise_covariance`` for all here."""
        ranges = as_finite_array(np.atleast_1d(ranges), "ranges", (None,))
        return np.broadcast_to(self.noise_covariance, (len(ranges), 2, 2)).copy()

    @staticmethod
    def _landmarks(landmarks: ArrayLike, name: str = "landmarks") -> FloatArray:
        if landmarks is None:
            raise TypeError(f"{name} must be an array of shape (n, 2), got None")
        array = np.asarray(landmarks, dtype=np.float64) if not isinstance(landmarks, (str, bytes)) else None
        if array is not None and array.ndim == 1 and array.shape == (2,):
            array = array[None, :]
        return as_finite_array(array if array is not None else landmarks, name, (None, 2))

    def predict(self, pose: ArrayLike, landmarks: ArrayLike) -> FloatArray:
        """Expected ``(range, bearing)`` of each landmark, shape (m, 2)."""
        return self.predict_trusted(as_finite_vector(pose, "pose", 3), self._landmarks(landmarks))

    @staticmethod
    def predict_trusted(pose: FloatArray, landmarks: FloatArray) -> FloatArray:
        """:meth:`predict` without input checks (``landmarks`` float64 (m, 2))."""
        dx = landmarks[:, 0] - pose[0]
        dy = landmarks[:, 1] - pose[1]
        z = np.empty((len(landmarks), 2))
        z[:, 0] = np.sqrt(dx * dx + dy * dy)
        z[:, 1] = (np.arctan2(dy, dx) - pose[2] + np.pi) % (2.0 * np.pi) - np.pi
        return z

    def jacobian(self, pose: ArrayLike, landmarks: ArrayLike) -> FloatArray:
        """``H`` of the class Notes for each landmark, shape (m, 2, 5)."""
        pose = as_finite_vector(pose, "pose", 3)
        landmarks = self._landmarks(landmarks)
        d = landmarks - pose[:2]
        q = np.einsum("ij,ij->i", d, d)
        if np.any(q <= 0.0):
            raise ValueError("landmarks must not coincide with the robot position")
        r = np.sqrt(q)
        dx, dy = d[:, 0], d[:, 1]
        H = np.zeros((len(d), 2, 5))
        H[:, 0, 0], H[:, 0, 1], H[:, 0, 3], H[:, 0, 4] = -dx / r, -dy / r, dx / r, dy / r
        H[:, 1, 0], H[:, 1, 1], H[:, 1, 2], H[:, 1, 3], H[:, 1, 4] = dy / q, -dx / q, -1.0, -dy / q, dx / q
        return H

    def inverse(self, pose: ArrayLike, ranges: ArrayLike, bearings: ArrayLike) -> FloatArray:
        """Landmark positions ``(x + r cos(phi + theta), y + r sin(phi + theta))``, shape (m, 2)."""
        pose = as_finite_vector(pose, "pose", 3)
        ranges = as_finite_array(np.atleast_1d(ranges), "ranges", (None,))
        bearings = as_finite_array(np.atleast_1d(bearings), "bearings", (len(ranges),))
        return self.inverse_trusted(pose, ranges, bearings)

    @staticmethod
    def inverse_trusted(pose: FloatArray, ranges: FloatArray, bearings: FloatArray) -> FloatArray:
        """:meth:`inverse` without input checks."""
        angle = bearings + pose[2]
        positions = np.empty((len(ranges), 2))
        positions[:, 0] = pose[0] + ranges * np.cos(angle)
        positions[:, 1] = pose[1] + ranges * np.sin(angle)
        return positions

    def inverse_jacobians(
        self, pose: ArrayLike, ranges: ArrayLike, bearings: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        """Jacobians of :meth:`inverse` with respect to the pose (m, 2, 3) and to ``(r, phi)`` (m, 2, 2)."""
        pose = as_finite_vector(pose, "pose", 3)
        ranges = as_finite_array(np.atleast_1d(ranges), "ranges", (None,))
        bearings = as_finite_array(np.atleast_1d(bearings), "bearings", (len(ranges),))
        angle = bearings + pose[2]
        c, s = np.cos(angle), np.sin(angle)
        wrt_pose = np.zeros((len(ranges), 2, 3))
        wrt_pose[:, 0, 0] = 1.0
        wrt_pose[:, 1, 1] = 1.0
        wrt_pose[:, 0, 2] = -ranges * s
        wrt_pose[:, 1, 2] = ranges * c
        wrt_measurement = np.stack([np.stack([c, -ranges * s], -1), np.stack([s, ranges * c], -1)], 1)
        return wrt_pose, wrt_measurement

    def visible(self, pose: ArrayLike, landmarks: ArrayLike) -> NDArray[np.bool_]:
        """Mask of the landmarks inside the range and field of view (no noise)."""
        return self._visible(self.predict(pose, landmarks))

    def _visible(self, z: FloatArray) -> NDArray[np.bool_]:
        mask = (z[:, 0] <= self.max_range) & (z[:, 0] > self.min_range)
        if self.fov < 2.0 * math.pi:
            mask &= np.abs(z[:, 1]) <= 0.5 * self.fov
        return mask

    def sample(
        self, pose: ArrayLike, landmarks: ArrayLike, rng: np.random.Generator, ids: ArrayLike | None = None
    ) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
        """Noisy ``(ranges, bearings, ids)`` of the visible landmarks.

        ``ids`` defaults to the landmarks' row indices. Ranges are kept
        positive (a draw below zero is reflected), bearings wrapped.
        """
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        pose = as_finite_vector(pose, "pose", 3)
        landmarks = self._landmarks(landmarks)
        if ids is not None:
            ids = np.asarray(ids)
            if ids.shape != (len(landmarks),) or not np.issubdtype(ids.dtype, np.integer):
                raise ValueError("ids must be one integer per landmark")
        return self.sample_trusted(pose, landmarks, rng, ids)

    def sample_trusted(
        self, pose: FloatArray, landmarks: FloatArray, rng: np.random.Generator, ids: ArrayLike | None = None
    ) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
        """:meth:`sample` without input checks, for the simulator's inner loop."""
        visible, z = _visible_measurements(
            float(pose[0]), float(pose[1]), float(pose[2]), landmarks, self.max_range, 0.5 * self.fov, self.min_range
        )
        noise = rng.standard_normal((len(visible), 2))
        ranges = np.abs(z[:, 0] + noise[:, 0] * self.sigma_range)
        bearings = (z[:, 1] + noise[:, 1] * self.sigma_bearing + np.pi) % (2.0 * np.pi) - np.pi
        visible_ids = visible if ids is None else np.asarray(ids)[visible].astype(np.int64)
        return ranges, bearings, visible_ids

    def range_sigma(self, ranges: ArrayLike) -> FloatArray:
        """The range noise's standard deviation at each range, m (constant here: ``sigma_range``)."""
        return np.full(np.shape(ranges), self.sigma_range)

    def sample_with_range_errors(
        self, pose: FloatArray, landmarks: FloatArray, unit_range_errors: FloatArray, rng: np.random.Generator
    ) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
        """Noisy ``(ranges, bearings, ids)`` whose range errors are given (unchecked, for the simulator).

        Landmark ``i``'s range error is ``range_sigma(r_i) * unit_range_errors[i]`` (a time-correlated
        process that the caller keeps, ``seif_gym.world.World``); the bearing noise is drawn here, white.
        """
        visible, z = _visible_measurements(
            float(pose[0]), float(pose[1]), float(pose[2]), landmarks, self.max_range, 0.5 * self.fov, self.min_range
        )
        ranges = np.abs(z[:, 0] + self.range_sigma(z[:, 0]) * unit_range_errors[visible])
        noise = rng.standard_normal(len(visible))
        bearings = (z[:, 1] + noise * self.sigma_bearing + np.pi) % (2.0 * np.pi) - np.pi
        return ranges, bearings, visible
