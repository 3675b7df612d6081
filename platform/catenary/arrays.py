"""NumPy array type aliases for annotations, shared by the core and the built-in plugins.

``IntArray`` holds int64 values (identifiers, counts, stored columns: 64-bit on every
platform); ``IndexArray`` holds ``intp`` indices, what ``argsort``, ``nonzero`` and
``searchsorted`` return and indexing takes.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "BoolArray",
    "Float32Array",
    "FloatArray",
    "IndexArray",
    "IntArray",
    "UInt8Array",
    "UInt16Array",
]

FloatArray = NDArray[np.float64]
Float32Array = NDArray[np.float32]
IntArray = NDArray[np.int64]
IndexArray = NDArray[np.intp]
BoolArray = NDArray[np.bool_]
UInt8Array = NDArray[np.uint8]
UInt16Array = NDArray[np.uint16]
