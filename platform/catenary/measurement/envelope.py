"""Min/max envelopes of a run's samples along the chainage, for plots and the track view.

A run holds a sample every few centimetres over up to a hundred kilometres; a plot or a screen
has about a thousand pixel columns. An envelope keeps each wire's minimum and maximum of each
quantity per bin of chainage: the picture is that of every sample drawn at that resolution, and
no local minimum (a hot spot) is ever averaged away.

- :class:`EnvelopeGrid` gathers them batch by batch on a plot's own bins (the reports), and
  :func:`envelope_path` draws them as a line through every bin's minimum and maximum.
- **Envelope levels**: each processing has an envelope file beside its samples file in the
  store (``catenary.storage.store.envelope_key``), written when the run is stored
  (``catenary process``) or pushed; :func:`ensure_envelopes` builds that of a processing
  stored before there were any. :func:`track_view` reads a window of chainage: the coarsest
  level that still gives each pixel column a bin, or the raw samples below ``RAW_BELOW_M``.

The envelope file (Parquet, metadata ``format = catenary-envelopes``, ``format_version = 1``)
holds one row per level of ``LEVELS_M``, wire and bin that has samples: ``level_m``, ``wire``,
``chainage_m`` (the bin's start), ``count`` (the samples in it) and ``min_Q``, ``max_Q`` of
each quantity ``Q`` of ``QUANTITIES`` (the samples file's columns; NaN where none of the bin's
samples has a value, e.g. no width at a fitting). Only the samples that count (``trusted``: no
vehicle sensor fault, surely the contact wire) are in it, as in the run report. Bin ``i`` of
level ``L`` covers chainage ``[i L, (i+1) L)``: a sample's bin is ``floor(chainage_m / L)``
of the finest level, and each coarser level is gathered from the finer one, so the levels
nest exactly. Rows are sorted by level, chainage and wire, in row groups of
``ROW_GROUP_ROWS``: a window reads only the groups that hold it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from numpy.typing import NDArray

from catenary.arrays import FloatArray, IntArray
from catenary.errors import FormatError, UserError
from catenary.measurement.samples import (
    TRUST_COLUMNS,
    SamplesSource,
    StoredSamples,
    read_sample_batches,
    trusted,
)
from catenary.storage.store import Store, StoredObject, StoreError, envelope_key

__all__ = [
    "ENVELOPE_SCHEMA",
    "LEVELS_M",
    "QUANTITIES",
    "RAW_BELOW_M",
    "Bins",
    "EnvelopeGrid",
    "TrackView",
    "WireTrace",
    "bin_samples",
    "choose_level",
    "coarsen",
    "ensure_envelopes",
    "envelope",
    "envelope_bytes",
    "envelope_levels",
    "envelope_path",
    "envelope_table",
    "merge_bins",
    "track_view",
    "write_envelopes",
]


def envelope(
    position_m: FloatArray, values: FloatArray, start_m: float, bin_m: float, bins: int
) -> tuple[FloatArray, FloatArray]:
    """Minimum and maximum of ``values`` per bin ``[start_m + i bin_m, start_m + (i+1) bin_m)``.

    Parameters
    ----------
    position_m, values : ndarray, shape (n,)
        Where each value lies [m] and the values; NaN values are left out. Positions outside
        ``[start_m, start_m + bins·bin_m]`` are left out (the end itself is in the last bin).
    start_m, bin_m : float
        The first bin's start and the bins' width [m].
    bins : int
        Number of bins.

    Returns
    -------
    low, high : ndarray, shape (bins,)
        NaN where a bin holds no value.
    """
    low = np.full(bins, np.inf)
    high = np.full(bins, -np.inf)
    _gather(low, high, position_m, values, start_m, bin_m)
    return _finish(low), _finish(high)


def _gather(
    low: FloatArray,
    high: FloatArray,
    position_m: FloatArray,
    values: FloatArray,
    start_m: float,
    bin_m: float,
) -> None:
    bins = low.shape[0]
    offset = (np.asarray(position_m, np.float64) - start_m) / bin_m
    keep = np.isfinite(values) & (offset >= 0.0) & (offset <= bins)
    index = np.minimum(offset[keep].astype(np.intp), bins - 1)
    np.minimum.at(low, index, values[keep])
    np.maximum.at(high, index, values[keep])


def _finish(extreme: FloatArray) -> FloatArray:
    return np.where(np.isfinite(extreme), extreme, np.nan)


class EnvelopeGrid:
    """Per-bin minimum and maximum of ``quantities`` for each wire, gathered batch by batch."""

    def __init__(self, start_m: float, bin_m: float, bins: int, quantities: Sequence[str]):
        self.start_m, self.bin_m, self.bins = start_m, bin_m, bins
        self.quantities = tuple(quantities)
        self._low: dict[tuple[int, str], FloatArray] = {}
        self._high: dict[tuple[int, str], FloatArray] = {}

    def add(
        self, position_m: FloatArray, wire: NDArray[np.integer], values: Mapping[str, FloatArray]
    ) -> None:
        """Gather one batch: ``(m,)`` positions, wire numbers and a ``(m,)`` array per
        quantity."""
        for number in np.unique(wire):
            rows = wire == number
            for quantity in self.quantities:
                key = (int(number), quantity)
                if key not in self._low:
                    self._low[key] = np.full(self.bins, np.inf)
                    self._high[key] = np.full(self.bins, -np.inf)
                _gather(
                    self._low[key],
                    self._high[key],
                    position_m[rows],
                    values[quantity][rows],
                    self.start_m,
                    self.bin_m,
                )

    @property
    def wires(self) -> list[int]:
        return sorted({wire for wire, _ in self._low})

    def series(
        self, wire: int, quantity: str, first: int, last: int
    ) -> tuple[FloatArray, FloatArray]:
        """``envelope_path`` of bins ``first`` to ``last`` (exclusive) of one wire."""
        low = _finish(self._low[(wire, quantity)][first:last])
        high = _finish(self._high[(wire, quantity)][first:last])
        return envelope_path(self.start_m + first * self.bin_m, self.bin_m, low, high)

    def has_data(self, wire: int, quantity: str, first: int, last: int) -> bool:
        """Whether the wire has any value of ``quantity`` in bins ``first:last``."""
        low = self._low.get((wire, quantity))
        return low is not None and bool(np.isfinite(low[first:last]).any())


def envelope_path(
    start_m: float, bin_m: float, low: FloatArray, high: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The vertices of a line through each bin's minimum then maximum, at the bin's centre;
    broken (a NaN vertex) at each run of empty bins. Shapes ``(2k,)``."""
    centre = start_m + (np.arange(low.shape[0]) + 0.5) * bin_m
    x = np.repeat(centre, 2)
    y = np.column_stack([low, high]).ravel()
    empty = ~np.isfinite(y)
    keep = ~empty | np.concatenate([[False], ~empty[:-1]])  # one NaN per gap, none leading
    return x[keep], y[keep]


