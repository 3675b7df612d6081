"""A run's full-resolution wear samples: one Parquet file per run (``catenary-samples`` v2).

Columns: the ``samples`` export columns of FORMATS.md, in its order (``selection_uncertain``,
bool: the processor could not decide that the point is the contact wire; such samples are
left out of the span figures, and so of the alerts), then the project's own (README, "File
formats"):

- ``span`` (int32): the span's number as stored in the database, -1 outside every span;
- ``vehicle_fault`` (bool): a displacement sensor sample of the scan was faulty or missing,
  so height and stagger are not trusted (such samples are left out of the span statistics).

The file's key-value metadata holds ``format = catenary-samples``, ``format_version = 2``.
Version 1 had no ``selection_uncertain``: its files read as if the column were all false
(``ADDED_COLUMNS``). Rows are written in blocks as the run is processed (each block sorted by
scan and wire) and read back in row groups, so neither side holds a whole run in memory.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

from catenary.arrays import BoolArray
from catenary.errors import FormatError, UserError
from catenary.measurement.compare import RunProfile
from catenary.measurement.spreadsheet import SHEET_ROWS, XlsxTableWriter, for_people
from catenary.storage.models import Run
from catenary.storage.runs import latest_processing
from catenary.storage.store import Store, check_key

__all__ = [
    "ADDED_COLUMNS",
    "EXPORT_COLUMNS",
    "FILE_COLUMNS",
    "SAMPLES_SCHEMA",
    "STDOUT",
    "TABLE_SUFFIXES",
    "TRUST_COLUMNS",
    "SampleWriter",
    "StoredSamples",
    "export_table",
    "one_of",
    "read_sample_batches",
    "run_profile",
    "run_samples",
    "sample_rows",
    "stored_samples_key",
    "trusted",
    "with_wire_positions",
]

TABLE_SUFFIXES = (".csv", ".xlsx", ".parquet")
"""The suffixes of the files a table is exported to (``export_table``)."""
STDOUT = "-"
"""The output that is standard output (CSV)."""

FORMAT = "catenary-samples"
FORMAT_VERSION = 2

EXPORT_COLUMNS = (
    "scan",
    "position_m",
    "chainage_m",
    "wire",
    "height_mm",
    "stagger_mm",
    "wear_width_mm",
    "residual_thickness_mm",
    "wire_position",
    "selection_uncertain",
    "cameras",
)
"""The ``samples`` export's columns (FORMATS.md), in order. ``wire_position`` is not in the
samples file: it comes from the span measurements (``with_wire_positions``)."""

FILE_COLUMNS = tuple(c for c in EXPORT_COLUMNS if c != "wire_position")
"""The export's columns that the samples file holds."""

SAMPLES_SCHEMA = pa.schema(
    [
        ("scan", pa.int64()),
        ("position_m", pa.float64()),
        ("chainage_m", pa.float64()),
        ("wire", pa.int32()),
        ("height_mm", pa.float64()),
        ("stagger_mm", pa.float64()),
        ("wear_width_mm", pa.float64()),
        ("residual_thickness_mm", pa.float64()),
        ("selection_uncertain", pa.bool_()),
        ("cameras", pa.int16()),
        ("span", pa.int32()),
        ("vehicle_fault", pa.bool_()),
    ],
    metadata={"format": FORMAT, "format_version": str(FORMAT_VERSION)},
)

ADDED_COLUMNS: dict[str, bool] = {"selection_uncertain": False}
"""Columns added after version 1, and the value a file without them means in every row."""

TRUST_COLUMNS = ("vehicle_fault", "selection_uncertain")
"""The columns that say whether a sample counts (``trusted``)."""

ROW_GROUP_ROWS = 16_384


def _detail(exc: OSError) -> str:
    """An operating system error's message on one line."""
    return " ".join(str(exc).split())


