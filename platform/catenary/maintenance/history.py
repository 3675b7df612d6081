"""Span-wire histories of one track: its span measurements across runs, as NumPy arrays.

A wire is identified within its span by its **position** (``catenary.positions``): its rank
among the wires the run measured in that span, left to right looking towards increasing
chainage; in an overlap the two wires are told apart by their lateral order. A **stretch** is
a span by its masts (codes as the mast ids of the register), or by
its chainages when it was measured without a register. A **history** is a stretch and
position across runs, from its last repair on (``catenary.maintenance.actions``).

An **anchor section** (the register's ``anchor_section``: spans are in the section of their
start mast) is measured by a run when the run's spans of that section and position cover
``SECTION_COVERAGE`` of its length; its value is the mean residual thickness of those spans,
weighted by their samples.

Everything is vectorised over rows, histories and sections; arrays ``(m,)`` are rows,
``(h,)`` histories, ``(k,)`` section measurements.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from catenary.arrays import FloatArray, IntArray, take
from catenary.maintenance.actions import touches
from catenary.maintenance.forecast import WearFit, fit_histories
from catenary.positions import wire_positions

__all__ = [
    "SECTION_COVERAGE",
    "Repairs",
    "SectionMeasurements",
    "SpanHistories",
    "SpanRows",
    "section_measurements",
    "span_histories",
    "wire_positions",
]

SECTION_COVERAGE = 0.9
"""Fraction of an anchor section's length a run must measure for its average to count."""


@dataclass(frozen=True)
class SpanRows:
    """Span measurement rows of one track (each ``(m,)``), with their runs' time and direction.

    ``mast_from``/``mast_to`` are mast ids (-1: measured without a register); ``wire_type`` an
    index into the caller's wire type names (-1: unknown); ``stagger_sum_mm`` is
    ``stagger_min_mm + stagger_max_mm`` in the run's track frame; ``time_years`` the run's start
    (``catenary.maintenance.forecast``) and ``direction`` +1 for increasing chainage, -1 for
    decreasing.
    """

    measurement_id: IntArray
    run_id: IntArray
    span: IntArray
    wire: IntArray
    mast_from: IntArray
    mast_to: IntArray
    start_m: FloatArray
    end_m: FloatArray
    min_thickness_mm: FloatArray
    mean_thickness_mm: FloatArray
    samples: IntArray
    stagger_sum_mm: FloatArray
    wire_type: IntArray
    time_years: FloatArray
    direction: FloatArray

    @property
    def rows(self) -> int:
        return int(self.run_id.shape[0])


@dataclass(frozen=True)
class Repairs:
    """Repairs on the track (each ``(a,)``): chainage range [m], wire position (-1: every
    wire) and time [years]."""

    from_m: FloatArray
    to_m: FloatArray
    wire: IntArray
    time_years: FloatArray

    @classmethod
    def none(cls) -> Repairs:
        empty = np.zeros(0)
        return cls(empty, empty, np.zeros(0, dtype=np.int64), empty)


def _groups(*keys: NDArray[np.generic]) -> tuple[IntArray, IntArray]:
    """Group rows with equal ``keys`` (each ``(m,)``): each row's group ``(m,)``, numbered in
    ``np.lexsort`` order of the keys (the last key first), and one row of each group."""
    order = np.lexsort(keys)
    change = np.zeros(order.shape[0], dtype=bool)
    change[:1] = True
    for key in keys:
        ordered = key[order]
        change[1:] |= ordered[1:] != ordered[:-1]
    group = np.empty(order.shape[0], dtype=np.int64)
    group[order] = np.cumsum(change) - 1
    return group, order[change]


def _last_per_group(group: IntArray, groups: int, *keys: NDArray[np.generic]) -> IntArray:
    """Index of the last row of each group by ``keys`` (lexsort order: the last key first),
    ``(groups,)``; -1 for a group with no row. Rows with ``group < 0`` are left out."""
    use = np.flatnonzero(group >= 0)
    order = use[np.lexsort((*(k[use] for k in keys), group[use]))]
    sorted_group = group[order]
    ends = np.flatnonzero(np.append(sorted_group[1:] != sorted_group[:-1], True))
    last = np.full(groups, -1, dtype=np.int64)
    if order.shape[0]:
        last[sorted_group[ends]] = order[ends]
    return last


@dataclass(frozen=True)
class SpanHistories:
    """The histories of one track (each ``(h,)``; ``row_history`` ``(m,)``).

    ``latest`` is the row of each history's latest run after its last repair (-1: none since),
    ``fit`` the line through its minimum residual thickness over those runs; ``repaired_years``
    the time of its last repair (-inf: none). ``row_history`` gives each row's history, -1 for
    a row from before its history's last repair.
    """

    position: IntArray
    mast_from: IntArray
    mast_to: IntArray
    start_m: FloatArray
    end_m: FloatArray
    latest: IntArray
    repaired_years: FloatArray
    fit: WearFit
    row_history: IntArray
    row_position: IntArray

    @property
    def histories(self) -> int:
        return int(self.position.shape[0])


