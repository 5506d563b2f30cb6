"""Robust estimators for calibrating noise models from heavy-tailed residuals.

Real residuals (``seif_gym.datasets.mrclam``: commands against Vicon ground
truth, range-bearing readings against the survey) are heavy-tailed and carry
outliers (misread barcodes, ground-truth glitches). Least squares and sample
variances follow the outliers; the estimators here bound their influence and
are Fisher-consistent at the Gaussian (they recover the Gaussian parameters
when there are no outliers):

* :func:`mad_scale`: the normalised median absolute deviation.
* :func:`huber_location`: Huber's M-estimate of location (scale by the MAD).
* :func:`huber_regression`: linear regression with Huber's loss by
  iteratively reweighted least squares, scale re-estimated by the MAD.
* :func:`fit_scale_model`: a *scale model* ``sigma_i(theta)`` (for example
  ``clip(a r_i, lo, hi)``) fitted to zero-mean residuals by Huber's
  "proposal 2" scale M-estimator.
* :func:`fit_variance_regression`: the same for a variance linear in
  non-negative coefficients, ``sigma_i^2 = x_i . c`` (motion-noise densities).
* :func:`robust_correlation`: a correlation that outliers do not drive.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import scipy.optimize
import scipy.stats
from numpy.typing import ArrayLike, NDArray

from seif_gym.type_aliases import FloatArray

__all__ = [
    "HUBER_K",
    "REJECT_AT",
    "SCALE_K",
    "fit_scale_model",
    "fit_variance_regression",
    "huber_location",
    "huber_regression",
    "mad_scale",
    "robust_correlation",
    "scale_consistency",
    "scale_objective",
    "trimmed_consistency",
]


#: Huber's tuning constant for location and regression (95 % efficiency at the Gaussian).
HUBER_K = 1.345
#: Tuning constant of the scale estimators' first stage: residuals beyond 2.5 sigma have bounded influence.
SCALE_K = 2.5
#: Their second stage leaves out residuals beyond this many sigma (gross outliers).
REJECT_AT = 3.0
_MAD_TO_SIGMA = 1.0 / scipy.stats.norm.ppf(0.75)


def _finite_1d(values: ArrayLike, name: str) -> FloatArray:
    if isinstance(values, (str, bytes)) or values is None:
        raise TypeError(f"{name} must be an array of numbers, got {type(values).__name__}")
    array = np.asarray(values, dtype=np.float64)
    if array.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional, got shape {array.shape}")
    if len(array) == 0:
        raise ValueError(f"{name} must not be empty")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite")
    return array


def mad_scale(residuals: ArrayLike) -> float:
    """``1.4826 median |e - median(e)|``: the standard deviation of a Gaussian, robustly."""
    e = _finite_1d(residuals, "residuals")
    return float(_MAD_TO_SIGMA * np.median(np.abs(e - np.median(e))))


def huber_location(values: ArrayLike, k: float = HUBER_K, tol: float = 1e-10, max_iter: int = 100) -> float:
    """Huber's M-estimate of location of ``values`` (scale fixed at their MAD).

    Notes
    -----
    Solves ``sum_i psi_k((x_i - m) / s) = 0`` with ``psi_k(u) = clip(u, -k, k)``
    and ``s`` the MAD scale, by iteratively reweighted means
    (weights ``min(1, k / |u_i|)``), starting from the median.
    """
    x = _finite_1d(values, "values")
    m = float(np.median(x))
    s = mad_scale(x)
    if s == 0.0:
        return m
    for _ in range(max_iter):
        u = np.abs(x - m) / s
        w = np.minimum(1.0, k / np.maximum(u, 1e-300))
        new = float(np.sum(w * x) / np.sum(w))
        if abs(new - m) <= tol * s:
            return new
        m = new
    return m


def huber_regression(
    design: ArrayLike,
    response: ArrayLike,
    k: float = HUBER_K,
    weights: ArrayLike | None = None,
    tol: float = 1e-10,
    max_iter: int = 200,
) -> tuple[FloatArray, float]:
    """Linear regression ``y ~ X b`` with Huber's loss: ``(b, scale)``.

    Parameters
    ----------
    design : array_like, shape (n, p)
        ``X``, full column rank.
    response : array_like, shape (n,)
        ``y``.
    k : float
        Huber's constant, in units of the residual scale.
    weights : array_like, shape (n,), optional
        Known relative precisions of the observations (``1 / variance``, up
        to a factor), e.g. for residuals whose scale grows with a window's
        length.

    Notes
    -----
    Iteratively reweighted least squares on ``sum_i rho_k(sqrt(w_i) r_i / s)``,
    ``r = y - X b``, with Huber's ``rho_k`` (quadratic within ``k``, linear
    beyond) and ``s`` the MAD of the weighted residuals, re-estimated each
    iteration. Starts from least squares.
    """
    X = np.asarray(design, dtype=np.float64)
    y = _finite_1d(response, "response")
    if X.ndim != 2 or X.shape[0] != len(y) or not np.all(np.isfinite(X)):
        raise ValueError(f"design must be a finite array of shape ({len(y)}, p), got {X.shape}")
    w0 = np.ones(len(y)) if weights is None else _finite_1d(weights, "weights")
    if len(w0) != len(y) or np.any(w0 <= 0):
        raise ValueError("weights must be positive, one per observation")
    root = np.sqrt(w0)
    b = np.linalg.lstsq(X * root[:, None], y * root, rcond=None)[0]
    scale = 0.0
    for _ in range(max_iter):
        r = (y - X @ b) * root
        scale = mad_scale(r)
        if scale == 0.0:
            break
        u = np.abs(r) / scale
        w = w0 * np.minimum(1.0, k / np.maximum(u, 1e-300))
        sw = np.sqrt(w)
        new = np.linalg.lstsq(X * sw[:, None], y * sw, rcond=None)[0]
        if np.max(np.abs(new - b)) <= tol * (1.0 + np.max(np.abs(b))):
            b = new
            break
        b = new
    return np.asarray(b, dtype=np.float64), float(scale)


def scale_consistency(k: float = SCALE_K) -> float:
    """``kappa = E[min(u^2, k^2)]`` for ``u ~ N(0, 1)``: makes :func:`fit_scale_model` consistent.

    Notes
    -----
    ``kappa = (2 Phi(k) - 1) - 2 k phi(k) + 2 k^2 (1 - Phi(k))``.
    """
    return float((2.0 * scipy.stats.norm.cdf(k) - 1.0) - 2.0 * k * scipy.stats.norm.pdf(k)
                 + 2.0 * k * k * scipy.stats.norm.sf(k))  # fmt: skip


def trimmed_consistency(c: float = REJECT_AT) -> float:
    """``m2 = E[u^2 | |u| <= c]`` for ``u ~ N(0, 1)``: the variance of a Gaussian trimmed at ``c``.

    Notes
    -----
    ``m2 = 1 - 2 c phi(c) / (2 Phi(c) - 1)``.
    """
    return float(1.0 - 2.0 * c * scipy.stats.norm.pdf(c) / (2.0 * scipy.stats.norm.cdf(c) - 1.0))


def _scale_objective(residuals: FloatArray, log_sigma: FloatArray, k: float, kappa: float,
                     inliers: NDArray[np.bool_] | None) -> tuple[float, FloatArray]:  # fmt: skip
    """The objective of :func:`fit_scale_model` and its derivative with respect to each ``log sigma_i``.

    ``inliers`` None: Huber's proposal 2 (``k``, ``kappa``); else the Gaussian
    objective over the inliers with the trimmed consistency ``kappa``.
    """
    u = np.abs(residuals) * np.exp(-log_sigma)
    if inliers is not None:
        u2 = np.where(inliers, u * u, 0.0)
        weight = inliers.astype(np.float64)
        return float(np.sum(0.5 * u2 + kappa * weight * log_sigma)), kappa * weight - u2
    inside = u <= k
    rho = np.where(inside, 0.5 * u * u, k * k * (0.5 + np.log(np.maximum(u, 1e-300) / k)))
    chi = np.where(inside, u * u, k * k)  # -d rho / d log sigma
    return float(np.sum(rho + kappa * log_sigma)), kappa - chi


def scale_objective(residuals: ArrayLike, log_sigma: ArrayLike, k: float = SCALE_K) -> float:
    """Huber's proposal-2 objective ``L_1`` of :func:`fit_scale_model` at given ``log sigma_i`` (to compare fits)."""
    e = _finite_1d(residuals, "residuals")
    return _scale_objective(e, np.asarray(log_sigma, dtype=np.float64), k, scale_consistency(k), None)[0]


