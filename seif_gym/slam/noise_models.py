"""Noise models that real data need: per-second motion noise, command correction, range-dependent sensing.

The models of :mod:`seif_gym.slam.models` follow the book: Thrun's velocity
model holds the noise of the controls ``(v, omega)`` over a step, so its
state-space noise shrinks like ``dt^2`` and a filter fed the same second of
driving in 100 steps of 10 ms believes it 100 times more than in one step;
the range-bearing sensor has one noise for all ranges. Real logs (the UTIAS
MRCLAM dataset, :mod:`seif_gym.datasets.mrclam`) need instead:

* :class:`PerSecondVelocityMotionModel`: the same kinematics, with noise
  specified *per second* (white noise on the executed controls, plus a
  lateral slip), so the predicted covariance grows linearly in time whatever
  the step length;
* :class:`CommandCorrection` and :class:`CorrectedMotionModel`: commanded
  velocities are biased (robots slow down in turns, turn rates are overstated);
  the correction maps a command to the controls the robot executes, in front
  of any motion model;
* :class:`RangeDependentSensor`: range noise ``sigma_r(r) = clip(a r, lo, hi)``.

Each is an ordinary motion model or sensor: a filter of :mod:`seif_gym.slam`
takes it where it takes :class:`~seif_gym.slam.models.VelocityMotionModel` or
:class:`~seif_gym.slam.models.RangeBearingSensor`, and the filters read the
per-measurement noise of a range-dependent sensor through
``sensor.measurement_covariances`` (see :class:`~seif_gym.slam.base.SlamFilter`).
The innovation gate that rejects outliers is a filter option
(``innovation_gate``), computed by :func:`mahalanobis_squared`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from seif_gym.slam.models import MotionModel, RangeBearingSensor, _sinc_and_derivative, wrap_angle
from seif_gym.type_aliases import FloatArray
from seif_gym.validation import (
    as_finite_array,
    as_finite_vector,
    as_nonnegative_scalar,
    as_positive_scalar,
    as_real_scalar,
)

__all__ = [
    "CommandCorrection",
    "CorrectedMotionModel",
    "PerSecondVelocityMotionModel",
    "RangeDependentSensor",
    "mahalanobis_squared",
]


def _density(value: ArrayLike, name: str) -> tuple[float, float, float]:
    """A triple of non-negative noise densities ``(constant, per v^2, per omega^2)``."""
    array = as_finite_vector(value, name, 3)
    if np.any(array < 0.0):
        raise ValueError(f"{name} must be non-negative, got {tuple(float(a) for a in array)}")
    return tuple(float(a) for a in array)  # type: ignore[return-value]


class PerSecondVelocityMotionModel:
    r"""Velocity motion model whose noise is specified per second (dt-linear).

    Parameters
    ----------
    forward : array_like of 3 floats, default (0, 0, 0)
        Density ``q_v = f0 + f1 v^2 + f2 omega^2`` of the forward-velocity
        noise, ``m^2/s`` (``f0`` in m^2/s, ``f1`` in s, ``f2`` in m^2 s/rad^2):
        the error of the distance driven in ``T`` seconds at constant
        controls has variance ``q_v T``.
    turn : array_like of 3 floats, default (0, 0, 0)
        Density ``q_w = t0 + t1 v^2 + t2 omega^2`` of the turn-rate noise,
        ``rad^2/s``: the heading error of ``T`` seconds has variance ``q_w T``.
    lateral : array_like of 3 floats, default (0, 0, 0)
        Density ``q_l = l0 + l1 v^2 + l2 omega^2`` of a sideways slip, ``m^2/s``,
        perpendicular to the chord of the step.
    noise_floor : float, default 1e-9
        Variance *per second* added to each diagonal entry of ``R``, so that
        the information filters stay well conditioned when the robot stands
        still; being per second, it keeps the model dt-linear.

    Notes
    -----
    The kinematics are those of :class:`~seif_gym.slam.models.VelocityMotionModel`
    (Thrun Table 5.3): the pose moves along the arc
    ``delta(theta, v, omega, dt)`` with Jacobians ``G = I + Delta`` and
    ``V = d delta / d(v, omega)`` (Thrun eq. 7.11). The executed controls are
    the commanded ones plus *white* noise of densities ``q_v``, ``q_w``
    averaged over the step, i.e. with covariance

    .. math:: M_{dt} = \mathrm{diag}(q_v, q_\omega) / \Delta t,

    and a lateral displacement ``N(0, q_l dt)`` along
    ``n = (-sin(theta + omega dt / 2), cos(theta + omega dt / 2), 0)``. The
    state-space noise is

    .. math:: R = V M_{dt} V^T + q_l \Delta t\, n n^T + \epsilon \Delta t\, I .

    Since ``V = dt J`` with ``J = (c, s, 0; *, *, 1)`` bounded, ``R = dt (J
    diag(q_v, q_w) J^T + q_l n n^T + eps I)``: linear in ``dt`` to first order.
    Predicting ``T`` seconds in ``N`` steps sums ``N`` such terms (propagated
    by ``G``), so the covariance is ``T`` times the per-second rate up to terms
    of order ``T^2`` (the heading noise turning into cross-track error), the
    same for every ``N``. Thrun's model, with ``M`` independent of ``dt``,
    gives ``R ~ dt^2`` and ``N`` times less covariance for ``N`` times more
    steps.
    """

    def __init__(
        self,
        forward: ArrayLike = (0.0, 0.0, 0.0),
        turn: ArrayLike = (0.0, 0.0, 0.0),
        lateral: ArrayLike = (0.0, 0.0, 0.0),
        noise_floor: float = 1e-9,
    ) -> None:
        self.forward = _density(forward, "forward")
        self.turn = _density(turn, "turn")
        self.lateral = _density(lateral, "lateral")
        self.noise_floor = as_positive_scalar(noise_floor, "noise_floor")

    def __repr__(self) -> str:
        return (
            f"PerSecondVelocityMotionModel(forward={self.forward}, turn={self.turn}, "
            f"lateral={self.lateral}, noise_floor={self.noise_floor})"
        )

    # -- validation -----------------------------------------------------------
    def validate_control(self, control: ArrayLike) -> FloatArray:
        """Return ``control`` as a finite ``(v, omega)`` array or raise."""
        return as_finite_vector(control, "control", 2)

    def _check(self, pose: ArrayLike, control: ArrayLike, dt: float) -> tuple[FloatArray, FloatArray, float]:
        return as_finite_vector(pose, "pose", 3), self.validate_control(control), as_positive_scalar(dt, "dt")

    # -- noise ----------------------------------------------------------------
    def noise_rates(self, control: ArrayLike) -> FloatArray:
        """``(q_v, q_w, q_l)`` at ``control``: variances per second (m^2/s, rad^2/s, m^2/s)."""
        v, w = self.validate_control(control)
        return np.array(self._rates(float(v), float(w)))

    def _rates(self, v: float, w: float) -> tuple[float, float, float]:
        vv, ww = v * v, w * w
        f, t, l_ = self.forward, self.turn, self.lateral
        return f[0] + f[1] * vv + f[2] * ww, t[0] + t[1] * vv + t[2] * ww, l_[0] + l_[1] * vv + l_[2] * ww

    def control_covariance(self, control: ArrayLike, dt: float) -> FloatArray:
        """``M_dt = diag(q_v, q_w) / dt`` (2, 2): covariance of the executed controls over one step."""
        q_v, q_w, _ = self.noise_rates(control)
        dt = as_positive_scalar(dt, "dt")
        return np.diag([q_v / dt, q_w / dt])

    # -- deterministic model --------------------------------------------------
    def displacement(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """Pose increment ``delta`` (angle not wrapped), as the velocity model's."""
        pose, control, dt = self._check(pose, control, dt)
        half = 0.5 * control[1] * dt
        sinc, _ = _sinc_and_derivative(half)
        mid = pose[2] + half
        return np.array(
            [control[0] * dt * math.cos(mid) * sinc, control[0] * dt * math.sin(mid) * sinc, control[1] * dt]
        )

    def predict(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """Noise-free next pose with the heading wrapped."""
        pose, control, dt = self._check(pose, control, dt)
        return self.predict_trusted(pose, control, dt)

    def predict_trusted(self, pose: FloatArray, control: FloatArray, dt: float) -> FloatArray:
        """:meth:`predict` without input checks."""
        delta = self.linearize_trusted(pose, control, dt)[0]
        return np.array([pose[0] + delta[0], pose[1] + delta[1], wrap_angle(float(pose[2] + delta[2]))])

    def jacobian_state(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """``G = I + Delta`` (3, 3)."""
        pose, control, dt = self._check(pose, control, dt)
        return self.linearize_trusted(pose, control, dt)[1]

    def jacobian_control(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """``V = d g / d(v, omega)`` (3, 2), Thrun eq. 7.11."""
        pose, control, dt = self._check(pose, control, dt)
        return self._terms(float(pose[2]), float(control[0]), float(control[1]), dt)[2]

    def noise_covariance(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """State-space noise ``R`` (3, 3) of the class Notes."""
        return self.linearize(pose, control, dt)[2]

    @staticmethod
    def _terms(theta: float, v: float, w: float, dt: float) -> tuple[float, float, FloatArray]:
        """``(cos mid, sin mid, V)`` of one step."""
        half = 0.5 * w * dt
        sinc, dsinc = _sinc_and_derivative(half)
        mid = theta + half
        c, s = math.cos(mid), math.sin(mid)
        jacobian_control = np.array(
            [
                [dt * c * sinc, v * dt * 0.5 * dt * (-s * sinc + c * dsinc)],
                [dt * s * sinc, v * dt * 0.5 * dt * (c * sinc + s * dsinc)],
                [0.0, dt],
            ]
        )
        return c, s, jacobian_control

    def linearize(self, pose: ArrayLike, control: ArrayLike, dt: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(delta, G, R)`` at ``pose`` for ``control`` over ``dt`` (class Notes)."""
        pose, control, dt = self._check(pose, control, dt)
        return self.linearize_trusted(pose, control, dt)

    def linearize_trusted(
        self, pose: FloatArray, control: FloatArray, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """:meth:`linearize` without input checks, for the filters (which validated the inputs)."""
        theta, v, w, dt = float(pose[2]), float(control[0]), float(control[1]), float(dt)
        c, s, V = self._terms(theta, v, w, dt)
        delta = np.array([v * V[0, 0], v * V[1, 0], w * dt])
        jacobian = np.array([[1.0, 0.0, -delta[1]], [0.0, 1.0, delta[0]], [0.0, 0.0, 1.0]])
        q_v, q_w, q_l = self._rates(v, w)
        noise = (V * np.array([q_v / dt, q_w / dt])) @ V.T
        normal = np.array([-s, c, 0.0])
        noise += (q_l * dt) * np.outer(normal, normal)
        noise[np.diag_indices(3)] += self.noise_floor * dt
        return delta, jacobian, 0.5 * (noise + noise.T)

    # -- stochastic model -----------------------------------------------------
    def sample(self, pose: ArrayLike, control: ArrayLike, dt: float, rng: np.random.Generator) -> FloatArray:
        """Draw the next true pose: the arc of the noisy controls, plus the lateral slip (class Notes)."""
        pose, control, dt = self._check(pose, control, dt)
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        return self.sample_trusted(pose, control, dt, rng)

    def sample_trusted(self, pose: FloatArray, control: FloatArray, dt: float, rng: np.random.Generator) -> FloatArray:
        """:meth:`sample` without input checks, for simulators."""
        v, w, dt = float(control[0]), float(control[1]), float(dt)
        q_v, q_w, q_l = self._rates(v, w)
        noise = rng.standard_normal(3)
        v_hat = v + math.sqrt(q_v / dt) * noise[0]
        w_hat = w + math.sqrt(q_w / dt) * noise[1]
        slip = math.sqrt(q_l * dt) * noise[2]
        theta = float(pose[2])
        half = 0.5 * w_hat * dt
        sinc, _ = _sinc_and_derivative(half)
        mid = theta + half
        c, s = math.cos(mid), math.sin(mid)
        return np.array(
            [
                pose[0] + v_hat * dt * c * sinc - slip * s,
                pose[1] + v_hat * dt * s * sinc + slip * c,
                wrap_angle(theta + w_hat * dt),
            ]
        )


@dataclass(frozen=True)
class CommandCorrection:
    r"""Map commanded velocities to the ones a robot executes.

    Parameters
    ----------
    speed_scale : float, default 1
        ``s_v > 0``.
    turn_slowdown : float, default 0
        ``c >= 0``, s/rad: the robot slows down in turns.
    speed_offset : float, default 0
        ``b_v``, m/s.
    turn_scale : float, default 1
        ``s_w > 0``.
    turn_offset : float, default 0
        ``b_w``, rad/s.

    Notes
    -----
    .. math:: v' = s_v\, v \max(0, 1 - c|\omega|) + b_v, \qquad
              \omega' = s_\omega\, \omega + b_\omega .

    The form transfers between the MRCLAM datasets (their README: at
    ``|omega| > 0.3`` rad/s the robots reach ~0.6 of the commanded speed, and
    the commanded turn rate is ~7 % high). Its Jacobian
    ``d(v', omega') / d(v, omega)`` is :meth:`jacobian` (``|omega|`` has no
    derivative at 0: the right-hand one is taken).
    """

    speed_scale: float = 1.0
    turn_slowdown: float = 0.0
    speed_offset: float = 0.0
    turn_scale: float = 1.0
    turn_offset: float = 0.0

    def __post_init__(self) -> None:
        for name in ("speed_scale", "turn_scale"):
            object.__setattr__(self, name, as_positive_scalar(getattr(self, name), name))
        object.__setattr__(self, "turn_slowdown", as_nonnegative_scalar(self.turn_slowdown, "turn_slowdown"))
        for name in ("speed_offset", "turn_offset"):
            object.__setattr__(self, name, as_real_scalar(getattr(self, name), name))

    @property
    def is_identity(self) -> bool:
        """True when the correction changes nothing."""
        return self == CommandCorrection()

    def apply(self, control: ArrayLike) -> FloatArray:
        """Corrected controls of ``control``: shape (2,) or (n, 2) -> the same shape."""
        array = np.asarray(control, dtype=np.float64) if not isinstance(control, (str, bytes)) else None
        if array is None or array.ndim not in (1, 2) or array.shape[-1] != 2:
            raise ValueError(
                f"control must have shape (2,) or (n, 2), got {getattr(array, 'shape', type(control).__name__)}"
            )
        array = as_finite_array(array, "control", (None,) * (array.ndim - 1) + (2,))
        if array.ndim == 1:
            return self.apply_trusted(array)
        factor = np.maximum(0.0, 1.0 - self.turn_slowdown * np.abs(array[:, 1]))
        return np.column_stack(
            [
                self.speed_scale * array[:, 0] * factor + self.speed_offset,
                self.turn_scale * array[:, 1] + self.turn_offset,
            ]
        )

    def apply_trusted(self, control: FloatArray) -> FloatArray:
        """:meth:`apply` of one finite control (2,), without checks."""
        v, w = float(control[0]), float(control[1])
        factor = max(0.0, 1.0 - self.turn_slowdown * abs(w))
        return np.array([self.speed_scale * v * factor + self.speed_offset, self.turn_scale * w + self.turn_offset])

    def jacobian(self, control: ArrayLike) -> FloatArray:
        """``d(v', omega') / d(v, omega)`` (2, 2) at one control."""
        v, w = as_finite_vector(control, "control", 2)
        factor = 1.0 - self.turn_slowdown * abs(w)
        if factor > 0.0:
            dv_dv = self.speed_scale * factor
            dv_dw = -self.speed_scale * v * self.turn_slowdown * (1.0 if w >= 0.0 else -1.0)
        else:
            dv_dv = dv_dw = 0.0
        return np.array([[dv_dv, dv_dw], [0.0, self.turn_scale]])

    def to_dict(self) -> dict[str, float]:
        """The parameters by name (JSON-ready)."""
        return {name: float(getattr(self, name)) for name in self.__dataclass_fields__}


class CorrectedMotionModel:
    """A motion model fed corrected commands: ``model`` at ``correction.apply(control)``.

    Parameters
    ----------
    model : MotionModel
        Any motion model of :mod:`seif_gym.slam` (``linearize``, ``sample``...).
    correction : CommandCorrection
        The map from commanded to executed velocities.

    Notes
    -----
    ``g'(x, u) = g(x, c(u))``: the increment and ``G = dg/dx`` are the
    model's at ``c(u)``, and so is the noise (the correction is deterministic;
    what it leaves unexplained is the model's noise). The control Jacobian is
    ``V' = V(c(u)) dc/du`` (:meth:`jacobian_control`).
    """

    def __init__(self, model: MotionModel, correction: CommandCorrection) -> None:
        if not callable(getattr(model, "linearize", None)) or not callable(getattr(model, "validate_control", None)):
            raise TypeError(
                f"model must be a motion model with linearize and validate_control, got {type(model).__name__}"
            )
        if not isinstance(correction, CommandCorrection):
            raise TypeError(f"correction must be a CommandCorrection, got {type(correction).__name__}")
        self.model = model
        self.correction = correction
        self._linearize = getattr(model, "linearize_trusted", model.linearize)

    def __repr__(self) -> str:
        return f"CorrectedMotionModel({self.model!r}, {self.correction!r})"

    def validate_control(self, control: ArrayLike) -> FloatArray:
        """Return the *commanded* ``control`` as a finite ``(v, omega)`` array or raise."""
        return self.model.validate_control(control)

    def corrected(self, control: ArrayLike) -> FloatArray:
        """The executed controls of a command."""
        return self.correction.apply_trusted(self.validate_control(control))

    def linearize(self, pose: ArrayLike, control: ArrayLike, dt: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The model's ``(delta, G, R)`` at the corrected controls."""
        return self.model.linearize(pose, self.corrected(control), dt)

    def linearize_trusted(
        self, pose: FloatArray, control: FloatArray, dt: float
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """:meth:`linearize` without input checks."""
        return self._linearize(pose, self.correction.apply_trusted(control), dt)

    def predict(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """The model's noise-free next pose at the corrected controls."""
        return self.model.predict(pose, self.corrected(control), dt)

    def jacobian_control(self, pose: ArrayLike, control: ArrayLike, dt: float) -> FloatArray:
        """``V' = V(c(u)) dc/du`` (3, 2), by the chain rule."""
        control = self.validate_control(control)
        # not part of MotionModel: every model of seif_gym.slam has it (another raises AttributeError here)
        model_jacobian = self.model.jacobian_control  # type: ignore[attr-defined]
        return model_jacobian(pose, self.correction.apply_trusted(control), dt) @ self.correction.jacobian(control)

    def sample(self, pose: ArrayLike, control: ArrayLike, dt: float, rng: np.random.Generator) -> FloatArray:
        """The model's draw at the corrected controls."""
        return self.model.sample(pose, self.corrected(control), dt, rng)

    def sample_trusted(self, pose: FloatArray, control: FloatArray, dt: float, rng: np.random.Generator) -> FloatArray:
        """:meth:`sample` without input checks."""
        sample = getattr(self.model, "sample_trusted", self.model.sample)
        return sample(pose, self.correction.apply_trusted(control), dt, rng)


class RangeDependentSensor(RangeBearingSensor):
    r"""Range-bearing sensor whose range noise grows with range.

    Parameters
    ----------
    range_slope : float, default 0.05
        ``a``: the range noise's standard deviation per metre of range.
    range_bounds : array_like of 2 floats, default (0.02, 0.5)
        ``(lo, hi)``, m, with ``0 < lo <= hi``.
    sigma_bearing, max_range, fov, min_range
        As for :class:`~seif_gym.slam.models.RangeBearingSensor`.

    Notes
    -----
    .. math:: \sigma_r(r) = \mathrm{clip}(a r, lo, hi), \qquad
              Q(r) = \mathrm{diag}(\sigma_r(r)^2, \sigma_\phi^2).

    The measurement function and its Jacobian ``H`` are the range-bearing
    sensor's (the noise does not change them). The filters evaluate ``Q`` at
    the *measured* range (:meth:`measurement_covariances`), the only range a
    new landmark has, so every filter weighs a measurement the same.
    :attr:`noise_covariance` holds the largest ``Q`` (``sigma_r = hi``), for code
    that takes one covariance for all measurements; ``sigma_range`` is ``hi``.
    :meth:`sample` draws the range noise at the true range.
    """

    #: The filters read per-measurement covariances from this sensor.
    range_dependent = True

    def __init__(
        self,
        range_slope: float = 0.05,
        range_bounds: ArrayLike = (0.02, 0.5),
        sigma_bearing: float = math.radians(2.0),
        max_range: float = 8.0,
        fov: float = 2.0 * math.pi,
        min_range: float = 0.0,
    ) -> None:
        slope = as_positive_scalar(range_slope, "range_slope")
        bounds = as_finite_vector(range_bounds, "range_bounds", 2)
        if not 0.0 < bounds[0] <= bounds[1]:
            raise ValueError(f"range_bounds must satisfy 0 < lo <= hi, got {tuple(float(b) for b in bounds)}")
        super().__init__(
            sigma_range=float(bounds[1]), sigma_bearing=sigma_bearing, max_range=max_range, fov=fov, min_range=min_range
        )
        self.range_slope = slope
        self.range_bounds: tuple[float, float] = (float(bounds[0]), float(bounds[1]))

    def __repr__(self) -> str:
        return (
            f"RangeDependentSensor(range_slope={self.range_slope}, range_bounds={self.range_bounds}, "
            f"sigma_bearing={self.sigma_bearing}, max_range={self.max_range}, fov={self.fov}, "
            f"min_range={self.min_range})"
        )

    def range_sigma(self, ranges: ArrayLike) -> FloatArray:
        """``sigma_r(r) = clip(a r, lo, hi)`` for each range, m."""
        ranges = as_finite_array(np.atleast_1d(ranges), "ranges", (None,))
        return np.clip(self.range_slope * ranges, *self.range_bounds)

    def range_sigma_derivative(self, ranges: ArrayLike) -> FloatArray:
        """``d sigma_r / d r``: ``a`` where ``lo < a r < hi``, else 0."""
        ranges = as_finite_array(np.atleast_1d(ranges), "ranges", (None,))
        scaled = self.range_slope * ranges
        inside = (scaled > self.range_bounds[0]) & (scaled < self.range_bounds[1])
        return np.where(inside, self.range_slope, 0.0)

    def measurement_covariances(self, ranges: ArrayLike) -> FloatArray:
        """``Q(r)`` of each measurement, shape (m, 2, 2)."""
        sigma = self.range_sigma(ranges)
        covs = np.zeros((len(sigma), 2, 2))
        covs[:, 0, 0] = sigma * sigma
        covs[:, 1, 1] = self.sigma_bearing**2
        return covs

    def sample_trusted(
        self, pose: FloatArray, landmarks: FloatArray, rng: np.random.Generator, ids: ArrayLike | None = None
    ) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
        """:meth:`sample` without input checks: the range noise at each true range."""
        visible = self._visible(self.predict_trusted(pose, landmarks))
        indices = np.flatnonzero(visible)
        z = self.predict_trusted(pose, landmarks[indices])
        noise = rng.standard_normal((len(indices), 2))
        sigma = np.clip(self.range_slope * z[:, 0], *self.range_bounds)
        ranges = np.abs(z[:, 0] + noise[:, 0] * sigma)
        bearings = (z[:, 1] + noise[:, 1] * self.sigma_bearing + np.pi) % (2.0 * np.pi) - np.pi
        visible_ids = indices.astype(np.int64) if ids is None else np.asarray(ids)[indices].astype(np.int64)
        return ranges, bearings, visible_ids


def mahalanobis_squared(innovations: ArrayLike, covariances: ArrayLike) -> FloatArray:
    """``d_i^2 = nu_i^T S_i^-1 nu_i`` for each innovation, shape (m,).

    Parameters
    ----------
    innovations : array_like, shape (m, 2)
        ``nu_i = wrap(z_i - h(mu))`` (bearing wrapped).
    covariances : array_like, shape (m, 2, 2)
        ``S_i = H_i Sigma H_i^T + Q_i``, symmetric positive definite.

    Notes
    -----
    For a consistent filter ``d_i^2`` is chi-square with 2 degrees of freedom;
    the innovation gate rejects ``d_i^2 > gate`` (13.8 is its 99.9 % quantile,
    9.21 its 99 %). Computed in closed form for 2 x 2 blocks.
    """
    nu = as_finite_array(innovations, "innovations", (None, 2))
    s = as_finite_array(covariances, "covariances", (len(nu), 2, 2))
    det = s[:, 0, 0] * s[:, 1, 1] - s[:, 0, 1] * s[:, 1, 0]
    if np.any(det <= 0.0) or np.any(s[:, 0, 0] <= 0.0):
        raise ValueError("covariances must be positive definite")
    off = 0.5 * (s[:, 0, 1] + s[:, 1, 0])
    return (s[:, 1, 1] * nu[:, 0] ** 2 - 2.0 * off * nu[:, 0] * nu[:, 1] + s[:, 0, 0] * nu[:, 1] ** 2) / det
