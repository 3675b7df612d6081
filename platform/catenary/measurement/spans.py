"""Spans of a run and their statistics per contact wire: the ``spans`` rows of FORMATS.md.

A run's spans are cut at chainages: the masts of the register (a span runs from one mast to
the next and has the wire type of the mast at its start), or, without a register, the
stagger's turning points (the registration points) found along the run, with the run's ends
closing its first and last span. :class:`SpanAccumulator` gathers, block after block, each
span and wire's minimum residual thickness and where it lies, its mean, the height and
stagger ranges and the number of samples, in memory bounded by the number of spans; and, given
the spans' boundaries (the masts), the median height and stagger of each wire within
``MAST_WINDOW_M`` of each boundary (the wire's values at the mast: its design values compare
with these), in memory bounded by the samples of those few metres.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import pyarrow as pa
from numpy.typing import ArrayLike

from catenary.arrays import FloatArray, IntArray
from catenary.domain import TrackRegister
from catenary.measurement.chainage import span_index

__all__ = [
    "MAST_WINDOW_M",
    "SPAN_COLUMNS",
    "SPAN_SCHEMA",
    "SpanAccumulator",
    "SpanLayout",
    "SpanStatistics",
    "span_table",
]

SPAN_COLUMNS = (
    "span",
    "mast_from",
    "mast_to",
    "start_chainage_m",
    "end_chainage_m",
    "wire",
    "wire_position",
    "wire_type",
    "min_residual_thickness_mm",
    "min_at_chainage_m",
    "mean_residual_thickness_mm",
    "height_min_mm",
    "height_max_mm",
    "stagger_min_mm",
    "stagger_max_mm",
    "samples",
)
"""The ``spans`` export's columns (FORMATS.md), in order; ``wire_position`` (the identity
users see, ``catenary.positions``) is the project's own, after ``wire``."""

SPAN_SCHEMA = pa.schema(
    [
        (
            c,
            pa.string()
            if c in ("mast_from", "mast_to", "wire_type")
            else pa.int64()
            if c in ("span", "wire", "wire_position", "samples")
            else pa.float64(),
        )
        for c in SPAN_COLUMNS
    ]
)
"""The ``spans`` export's Arrow schema."""

MAST_WINDOW_M = 1.0
"""A wire's value at a mast is the median of its samples within this distance of it [m]."""


def span_table(rows: Iterable[object]) -> pa.Table:
    """The ``spans`` export of ``rows`` (objects with the ``SPAN_COLUMNS`` as attributes, such
    as stored span measurements), one row each, in their order."""
    rows = list(rows)
    return pa.table({c: [getattr(r, c) for r in rows] for c in SPAN_COLUMNS}, schema=SPAN_SCHEMA)


@dataclass(frozen=True)
class SpanLayout:
    """Where a run's spans begin and end: span ``i`` is ``[boundaries_m[i], boundaries_m[i+1])``.

    ``number`` is the span's number as stored (the index of its first mast in the register, or
    its order along the run without one); ``mast_from``, ``mast_to`` and ``wire_type`` are
    None without a register.
    """

    boundaries_m: FloatArray  # (k + 1,) ascending chainage [m]
    number: IntArray  # (k,)
    mast_from: tuple[str | None, ...]
    mast_to: tuple[str | None, ...]
    wire_type: tuple[str | None, ...]

    @property
    def spans(self) -> int:
        return int(self.number.shape[0])

    @classmethod
    def from_register(cls, register: TrackRegister) -> SpanLayout:
        k = register.masts - 1
        return cls(
            boundaries_m=register.chainage_m,
            number=np.arange(k, dtype=np.int64),
            mast_from=register.mast[:-1],
            mast_to=register.mast[1:],
            wire_type=register.wire_type[:-1],
        )

    @classmethod
    def from_turning_points(
        cls, turning_chainage_m: ArrayLike, run_chainage_m: tuple[float, float]
    ) -> SpanLayout:
        """Spans between consecutive turning points, the run's ends closing the outer two."""
        first, last = sorted(run_chainage_m)
        inner = np.sort(np.asarray(turning_chainage_m, dtype=np.float64))
        inner = inner[(inner > first) & (inner < last)]
        boundaries = np.concatenate([[first], inner, [np.nextafter(last, np.inf)]])
        k = boundaries.shape[0] - 1
        return cls(
            boundaries_m=boundaries,
            number=np.arange(k, dtype=np.int64),
            mast_from=(None,) * k,
            mast_to=(None,) * k,
            wire_type=(None,) * k,
        )

    def index(self, chainage_m: ArrayLike) -> IntArray:
        """Index (into this layout) of the span of each chainage, ``(m,)``; -1 outside all."""
        return span_index(chainage_m, self.boundaries_m).astype(np.int64)


@dataclass(frozen=True)
class SpanStatistics:
    """One span and wire of a run (layout index ``span``; lengths in mm, chainage in m)."""

    span: int
    wire: int
    samples: int
    thickness_samples: int
    min_residual_thickness_mm: float
    min_at_chainage_m: float
    mean_residual_thickness_mm: float
    height_min_mm: float
    height_max_mm: float
    stagger_min_mm: float
    stagger_max_mm: float
    height_at_start_mm: float = float("nan")
    height_at_end_mm: float = float("nan")
    stagger_at_start_mm: float = float("nan")


