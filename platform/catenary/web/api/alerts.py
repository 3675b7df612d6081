"""The API's alerts: ``GET /alerts`` (as ``catenary alerts list``: ``list_alerts``, paged),
``POST /alerts/{id}/acknowledge`` and ``POST /alerts/{id}/resolve`` (a planner; in the audit
trail as the signed-in user's change). Fields as ``catenary alerts list --format json``."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated, Any, Literal, get_args

from fastapi import APIRouter, HTTPException, Path, Query, Request
from pydantic import BaseModel, Field
from sqlalchemy.orm import Session

from catenary.errors import UserError
from catenary.limits import LEVELS
from catenary.maintenance.alerts.lifecycle import (
    acknowledge_alert,
    alert_json,
    list_alerts,
    resolve_alert,
)
from catenary.storage.database import session_scope
from catenary.storage.models import ALERT_KINDS, Alert
from catenary.web.api.runs import errors
from catenary.web.api.spans import MAX_LIMIT, chainage_query, check_range
from catenary.web.app import state
from catenary.web.auth import Principal, requires
from catenary.web.errors import NotFound

__all__ = ["AlertOut", "AlertPageOut", "router"]

router = APIRouter(tags=["alerts"], responses=errors())

Level = Literal["plan", "urgent", "critical"]
Kind = Literal["threshold", "forecast", "geometry"]
assert set(get_args(Level)) == set(LEVELS) and set(get_args(Kind)) == set(ALERT_KINDS)
AlertId = Annotated[int, Path(ge=1, le=2**62, description="The alert's id.")]


class AlertOut(BaseModel):
    """An alert as ``catenary alerts list --format json`` shows it (``alert_json``;
    ``wire_position``: the wire's position in its span; times ISO 8601 UTC)."""

    id: int
    line: str
    track: str
    wire_position: int
    mast_from: str | None
    mast_to: str | None
    start_chainage_m: float
    end_chainage_m: float
    rule: str
    level: str
    kind: str
    value: float
    threshold: float
    status: str
    raised_at: str | None
    acknowledged_by: str | None
    acknowledged_at: str | None
    resolved_at: str | None
    resolved_by_run_id: int | None
    resolved_by_action_id: int | None
    span_measurement_id: int | None
    details: dict[str, Any] | None

    @classmethod
    def of(cls, alert: Alert) -> AlertOut:
        return cls(**alert_json(alert))


class AlertPageOut(BaseModel):
    """A page of alerts, most severe first; ``next``: the next page's address (None: the
    last)."""

    limit: int
    offset: int
    next: str | None
    alerts: list[AlertOut]


class ResolveIn(BaseModel):
    """Why the alert is resolved by hand."""

    note: str | None = Field(default=None, max_length=2000)


@router.get("/alerts")
def alerts(
    request: Request,
    user: Annotated[Principal, requires("viewer")],
    status: Annotated[
        Literal["active", "open", "acknowledged", "resolved", "all"],
        Query(description="'active': open and acknowledged."),
    ] = "active",
    level: Annotated[list[Level] | None, Query(description="Only these levels.")] = None,
    kind: Annotated[list[Kind] | None, Query(description="Only these kinds.")] = None,
    line: Annotated[str | None, Query(max_length=64)] = None,
    track: Annotated[str | None, Query(max_length=64)] = None,
    from_m: Annotated[float | None, chainage_query("Alerts ending after this.")] = None,
    to_m: Annotated[float | None, chainage_query("Alerts starting before this.")] = None,
    limit: Annotated[int, Query(ge=1, le=MAX_LIMIT)] = 100,
    offset: Annotated[int, Query(ge=0)] = 0,
) -> AlertPageOut:
    """Alerts as a planner reads them: most severe level first, then line, track, chainage."""
    check_range(from_m, to_m)
    with session_scope(state(request).engine, read_only=True) as session:
        found = list_alerts(
            session,
            status,
            line,
            level or (),
            track=track,
            kinds=kind or (),
            from_m=from_m,
            to_m=to_m,
            limit=limit + 1,
            offset=offset,
        )
        page = [AlertOut.of(a) for a in found[:limit]]
    following = (
        str(request.url.include_query_params(offset=offset + limit)) if len(found) > limit else None
    )
    return AlertPageOut(limit=limit, offset=offset, next=following, alerts=page)


def _changed(session: Session, alert_id: int, change: Any) -> AlertOut:
    """``change()``'s alert; 404 for an unknown alert, 409 for one in the wrong status."""
    if session.get(Alert, alert_id) is None:
        raise NotFound(f"no alert {alert_id} in the database")
    try:
        alert = change()
    except UserError as exc:
        raise HTTPException(409, str(exc)) from None
    return AlertOut.of(alert)


_WRITES = errors({404: "No such alert.", 409: "The alert's status does not allow it."})


@router.post("/alerts/{alert_id}/acknowledge", responses=_WRITES)
def acknowledge(
    request: Request, alert_id: AlertId, user: Annotated[Principal, requires("planner")]
) -> AlertOut:
    """Acknowledge an open alert as the signed-in user (a planner)."""
    with session_scope(state(request).engine) as session:
        now = datetime.now(UTC)
        return _changed(
            session,
            alert_id,
            lambda: acknowledge_alert(session, alert_id, user.name, now, actor=user.name),
        )


@router.post("/alerts/{alert_id}/resolve", responses=_WRITES)
def resolve(
    request: Request,
    alert_id: AlertId,
    user: Annotated[Principal, requires("planner")],
    body: ResolveIn | None = None,
) -> AlertOut:
    """Resolve an alert by hand as the signed-in user (a planner), with an optional note."""
    note = body.note if body is not None else None
    with session_scope(state(request).engine) as session:
        now = datetime.now(UTC)
        return _changed(
            session,
            alert_id,
            lambda: resolve_alert(session, alert_id, user.name, now, note, actor=user.name),
        )