class SampleWriter:
    """Writes sample rows to a Parquet file in row groups of ``ROW_GROUP_ROWS``.

    ``schema`` is :data:`SAMPLES_SCHEMA` unless given (the pipeline's intermediate file has
    its own). Use as a context manager; :meth:`abort` removes the file. A write that fails (a
    full disk) is a ``UserError`` naming the folder.
    """

    def __init__(self, path: Path, schema: pa.Schema = SAMPLES_SCHEMA) -> None:
        self.path = path
        self.schema = schema
        self.rows = 0
        self._parts: list[pa.Table] = []
        self._buffered = 0
        with self._writing():
            self._writer = pq.ParquetWriter(path, schema)

    @contextmanager
    def _writing(self) -> Iterator[None]:
        try:
            yield
        except OSError as exc:
            raise UserError(f"{self.path.parent}: cannot write samples ({_detail(exc)})") from None

    def write(self, columns: Mapping[str, Any]) -> None:
        """Append rows: every column of the schema as an array ``(m,)``."""
        table = pa.table({f.name: columns[f.name] for f in self.schema}, schema=self.schema)
        if table.num_rows == 0:
            return
        self._parts.append(table)
        self._buffered += table.num_rows
        self.rows += table.num_rows
        if self._buffered >= ROW_GROUP_ROWS:
            self._flush()

    def _flush(self) -> None:
        if self._parts:
            with self._writing():
                self._writer.write_table(pa.concat_tables(self._parts), ROW_GROUP_ROWS)
            self._parts, self._buffered = [], 0

    def close(self) -> None:
        self._flush()
        with self._writing():
            self._writer.close()

    def abort(self) -> None:
        """Close and remove the file (removed all the same when closing fails: a full disk)."""
        with suppress(OSError):
            self._writer.close()
        self.path.unlink(missing_ok=True)

    def __enter__(self) -> SampleWriter:
        return self

    def __exit__(self, kind: object, value: object, traceback: object) -> None:
        if kind is None:
            self.close()
        else:
            self.abort()


@dataclass(frozen=True)
class StoredSamples:
    """A samples file in the store: ``key`` in ``store``."""

    store: Store
    key: str

    def __str__(self) -> str:
        return self.store.describe(self.key)

    @property
    def name(self) -> str:
        """The file's name (the key's last part)."""
        return self.key.rsplit("/", 1)[-1]


SamplesSource = Path | StoredSamples
"""A samples file: a local file (the pipeline's own) or one in the store."""


def _open(source: SamplesSource) -> pq.ParquetFile:
    try:
        if isinstance(source, StoredSamples):
            return pq.ParquetFile(source.store.open_input(source.key))
        return pq.ParquetFile(source)
    except FileNotFoundError:
        raise UserError(f"{source}: samples file not found") from None
    except (pa.ArrowInvalid, OSError) as exc:
        raise FormatError(source, f"not a readable Parquet file ({exc})") from None


def _columns(
    path: SamplesSource, handle: pq.ParquetFile, wanted: Iterable[str]
) -> tuple[list[str], list[str]]:
    """The ``wanted`` columns the file holds, and those it lacks from ``ADDED_COLUMNS`` (an
    older version's file); a ``FormatError`` for any other it lacks."""
    names = handle.schema_arrow.names
    missing = [c for c in wanted if c not in names and c not in ADDED_COLUMNS]
    if missing:
        raise FormatError(path, f"no column {missing[0]!r}")
    return [c for c in wanted if c in names], [c for c in wanted if c not in names]


def read_sample_batches(
    path: SamplesSource,
    columns: list[str] | None = None,
    *,
    within_m: tuple[float, float] | None = None,
) -> Iterator[dict[str, np.ndarray[Any, Any]]]:
    """The samples of a file (``columns``, default all, with those of ``ADDED_COLUMNS`` an
    older file lacks filled in), row group by row group, as NumPy columns.

    With ``within_m = (from_m, to_m)``, only the row groups whose chainage statistics meet
    that window are read (rows are written in scan order, so a window reads the few groups
    that cover it); their rows are not filtered.
    """
    handle = _open(path)
    wanted = columns if columns is not None else [*handle.schema_arrow.names, *ADDED_COLUMNS]
    held, added = _columns(path, handle, list(dict.fromkeys(wanted)))
    for group in range(handle.num_row_groups):
        if within_m is not None and not _meets(handle, group, *within_m):
            continue
        table = handle.read_row_group(group, columns=held)
        batch = {name: table.column(name).to_numpy() for name in held}
        for name in added:
            batch[name] = np.full(table.num_rows, ADDED_COLUMNS[name])
        yield batch


def _meets(handle: pq.ParquetFile, group: int, from_m: float, to_m: float) -> bool:
    """Whether row group ``group`` may hold a chainage in ``[from_m, to_m]`` (by its column
    statistics; a group without them may)."""
    meta = handle.metadata.row_group(group)
    column = handle.schema_arrow.get_field_index("chainage_m")
    stats = meta.column(column).statistics if column >= 0 else None
    if stats is None or not stats.has_min_max:
        return True
    return bool(stats.min <= to_m and stats.max >= from_m)


