"""The span page (``/span?line=L&track=T&mast=M[&wire_position=P]``, or ``&from_m=&to_m=`` for
spans without a register): its history over runs with a chart of the minimum residual
thickness and the limits, wear rate and forecasts (``span_history``, as the API and ``catenary
history``), the latest run's figures for it, its alerts and maintenance actions."""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, Request
from starlette.responses import Response

from catenary.maintenance.alerts.lifecycle import list_alerts
from catenary.storage.database import session_scope
from catenary.storage.spans import list_spans
from catenary.web.api.spans import SpanHistoryOut, SpanQuery, WireHistoryOut, span_history
from catenary.web.app import state
from catenary.web.auth import Principal, page_user, requires
from catenary.web.templating import render

__all__ = ["Chart", "history_chart", "router"]

router = APIRouter()

ALERTS_SHOWN = 50
"""The most alerts the page lists (the alerts page has the rest)."""
WIRE_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd")
FORECAST_YEARS = 10.0
"""How far past the last run the chart reaches for a forecast at most [years]."""
SECONDS_PER_YEAR = 365.25 * 86400.0


@dataclass(frozen=True)
class Series:
    """One wire position's points in the chart's pixels and its label; ``forecast``: from its
    last point to where it reaches its first limit, and that date's interval ``(x_low,
    x_high, y)`` (empty: no forecast within the chart)."""

    label: str
    colour: str
    points: list[tuple[float, float]]
    forecast: list[tuple[float, float]]
    interval: tuple[float, float, float] | None


def _forecast(wire: WireHistoryOut) -> tuple[float, float, float, float] | None:
    """The first limit's forecast as ``(threshold_mm, central, low, high)`` [POSIX s]; None
    without a dated one."""
    for f in wire.forecasts:
        if f.reaches is not None and f.reaches[:1].isdigit():
            central, low, high = (
                datetime.fromisoformat(d).replace(tzinfo=UTC).timestamp()
                if d is not None and d[:1].isdigit()
                else math.nan
                for d in (f.reaches, f.low, f.high)
            )
            return f.threshold_mm, central, low, high
    return None


@dataclass(frozen=True)
class Chart:
    """A chart's drawing in pixels: series, limit lines ``(y, level, label)``, axis ticks
    ``(position, label)``."""

    width: int
    height: int
    left: int
    bottom: int
    series: list[Series]
    limits: list[tuple[float, str, str]]
    x_ticks: list[tuple[float, str]]
    y_ticks: list[tuple[float, str]]


def history_chart(wires: list[WireHistoryOut], width: int = 680, height: int = 280) -> Chart:
    """The minimum residual thickness of each wire position over time, with the thresholds
    of its forecasts, scaled into ``width`` x ``height`` pixels."""
    left, right, top, bottom = 56, 12, 12, 28
    times = [r.started_at.timestamp() for w in wires for r in w.runs]
    values = [r.min_residual_thickness_mm for w in wires for r in w.runs]
    limits = {(f.threshold_mm, f.level) for w in wires for f in w.forecasts}
    values += [value for value, _ in limits]
    if not times:
        return Chart(width, height, left, height - bottom, [], [], [], [])
    t0, t1 = min(times), max(times)
    forecasts = [_forecast(w) for w in wires]
    horizon = t1 + FORECAST_YEARS * SECONDS_PER_YEAR
    t1 = max([t1, *(f[1] for f in forecasts if f is not None and f[1] <= horizon)])
    t0, t1 = (t0 - 86400.0, t1 + 86400.0) if t1 - t0 < 86400.0 else (t0, t1)
    low, high = math.floor(min(values) - 0.2), math.ceil(max(values) + 0.2)

    def x(moment: float) -> float:
        return round(left + (moment - t0) / (t1 - t0) * (width - left - right), 1)

    def y(mm: float) -> float:
        return round(height - bottom - (mm - low) / (high - low) * (height - top - bottom), 1)

    series = []
    for k, (w, f) in enumerate(zip(wires, forecasts, strict=True)):
        points = [(x(r.started_at.timestamp()), y(r.min_residual_thickness_mm)) for r in w.runs]
        shown = f is not None and f[1] <= t1 and bool(points)
        forecast = [points[-1], (x(f[1]), y(f[0]))] if f is not None and shown else []
        interval = None
        if f is not None and shown:
            ends = [t0 if math.isnan(t) else min(max(t, t0), t1) for t in f[2:]]
            interval = (x(ends[0]), x(ends[1]), y(f[0]))
        colour = WIRE_COLOURS[k % len(WIRE_COLOURS)]
        series.append(Series(f"position {w.wire_position}", colour, points, forecast, interval))
    years = range(datetime.fromtimestamp(t0, UTC).year, datetime.fromtimestamp(t1, UTC).year + 2)
    x_ticks = [
        (x(moment), str(year))
        for year in years
        if t0 <= (moment := datetime(year, 1, 1, tzinfo=UTC).timestamp()) <= t1
    ]
    step = max(1, (high - low) // 6)
    y_ticks = [(y(mm), f"{mm:g}") for mm in range(low, high + 1, step)]
    lines = [(y(v), level, f"{level} {v:.2f} mm") for v, level in sorted(limits)]
    return Chart(width, height, left, height - bottom, series, lines, x_ticks, y_ticks)


@router.get("/span")
def span_page(
    request: Request,
    user: Annotated[Principal, requires("viewer", page_user)],
    line: Annotated[str, Query(min_length=1, max_length=64)],
    track: Annotated[str, Query(min_length=1, max_length=64)],
    mast: Annotated[str | None, Query(min_length=1, max_length=64)] = None,
    from_m: Annotated[float | None, Query(allow_inf_nan=False)] = None,
    to_m: Annotated[float | None, Query(allow_inf_nan=False)] = None,
    wire_position: Annotated[int | None, Query(ge=0, le=100)] = None,
) -> Response:
    """A span's page."""
    ranged = from_m is not None and to_m is not None
    if (from_m is None) != (to_m is None) or (mast is not None) == ranged:
        raise HTTPException(400, "give mast, or from_m and to_m")
    if from_m is not None and to_m is not None and from_m > to_m:
        raise HTTPException(400, f"from_m {from_m:g} must not exceed to_m {to_m:g}")
    web = state(request)
    with session_scope(web.engine, read_only=True) as session:
        history: SpanHistoryOut = span_history(
            web, session, SpanQuery(line, track, mast, from_m, to_m, wire_position)
        )
        start = min((w.start_chainage_m for w in history.wires), default=from_m)
        end = max((w.end_chainage_m for w in history.wires), default=to_m)
        latest = [
            s
            for s in list_spans(
                session, line=line, track=track, from_m=start, to_m=end, limit=100
            ).spans
            if (mast is None or s.measurement.mast_from == mast)
            and wire_position in (None, s.measurement.wire_position)
        ]
        alerts = list_alerts(
            session, "all", line, track=track, from_m=start, to_m=end, limit=ALERTS_SHOWN
        )
        if wire_position is not None:
            alerts = [a for a in alerts if a.wire == wire_position]
        context = {
            "history": history,
            "mast": mast,
            "wire_position": wire_position,
            "start_m": start,
            "end_m": end,
            "latest": latest,
            "alerts": alerts,
            "alerts_shown": ALERTS_SHOWN,
            "chart": history_chart(history.wires),
        }
        return render(request, "span.html", context)
