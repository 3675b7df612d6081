"""``catenary export``: a stored run's samples or spans as CSV or Parquet (FORMATS.md)."""

from __future__ import annotations

from pathlib import Path

from sqlalchemy import select

from catenary.config import Settings
from catenary.errors import UserError
from catenary.measurement.samples import export_table, run_samples, with_wire_positions
from catenary.measurement.spans import SPAN_SCHEMA, span_table
from catenary.storage.database import open_database, session_scope
from catenary.storage.models import SpanMeasurement
from catenary.storage.runs import find_run
from catenary.storage.store import open_store

__all__ = ["EXPORTS", "export_run"]

EXPORTS = ("samples", "spans")
"""What a run exports: full-resolution samples, or one row per span and wire."""


def export_run(settings: Settings, reference: str, what: str, output: Path) -> tuple[int, int]:
    """Write run ``reference``'s ``what`` (one of ``EXPORTS``) to ``output`` (the suffix, .csv
    or .parquet, chooses the format); returns the rows written and the run's id."""
    if output.suffix.lower() not in (".csv", ".parquet"):
        raise UserError(f"{output}: the output's suffix must be .csv or .parquet")
    with (
        open_database(settings) as engine,
        session_scope(engine, read_only=True) as session,
    ):
        run = find_run(session, reference)
        if what == "spans":
            rows = session.scalars(
                select(SpanMeasurement)
                .where(SpanMeasurement.processing_id == run.processing_id)
                .order_by(SpanMeasurement.span, SpanMeasurement.wire)
            )
            written = export_table(iter([span_table(rows)]), SPAN_SCHEMA, output)
        else:
            samples = run_samples(open_store(settings), run)
            positions = {
                (s.span, s.wire): s.wire_position
                for s in session.scalars(
                    select(SpanMeasurement).where(
                        SpanMeasurement.processing_id == run.processing_id
                    )
                )
            }
            tables, schema = with_wire_positions(samples, positions)
            written = export_table(tables, schema, output)
        return written, run.id