def trusted(batch: Mapping[str, np.ndarray[Any, Any]]) -> BoolArray:
    """The samples of a batch (read with ``TRUST_COLUMNS``) that count: no vehicle sensor
    fault, and surely the contact wire (not ``selection_uncertain``), ``(m,)``."""
    return np.asarray(~batch["vehicle_fault"] & ~batch["selection_uncertain"], dtype=bool)


def export_table(
    batches: Iterator[pa.Table], schema: pa.Schema, output: Path, total: int | None = None
) -> int:
    """Write tables to ``output`` as CSV, ``.xlsx`` or Parquet (by its suffix; ``-``: CSV to
    standard output); returns the rows written.

    Written to a temporary file beside ``output`` and renamed at the end: an interrupted
    export leaves no partial file; a write that fails (a full disk) is a ``UserError`` naming
    ``output``. CSV and ``.xlsx`` are for people: numbers rounded to what they mean, text
    cells that a spreadsheet would evaluate neutralised, control characters escaped
    (``for_people``). More rows than an ``.xlsx`` sheet holds is a ``UserError`` naming
    ``output`` and the count, and writes nothing: before any row is written when the caller
    knows the ``total``, else on the batch that overflows.
    """
    if str(output) == STDOUT:
        return _csv_to_stdout(batches, schema)
    suffix = output.suffix.lower()
    if suffix not in TABLE_SUFFIXES:
        raise UserError(f"{output}: the output's suffix must be {one_of(TABLE_SUFFIXES)}")
    partial = output.with_name(f".{output.name}.partial")
    rows = 0
    try:
        if suffix == ".parquet":
            with pq.ParquetWriter(partial, schema) as writer:
                for table in batches:
                    writer.write_table(table)
                    rows += table.num_rows
        elif suffix == ".xlsx":
            if total is not None:
                _check_sheet_rows(output, total)
            with XlsxTableWriter(partial, schema) as sheet:
                for table in batches:
                    if 1 + rows + table.num_rows > SHEET_ROWS:
                        _check_sheet_rows(
                            output, rows + table.num_rows + sum(t.num_rows for t in batches)
                        )
                    sheet.write_table(table)
                    rows += table.num_rows
        else:
            with pa_csv.CSVWriter(partial, schema) as writer:
                for table in batches:
                    writer.write_table(for_people(table))
                    rows += table.num_rows
        partial.replace(output)
    except BaseException as exc:
        partial.unlink(missing_ok=True)
        if isinstance(exc, OSError):  # a full disk, a folder that may not be written
            raise UserError(f"{output}: cannot write ({_detail(exc)})") from None
        raise
    return rows


def _check_sheet_rows(output: Path, total: int) -> None:
    """Refuse ``total`` rows to an ``.xlsx`` sheet ``output`` if they do not fit under its
    header."""
    if 1 + total > SHEET_ROWS:
        raise UserError(
            f"{output}: {total} rows is more than a sheet holds "
            f"({SHEET_ROWS - 1} below the header); write .csv or .parquet"
        )


def sample_rows(path: SamplesSource) -> int:
    """The rows of a samples file (from its footer, without reading them)."""
    return int(_open(path).metadata.num_rows)


def one_of(suffixes: tuple[str, ...]) -> str:
    """``suffixes`` as a sentence says them: ".a, .b or .c"."""
    return " or ".join([", ".join(suffixes[:-1]), suffixes[-1]] if len(suffixes) > 1 else suffixes)


def _csv_to_stdout(batches: Iterator[pa.Table], schema: pa.Schema) -> int:
    """Write tables as CSV for people to standard output; returns the rows written. A reader
    that stops early (``| head``) is a ``UserError`` saying how many rows were written."""
    sys.stdout.flush()
    rows = 0
    try:
        with pa_csv.CSVWriter(sys.stdout.buffer, schema) as writer:
            for table in batches:
                writer.write_table(for_people(table))
                rows += table.num_rows
        sys.stdout.buffer.flush()
    except BrokenPipeError:
        # nothing more reaches the reader, Python's own flush at exit included
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        raise UserError(
            f"standard output closed by its reader: {rows} rows or fewer written"
        ) from None
    return rows


