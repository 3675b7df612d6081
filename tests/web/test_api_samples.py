"""``GET /api/v1/samples``: a chainage range of a processed run's samples file in the store,
paged or streamed; and ``samples_in_range`` on a file of many row groups."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner
from sqlalchemy import Engine

from catenary.cli import cli
from catenary.measurement.samples import (
    EXPORT_COLUMNS,
    SAMPLES_SCHEMA,
    SampleWriter,
    run_samples,
    samples_in_range,
    with_wire_positions,
)
from catenary.storage.database import session_scope
from catenary.storage.runs import find_run
from catenary.storage.spans import wire_positions_of
from tests.conftest import SmallRun
from tests.web.conftest import Web


def _file(path: Path, rows: int, block: int) -> Path:
    """A samples file of ``rows`` scans of one wire, 0.1 m apart from chainage 0, written in
    blocks of ``block`` rows (row groups of ``ROW_GROUP_ROWS``)."""
    with SampleWriter(path) as writer:
        for start in range(0, rows, block):
            scan = np.arange(start, min(rows, start + block))
            columns: dict[str, Any] = {f.name: np.zeros(scan.shape[0]) for f in SAMPLES_SCHEMA}
            columns |= {
                "scan": scan,
                "position_m": scan * 0.1,
                "chainage_m": scan * 0.1,
                "wire": np.zeros(scan.shape[0], dtype=np.int32),
                "selection_uncertain": np.zeros(scan.shape[0], dtype=bool),
                "cameras": np.full(scan.shape[0], 3, dtype=np.int16),
                "span": (scan // 500).astype(np.int32),
                "vehicle_fault": np.zeros(scan.shape[0], dtype=bool),
            }
            writer.write(columns)
    return path


def test_a_range_read_in_pages_that_join_up(tmp_path: Path) -> None:
    path = _file(tmp_path / "samples.parquet", 100_000, 5_000)
    assert pq.ParquetFile(path).num_row_groups > 4
    positions = {(span, 0): 0 for span in range(200)}
    seen: list[pa.Table] = []
    after: int | None = -1
    while after is not None:
        page = samples_in_range(path, positions, 1500.0, 4200.05, after=after, limit=7000)
        assert page.table.num_rows <= 7000
        seen.append(page.table)
        after = page.next_after
    scans = pa.concat_tables(seen).column("scan").to_numpy()
    np.testing.assert_array_equal(scans, np.arange(15000, 42001))  # 0.1 m apart, both ends in
    assert pa.concat_tables(seen).column_names == list(EXPORT_COLUMNS)
    empty = samples_in_range(path, positions, 20000.0, 30000.0, limit=10)
    assert empty.table.num_rows == 0 and empty.next_after is None


@pytest.mark.slow
def test_samples_of_a_processed_run_paged_and_streamed(
    web: Web, engine: Engine, small_run: SmallRun, database_url: str
) -> None:
    processed = CliRunner().invoke(cli, small_run.process_args(database_url))
    assert processed.exit_code == 0, processed.output
    store = web.app.state.web.store
    with session_scope(engine, read_only=True) as session:
        run = find_run(session, "latest")
        source = run_samples(store, run)
        tables, _ = with_wire_positions(source, wire_positions_of(session, run.processing_id))
    whole = pa.concat_tables(tables)
    metres = whole.column("chainage_m").to_numpy()
    from_m, to_m = (float(x) for x in np.quantile(metres, [0.25, 0.6]))
    inside = whole.filter(pa.array((metres >= from_m) & (metres <= to_m)))
    assert inside.num_rows > 500

    client = web.api("vera")
    seen: list[dict[str, Any]] = []
    address: str | None = f"/api/v1/samples?run=latest&from_m={from_m!r}&to_m={to_m!r}&limit=200"
    while address:
        answer = client.get(address)
        assert answer.status_code == 200, answer.text
        page = answer.json()
        assert len(page["samples"]) <= 200
        seen += page["samples"]
        address = page["next"]
    assert [(s["scan"], s["wire"]) for s in seen] == list(
        zip(inside.column("scan").to_pylist(), inside.column("wire").to_pylist(), strict=True)
    )
    expected = inside.column("residual_thickness_mm").to_numpy(zero_copy_only=False)
    got = np.array([np.nan if s["residual_thickness_mm"] is None else s["residual_thickness_mm"]
                    for s in seen])  # fmt: skip
    np.testing.assert_allclose(got, expected, atol=1e-9, equal_nan=True)
    assert {s["wire_position"] for s in seen} <= {None, 0, 1, 2}
    assert set(seen[0]) == set(EXPORT_COLUMNS)

    params = {"run": "latest", "from_m": from_m, "to_m": to_m}
    ndjson = client.get("/api/v1/samples", params=params | {"format": "ndjson"})
    assert ndjson.headers["content-type"].startswith("application/x-ndjson")
    lines = [json.loads(line) for line in ndjson.text.splitlines()]
    assert lines == seen
    streamed = client.get("/api/v1/samples", params=params | {"format": "csv"})
    rows = list(csv.DictReader(io.StringIO(streamed.text)))
    assert len(rows) == inside.num_rows and list(rows[0]) == list(EXPORT_COLUMNS)


@pytest.mark.parametrize(
    ("query", "status", "words"),
    [
        ({"run": "latest", "from_m": 5, "to_m": 1}, 422, "must not exceed"),
        ({"run": "latest", "from_m": 0, "to_m": 1, "limit": 10_001}, 422, "limit"),
        ({"run": "latest", "from_m": 0, "to_m": 1, "after": -2}, 422, "after"),
        ({"run": "latest", "from_m": 0}, 422, "to_m"),
        ({"run": "latest", "from_m": 0, "to_m": "x"}, 422, "to_m"),
        ({"run": "latest", "from_m": 0, "to_m": 1, "format": "xml"}, 422, "format"),
        ({"run": "123456", "from_m": 0, "to_m": 1}, 404, "no run"),
    ],
)
def test_bad_sample_queries_are_one_clear_error(
    web: Web, query: dict[str, Any], status: int, words: str
) -> None:
    answer = web.api("vera").get("/api/v1/samples", params=query)
    assert answer.status_code == status
    assert list(answer.json()) == ["error"] and words in answer.json()["error"]


def test_a_run_without_a_samples_file_is_refused(web: Web, engine: Engine, build: Any) -> None:
    with session_scope(engine) as session:
        build.run(session)
    answer = web.api("vera").get("/api/v1/samples", params={"run": "latest", "from_m": 0,
                                                           "to_m": 1})  # fmt: skip
    assert answer.status_code == 400 and "no samples file" in answer.json()["error"]
