"""Array type aliases shared by the library (one home; numpy's ``NDArray`` with the dtypes used here)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["BoolArray", "Float32Array", "FloatArray", "IntArray", "UInt8Array"]

#: float64 arrays: poses, means, covariances, information blocks, measurements.
FloatArray = NDArray[np.float64]
#: float32 arrays: the observation vectors.
Float32Array = NDArray[np.float32]
#: int64 arrays: landmark ids and indices, counts.
IntArray = NDArray[np.int64]
#: Boolean masks.
BoolArray = NDArray[np.bool_]
#: uint8 rasters: the belief map and the coverage grid.
UInt8Array = NDArray[np.uint8]
