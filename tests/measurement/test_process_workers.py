"""``catenary process --workers N``: blocks staged in worker processes store exactly what one
process stores, with the real command, database and files."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner
from sqlalchemy import create_engine, select
from sqlalchemy.orm import Session

from catenary.cli import cli
from catenary.measurement import parallel, process
from catenary.storage.models import Run, SpanMeasurement

from ..conftest import SmallRun

IDS = {"id", "run_id", "processing_id"}


def _process(
    small_run: SmallRun, folder: Path, monkeypatch: pytest.MonkeyPatch, *options: str
) -> tuple[list[tuple[Any, ...]], dict[str, np.ndarray], dict[str, bytes]]:
    """Process the run into a new database and data folder under ``folder``; its span
    measurements (without ids), its samples file's columns and its image evidence (by file
    name)."""
    data = folder / "data"
    monkeypatch.setenv("CATENARY_DATA_DIR", str(data))
    url = f"sqlite:///{folder / 'catenary.sqlite'}"
    runner = CliRunner()
    assert runner.invoke(cli, ["--db", url, "db", "upgrade"]).exit_code == 0
    result = runner.invoke(cli, [*small_run.process_args(url), *options])
    assert result.exit_code == 0, result.output
    columns = [c.name for c in SpanMeasurement.__table__.c if c.name not in IDS]
    with Session(create_engine(url)) as session:
        spans = [
            tuple(getattr(row, c) for c in columns)
            for row in session.scalars(
                select(SpanMeasurement).order_by(SpanMeasurement.span, SpanMeasurement.wire)
            )
        ]
        (run,) = session.scalars(select(Run))
        assert run.processing is not None and run.processing.samples_key
        table = pq.read_table(data / run.processing.samples_key)
    evidence = {path.name: path.read_bytes() for path in (data / "evidence").rglob("*.png")}
    return spans, {name: table.column(name).to_numpy() for name in table.column_names}, evidence


def test_two_workers_store_exactly_what_one_stores(
    small_run: SmallRun, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # blocks of 128 scans: 11 blocks, more than the 2 x 2 in flight, so that the pool is
    # refilled while earlier blocks are taken in order; the image evidence cut a point at a
    # time, likewise
    monkeypatch.setattr(process, "BLOCK_SCANS", 128)
    monkeypatch.setattr(process, "EVIDENCE_CUT", 1)
    assert parallel.IN_FLIGHT_PER_WORKER * 2 < 11
    one = _process(small_run, tmp_path / "one", monkeypatch, "--workers", "1")
    two = _process(small_run, tmp_path / "two", monkeypatch, "--workers", "2")
    (spans_1, samples_1, evidence_1), (spans_2, samples_2, evidence_2) = one, two
    assert len(spans_1) > 0 and len(samples_1["scan"]) > 1000
    assert len(evidence_1) > parallel.IN_FLIGHT_PER_WORKER * 2
    assert evidence_2 == evidence_1  # every crop, byte for byte
    assert spans_2 == spans_1  # every span measurement, exactly
    assert samples_2.keys() == samples_1.keys()
    for name, column in samples_1.items():  # bit for bit (a NaN where the other has one)
        assert np.array_equal(samples_2[name], column, equal_nan=column.dtype.kind == "f"), name
