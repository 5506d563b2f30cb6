"""Ackermann car model of the Victoria Park vehicle (Guivant & Nebot 2001).

The state is the pose of the **laser** ``(x, y, phi)``, not of the rear axle,
so that the range-bearing sensor needs no mounting offset. The controls are
what the vehicle logs: ``u = (v_e, alpha)``, the speed measured by the
encoder on the rear-left wheel (m/s) and the front-wheel steering angle (rad,
positive to the left). With ``t = tan(alpha)``::

    v_c   = v_e / (1 - t H / L)               encoder speed -> rear-axle-centre speed
    w     = v_c t / L                          heading rate
    delta = dt ( v_c cos phi - w (a sin phi + b cos phi),
                 v_c sin phi + w (a cos phi - b sin phi),
                 w )

(``L`` wheelbase, ``H`` lateral offset of the encoder, ``a``, ``b`` position of
the laser ahead of the rear axle and to the side of the centre line; the
constants of ``docs/data/victoria_park.md``).

:class:`AckermannLaserModel` provides what every filter of
:mod:`seif_gym.slam` takes from a motion model (the interface of
:class:`~seif_gym.slam.models.VelocityMotionModel`): ``linearize`` /
``linearize_trusted`` returning ``(delta, G, R)``, ``predict``, ``sample``,
``validate_control`` and the Jacobians.

Noise model
-----------
The logged controls are treated as the true ones plus white noise. At the
logging period ``reference_dt`` (25 ms) the control error has the covariance

    M = diag(sigma_speed^2 + (sigma_speed_rel v_e)^2, sigma_steering^2),

and a step of another length ``dt`` gets ``M * reference_dt / dt`` (the
average of white noise over ``dt``). The state-space noise is the control
noise propagated through the control Jacobian ``V = d g / d u`` plus a floor::

    R = V M (reference_dt / dt) V^T + floor (dt / reference_dt) I.

Both terms grow linearly with ``dt``, so splitting a step in two (as the
Victoria Park runner does at every laser scan) leaves the noise of the whole
interval unchanged. The floor keeps ``R`` invertible when the car stands still.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from seif_gym.slam.models import wrap_angle
from seif_gym.type_aliases import FloatArray
from seif_gym.validation import as_finite_vector, as_nonnegative_scalar, as_positive_scalar, as_real_scalar

__all__ = ["AckermannLaserModel"]


class AckermannLaserModel:
    """Car-like motion of the laser of the Victoria Park vehicle, controls ``(v_e, alpha)``.

    Parameters
    ----------
    wheelbase : float
        ``L``, rear axle to front axle, metres (2.83).
    encoder_offset : float
        ``H``, lateral distance from the rear-axle centre to the rear-left
        wheel encoder, metres (0.76).
    laser_ahead : float
        ``a``, laser position ahead of the **rear** axle, metres
        (``2.83 + 0.95 = 3.78``).
    laser_lateral : float
        ``b``, lateral laser offset from the centre line, metres (0.5).
    sigma_speed : float
        Standard deviation of the encoder-speed error per ``reference_dt``, m/s.
    sigma_speed_rel : float
        Additional speed error proportional to the speed (dimensionless).
    sigma_steering : float
        Standard deviation of the steering-angle error per ``reference_dt``, rad.
    reference_dt : float
        Period at which the noise above applies, seconds (the odometry period).
    noise_floor : float
        Variance added to each diagonal entry of ``R`` per ``reference_dt``.
    max_steering : float
        Largest accepted ``|alpha|``, rad; ``validate_control`` rejects more.
        It must stay below ``atan(L / H)``, where ``v_c`` is undefined.

    Notes
    -----
    ``G = d g / d pose = [[1, 0, -delta_y], [0, 1, delta_x], [0, 0, 1]]``
    (``delta`` depends on the pose only through ``phi``, and ``d delta_x / d phi
    = -delta_y``, ``d delta_y / d phi = delta_x``), the same structure as the
    velocity model's. ``tests/slam/test_car_model.py`` checks ``G`` and ``V``
    against finite differences.
    """

    def __init__(
        self,
        wheelbase: float = 2.83,
        encoder_offset: float = 0.76,
        laser_ahead: float = 3.78,
        laser_lateral: float = 0.5,
        sigma_speed: float = 0.5,
        sigma_speed_rel: float = 0.05,
        sigma_steering: float = math.radians(1.0),
        reference_dt: float = 0.025,
        noise_floor: float = 1e-8,
        max_steering: float = 1.2,
    ) -> None:
        self.wheelbase = as_positive_scalar(wheelbase, "wheelbase")
        self.encoder_offset = as_nonnegative_scalar(encoder_offset, "encoder_offset")
        self.laser_ahead = as_real_scalar(laser_ahead, "laser_ahead")
        self.laser_lateral = as_real_scalar(laser_lateral, "laser_lateral")
        self.sigma_speed = as_nonnegative_scalar(sigma_speed, "sigma_speed")
        self.sigma_speed_rel = as_nonnegative_scalar(sigma_speed_rel, "sigma_speed_rel")
        self.sigma_steering = as_nonnegative_scalar(sigma_steering, "sigma_steering")
        self.reference_dt = as_positive_scalar(reference_dt, "reference_dt")
        self.noise_floor = as_positive_scalar(noise_floor, "noise_floor")
        self.max_steering = as_positive_scalar(max_steering, "max_steering")
        if self.max_steering >= math.pi / 2:
            raise ValueError(f"max_steering must be below pi/2, got {self.max_steering}")
        if abs(math.tan(self.max_steering) * self.encoder_offset / self.wheelbase) >= 0.95:
            raise ValueError("max_steering too large: 1 - tan(alpha) H / L must stay away from zero")

    def __repr__(self) -> str:
        return (
            f"AckermannLaserModel(wheelbase={self.wheelbase}, encoder_offset={self.encoder_offset}, "
            f"laser_ahead={self.laser_ahead}, laser_lateral={self.laser_lateral}, sigma_speed={self.sigma_speed}, "
            f"sigma_speed_rel={self.sigma_speed_rel}, sigma_steering={self.sigma_steering}, "
            f"reference_dt={self.reference_dt}, noise_floor={self.noise_floor})"
        )

    # -- validation ---------------------------------------------------------
    def validate_control(self, control: ArrayLike) -> FloatArray:
        """Return ``control`` as a finite ``(v_e, alpha)`` array with ``|alpha| <= max_steering``, or raise."""
        control = as_finite_vector(control, "control", 2)
        if abs(control[1]) > self.max_steering:
            raise ValueError(f"steering angle must satisfy |alpha| <= {self.max_steering}, got {control[1]}")
        return control

    def _check(self, pose: ArrayLike, control: ArrayLike, dt: float) -> tuple[FloatArray, FloatArray, float]:
        return as_finite_vector(pose, "pose", 3), self.validate_control(control), as_positive_scalar(dt, "dt")

    # -- deterministic model ------------------------------------------------
    def _terms(
        self, phi: float, v_e: float, alpha: float, dt: float
    ) -> tuple[float, float, float, float, float, float, float, float]:
        """Shared intermediate quantities of the model and its Jacobians: ``(t, k, v_c, w, c, s, dx, dy)``."""
        L, H, a, b = self.wheelbase, self.encoder_offset, self.laser_ahead, self.laser_lateral
        t = math.tan(alpha)
        k = 1.0 - t * H / L
        v_c = v_e / k
        w = v_c * t / L
        c, s = math.cos(phi), math.sin(phi)
        dx = dt * (v_c * c - w * (a * s + b * c))
        dy = dt * (v_c * s + w * (a * c - b * s))
        return t, k, v_c, w, c, s, dx, dy

    def displacement(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """Pose increment ``delta`` (heading not wrapped)."""
        pose, control, dt = self._check(pose, control, dt)
        *_, w, _, _, dx, dy = self._terms(float(pose[2]), float(control[0]), float(control[1]), dt)
        return np.array([dx, dy, w * dt])

    def predict(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """Noise-free next pose with the heading wrapped."""
        pose, control, dt = self._check(pose, control, dt)
        return self.predict_trusted(pose, control, dt)

    def predict_trusted(self, pose: FloatArray, control: FloatArray | tuple[float, float], dt: float) -> FloatArray:
        """:meth:`predict` without input checks."""
        *_, w, _, _, dx, dy = self._terms(float(pose[2]), float(control[0]), float(control[1]), float(dt))
        return np.array([pose[0] + dx, pose[1] + dy, wrap_angle(float(pose[2]) + w * float(dt))])

    def jacobian_state(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """``G = d g / d pose`` (3, 3)."""
        pose, control, dt = self._check(pose, control, dt)
        *_, dx, dy = self._terms(float(pose[2]), float(control[0]), float(control[1]), dt)
        return np.array([[1.0, 0.0, -dy], [0.0, 1.0, dx], [0.0, 0.0, 1.0]])

    def _control_jacobian(self, phi: float, v_e: float, alpha: float, dt: float) -> tuple[float, ...]:
        """Entries of ``V = d delta / d (v_e, alpha)`` row by row, and the terms they share."""
        L, H, a, b = self.wheelbase, self.encoder_offset, self.laser_ahead, self.laser_lateral
        t, k, v_c, w, c, s, dx, dy = self._terms(phi, v_e, alpha, dt)
        sec2 = 1.0 + t * t
        dvc_dv = 1.0 / k
        dvc_da = v_e * (H / L) * sec2 / (k * k)
        dw_dv = dvc_dv * t / L
        dw_da = (dvc_da * t + v_c * sec2) / L
        px = a * s + b * c  # lever arm terms of delta_x and delta_y
        py = a * c - b * s
        return (
            dt * (dvc_dv * c - dw_dv * px), dt * (dvc_da * c - dw_da * px),
            dt * (dvc_dv * s + dw_dv * py), dt * (dvc_da * s + dw_da * py),
            dt * dw_dv, dt * dw_da,
            dx, dy, w,
        )  # fmt: skip

    def jacobian_control(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """``V = d g / d (v_e, alpha)`` (3, 2)."""
        pose, control, dt = self._check(pose, control, dt)
        j = self._control_jacobian(float(pose[2]), float(control[0]), float(control[1]), dt)
        return np.array(j[:6]).reshape(3, 2)

    def control_covariance(self, control: ArrayLike, dt: float | None = None) -> FloatArray:
        """``M`` (2, 2) of the control error for a step of ``dt`` (default ``reference_dt``)."""
        v_e, _ = self.validate_control(control)
        scale = 1.0 if dt is None else self.reference_dt / as_positive_scalar(dt, "dt")
        return scale * np.diag([self.sigma_speed**2 + (self.sigma_speed_rel * v_e) ** 2, self.sigma_steering**2])

    def noise_covariance(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """State-space noise ``R`` (3, 3) of the module docstring."""
        return self.linearize(pose, control, dt)[2]

    def linearize(self, pose: ArrayLike, control: ArrayLike, dt: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(delta, G, R)`` at ``pose`` for ``control`` over ``dt`` (module docstring)."""
        pose, control, dt = self._check(pose, control, dt)
        return self.linearize_trusted(pose, control, dt)

    def linearize_trusted(
        self, pose: FloatArray, control: FloatArray, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """:meth:`linearize` without input checks, for filters that validated the inputs."""
        dt = float(dt)
        v_e = float(control[0])
        v00, v01, v10, v11, v20, v21, dx, dy, w = self._control_jacobian(float(pose[2]), v_e, float(control[1]), dt)
        scale = self.reference_dt / dt
        m_v = (self.sigma_speed**2 + (self.sigma_speed_rel * v_e) ** 2) * scale
        m_a = self.sigma_steering**2 * scale
        floor = self.noise_floor * dt / self.reference_dt
        r01 = v00 * m_v * v10 + v01 * m_a * v11
        r02 = v00 * m_v * v20 + v01 * m_a * v21
        r12 = v10 * m_v * v20 + v11 * m_a * v21
        noise = np.array(
            [
                [v00 * m_v * v00 + v01 * m_a * v01 + floor, r01, r02],
                [r01, v10 * m_v * v10 + v11 * m_a * v11 + floor, r12],
                [r02, r12, v20 * m_v * v20 + v21 * m_a * v21 + floor],
            ]
        )
        delta = np.array([dx, dy, w * dt])
        jacobian = np.array([[1.0, 0.0, -dy], [0.0, 1.0, dx], [0.0, 0.0, 1.0]])
        return delta, jacobian, noise

    # -- stochastic model ---------------------------------------------------
    def sample(self, pose: ArrayLike, control: ArrayLike, dt: float, rng: np.random.Generator) -> FloatArray:
        """Next true pose: the controls perturbed by ``N(0, M reference_dt / dt)``, then :meth:`predict`.

        The perturbed steering angle is clipped to ``max_steering``. The floor
        is not sampled (it only conditions the filters).
        """
        pose, control, dt = self._check(pose, control, dt)
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        return self.sample_trusted(pose, control, dt, rng)

    def sample_trusted(self, pose: FloatArray, control: FloatArray, dt: float, rng: np.random.Generator) -> FloatArray:
        """:meth:`sample` without input checks."""
        v_e, alpha = float(control[0]), float(control[1])
        scale = math.sqrt(self.reference_dt / float(dt))
        noise = rng.standard_normal(2)
        v_hat = v_e + scale * math.hypot(self.sigma_speed, self.sigma_speed_rel * v_e) * noise[0]
        a_hat = min(max(alpha + scale * self.sigma_steering * noise[1], -self.max_steering), self.max_steering)
        return self.predict_trusted(pose, (v_hat, a_hat), dt)
