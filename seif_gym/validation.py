"""Input checks shared by the filters, the models, the env and its wrappers.

Every public entry point of :mod:`seif_gym.slam`, the env's configurations
and the observation wrappers validate their arguments here *before* they
touch any state, so a bad call raises a clear ``ValueError`` or
``TypeError`` naming the argument and leaves the object exactly as it was.

>>> from seif_gym.validation import as_positive_scalar
>>> as_positive_scalar(2, "cell")
2.0
>>> as_positive_scalar(0.0, "cell")
Traceback (most recent call last):
    ...
ValueError: cell must be positive, got 0.0
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "as_finite_vector",
    "as_finite_array",
    "as_real_scalar",
    "as_positive_scalar",
    "as_nonnegative_scalar",
    "as_scalar_between",
    "as_count",
    "as_id_array",
    "as_covariance",
]


def _kind(value: Any) -> str:
    return type(value).__name__


def as_finite_array(value: Any, name: str, shape: tuple[int | None, ...]) -> NDArray[np.float64]:
    """Return ``value`` as a finite float64 array of ``shape`` (``None`` = any length)."""
    # fast path for the common case, a float64 array of the right shape: a sum is
    # finite only if every entry is (an overflowing sum falls through to the full check)
    if type(value) is np.ndarray and value.dtype == np.float64 and value.ndim == len(shape):
        if all(expected is None or actual == expected for actual, expected in zip(value.shape, shape)):
            if math.isfinite(value.sum()):
                return value
    if isinstance(value, (str, bytes)) or value is None:
        raise TypeError(f"{name} must be an array of numbers, got {_kind(value)}")
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise TypeError(f"{name} must be an array of numbers, got {_kind(value)}") from error
    if array.ndim != len(shape) or any(
        expected is not None and actual != expected for actual, expected in zip(array.shape, shape)
    ):
        wanted = "(" + ", ".join("n" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
        raise ValueError(f"{name} must have shape {wanted}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        bad = array[~np.isfinite(array)]
        raise ValueError(f"{name} must be finite, got {bad.size} non-finite value(s) such as {bad.flat[0]}")
    return array


def as_finite_vector(value: Any, name: str, length: int) -> NDArray[np.float64]:
    """Return ``value`` as a finite float64 vector of ``length`` entries."""
    return as_finite_array(value, name, (length,))


def as_real_scalar(value: Any, name: str) -> float:
    """Return ``value`` (a real number or a 0-d numeric array) as a finite float."""
    if isinstance(value, bool) or not isinstance(value, (numbers.Real, np.floating, np.integer)):
        if isinstance(value, np.ndarray) and value.shape == () and np.issubdtype(value.dtype, np.number):
            value = value.item()
        else:
            raise TypeError(f"{name} must be a real number, got {_kind(value)}")
    result = float(value)
    if not np.isfinite(result):
        raise ValueError(f"{name} must be finite, got {result}")
    return result


def as_positive_scalar(value: Any, name: str) -> float:
    """Return ``value`` as a finite float that is strictly positive."""
    result = as_real_scalar(value, name)
    if result <= 0.0:
        raise ValueError(f"{name} must be positive, got {result}")
    return result


def as_nonnegative_scalar(value: Any, name: str) -> float:
    """Return ``value`` as a finite float that is zero or positive."""
    result = as_real_scalar(value, name)
    if result < 0.0:
        raise ValueError(f"{name} must be non-negative, got {result}")
    return result


def as_scalar_between(value: Any, name: str, low: float, high: float) -> float:
    """Return ``value`` as a finite float strictly between ``low`` and ``high``.

    >>> as_scalar_between(1.5, "recovery_relaxation", 0.0, 2.0)
    1.5
    >>> as_scalar_between(1, "split_weight", 0.0, 1.0)
    Traceback (most recent call last):
        ...
    ValueError: split_weight must lie strictly between 0.0 and 1.0, got 1.0
    """
    result = as_real_scalar(value, name)
    if not low < result < high:
        raise ValueError(f"{name} must lie strictly between {low} and {high}, got {result}")
    return result


def as_count(value: Any, name: str, minimum: int = 0) -> int:
    """Return ``value`` (an int, not a bool nor a float) as an int of at least ``minimum``.

    A float is refused even when it holds a whole number: a count that arrives
    as ``2.0`` was usually computed, not meant.

    >>> as_count(3, "recovery_budget")
    3
    >>> as_count(0, "max_active", minimum=1)
    Traceback (most recent call last):
        ...
    ValueError: max_active must be a positive int, got 0
    """
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an int, got {_kind(value)}")
    if value < minimum:
        wanted = {0: "a non-negative int", 1: "a positive int"}.get(minimum, f"an int of at least {minimum}")
        raise ValueError(f"{name} must be {wanted}, got {value}")
    return int(value)


def as_id_array(value: Any, name: str, length: int | None = None) -> NDArray[np.int64]:
    """Return ``value`` as a 1-D int64 array of landmark ids.

    Floats are refused even when they hold whole numbers: an id that arrives
    as ``3.0`` usually means a column of the wrong array was passed.
    """
    if isinstance(value, (str, bytes)) or value is None:
        raise TypeError(f"{name} must be an array of integers, got {_kind(value)}")
    array = np.asarray(value)
    if array.ndim != 1:
        raise ValueError(f"{name} must be one-dimensional, got shape {array.shape}")
    if array.size == 0:
        array = array.astype(np.int64)
    elif array.dtype == np.bool_ or not np.issubdtype(array.dtype, np.integer):
        raise TypeError(f"{name} must hold integers, got dtype {array.dtype}")
    if length is not None and array.shape[0] != length:
        raise ValueError(f"{name} must have {length} entries to match the other arguments, got {array.shape[0]}")
    return array.astype(np.int64, copy=False)


def as_covariance(value: Any, name: str, dim: int) -> NDArray[np.float64]:
    """Return ``value`` as a symmetric positive definite ``dim`` x ``dim`` matrix."""
    matrix = as_finite_array(value, name, (dim, dim))
    if not np.allclose(matrix, matrix.T, rtol=1e-10, atol=1e-12):
        raise ValueError(f"{name} must be symmetric")
    try:
        np.linalg.cholesky(matrix)
    except np.linalg.LinAlgError as error:
        raise ValueError(f"{name} must be positive definite") from error
    return 0.5 * (matrix + matrix.T)
