"""Span measurements as the web API and pages list them: the latest run of each track (or one
run), its latest processing's rows, filtered by track and chainage in SQL, worst first or along
the track, a page at a time."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime

from sqlalchemy import Select, func, select
from sqlalchemy.orm import Session

from catenary.errors import UserError
from catenary.storage.models import Line, Run, SpanMeasurement, Track

__all__ = ["SPAN_ORDERS", "ListedSpan", "SpanPage", "list_spans", "wire_positions_of"]

SPAN_ORDERS = ("chainage", "worst")
"""``chainage``: by line, track, chainage and wire position; ``worst``: lowest minimum
residual thickness first."""


@dataclass(frozen=True)
class ListedSpan:
    """A span measurement with its run's and track's identity."""

    measurement: SpanMeasurement
    line: str
    track: str | None
    run_id: int
    run_uuid: str
    started_at: datetime


@dataclass(frozen=True)
class SpanPage:
    """A page of span measurements and how many match in all."""

    spans: list[ListedSpan]
    total: int


def _latest_runs(line: str | None, track: str | None) -> Select[tuple[int]]:
    """The latest complete run of each track (of ``line``, ``track`` if given), by id."""
    ranked = (
        select(
            Run.id,
            func.row_number()
            .over(partition_by=Run.track_id, order_by=(Run.started_at.desc(), Run.id.desc()))
            .label("rank"),
        )
        .join(Track, Run.track_id == Track.id)
        .join(Line, Track.line_id == Line.id)
        .where(Run.status == "complete")
    )
    if line is not None:
        ranked = ranked.where(Line.code == line)
    if track is not None:
        ranked = ranked.where(Track.code == track)
    latest = ranked.subquery()
    return select(latest.c.id).where(latest.c.rank == 1)


def list_spans(
    session: Session,
    *,
    line: str | None = None,
    track: str | None = None,
    run: Run | None = None,
    from_m: float | None = None,
    to_m: float | None = None,
    order: str = "chainage",
    limit: int = 100,
    offset: int = 0,
) -> SpanPage:
    """The span measurements of the latest processing of run ``run``, or of the latest complete
    run of each track (of ``line`` and ``track`` when given), that overlap ``from_m`` to
    ``to_m`` [m]; ``limit`` of them from ``offset`` on, in ``order`` (``SPAN_ORDERS``; ties by
    wire position and id, so pages join up). Two queries: the page and the count."""
    if order not in SPAN_ORDERS:
        raise UserError(f"unknown order {order!r} (known: {', '.join(SPAN_ORDERS)})")
    if from_m is not None and to_m is not None and from_m > to_m:
        raise UserError(f"from_m {from_m:g} must not exceed to_m {to_m:g}")
    sm = SpanMeasurement
    query = (
        select(sm, Line.code, Track.code, Run.id, Run.uuid, Run.started_at)
        .join(Run, (sm.run_id == Run.id) & (sm.processing_id == Run.processing_id))
        .join(Line, Run.line_id == Line.id)
        .outerjoin(Track, Run.track_id == Track.id)
    )
    if run is not None:
        query = query.where(Run.id == run.id)
    else:
        query = query.where(Run.id.in_(_latest_runs(line, track)))
    if from_m is not None:
        query = query.where(sm.end_chainage_m > from_m)
    if to_m is not None:
        query = query.where(sm.start_chainage_m < to_m)
    total = session.scalar(select(func.count()).select_from(query.order_by(None).subquery()))
    along = (Line.code, Track.code, sm.start_chainage_m, sm.wire_position, sm.id)
    ordering = (sm.min_residual_thickness_mm, *along) if order == "worst" else along
    found = session.execute(query.order_by(*ordering).limit(limit).offset(offset)).all()
    return SpanPage(
        spans=[ListedSpan(*row) for row in found],
        total=int(total or 0),
    )


def wire_positions_of(session: Session, processing_id: int | None) -> dict[tuple[int, int], int]:
    """A processing's ``(span, wire)`` -> wire position, from its span measurements."""
    sm = SpanMeasurement
    found = session.execute(
        select(sm.span, sm.wire, sm.wire_position).where(sm.processing_id == processing_id)
    )
    return {(span, wire): position for span, wire, position in found}
