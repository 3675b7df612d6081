"""Linear events: per-span results for an asset management system's linear assets.

Long format, one row per span, contact wire and measure, so that every row is one event on
the linear asset (line, track, from, to, markers) with one value, whatever measures are added
later:

| column | meaning |
| --- | --- |
| ``line``, ``track`` | codes of the register |
| ``from_m``, ``to_m`` | the span's chainage range [m] |
| ``from_marker``, ``to_marker`` | the masts at its ends (empty without a mast register) |
| ``wire``, ``wire_type`` | contact wire number within the run, and its type |
| ``measure`` | one of ``MEASURES`` (the ``spans`` export's column names, units in them) |
| ``value``, ``unit`` | the measure's value and unit |
| ``at_m`` | where along the span the value lies [m], for the minimum residual thickness only |
| ``run_id``, ``date`` | the run measured, and its date (UTC, ``YYYY-MM-DD``) |

Runs: the one given (``RUN`` or ``--latest``), else the latest complete run (by date) of every
track of ``--line`` (and ``--track``), or of every line. ``.csv``, ``.xlsx`` or ``.parquet``.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pyarrow as pa
from sqlalchemy import select
from sqlalchemy.orm import Session

from catenary.errors import UserError
from catenary.measurement.samples import export_table
from catenary.plugins import ReportRequest
from catenary.storage.database import open_database, session_scope
from catenary.storage.models import Line, Run, SpanMeasurement, Track
from catenary.storage.runs import find_run
from catenary_reports.request import Request, check_output, parse_request

__all__ = ["EVENT_SCHEMA", "MEASURES", "write"]

MEASURES = (
    ("min_residual_thickness_mm", "mm"),
    ("mean_residual_thickness_mm", "mm"),
    ("height_min_mm", "mm"),
    ("height_max_mm", "mm"),
    ("stagger_min_mm", "mm"),
    ("stagger_max_mm", "mm"),
)
"""The measures exported per span and wire, with their units, in row order."""

EVENT_SCHEMA = pa.schema(
    [
        ("line", pa.string()),
        ("track", pa.string()),
        ("from_m", pa.float64()),
        ("to_m", pa.float64()),
        ("from_marker", pa.string()),
        ("to_marker", pa.string()),
        ("wire", pa.int64()),
        ("wire_position", pa.int64()),
        ("wire_type", pa.string()),
        ("measure", pa.string()),
        # every measure is in mm: its decimals in CSV (catenary.measurement.spreadsheet)
        pa.field("value", pa.float64(), metadata={"unit": "mm"}),
        ("unit", pa.string()),
        ("at_m", pa.float64()),
        ("run_id", pa.int64()),
        ("date", pa.string()),
    ]
)


def _runs(session: Session, request: Request) -> list[Run]:
    if request.runs:
        run = find_run(session, request.runs[0])
        code = run.track.code if run.track else None
        if request.line not in (None, run.line.code) or request.track not in (None, code):
            asked = f"line {request.line!r}" + (
                f" track {request.track!r}" if request.track else ""
            )
            raise UserError(
                f"run {run.id} is on line {run.line.code!r} track {code!r}, not {asked}"
            )
        return [run]
    query = select(Track).join(Line).order_by(Line.code, Track.code)
    if request.line is not None:
        query = query.where(Line.code == request.line)
    if request.track is not None:
        query = query.where(Track.code == request.track)
    runs = []
    for track in session.scalars(query):
        latest = session.scalars(
            select(Run)
            .where(Run.track_id == track.id, Run.status == "complete")
            .order_by(Run.started_at.desc(), Run.id.desc())
            .limit(1)
        ).first()
        if latest is not None:
            runs.append(latest)
    if not runs:
        where = "any line" if request.line is None else f"line {request.line!r}"
        where += f" track {request.track!r}" if request.track else ""
        raise UserError(f"no complete run on {where} in the database")
    return runs


def _events(session: Session, run: Run) -> pa.Table:
    spans = session.scalars(
        select(SpanMeasurement)
        .where(SpanMeasurement.processing_id == run.processing_id)
        .order_by(SpanMeasurement.start_chainage_m, SpanMeasurement.wire)
    )
    rows: list[dict[str, Any]] = []
    day = run.started_at.date().isoformat()
    for s in spans:
        for measure, unit in MEASURES:
            rows.append(
                {
                    "line": run.line.code,
                    "track": run.track.code if run.track else None,
                    "from_m": s.start_chainage_m,
                    "to_m": s.end_chainage_m,
                    "from_marker": s.mast_from,
                    "to_marker": s.mast_to,
                    "wire": s.wire,
                    "wire_position": s.wire_position,
                    "wire_type": s.wire_type,
                    "measure": measure,
                    "value": getattr(s, measure),
                    "unit": unit,
                    "at_m": s.min_at_chainage_m if measure == "min_residual_thickness_mm" else None,
                    "run_id": run.id,
                    "date": day,
                }
            )
    return pa.Table.from_pylist(rows, schema=EVENT_SCHEMA)


def write(raw: ReportRequest, output: Path) -> Path:
    """Write the linear events of the runs chosen by ``raw`` (module docstring) to ``output``."""
    request = parse_request("linear-events", raw, runs=(0, 1), line=True)
    check_output(output, (".csv", ".xlsx", ".parquet"))
    with (
        open_database(request.settings) as engine,
        session_scope(engine, read_only=True) as session,
    ):
        runs = _runs(session, request)
        tables: Iterator[pa.Table] = (_events(session, run) for run in runs)
        export_table(tables, EVENT_SCHEMA, output)
    return output