LEVELS_M = (1.0, 10.0, 100.0)
"""The envelope file's bin widths [m], finest first; each a whole multiple of the one before."""
QUANTITIES = ("residual_thickness_mm", "height_mm", "stagger_mm")
"""The samples file's columns an envelope file holds the minimum and maximum of."""
RAW_BELOW_M = 1000.0
"""A window of chainage shorter than this [m] is read from the samples themselves."""
ROW_GROUP_ROWS = 8192
"""Rows per row group of an envelope file."""
MERGE_ROWS = 1 << 16
"""Bins gathered from batches before they are merged (then at least as many as merged)."""

FORMAT = "catenary-envelopes"
FORMAT_VERSION = 1
ENVELOPE_SCHEMA = pa.schema(
    [
        ("level_m", pa.float64()),
        ("wire", pa.int32()),
        ("chainage_m", pa.float64()),
        ("count", pa.int64()),
        *[(f"{side}_{q}", pa.float64()) for q in QUANTITIES for side in ("min", "max")],
    ],
    metadata={"format": FORMAT, "format_version": str(FORMAT_VERSION)},
)


@dataclass(frozen=True)
class Bins:
    """Per wire and bin of width ``bin_m``: the samples' ``count`` and each quantity's minimum
    (``low``) and maximum (``high``), NaN where none has a value. Shapes ``(k,)``, sorted by
    wire then bin; bin ``index`` covers chainage ``[index bin_m, (index+1) bin_m)``."""

    bin_m: float
    wire: IntArray
    index: IntArray
    count: IntArray
    low: Mapping[str, FloatArray]
    high: Mapping[str, FloatArray]

    @property
    def chainage_m(self) -> FloatArray:
        """Each bin's start [m], ``(k,)``."""
        return np.asarray(self.index * self.bin_m, dtype=np.float64)


