"""Wire positions: the identity of a contact wire that users see.

A run numbers its wires in order of appearance (``wire``: 0, 1, ... along the run), so the
same wire has another number in a run that starts elsewhere or runs the other way. Users see
the wire's **position** instead: its rank among the wires the run measured in the span, left
to right looking toward increasing chainage (by the middle of its stagger range, the sign of
the run's direction undone; ties by the run's number). Outside overlaps a span has one wire,
position 0, whatever the run.
"""

from __future__ import annotations

import numpy as np

from catenary.arrays import FloatArray, IntArray

__all__ = ["wire_positions"]


def wire_positions(
    run_id: IntArray, span: IntArray, line_stagger_mm: FloatArray, wire: IntArray
) -> IntArray:
    """Each row's rank among the rows of its run and span by ``line_stagger_mm`` (ties by the
    run's wire number), ``(m,)``: 0 for the leftmost."""
    order = np.lexsort((wire, line_stagger_mm, span, run_id))
    run_sorted, span_sorted = run_id[order], span[order]
    new = np.ones(order.shape[0], dtype=bool)
    new[1:] = (run_sorted[1:] != run_sorted[:-1]) | (span_sorted[1:] != span_sorted[:-1])
    index = np.arange(order.shape[0])
    first = np.maximum.accumulate(np.where(new, index, 0))
    position = np.empty(order.shape[0], dtype=np.int64)
    position[order] = index - first
    return position
