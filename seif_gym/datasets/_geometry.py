"""Geometry the dataset scorers share."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from seif_gym.type_aliases import FloatArray

__all__ = ["rigid_alignment"]


def rigid_alignment(source: ArrayLike, target: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Rotation ``R`` (2, 2) and translation ``t`` (2,) minimising ``sum |R source_i + t - target_i|^2``.

    Kabsch/Umeyama without scale; a proper rotation (``det R = +1``).

    Raises
    ------
    ValueError
        Unless ``source`` and ``target`` are two ``(n, 2)`` point sets with ``n >= 2``.
    """
    source = np.asarray(source, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 2 or len(source) < 2:
        raise ValueError(f"need two (n, 2) point sets with n >= 2, got {source.shape} and {target.shape}")
    mean_s, mean_t = source.mean(0), target.mean(0)
    cross = (target - mean_t).T @ (source - mean_s)
    u, _, vt = np.linalg.svd(cross)
    sign = np.sign(np.linalg.det(u @ vt)) or 1.0
    rotation = u @ np.diag([1.0, sign]) @ vt
    return rotation, mean_t - rotation @ mean_s