def _reduce(
    bin_m: float,
    wire: IntArray,
    index: IntArray,
    count: IntArray,
    low: Mapping[str, FloatArray],
    high: Mapping[str, FloatArray],
) -> Bins:
    """The ``(m,)`` partial bins (repeated ``(wire, index)`` pairs) gathered into one per pair."""
    order = np.lexsort((index, wire))
    wire, index = wire[order], index[order]
    new = np.ones(wire.shape, dtype=bool)
    new[1:] = (wire[1:] != wire[:-1]) | (index[1:] != index[:-1])
    start = np.flatnonzero(new)
    if start.shape[0] == 0:  # reduceat needs one index at least
        return Bins(bin_m, wire, index, count[order], low, high)
    return Bins(
        bin_m,
        wire[start],
        index[start],
        np.add.reduceat(count[order], start),
        {q: np.fmin.reduceat(v[order], start) for q, v in low.items()},
        {q: np.fmax.reduceat(v[order], start) for q, v in high.items()},
    )


def bin_samples(
    chainage_m: FloatArray,
    wire: NDArray[np.integer],
    values: Mapping[str, FloatArray],
    bin_m: float,
) -> Bins:
    """The bins of width ``bin_m`` of samples: ``(m,)`` chainages, wire numbers and an ``(m,)``
    array per quantity (NaN: no value). Samples without a finite chainage are left out."""
    keep = np.isfinite(chainage_m)
    index = np.floor(chainage_m[keep] / bin_m).astype(np.int64)
    kept = {q: np.asarray(v, dtype=np.float64)[keep] for q, v in values.items()}
    return _reduce(
        bin_m,
        np.asarray(wire[keep], dtype=np.int64),
        index,
        np.ones(index.shape, dtype=np.int64),
        kept,
        kept,
    )


def merge_bins(parts: Sequence[Bins], factor: int = 1) -> Bins:
    """Bins of one width gathered apart (batches) as one, ``factor`` times as wide (bin ``i``
    goes to ``i // factor``). ``parts`` must not be empty."""
    low = {q: np.concatenate([p.low[q] for p in parts]) for q in parts[0].low}
    high = {q: np.concatenate([p.high[q] for p in parts]) for q in parts[0].high}
    return _reduce(
        parts[0].bin_m * factor,
        np.concatenate([p.wire for p in parts]),
        np.concatenate([p.index for p in parts]) // factor,
        np.concatenate([p.count for p in parts]),
        low,
        high,
    )


def coarsen(finest: Bins, levels_m: Sequence[float] = LEVELS_M) -> list[Bins]:
    """The bins of each width of ``levels_m`` (the first is ``finest.bin_m``), each gathered
    from the one before; ``ValueError`` unless each width is a whole multiple of the last."""
    levels = [finest]
    for level_m in levels_m[1:]:
        factor = level_m / levels[-1].bin_m
        if factor < 1 or not math.isclose(factor, round(factor)):
            raise ValueError(f"level {level_m} m is not a multiple of {levels[-1].bin_m} m")
        levels.append(merge_bins([levels[-1]], round(factor)))
    return levels


def envelope_levels(
    chainage_m: FloatArray,
    wire: NDArray[np.integer],
    values: Mapping[str, FloatArray],
    levels_m: Sequence[float] = LEVELS_M,
) -> list[Bins]:
    """The bins of samples (``bin_samples``' arrays) at each width of ``levels_m``."""
    return coarsen(bin_samples(chainage_m, wire, values, levels_m[0]), levels_m)


