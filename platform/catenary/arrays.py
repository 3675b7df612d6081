"""NumPy array type aliases for annotations, shared by the core and the built-in plugins.

``IntArray`` holds int64 values (identifiers, counts, stored columns: 64-bit on every
platform); ``IndexArray`` holds ``intp`` indices, what ``argsort``, ``nonzero`` and
``searchsorted`` return and indexing takes.

``take`` indexes with -1 for "none", which plain indexing (or ``np.where``, which evaluates
both branches) cannot do on an empty array.
"""

from __future__ import annotations

from typing import Any, TypeVar

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
    "row_median",
    "take",
]

FloatArray = NDArray[np.float64]
Float32Array = NDArray[np.float32]
IntArray = NDArray[np.int64]
IndexArray = NDArray[np.intp]
BoolArray = NDArray[np.bool_]
UInt8Array = NDArray[np.uint8]
UInt16Array = NDArray[np.uint16]

_T = TypeVar("_T", bound=np.generic)


def take(values: NDArray[_T], index: NDArray[np.integer[Any]], fill: object) -> NDArray[_T]:
    """``values[index]`` where ``index >= 0``, ``fill`` where it is -1 (``values`` may be
    empty); the shape of ``index``."""
    out = np.full(index.shape, fill, dtype=values.dtype)
    hit = index >= 0
    out[hit] = values[index[hit]]
    return out


def row_median(values: NDArray[np.float64]) -> NDArray[np.float64]:
    """Median of the finite values of each row of a narrow ``(m, k)`` array (NaN if none):
    a sort of a few columns, quicker than ``np.nanmedian``."""
    ordered = np.sort(np.where(np.isfinite(values), values, np.inf), axis=1)
    count = np.isfinite(values).sum(axis=1)
    low = np.take_along_axis(ordered, np.maximum((count - 1) // 2, 0)[:, np.newaxis], 1)[:, 0]
    high = np.take_along_axis(ordered, np.maximum(count // 2, 0)[:, np.newaxis], 1)[:, 0]
    with np.errstate(invalid="ignore"):
        return np.where(count > 0, 0.5 * (low + high), np.nan)