def sample_tables(
    path: SamplesSource, columns: tuple[str, ...] = FILE_COLUMNS
) -> Iterator[pa.Table]:
    """The samples file's row groups as tables of ``columns`` (those of ``ADDED_COLUMNS`` an
    older file lacks filled in), in that order."""
    handle = _open(path)
    held, added = _columns(path, handle, columns)
    schema = export_schema(path, columns)
    for group in range(handle.num_row_groups):
        table = handle.read_row_group(group, columns=held)
        filled = {
            name: pa.array(np.full(table.num_rows, ADDED_COLUMNS[name]), schema.field(name).type)
            for name in added
        }
        yield pa.table(
            {c: filled[c] if c in filled else table.column(c) for c in columns}, schema=schema
        )


def export_schema(path: SamplesSource, columns: tuple[str, ...] = FILE_COLUMNS) -> pa.Schema:
    """The schema of ``columns`` of a samples file (an older file's as the current one's)."""
    schema = _open(path).schema_arrow
    return pa.schema(
        [schema.field(c) if c in schema.names else SAMPLES_SCHEMA.field(c) for c in columns]
    )


def with_wire_positions(
    source: SamplesSource, positions: Mapping[tuple[int, int], int]
) -> tuple[Iterator[pa.Table], pa.Schema]:
    """The ``samples`` export of a samples file: its ``FILE_COLUMNS`` and each row's
    ``wire_position`` from ``positions`` (the span measurements' ``(span, wire)`` ->
    ``wire_position``; empty outside every span measured), as tables and their schema."""
    file_schema = export_schema(source)
    schema = pa.schema(
        [pa.field("wire_position", pa.int32()) if c == "wire_position" else file_schema.field(c)
         for c in EXPORT_COLUMNS]
    )  # fmt: skip
    # (span + 1, wire) -> position, -1 for none: a row outside every span has span -1
    lookup = np.full(
        (
            max((k[0] for k in positions), default=-1) + 2,
            max((k[1] for k in positions), default=0) + 1,
        ),
        -1,
        dtype=np.int32,
    )
    for (span, wire), position in positions.items():
        lookup[span + 1, wire] = position

    def tables() -> Iterator[pa.Table]:
        for table in sample_tables(source, (*FILE_COLUMNS, "span")):
            span = table.column("span").to_numpy(zero_copy_only=False).astype(np.int64) + 1
            wire = table.column("wire").to_numpy(zero_copy_only=False).astype(np.int64)
            inside = (span >= 0) & (span < lookup.shape[0]) & (wire >= 0) & (wire < lookup.shape[1])
            found = np.full(span.shape, -1, dtype=np.int32)
            found[inside] = lookup[span[inside], wire[inside]]
            columns = {c: table.column(c) for c in FILE_COLUMNS}
            columns["wire_position"] = pa.array(found, pa.int32(), mask=found < 0)
            yield pa.table(columns).select(list(EXPORT_COLUMNS)).cast(schema)

    return tables(), schema


def stored_samples_key(run: object, key: str) -> str:
    """``key``, the samples file of run ``run`` (its id or UUID, for the message), if it is a
    store key; else a ``UserError``."""
    try:
        return check_key(key)
    except ValueError:
        raise UserError(
            f"run {run}: its samples file {key!r} is not a store key (a path outside the "
            "data directory, stored by hand?)"
        ) from None


def run_samples(store: Store, run: Run) -> StoredSamples:
    """The samples file of the run's latest processing in ``store``
    (``Processing.samples_key``)."""
    key = latest_processing(run).samples_key
    if not key:
        raise UserError(f"run {run.id} has no samples file")
    return StoredSamples(store, stored_samples_key(run.id, key))


def run_profile(store: Store, run: Run) -> RunProfile:
    """The run's samples for ``compare_profiles``: those that count (``trusted``), the
    stagger in the line frame (positive to the right looking toward increasing chainage)."""
    columns = ["chainage_m", "wire", "stagger_mm", "residual_thickness_mm", *TRUST_COLUMNS]
    parts = list(read_sample_batches(run_samples(store, run), columns))
    values = {c: np.concatenate([p[c] for p in parts]) for c in columns} if parts else None
    if values is None:
        raise UserError(f"run {run.id} has no samples")
    good = trusted(values)
    sign = 1.0 if run.direction == "increasing" else -1.0
    return RunProfile(
        chainage_m=values["chainage_m"][good],
        wire=values["wire"][good].astype(np.int64),
        stagger_mm=sign * values["stagger_mm"][good],
        residual_thickness_mm=values["residual_thickness_mm"][good],
    )