def span_histories(rows: SpanRows, repairs: Repairs) -> SpanHistories:
    """Group a track's rows into histories, drop what came before each one's last repair, and
    fit each history's minimum residual thickness against time."""
    line_stagger = rows.direction * rows.stagger_sum_mm
    position = wire_positions(rows.run_id, rows.span, line_stagger, rows.wire)
    by_masts = rows.mast_from >= 0
    # a stretch: (0, mast indices) or (1, chainages); with the position, a history
    flag = (~by_masts).astype(np.float64)
    low = np.where(by_masts, rows.mast_from, rows.start_m)
    high = np.where(by_masts, rows.mast_to, rows.end_m)
    history, first = _groups(position, high, low, flag)
    unique = np.column_stack([flag[first], low[first], high[first], position[first]])
    count = first.shape[0]
    newest = _last_per_group(history, count, rows.run_id, rows.time_years)
    start, end = rows.start_m[newest], rows.end_m[newest]
    hist_position = unique[:, 3].astype(np.int64)
    # the last repair touching each history's span, on its wire or on every wire
    hit = touches(repairs.from_m[None, :], repairs.to_m[None, :], start[:, None], end[:, None])
    hit &= (repairs.wire[None, :] < 0) | (repairs.wire[None, :] == hist_position[:, None])
    repaired = np.max(np.where(hit, repairs.time_years[None, :], -np.inf), axis=1, initial=-np.inf)
    kept = np.where(rows.time_years > repaired[history], history, -1)
    latest = _last_per_group(kept, count, rows.run_id, rows.time_years)
    use = kept >= 0
    fit = fit_histories(kept[use], rows.time_years[use], rows.min_thickness_mm[use], count)
    return SpanHistories(
        position=hist_position,
        mast_from=np.where(unique[:, 0] == 0, unique[:, 1], -1).astype(np.int64),
        mast_to=np.where(unique[:, 0] == 0, unique[:, 2], -1).astype(np.int64),
        start_m=start,
        end_m=end,
        latest=latest,
        repaired_years=repaired,
        fit=fit,
        row_history=kept,
        row_position=position,
    )


@dataclass(frozen=True)
class SectionMeasurements:
    """Each anchor section and position's latest measurement (each ``(k,)``).

    ``section`` indexes the caller's sections, ``run_id`` and ``time_years`` are the run's,
    ``mean_thickness_mm`` the samples-weighted mean over the run's spans of the section,
    ``coverage`` the fraction of the section's length they cover and ``wire_type`` theirs (-2:
    the spans disagree).
    """

    section: IntArray
    position: IntArray
    run_id: IntArray
    time_years: FloatArray
    mean_thickness_mm: FloatArray
    coverage: FloatArray
    wire_type: IntArray


def section_measurements(
    rows: SpanRows,
    histories: SpanHistories,
    mast_section: IntArray,
    section_length_m: FloatArray,
) -> SectionMeasurements:
    """The latest run that measured each anchor section and position (``SECTION_COVERAGE``).

    ``mast_section`` maps a mast id to its section's index (-1: none; ids beyond it: none),
    ``section_length_m`` ``(s,)`` gives each section's length. Only rows after their
    history's last repair count.
    """
    sections = section_length_m.shape[0]
    known = (rows.mast_from >= 0) & (rows.mast_from < mast_section.shape[0])
    section = take(mast_section, np.where(known, rows.mast_from, -1), -1)
    use = np.flatnonzero((section >= 0) & (histories.row_history >= 0))
    position = histories.row_position[use]
    width = int(position.max(initial=0)) + 1
    runs, run_index = np.unique(rows.run_id[use], return_inverse=True)
    run_index = run_index.reshape(-1)
    # one group per (run, section, position)
    group = (run_index * sections + section[use]) * width + position
    groups, inverse = np.unique(group, return_inverse=True)
    inverse = inverse.reshape(-1)
    k = groups.shape[0]
    samples = rows.samples[use].astype(np.float64)
    weight = np.bincount(inverse, samples, k)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(inverse, rows.mean_thickness_mm[use] * samples, k) / weight
    length = np.bincount(inverse, rows.end_m[use] - rows.start_m[use], k)
    wire_type = rows.wire_type[use]
    low = np.full(k, np.iinfo(np.int64).max)
    high = np.full(k, np.iinfo(np.int64).min)
    np.minimum.at(low, inverse, wire_type)
    np.maximum.at(high, inverse, wire_type)
    time = np.zeros(k)
    time[inverse] = rows.time_years[use]
    group_section = (groups // width) % sections
    group_position = groups % width
    group_run = runs[groups // width // sections] if k else np.zeros(0, dtype=np.int64)
    coverage = length / section_length_m[group_section]
    # the latest run of each (section, position) that covered it
    covered = np.flatnonzero(coverage >= SECTION_COVERAGE)
    targets, slot = np.unique(
        group_section[covered] * width + group_position[covered], return_inverse=True
    )
    latest = _last_per_group(
        slot.reshape(-1).astype(np.int64), targets.shape[0], group_run[covered], time[covered]
    )
    pick = covered[latest]
    return SectionMeasurements(
        section=group_section[pick],
        position=group_position[pick],
        run_id=group_run[pick],
        time_years=time[pick],
        mean_thickness_mm=mean[pick],
        coverage=coverage[pick],
        wire_type=np.where(low[pick] == high[pick], low[pick], -2),
    )
