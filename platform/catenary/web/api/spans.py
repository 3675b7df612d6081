"""The API's spans: ``GET /spans`` (the latest run's span measurements of each track, or one
run's, by chainage or worst first, paged) and ``GET /spans/history`` (a span's history over
runs, wear rate and forecasts, as ``catenary history`` prints them; and its maintenance
actions). Fields are the ``spans`` export's columns (FORMATS.md)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Annotated, Literal

import numpy as np
from fastapi import APIRouter, HTTPException, Query, Request
from pydantic import BaseModel
from sqlalchemy.orm import Session

from catenary.limits import choose_policy
from catenary.maintenance.actions import list_maintenance
from catenary.maintenance.forecast import CONFIDENCE, MIN_RUNS, reach_text
from catenary.maintenance.trends import TrackTrends, history_rows, rate_interval, span_trends
from catenary.storage.database import session_scope
from catenary.storage.models import MaintenanceAction, SpanMeasurement
from catenary.storage.spans import list_spans
from catenary.web.api.runs import errors, run_of, track_of
from catenary.web.app import WebState, state
from catenary.web.auth import Principal, requires

__all__ = [
    "MaintenanceActionOut",
    "SpanHistoryOut",
    "SpanOut",
    "SpanPageOut",
    "router",
    "span_history",
]

router = APIRouter(tags=["spans"], responses=errors())

MAX_LIMIT = 1000
"""The most rows one page holds."""


def chainage_query(description: str) -> object:
    """A finite chainage [m] query parameter."""
    return Query(description=description, allow_inf_nan=False, ge=-1.0e7, le=1.0e7)


def check_range(from_m: float | None, to_m: float | None) -> None:
    """422 unless ``from_m`` <= ``to_m``."""
    if from_m is not None and to_m is not None and from_m > to_m:
        raise HTTPException(422, f"from_m {from_m:g} must not exceed to_m {to_m:g}")


class SpanOut(BaseModel):
    """A span and wire of a run: the ``spans`` export's columns and the run's identity."""

    line: str
    track: str | None
    run_id: int
    run_uuid: str
    started_at: datetime
    span: int
    mast_from: str | None
    mast_to: str | None
    start_chainage_m: float
    end_chainage_m: float
    wire: int
    wire_position: int
    wire_type: str
    min_residual_thickness_mm: float
    min_at_chainage_m: float
    mean_residual_thickness_mm: float
    height_min_mm: float
    height_max_mm: float
    stagger_min_mm: float
    stagger_max_mm: float
    samples: int


class SpanPageOut(BaseModel):
    """A page of spans: ``total`` match; ``next`` is the next page's address (None: the
    last)."""

    total: int
    limit: int
    offset: int
    next: str | None
    spans: list[SpanOut]


def _span_out(m: SpanMeasurement, line: str, track: str | None, run_id: int, uuid: str,
              started_at: datetime) -> SpanOut:  # fmt: skip
    return SpanOut(
        line=line,
        track=track,
        run_id=run_id,
        run_uuid=uuid,
        started_at=started_at,
        span=m.span,
        mast_from=m.mast_from,
        mast_to=m.mast_to,
        start_chainage_m=m.start_chainage_m,
        end_chainage_m=m.end_chainage_m,
        wire=m.wire,
        wire_position=m.wire_position,
        wire_type=m.wire_type,
        min_residual_thickness_mm=m.min_residual_thickness_mm,
        min_at_chainage_m=m.min_at_chainage_m,
        mean_residual_thickness_mm=m.mean_residual_thickness_mm,
        height_min_mm=m.height_min_mm,
        height_max_mm=m.height_max_mm,
        stagger_min_mm=m.stagger_min_mm,
        stagger_max_mm=m.stagger_max_mm,
        samples=m.samples,
    )


@router.get("/spans", responses=errors({404: "No such line, track or run."}))
def spans(
    request: Request,
    user: Annotated[Principal, requires("viewer")],
    line: Annotated[str | None, Query(max_length=64, description="Only this line's.")] = None,
    track: Annotated[
        str | None, Query(max_length=64, description="Only this track's (needs line).")
    ] = None,
    from_m: Annotated[float | None, chainage_query("Spans ending after this chainage.")] = None,
    to_m: Annotated[float | None, chainage_query("Spans starting before this chainage.")] = None,
    run: Annotated[
        str | None,
        Query(max_length=64, description="This run's (id, UUID, prefix or 'latest')."),
    ] = None,
    order: Annotated[
        Literal["chainage", "worst"],
        Query(description="'worst': lowest minimum residual thickness first."),
    ] = "chainage",
    limit: Annotated[int, Query(ge=1, le=MAX_LIMIT, description="Spans per page.")] = 100,
    offset: Annotated[int, Query(ge=0, description="Spans skipped.")] = 0,
) -> SpanPageOut:
    """The span measurements of the latest processing of the latest complete run of each
    track (or of ``run``), overlapping ``from_m`` to ``to_m``, a page at a time."""
    check_range(from_m, to_m)
    if track is not None and line is None:
        raise HTTPException(422, "track needs line (track codes repeat between lines)")
    with session_scope(state(request).engine, read_only=True) as session:
        if line is not None and track is not None:
            track_of(session, line, track)
        page = list_spans(
            session,
            line=line,
            track=track,
            run=run_of(session, run) if run is not None else None,
            from_m=from_m,
            to_m=to_m,
            order=order,
            limit=limit,
            offset=offset,
        )
        found = [
            _span_out(s.measurement, s.line, s.track, s.run_id, s.run_uuid, s.started_at)
            for s in page.spans
        ]
    after = offset + limit
    following = str(request.url.include_query_params(offset=after)) if after < page.total else None
    return SpanPageOut(total=page.total, limit=limit, offset=offset, next=following, spans=found)


# --- a span's history -----------------------------------------------------------------------


class HistoryRunOut(BaseModel):
    """One run's measurement of the span and wire; staggers looking toward increasing
    chainage (the run's direction undone). ``since_repair``: false for a run before the last
    repair (not in the wear rate)."""

    run_id: int
    started_at: datetime
    direction: str
    min_residual_thickness_mm: float
    mean_residual_thickness_mm: float
    height_min_mm: float
    height_max_mm: float
    stagger_min_mm: float
    stagger_max_mm: float
    since_repair: bool


class ForecastOut(BaseModel):
    """When the fitted line reaches a limit: a date (ISO 8601), 'never', 'reached' or None
    (no forecast); ``low``..``high`` its confidence interval."""

    rule: str
    level: str
    threshold_mm: float
    reaches: str | None
    low: str | None
    high: str | None


class WireHistoryOut(BaseModel):
    """One wire position of the span over the runs: its measurements, wear rate (with its
    confidence interval, None with fewer than the runs needed) and forecasts."""

    wire_position: int
    mast_from: str | None
    mast_to: str | None
    start_chainage_m: float
    end_chainage_m: float
    wire_type: str | None
    runs: list[HistoryRunOut]
    fitted_runs: int
    wear_rate_mm_per_year: float | None
    wear_rate_low_mm_per_year: float | None
    wear_rate_high_mm_per_year: float | None
    forecasts: list[ForecastOut]


class MaintenanceActionOut(BaseModel):
    """A maintenance action (``wire``: the wire position it names, None: every wire)."""

    id: int
    line: str
    track: str
    kind: str
    from_chainage_m: float
    to_chainage_m: float
    mast_from: str | None
    mast_to: str | None
    wire_position: int | None
    performed_at: datetime
    recorded_by: str
    note: str | None

    @classmethod
    def of(cls, action: MaintenanceAction) -> MaintenanceActionOut:
        return cls(
            id=action.id,
            line=action.track.line.code,
            track=action.track.code,
            kind=action.kind,
            from_chainage_m=action.from_chainage_m,
            to_chainage_m=action.to_chainage_m,
            mast_from=action.mast_from,
            mast_to=action.mast_to,
            wire_position=action.wire,
            performed_at=action.performed_at,
            recorded_by=action.recorded_by,
            note=action.note,
        )


class SpanHistoryOut(BaseModel):
    """A span's history: each wire position's, the policy forecast (None: no policy) at
    ``confidence``, and the maintenance actions touching the span, latest first."""

    line: str
    track: str
    policy: str | None
    confidence: float
    min_runs: int
    wires: list[WireHistoryOut]
    maintenance_actions: list[MaintenanceActionOut]


def _finite(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def _reach(years: float) -> str | None:
    text = reach_text(float(years))
    return None if text == "-" else text


def _wire_history(trends: TrackTrends, h: int) -> WireHistoryOut:
    data, hist, rows = trends.data, trends.histories, trends.data.rows
    geometry = data.geometry
    found = history_rows(trends, h)
    runs = []
    for row in found.tolist():
        sign = float(rows.direction[row])
        staggers = (geometry.stagger_min_mm[row], geometry.stagger_max_mm[row])
        left, right = sorted(sign * float(s) for s in staggers)
        runs.append(
            HistoryRunOut(
                run_id=int(rows.run_id[row]),
                started_at=data.run_started_at(int(rows.run_id[row])),
                direction="increasing" if sign > 0 else "decreasing",
                min_residual_thickness_mm=float(rows.min_thickness_mm[row]),
                mean_residual_thickness_mm=float(rows.mean_thickness_mm[row]),
                height_min_mm=float(geometry.height_min_mm[row]),
                height_max_mm=float(geometry.height_max_mm[row]),
                stagger_min_mm=left,
                stagger_max_mm=right,
                since_repair=bool(hist.row_history[row] >= 0),
            )
        )
    fit = hist.fit
    fitted = fit.runs[h] >= MIN_RUNS and np.isfinite(fit.slope_mm_per_year[h])
    low, high = (float(x[h]) for x in rate_interval(fit))
    forecasts = [
        ForecastOut(
            rule=limit.rule.name,
            level=limit.rule.rule.level,
            threshold_mm=float(limit.threshold_mm[h]),
            reaches=_reach(limit.reach.central[h]),
            low=_reach(limit.reach.low[h]),
            high=_reach(limit.reach.high[h]),
        )
        for limit in trends.limits
        if np.isfinite(limit.threshold_mm[h])
    ]
    codes, kind = data.mast_code, int(trends.wire_type[h])
    return WireHistoryOut(
        wire_position=int(hist.position[h]),
        mast_from=codes[hist.mast_from[h]] if hist.mast_from[h] >= 0 else None,
        mast_to=codes[hist.mast_to[h]] if hist.mast_to[h] >= 0 else None,
        start_chainage_m=float(hist.start_m[h]),
        end_chainage_m=float(hist.end_m[h]),
        wire_type=trends.wire_type_names[kind] if kind >= 0 else None,
        runs=runs,
        fitted_runs=int(fit.runs[h]),
        wear_rate_mm_per_year=_finite(fit.wear_rate_mm_per_year[h]) if fitted else None,
        wear_rate_low_mm_per_year=_finite(low) if fitted else None,
        wear_rate_high_mm_per_year=_finite(high) if fitted else None,
        forecasts=forecasts,
    )


@dataclass(frozen=True)
class SpanQuery:
    """Which span: its start mast, or a chainage range; one wire position or all."""

    line: str
    track: str
    mast: str | None
    from_m: float | None
    to_m: float | None
    wire_position: int | None


def span_history(web: WebState, session: Session, query: SpanQuery) -> SpanHistoryOut:
    """The history of the span ``query`` names, through ``span_trends`` (as ``catenary
    history``) with the configured policy; ``NotFound`` for an unknown track, ``UserError``
    for an unknown mast or nothing measured there."""
    track = track_of(session, query.line, query.track)
    policy = choose_policy(web.settings, web.registry.limit_policies())
    where = f"line {query.line} track {query.track}"
    trends, chosen = span_trends(
        session,
        track.id,
        where,
        web.registry.wire_types(),
        policy,
        mast=query.mast,
        from_m=query.from_m,
        to_m=query.to_m,
    )
    wires = [_wire_history(trends, h) for h in chosen.tolist()]
    if query.wire_position is not None:
        wires = [w for w in wires if w.wire_position == query.wire_position]
    start = min(w.start_chainage_m for w in wires) if wires else query.from_m
    end = max(w.end_chainage_m for w in wires) if wires else query.to_m
    actions = list_maintenance(session, track, start, end)
    if query.wire_position is not None:
        actions = [a for a in actions if a.wire is None or a.wire == query.wire_position]
    return SpanHistoryOut(
        line=query.line,
        track=query.track,
        policy=policy.name if policy else None,
        confidence=CONFIDENCE,
        min_runs=MIN_RUNS,
        wires=wires,
        maintenance_actions=[MaintenanceActionOut.of(a) for a in actions],
    )


@router.get(
    "/spans/history",
    responses=errors(
        {400: "No such mast, or nothing measured there.", 404: "No such line or track."}
    ),
)
def history(
    request: Request,
    user: Annotated[Principal, requires("viewer")],
    line: Annotated[str, Query(min_length=1, max_length=64)],
    track: Annotated[str, Query(min_length=1, max_length=64)],
    mast: Annotated[
        str | None, Query(min_length=1, max_length=64, description="The span's start mast.")
    ] = None,
    from_m: Annotated[float | None, chainage_query("Without mast: spans ending after.")] = None,
    to_m: Annotated[float | None, chainage_query("Without mast: spans starting before.")] = None,
    wire_position: Annotated[
        int | None, Query(ge=0, le=100, description="Only this wire position.")
    ] = None,
) -> SpanHistoryOut:
    """A span's minimum residual thickness, height and stagger over the runs, each wire
    position's wear rate and the forecast to each limit of the configured policy, and the
    maintenance actions on it."""
    check_range(from_m, to_m)
    ranged = from_m is not None and to_m is not None
    if (from_m is None) != (to_m is None) or (mast is not None) == ranged:
        raise HTTPException(422, "give mast, or from_m and to_m")
    web = state(request)
    with session_scope(web.engine, read_only=True) as session:
        return span_history(web, session, SpanQuery(line, track, mast, from_m, to_m, wire_position))
