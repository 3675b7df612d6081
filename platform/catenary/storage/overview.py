"""The fleet at a glance, in a few aggregate queries: each track with its register and its
latest run, and the thinnest spans of those runs.

A track's latest run is its complete run that started last (as the maintenance report
reads it); its spans are those of that run's latest processing. Nothing here reads every
span into Python: mast counts and the thinnest spans are found by the database
(``span_measurements``' index on ``processing_id, min_residual_thickness_mm``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import Select, func, select, true
from sqlalchemy.orm import Session, contains_eager

from catenary.storage.models import Line, Mast, Run, SpanMeasurement, Track, Vehicle

__all__ = ["TrackSummary", "latest_runs", "track_summaries", "worst_spans"]


def latest_runs() -> Select[Any]:
    """A query of ``(track_id, run_id, processing_id)``: each track's latest complete run."""
    rank = (
        func.row_number()
        .over(partition_by=Run.track_id, order_by=(Run.started_at.desc(), Run.id.desc()))
        .label("rank")
    )
    ranked = (
        select(Run.track_id, Run.id.label("run_id"), Run.processing_id, rank)
        .where(Run.status == "complete", Run.track_id.is_not(None))
        .subquery()
    )
    return select(ranked.c.track_id, ranked.c.run_id, ranked.c.processing_id).where(
        ranked.c.rank == 1
    )


@dataclass(frozen=True)
class TrackSummary:
    """A track of the register: its masts and spans (between consecutive masts) and its
    latest complete run (None: none yet)."""

    line: str
    track: str
    masts: int
    latest: Run | None

    @property
    def spans(self) -> int:
        return max(self.masts - 1, 0)


def track_summaries(session: Session) -> list[TrackSummary]:
    """Every track, by line and track code."""
    tracks = session.execute(select(Track.id, Line.code, Track.code).join(Line)).all()
    masts: dict[int, int] = {
        track_id: n
        for track_id, n in session.execute(
            select(Mast.track_id, func.count()).group_by(Mast.track_id)
        )
    }
    latest = latest_runs().subquery()
    runs = {
        run.track_id: run
        for run in session.scalars(
            select(Run)
            .join(latest, latest.c.run_id == Run.id)
            .join(Vehicle, Run.vehicle_id == Vehicle.id)
            .options(contains_eager(Run.vehicle))
        )
    }
    return sorted(
        (
            TrackSummary(line, track, masts.get(id_, 0), runs.get(id_))
            for id_, line, track in tracks
        ),
        key=lambda t: (t.line, t.track),
    )


def worst_spans(session: Session, limit: int = 20) -> list[tuple[str, str, SpanMeasurement]]:
    """The ``limit`` span-wires of lowest minimum residual thickness among the tracks'
    latest runs, thinnest first, each with its line and track code.

    On PostgreSQL each latest processing gives its own thinnest ``limit`` (a lateral join on
    the index), so only tracks x ``limit`` rows are sorted; elsewhere the database sorts the
    latest processings' rows.
    """
    latest = latest_runs().subquery()
    thinnest = SpanMeasurement.min_residual_thickness_mm
    if session.get_bind().dialect.name == "postgresql":
        each = (
            select(SpanMeasurement.id)
            .where(SpanMeasurement.processing_id == latest.c.processing_id)
            .order_by(thinnest, SpanMeasurement.id)
            .limit(limit)
            .lateral()
        )
        chosen = select(each.c.id).select_from(latest).join(each, true())
    else:
        chosen = select(SpanMeasurement.id).join(
            latest, SpanMeasurement.processing_id == latest.c.processing_id
        )
    found = session.execute(
        select(Line.code, Track.code, SpanMeasurement)
        .join(Track, SpanMeasurement.track_id == Track.id)
        .join(Line, Track.line_id == Line.id)
        .where(SpanMeasurement.id.in_(chosen.scalar_subquery()))
        .order_by(thinnest, SpanMeasurement.id)
        .limit(limit)
    )
    return [(line, track, span) for line, track, span in found]
