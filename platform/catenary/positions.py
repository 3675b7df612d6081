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

__all__ = ["positions_along", "wire_positions"]


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


def positions_along(
    chainage_m: FloatArray,
    wire: IntArray,
    span_start_m: FloatArray,
    span_wire: IntArray,
    span_position: IntArray,
) -> IntArray:
    """The wire position of points of a run along the chainage (e.g. envelope bins: their
    centres), from the run's span measurements: that of the point's wire in the last span of
    that wire starting at or before the point (its first span, for a point before them all).

    Parameters
    ----------
    chainage_m, wire : ndarray, shape (n,)
        The points' chainage [m] and the run's wire number.
    span_start_m, span_wire, span_position : ndarray, shape (m,)
        Each span measurement's start chainage [m], wire number and wire position.

    Returns
    -------
    ndarray, shape (n,)
        The position; -1 for a wire without a span measurement.
    """
    position = np.full(chainage_m.shape[0], -1, dtype=np.int64)
    for number in np.unique(wire):
        mine = span_wire == number
        if not mine.any():
            continue
        order = np.argsort(span_start_m[mine], kind="stable")
        starts, ranks = span_start_m[mine][order], span_position[mine][order]
        points = wire == number
        found = np.searchsorted(starts, chainage_m[points], side="right") - 1
        position[points] = ranks[np.clip(found, 0, starts.shape[0] - 1)]
    return position
