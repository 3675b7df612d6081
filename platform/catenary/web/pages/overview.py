"""The fleet overview (``/``): tracks and their latest runs, the thinnest spans of those
runs, open alerts by level and the wire expected at its limit within the planning horizon."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Annotated

from fastapi import APIRouter, Request
from starlette.responses import Response

from catenary.limits import LEVELS
from catenary.maintenance.alerts import alert_counts, due_forecasts, forecast_date, horizon_days
from catenary.storage.database import session_scope
from catenary.storage.overview import track_summaries, worst_spans
from catenary.web.app import state
from catenary.web.auth import Principal, page_user, requires
from catenary.web.templating import render

__all__ = ["LISTED", "router"]

router = APIRouter()

LISTED = 20
"""The most worst spans, and forecasts, the overview lists."""


@router.get("/")
def overview(
    request: Request, user: Annotated[Principal, requires("viewer", page_user)]
) -> Response:
    shared = state(request)
    horizon = horizon_days(shared.settings)
    until = datetime.now(UTC) + timedelta(days=horizon)
    with session_scope(shared.engine, read_only=True) as session:
        tracks = track_summaries(session)
        worst = worst_spans(session, LISTED)
        counts = alert_counts(session, "open")
        due_total, due = due_forecasts(session, until, LISTED)
        context = {
            "tracks": tracks,
            "worst": worst,
            "counts": [(level, counts[level]) for level in reversed(LEVELS)],
            "due_total": due_total,
            "due": [(alert, forecast_date(alert.details)) for alert in due],
            "horizon_days": horizon,
            "until": until,
            "listed": LISTED,
        }
        return render(request, "overview.html", context)