def _refit(
    residuals: FloatArray,
    log_sigma: Callable[[FloatArray], FloatArray],
    minimise: Callable[..., FloatArray],
    theta: FloatArray,
    k: float,
    reject: float | None,
) -> FloatArray:
    """Huber's proposal 2 from ``theta``, then (``reject``) the trimmed Gaussian fit until the inliers settle."""
    theta = minimise(theta, None, scale_consistency(k))
    if reject is None:
        return theta
    m2 = trimmed_consistency(reject)
    inliers = None
    for _ in range(30):
        current = np.abs(residuals) * np.exp(-log_sigma(theta)) <= reject
        if inliers is not None and np.array_equal(current, inliers):
            break
        inliers = current
        theta = minimise(theta, inliers, m2)
    return theta


def fit_scale_model(
    residuals: ArrayLike,
    log_sigma: Callable[[FloatArray], FloatArray],
    theta0: ArrayLike,
    k: float = SCALE_K,
    reject: float | None = REJECT_AT,
) -> FloatArray:
    r"""Fit a scale model ``sigma_i(theta)`` to zero-mean residuals, robustly.

    Parameters
    ----------
    residuals : array_like, shape (n,)
        ``e_i``, assumed ``sigma_i(theta) u_i`` with ``u_i`` standard normal,
        plus outliers.
    log_sigma : callable
        ``theta -> log sigma_i(theta)``, shape (n,); parametrise ``theta`` so
        that every real vector is valid (logs of positive parameters).
    theta0 : array_like, shape (p,)
        Starting point.
    k : float
        Huber's constant of the first stage.
    reject : float or None
        Residuals beyond ``reject sigma_i`` are outliers in the second stage
        (None: no second stage).

    Returns
    -------
    ndarray, shape (p,)

    Notes
    -----
    Two stages, minimised by Nelder-Mead (the models may have kinks, e.g.
    a clip). First Huber's "proposal 2" scale M-estimator:

    .. math:: L_1(\theta) = \sum_i \rho_k(e_i / \sigma_i) + \kappa_k \log \sigma_i,

    ``rho_k(u) = u^2/2`` for ``|u| <= k`` and ``k^2 (1/2 + log(|u|/k))``
    beyond, whose derivative in ``log sigma_i`` is ``kappa_k - min(u_i^2, k^2)``;
    with ``kappa_k = E[min(u^2, k^2)]`` (:func:`scale_consistency`) the
    estimating equation holds in expectation at the true ``theta``. An
    outlier's influence is bounded but not zero, so, second, the residuals
    with ``|e_i| > reject sigma_i`` are set aside and

    .. math:: L_2(\theta) = \sum_{|u_i| \le c} u_i^2 / 2 + m_2(c) \log \sigma_i

    is minimised, ``m_2(c) = E[u^2 | |u| <= c]`` (:func:`trimmed_consistency`),
    the inliers re-selected until they settle: a trimmed Gaussian fit,
    consistent at the Gaussian, in which gross outliers have no influence.
    """
    e = _finite_1d(residuals, "residuals")

    def minimise(theta: FloatArray, inliers: NDArray[np.bool_] | None, kappa: float) -> FloatArray:
        def objective(t: FloatArray) -> float:
            return _scale_objective(e, np.asarray(log_sigma(t), dtype=np.float64), k, kappa, inliers)[0]

        result = scipy.optimize.minimize(objective, np.asarray(theta, dtype=np.float64), method="Nelder-Mead",
                                         options={"maxiter": 4000, "xatol": 1e-8, "fatol": 1e-10})  # fmt: skip
        return np.asarray(result.x, dtype=np.float64)

    return _refit(
        e,
        lambda t: np.asarray(log_sigma(t), dtype=np.float64),
        minimise,
        np.asarray(theta0, dtype=np.float64),
        k,
        reject,
    )


