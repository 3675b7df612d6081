"""Samples files: version 2 adds ``selection_uncertain``; version 1 files still read, as if
every row were surely the contact wire."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from catenary.errors import FormatError
from catenary.measurement.samples import (
    EXPORT_COLUMNS,
    FILE_COLUMNS,
    SAMPLES_SCHEMA,
    TRUST_COLUMNS,
    SampleWriter,
    export_schema,
    export_table,
    read_sample_batches,
    trusted,
    with_wire_positions,
)

ROWS = 5


def columns(uncertain: list[bool] | None = None) -> dict[str, np.ndarray]:
    values = {
        "scan": np.arange(ROWS),
        "position_m": np.arange(ROWS) * 0.04,
        "chainage_m": 1000.0 + np.arange(ROWS) * 0.04,
        "wire": np.zeros(ROWS, np.int32),
        "height_mm": np.full(ROWS, 5300.0),
        "stagger_mm": np.linspace(-200.0, -199.0, ROWS),
        "wear_width_mm": np.full(ROWS, 6.0),
        "residual_thickness_mm": np.full(ROWS, 11.2),
        "cameras": np.full(ROWS, 4, np.int16),
        "span": np.zeros(ROWS, np.int32),
        "vehicle_fault": np.array([False, True, False, False, False]),
    }
    if uncertain is not None:
        values["selection_uncertain"] = np.array(uncertain)
    return values


def version_1_file(path: Path) -> Path:
    """A samples file as version 1 wrote it: no ``selection_uncertain``."""
    schema = pa.schema(
        [f for f in SAMPLES_SCHEMA if f.name != "selection_uncertain"],
        metadata={"format": "catenary-samples", "format_version": "1"},
    )
    with SampleWriter(path, schema) as writer:
        writer.write(columns())
    return path


def test_the_current_version_stores_the_flag(tmp_path: Path) -> None:
    path = tmp_path / "v2.parquet"
    with SampleWriter(path) as writer:
        writer.write(columns([False, False, True, True, False]))
    metadata = pq.read_schema(path).metadata
    assert metadata[b"format_version"] == b"2"
    (batch,) = read_sample_batches(path, ["scan", *TRUST_COLUMNS])
    np.testing.assert_array_equal(batch["selection_uncertain"], [False, False, True, True, False])
    np.testing.assert_array_equal(trusted(batch), [True, False, False, False, True])


def test_a_version_1_file_reads_as_all_certain(tmp_path: Path) -> None:
    path = version_1_file(tmp_path / "v1.parquet")
    (every,) = read_sample_batches(path)
    np.testing.assert_array_equal(every["selection_uncertain"], np.zeros(ROWS, dtype=bool))
    np.testing.assert_array_equal(every["residual_thickness_mm"], np.full(ROWS, 11.2))
    (some,) = read_sample_batches(path, ["chainage_m", *TRUST_COLUMNS])
    assert list(some) == ["chainage_m", *TRUST_COLUMNS]
    np.testing.assert_array_equal(trusted(some), [True, False, True, True, True])
    with pytest.raises(FormatError, match="no column 'wire_width'"):
        next(read_sample_batches(path, ["wire_width"]))


def test_a_version_1_file_exports_the_flag_false(tmp_path: Path) -> None:
    path = version_1_file(tmp_path / "v1.parquet")
    schema = export_schema(path)
    assert schema.names == list(FILE_COLUMNS)
    assert schema.field("selection_uncertain").type == pa.bool_()
    output = tmp_path / "samples.csv"
    tables, schema = with_wire_positions(path, {(0, 0): 0})
    assert schema.names == list(EXPORT_COLUMNS)
    assert export_table(tables, schema, output) == ROWS
    with output.open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == list(EXPORT_COLUMNS)
    assert [r["selection_uncertain"] for r in rows] == ["false"] * ROWS
    assert [r["wire_position"] for r in rows] == ["0"] * ROWS
    parquet = tmp_path / "samples.parquet"
    export_table(*with_wire_positions(path, {}), parquet)  # no span measured: empty
    table = pq.read_table(parquet)
    assert table.column_names == list(EXPORT_COLUMNS)
    assert table.column("selection_uncertain").to_pylist() == [False] * ROWS
    assert table.column("wire_position").to_pylist() == [None] * ROWS


def test_each_rows_wire_position_comes_from_its_span_and_wire(tmp_path: Path) -> None:
    path = tmp_path / "samples.parquet"
    rows = columns()
    rows["span"] = np.array([-1, 3, 3, 4, 4], np.int32)
    rows["wire"] = np.array([0, 0, 1, 1, 2], np.int32)
    with SampleWriter(path) as writer:
        writer.write({**rows, "selection_uncertain": np.zeros(ROWS, bool)})
    tables, _ = with_wire_positions(path, {(3, 0): 1, (3, 1): 0, (4, 1): 0})
    (table,) = tables
    assert table.column("wire_position").to_pylist() == [None, 1, 0, 0, None]