class SpanAccumulator:
    """Per span and wire statistics gathered over blocks of samples; with ``boundaries_m``
    (the layout's, ascending [m]), the wires' median height and stagger at each boundary."""

    def __init__(self, boundaries_m: ArrayLike | None = None) -> None:
        self._groups: dict[tuple[int, int], list[float]] = {}
        self._boundaries = (
            np.zeros(0) if boundaries_m is None else np.asarray(boundaries_m, dtype=np.float64)
        )
        self._at_mast: dict[tuple[int, int], list[FloatArray]] = {}

    def _add_at_masts(self, wire: IntArray, c: FloatArray, z: FloatArray, x: FloatArray) -> None:
        b = self._boundaries
        if b.shape[0] == 0:
            return
        right = np.clip(np.searchsorted(b, c), 0, b.shape[0] - 1)
        left = np.maximum(right - 1, 0)
        nearest = np.where(np.abs(c - b[left]) <= np.abs(c - b[right]), left, right)
        near = np.abs(c - b[nearest]) <= MAST_WINDOW_M
        for mast, w in set(zip(nearest[near].tolist(), wire[near].tolist(), strict=True)):
            rows = near & (nearest == mast) & (wire == w)
            self._at_mast.setdefault((mast, w), []).append(np.stack([z[rows], x[rows]]))

    def _median_at(self, mast: int, wire: int) -> tuple[float, float]:
        """Median height and stagger [mm] of ``wire`` at boundary ``mast`` (NaN: no sample)."""
        parts = self._at_mast.get((mast, wire))
        if not parts:
            return float("nan"), float("nan")
        values = np.concatenate(parts, axis=1)
        return float(np.median(values[0])), float(np.median(values[1]))

    def add(
        self,
        span: ArrayLike,
        wire: ArrayLike,
        chainage_m: ArrayLike,
        residual_thickness_mm: ArrayLike,
        height_mm: ArrayLike,
        stagger_mm: ArrayLike,
    ) -> None:
        """Add samples, each ``(m,)``; rows with span -1 are left out, NaN thickness counts
        as a sample without a thickness."""
        s = np.asarray(span, dtype=np.int64)
        keep = s >= 0
        s = s[keep]
        if s.size == 0:
            return
        w = np.asarray(wire, dtype=np.int64)[keep]
        c = np.asarray(chainage_m, dtype=np.float64)[keep]
        h = np.asarray(residual_thickness_mm, dtype=np.float64)[keep]
        z = np.asarray(height_mm, dtype=np.float64)[keep]
        x = np.asarray(stagger_mm, dtype=np.float64)[keep]
        self._add_at_masts(w, c, z, x)
        finite = np.isfinite(h)
        # sorted by group, then by thickness (NaN last): each group's first row is its minimum
        order = np.lexsort((np.where(finite, h, np.inf), w, s))
        s, w, finite = s[order], w[order], finite[order]
        c, h, z, x = c[order], h[order], z[order], x[order]
        start = np.flatnonzero(np.r_[True, (np.diff(s) != 0) | (np.diff(w) != 0)])
        count = np.diff(np.r_[start, s.shape[0]])
        thick_count = np.add.reduceat(finite.astype(np.int64), start)
        thick_sum = np.add.reduceat(np.where(finite, h, 0.0), start)
        stats = np.stack(
            [
                count.astype(np.float64),
                thick_count.astype(np.float64),
                thick_sum,
                np.where(finite[start], h[start], np.inf),
                np.where(finite[start], c[start], np.nan),
                np.minimum.reduceat(z, start),
                np.maximum.reduceat(z, start),
                np.minimum.reduceat(x, start),
                np.maximum.reduceat(x, start),
            ],
            axis=1,
        )
        keys = zip(s[start].tolist(), w[start].tolist(), strict=True)
        for key, row in zip(keys, stats.tolist(), strict=True):
            self._merge(key, row)

    def _merge(self, key: tuple[int, int], row: list[float]) -> None:
        held = self._groups.get(key)
        if held is None:
            self._groups[key] = row
            return
        held[0] += row[0]
        held[1] += row[1]
        held[2] += row[2]
        if row[3] < held[3]:
            held[3], held[4] = row[3], row[4]
        held[5] = min(held[5], row[5])
        held[6] = max(held[6], row[6])
        held[7] = min(held[7], row[7])
        held[8] = max(held[8], row[8])

    def results(self) -> list[SpanStatistics]:
        """Every span and wire seen, in order of span then wire."""
        out = []
        for (span, wire), g in sorted(self._groups.items()):
            height_start, stagger_start = self._median_at(span, wire)
            height_end, _ = self._median_at(span + 1, wire)
            out.append(
                SpanStatistics(
                    span=span,
                    wire=wire,
                    samples=int(g[0]),
                    thickness_samples=int(g[1]),
                    min_residual_thickness_mm=g[3] if g[1] else float("nan"),
                    min_at_chainage_m=g[4],
                    mean_residual_thickness_mm=g[2] / g[1] if g[1] else float("nan"),
                    height_min_mm=g[5],
                    height_max_mm=g[6],
                    stagger_min_mm=g[7],
                    stagger_max_mm=g[8],
                    height_at_start_mm=height_start,
                    height_at_end_mm=height_end,
                    stagger_at_start_mm=stagger_start,
                )
            )
        return out