def envelope_table(levels: Sequence[Bins]) -> pa.Table:
    """The envelope file's rows (``ENVELOPE_SCHEMA``) of ``levels`` of ``QUANTITIES``, sorted by
    level, chainage and wire."""
    parts = []
    for bins in levels:
        order = np.lexsort((bins.wire, bins.index))
        columns: dict[str, object] = {
            "level_m": np.full(order.shape, bins.bin_m),
            "wire": bins.wire[order].astype(np.int32),
            "chainage_m": bins.chainage_m[order],
            "count": bins.count[order],
        }
        for q in QUANTITIES:
            columns[f"min_{q}"] = bins.low[q][order]
            columns[f"max_{q}"] = bins.high[q][order]
        parts.append(pa.table(columns, schema=ENVELOPE_SCHEMA))
    return pa.concat_tables(parts) if parts else ENVELOPE_SCHEMA.empty_table()


def _read_levels(source: SamplesSource) -> list[Bins]:
    """``envelope_levels`` of a samples file's samples that count, read batch by batch: memory
    holds the finest level's bins and at most as many gathered since the last merge."""
    merged: list[Bins] = []  # one at most
    pending: list[Bins] = []
    columns = ["chainage_m", "wire", *TRUST_COLUMNS, *QUANTITIES]
    for batch in read_sample_batches(source, columns):
        good = trusted(batch)
        values = {q: batch[q][good] for q in QUANTITIES}
        pending.append(
            bin_samples(batch["chainage_m"][good], batch["wire"][good], values, LEVELS_M[0])
        )
        held = merged[0].wire.shape[0] if merged else 0
        if sum(p.wire.shape[0] for p in pending) >= max(held, MERGE_ROWS):
            merged, pending = [merge_bins([*merged, *pending])], []
    parts = [*merged, *pending]
    if not parts:  # a file without row groups
        none = np.empty(0)
        parts = [
            bin_samples(none, none.astype(np.int64), dict.fromkeys(QUANTITIES, none), LEVELS_M[0])
        ]
    return coarsen(merge_bins(parts))


def envelope_bytes(source: SamplesSource) -> bytes:
    """The envelope file (Parquet) of a samples file, read batch by batch."""
    sink = pa.BufferOutputStream()
    pq.write_table(envelope_table(_read_levels(source)), sink, row_group_size=ROW_GROUP_ROWS)
    return bytes(sink.getvalue().to_pybytes())


def write_envelopes(
    store: Store, samples_key: str, source: SamplesSource | None = None
) -> StoredObject:
    """Build the envelope file of the samples file at ``samples_key`` from ``source`` (a copy
    of it; by default that file in ``store``) and put it at ``envelope_key(samples_key)``."""
    built = envelope_bytes(StoredSamples(store, samples_key) if source is None else source)
    return store.put_bytes(built, envelope_key(samples_key))


def ensure_envelopes(store: Store, samples_key: str) -> str:
    """The key of the envelope file of the samples file at ``samples_key`` (a processing's
    ``samples_key``), built from the samples first if the store lacks it (a processing stored
    before envelope files were written)."""
    key = envelope_key(samples_key)
    if not store.exists(key):
        write_envelopes(store, samples_key)
    return key


@dataclass(frozen=True)
class WireTrace:
    """One wire's values along a window: ``chainage_m`` (bin starts, or the samples' own
    chainage), and per quantity the minimum ``low`` and maximum ``high`` of each bin (the
    sample's value, both, for raw samples). Shapes ``(k,)``, by increasing chainage."""

    chainage_m: FloatArray
    low: Mapping[str, FloatArray]
    high: Mapping[str, FloatArray]


@dataclass(frozen=True)
class TrackView:
    """What :func:`track_view` read of window ``[from_m, to_m]``: each wire's trace, and the bin
    width ``level_m`` it was read at (None: the raw samples)."""

    from_m: float
    to_m: float
    level_m: float | None
    wires: Mapping[int, WireTrace]

    @property
    def raw(self) -> bool:
        """Whether the traces are the samples themselves."""
        return self.level_m is None


def choose_level(
    from_m: float, to_m: float, columns: int, levels_m: Sequence[float] = LEVELS_M
) -> float | None:
    """The bin width to draw window ``[from_m, to_m]`` on ``columns`` pixel columns at: None
    (the raw samples) when it is shorter than ``RAW_BELOW_M``, else the coarsest level no
    wider than a column (``(to_m - from_m) / columns``), else the finest."""
    width_m = to_m - from_m
    if width_m < RAW_BELOW_M:
        return None
    fitting = [level for level in levels_m if level <= width_m / columns]
    return max(fitting) if fitting else min(levels_m)


