"""What the dataset loaders share: read-only copies of their arrays."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray


def frozen(array: ArrayLike, dtype: DTypeLike) -> NDArray:
    """A read-only copy of ``array`` as ``dtype`` (the loaders' results cannot be changed in place)."""
    array = np.array(array, dtype=dtype, copy=True)
    array.setflags(write=False)
    return array
