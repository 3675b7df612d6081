"""``catenary export``: a stored run's samples or spans as CSV, ``.xlsx`` or Parquet, or its
spans as GeoJSON (FORMATS.md; README, "File formats")."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from sqlalchemy import select
from sqlalchemy.orm import Session

from catenary.config import Settings
from catenary.errors import UserError
from catenary.geojson import MastPositions, feature, feature_collection, write_geojson
from catenary.measurement.samples import (
    STDOUT,
    TABLE_SUFFIXES,
    export_table,
    one_of,
    run_samples,
    sample_rows,
    with_wire_positions,
)
from catenary.measurement.spans import SPAN_SCHEMA, span_table
from catenary.storage.database import open_database, session_scope
from catenary.storage.models import Mast, Run, SpanMeasurement
from catenary.storage.runs import find_run
from catenary.storage.spans import wire_positions_of
from catenary.storage.store import open_store
from catenary.text import printable

__all__ = ["EXPORTS", "Exported", "export_run", "track_positions"]

EXPORTS = ("samples", "spans")
"""What a run exports: full-resolution samples, or one row per span and wire."""


@dataclass(frozen=True)
class Exported:
    """What ``export_run`` wrote: ``rows`` (GeoJSON: features) of run ``run_id``;
    ``left_out``: the GeoJSON rows left out for want of mast coordinates."""

    rows: int
    run_id: int
    left_out: int = 0


def export_run(settings: Settings, reference: str, what: str, output: Path) -> Exported:
    """Write run ``reference``'s ``what`` (one of ``EXPORTS``) to ``output``: the suffix
    chooses the format (``TABLE_SUFFIXES``, or ``.geojson`` for spans); ``-``: CSV to
    standard output."""
    suffix = output.suffix.lower()
    geojson = suffix == ".geojson" and what == "spans"
    if str(output) != STDOUT and suffix not in TABLE_SUFFIXES and not geojson:
        known = one_of((*TABLE_SUFFIXES, *((".geojson",) if what == "spans" else ())))
        raise UserError(f"{output}: the output's suffix must be {known} (or -, standard output)")
    with (
        open_database(settings) as engine,
        session_scope(engine, read_only=True) as session,
    ):
        run = find_run(session, reference)
        if what == "spans":
            rows = list(
                session.scalars(
                    select(SpanMeasurement)
                    .where(SpanMeasurement.processing_id == run.processing_id)
                    .order_by(SpanMeasurement.span, SpanMeasurement.wire)
                )
            )
            if geojson:
                return _spans_geojson(session, run, rows, output)
            written = export_table(iter([span_table(rows)]), SPAN_SCHEMA, output)
        else:
            samples = run_samples(open_store(settings), run)
            positions = wire_positions_of(session, run.processing_id)
            tables, schema = with_wire_positions(samples, positions)
            written = export_table(tables, schema, output, sample_rows(samples))
        return Exported(written, run.id)


def track_positions(session: Session, track_id: int) -> tuple[MastPositions, set[str]]:
    """The positioned masts of a track, and the codes of those among them."""
    masts = session.execute(
        select(Mast.code, Mast.chainage_m, Mast.latitude, Mast.longitude).where(
            Mast.track_id == track_id
        )
    ).all()
    positions = MastPositions.of((m.chainage_m, m.latitude, m.longitude) for m in masts)
    return positions, {m.code for m in masts if m.latitude is not None and m.longitude is not None}


def _spans_geojson(
    session: Session, run: Run, rows: list[SpanMeasurement], output: Path
) -> Exported:
    """The spans as LineStrings from their start mast to their end mast, the ``spans``
    export's columns as properties; spans whose masts have no coordinates are left out."""
    positions, placed = track_positions(session, run.track_id) if run.track_id else (None, set())
    if positions is None or positions.empty:
        raise UserError(
            printable(
                f"{output}: the mast register of run {run.id}'s track has no coordinates "
                "(latitude, longitude; FORMATS.md, Mast register)"
            )
        )
    features = []
    for row, properties in zip(rows, span_table(rows).to_pylist(), strict=True):
        geometry = positions.stretch(row.start_chainage_m, row.end_chainage_m)
        if geometry is not None and row.mast_from in placed and row.mast_to in placed:
            features.append(feature(geometry, properties))
    write_geojson(output, feature_collection(features))
    return Exported(len(features), run.id, left_out=len(rows) - len(features))