def _traces(
    wire: NDArray[np.integer],
    chainage_m: FloatArray,
    low: Mapping[str, FloatArray],
    high: Mapping[str, FloatArray],
) -> dict[int, WireTrace]:
    """``(m,)`` rows split per wire, each by increasing chainage."""
    order = np.lexsort((chainage_m, wire))
    numbers, first = np.unique(wire[order], return_index=True)
    bounds = [*first.tolist(), order.shape[0]]
    traces = {}
    for number, begin, end in zip(numbers.tolist(), bounds[:-1], bounds[1:], strict=True):
        rows = order[begin:end]
        traces[int(number)] = WireTrace(
            chainage_m[rows],
            {q: v[rows] for q, v in low.items()},
            {q: v[rows] for q, v in high.items()},
        )
    return traces


def track_view(
    store: Store,
    samples_key: str,
    from_m: float,
    to_m: float,
    columns: int,
    quantities: Sequence[str] = QUANTITIES,
) -> TrackView:
    """The samples file at ``samples_key`` (a processing's) along chainage ``[from_m, to_m]``
    drawn on ``columns`` pixel columns: at ``choose_level``'s bin width from its envelope file
    (built first if missing: ``ensure_envelopes``), the bins that meet the window; or its raw
    samples in the window that count (``trusted``). Only the row groups that hold the window
    are read. A window or quantity the view cannot draw is a ``UserError``."""
    if not (math.isfinite(from_m) and math.isfinite(to_m) and from_m < to_m):
        raise UserError(f"chainage window {from_m} to {to_m} m: the start must be below the end")
    if columns < 1:
        raise UserError(f"columns {columns}: a view needs one pixel column at least")
    unknown = [q for q in quantities if q not in QUANTITIES]
    if unknown:
        raise UserError(f"quantity {unknown[0]!r}: not one of {', '.join(QUANTITIES)}")
    level_m = choose_level(from_m, to_m, columns)
    if level_m is None:
        return _raw_view(StoredSamples(store, samples_key), from_m, to_m, quantities)
    import pyarrow.dataset as ds  # here: it imports pandas, which ``process`` never needs

    key = ensure_envelopes(store, samples_key)
    window = (
        (ds.field("level_m") == level_m)
        & (ds.field("chainage_m") > from_m - level_m)
        & (ds.field("chainage_m") <= to_m)
    )
    names = ["wire", "chainage_m", *(f"{side}_{q}" for q in quantities for side in ("min", "max"))]
    try:
        table = ds.dataset(key, filesystem=store.filesystem, format="parquet").to_table(
            columns=names, filter=window
        )
    except pa.ArrowInvalid as exc:
        raise FormatError(store.describe(key), f"not a readable envelope file ({exc})") from None
    except OSError as exc:
        raise StoreError(
            f"{store.describe(key)}: cannot read: {' '.join(str(exc).split())}"
        ) from None
    column = {name: table.column(name).to_numpy() for name in names}
    return TrackView(
        from_m,
        to_m,
        level_m,
        _traces(
            column["wire"],
            column["chainage_m"],
            {q: column[f"min_{q}"] for q in quantities},
            {q: column[f"max_{q}"] for q in quantities},
        ),
    )


def _raw_view(
    source: StoredSamples, from_m: float, to_m: float, quantities: Sequence[str]
) -> TrackView:
    """``track_view`` of the samples themselves."""
    parts = []
    names = ["chainage_m", "wire", *TRUST_COLUMNS, *quantities]
    for batch in read_sample_batches(source, names, within_m=(from_m, to_m)):
        chainage = batch["chainage_m"]
        keep = trusted(batch) & (chainage >= from_m) & (chainage <= to_m)
        parts.append({name: batch[name][keep] for name in ("chainage_m", "wire", *quantities)})
    rows = {
        name: np.concatenate([p[name] for p in parts]) if parts else np.empty(0)
        for name in ("chainage_m", "wire", *quantities)
    }
    values = {q: rows[q].astype(np.float64) for q in quantities}
    wire = rows["wire"].astype(np.int64)
    return TrackView(from_m, to_m, None, _traces(wire, rows["chainage_m"], values, values))