def fit_variance_regression(
    residuals: ArrayLike, features: ArrayLike, k: float = SCALE_K, reject: float | None = REJECT_AT
) -> FloatArray:
    r"""Non-negative coefficients ``c`` of a variance model ``sigma_i^2 = x_i . c``, fitted robustly.

    Parameters
    ----------
    residuals : array_like, shape (n,)
        Zero-mean residuals ``e_i`` (for example the heading error of a
        window of driving).
    features : array_like, shape (n, p)
        Non-negative ``x_i`` (for example the window's duration and its
        integrals of ``v^2`` and ``omega^2``), each column with some positive entry.
    k, reject : float
        As for :func:`fit_scale_model`.

    Returns
    -------
    ndarray, shape (p,)
        ``c >= 0``.

    Notes
    -----
    The two stages of :func:`fit_scale_model` with
    ``log sigma_i = log(x_i . c) / 2``, minimised over ``c >= 0`` by L-BFGS-B
    with the analytic gradient ``dL/dc_j = sum_i g_i x_ij / (2 x_i . c)``,
    ``g_i`` the derivative in ``log sigma_i``, on columns scaled to unit mean.
    """
    e = _finite_1d(residuals, "residuals")
    X = np.asarray(features, dtype=np.float64)
    if X.ndim != 2 or X.shape[0] != len(e) or not np.all(np.isfinite(X)) or np.any(X < 0):
        raise ValueError(f"features must be a finite non-negative array of shape ({len(e)}, p), got {X.shape}")
    column_scale = X.mean(axis=0)
    if np.any(column_scale <= 0):
        raise ValueError("every column of features must have a positive entry")
    Xs = X / column_scale
    level = max(mad_scale(e) ** 2, 1e-300)
    tiny = level * 1e-12

    def log_sigma(c: FloatArray) -> FloatArray:
        return 0.5 * np.log(np.maximum(Xs @ c, 1e-300))

    def minimise(c: FloatArray, inliers: NDArray[np.bool_] | None, kappa: float) -> FloatArray:
        def objective(c: FloatArray) -> tuple[float, FloatArray]:
            variance = np.maximum(Xs @ c, 1e-300)
            value, slope = _scale_objective(e, 0.5 * np.log(variance), k, kappa, inliers)
            return value, Xs.T @ (slope * 0.5 / variance)

        result = scipy.optimize.minimize(objective, np.maximum(c, tiny), jac=True, method="L-BFGS-B",
                                         bounds=[(tiny, None)] * X.shape[1],
                                         options={"maxiter": 1000, "ftol": 1e-15, "gtol": 1e-12})  # fmt: skip
        return np.asarray(result.x, dtype=np.float64)

    start = np.full(X.shape[1], level / X.shape[1])  # the MAD variance spread over the columns
    coefficients = _refit(e, log_sigma, minimise, start, k, reject)
    return np.where(coefficients <= 2.0 * tiny, 0.0, coefficients) / column_scale


def robust_correlation(a: ArrayLike, b: ArrayLike) -> float:
    """Correlation of two paired samples from robust standardisation (MAD, median), clipped to [-1, 1].

    Notes
    -----
    ``(s(a/sa + b/sb)^2 - s(a/sa - b/sb)^2) / (s(a/sa + b/sb)^2 + s(a/sa - b/sb)^2)``
    with ``s`` the MAD scale (the Gnanadesikan-Kettenring identity).
    """
    x = _finite_1d(a, "a")
    y = _finite_1d(b, "b")
    if len(x) != len(y):
        raise ValueError("a and b must have the same length")
    sx, sy = mad_scale(x), mad_scale(y)
    if sx == 0.0 or sy == 0.0:
        return math.nan
    plus, minus = mad_scale(x / sx + y / sy) ** 2, mad_scale(x / sx - y / sy) ** 2
    return float(np.clip((plus - minus) / (plus + minus), -1.0, 1.0))
