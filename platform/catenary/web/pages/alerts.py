"""The alerts page (``/alerts``): alerts filtered by status, level, kind, line and track, a
page at a time; a planner acknowledges, resolves and records maintenance from it, as the
signed-in user (each change in the audit trail under their name)."""

from __future__ import annotations

from collections.abc import Mapping
from datetime import UTC, datetime, time
from typing import Annotated
from urllib.parse import parse_qsl, urlencode

from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import RedirectResponse
from sqlalchemy.orm import Session
from starlette.datastructures import FormData
from starlette.responses import Response

from catenary.domain import ALERT_STATUSES, MAINTENANCE_KINDS
from catenary.errors import UserError
from catenary.limits import LEVELS
from catenary.maintenance.actions import record_maintenance
from catenary.maintenance.alerts import (
    acknowledge_alert,
    alert_stretch,
    alert_summary,
    list_alerts,
    resolve_alert,
)
from catenary.storage.database import session_scope
from catenary.storage.models import ALERT_KINDS, Alert
from catenary.web.app import state
from catenary.web.auth import Principal, checked_form, page_user, requires
from catenary.web.errors import NotFound
from catenary.web.templating import render

__all__ = ["PAGE_SIZE", "router"]

router = APIRouter()

PAGE_SIZE = 50
"""Alerts on one page."""

STATUSES = ("active", *ALERT_STATUSES, "all")
FILTERS = ("status", "level", "kind", "line", "track")
Filter = Annotated[str | None, Query(max_length=64)]


def _given(value: str | None) -> str | None:
    """A filter's value; None for an empty field."""
    if value is None:
        return None
    return value.strip() or None


def _one_of(field: str, value: str | None, known: tuple[str, ...]) -> str | None:
    if value is not None and value not in known:
        raise UserError(f"{field} {value!r}: not one of {', '.join(known)}")
    return value


def _notice(query: Mapping[str, str]) -> str | None:
    """The one line that says what the last change did (``done`` and its ids)."""
    done, alert, action = query.get("done"), query.get("alert", ""), query.get("action", "")
    if done in ("acknowledged", "resolved") and alert.isdigit():
        return f"Alert {alert} {done}."
    if done == "maintenance" and action.isdigit():
        resolved = query.get("resolved", "0")
        return f"Maintenance action {action} recorded; {int(resolved or 0)} alert(s) resolved."
    return None


@router.get("/alerts")
def alerts(
    request: Request,
    user: Annotated[Principal, requires("viewer", page_user)],
    status: Filter = "active",
    level: Filter = None,
    kind: Filter = None,
    line: Filter = None,
    track: Filter = None,
    page: Annotated[int, Query(ge=1, le=100_000)] = 1,
) -> Response:
    filters = {
        "status": _one_of("status", _given(status) or "active", STATUSES),
        "level": _one_of("level", _given(level), LEVELS),
        "kind": _one_of("kind", _given(kind), ALERT_KINDS),
        "line": _given(line),
        "track": _given(track),
    }
    if filters["track"] is not None and filters["line"] is None:
        raise UserError("track: give the line as well")
    chosen = {k: v for k, v in filters.items() if v is not None}

    def at(number: int) -> str:
        return "/alerts?" + urlencode({**chosen, "page": number})

    with session_scope(state(request).engine, read_only=True) as session:
        found = list_alerts(
            session,
            status=str(filters["status"]),
            line=filters["line"],
            levels=[filters["level"]] if filters["level"] else [],
            track=filters["track"],
            kinds=[filters["kind"]] if filters["kind"] else [],
            limit=PAGE_SIZE + 1,
            offset=(page - 1) * PAGE_SIZE,
        )
        rows = [(a, alert_stretch(a), alert_summary(a)) for a in found[:PAGE_SIZE]]
        context = {
            "rows": rows,
            "filters": filters,
            "statuses": STATUSES,
            "levels": tuple(reversed(LEVELS)),
            "kinds": ALERT_KINDS,
            "maintenance_kinds": MAINTENANCE_KINDS,
            "page": page,
            "previous_url": at(page - 1) if page > 1 else None,
            "next_url": at(page + 1) if len(found) > PAGE_SIZE else None,
            "back": urlencode({**chosen, "page": page}),
            "notice": _notice(request.query_params),
            "today": datetime.now(UTC).date().isoformat(),
        }
        return render(request, "alerts.html", context)


def _back(form: FormData, **done: object) -> RedirectResponse:
    """303 to the list the form came from (its filters, from the form's ``back``), saying what
    was done."""
    sent = str(form.get("back", ""))
    kept = {k: v for k, v in parse_qsl(sent) if k in (*FILTERS, "page")}
    return RedirectResponse("/alerts?" + urlencode({**kept, **done}), status_code=303)


def _performed_at(text: str, now: datetime) -> datetime:
    """A form's date (``YYYY-MM-DD``: noon that day) or time (``YYYY-MM-DDTHH:MM``), UTC, not
    in the future."""
    try:
        moment = (
            datetime.fromisoformat(text)
            if "T" in text
            else datetime.combine(datetime.fromisoformat(text).date(), time(12, 0))
        )
    except ValueError:
        raise UserError(
            f"performed at {text[:40]!r}: give a date YYYY-MM-DD or a time YYYY-MM-DDTHH:MM (UTC)"
        ) from None
    moment = moment.replace(tzinfo=UTC) if moment.tzinfo is None else moment.astimezone(UTC)
    if moment.date() > now.date():
        raise UserError(f"performed at {text[:40]!r}: that is in the future")
    return min(moment, now)


def _found(session: Session, alert_id: int) -> Alert:
    """Alert ``alert_id``; 404 if there is none."""
    alert = session.get(Alert, alert_id)
    if alert is None:
        raise NotFound(f"no alert {alert_id} in the database")
    return alert


@router.post("/alerts/{alert_id}/acknowledge")
def acknowledge(
    request: Request,
    alert_id: int,
    user: Annotated[Principal, requires("planner", page_user)],
    form: Annotated[FormData, Depends(checked_form)],
) -> Response:
    with session_scope(state(request).engine) as session:
        _found(session, alert_id)
        acknowledge_alert(session, alert_id, user.name, datetime.now(UTC), actor=user.name)
    return _back(form, done="acknowledged", alert=alert_id)


@router.post("/alerts/{alert_id}/resolve")
def resolve(
    request: Request,
    alert_id: int,
    user: Annotated[Principal, requires("planner", page_user)],
    form: Annotated[FormData, Depends(checked_form)],
) -> Response:
    note = str(form.get("note", "")).strip() or None
    with session_scope(state(request).engine) as session:
        _found(session, alert_id)
        resolve_alert(session, alert_id, user.name, datetime.now(UTC), note, actor=user.name)
    return _back(form, done="resolved", alert=alert_id)


@router.post("/alerts/{alert_id}/maintenance")
def maintenance(
    request: Request,
    alert_id: int,
    user: Annotated[Principal, requires("planner", page_user)],
    form: Annotated[FormData, Depends(checked_form)],
) -> Response:
    """Record maintenance on the alert's stretch and wire."""
    now = datetime.now(UTC)
    performed_at = _performed_at(str(form.get("performed_at", "")).strip(), now)
    note = str(form.get("note", "")).strip() or None
    with session_scope(state(request).engine) as session:
        alert = _found(session, alert_id)
        recorded = record_maintenance(
            session,
            alert.track,
            str(form.get("kind", "")),
            alert.start_chainage_m,
            alert.end_chainage_m,
            performed_at,
            user.name,
            now=now,
            mast_from=alert.mast_from,
            mast_to=alert.mast_to,
            wire=alert.wire,
            note=note,
            actor=user.name,
        )
        action, resolved = recorded.action.id, len(recorded.resolved)
    return _back(form, done="maintenance", action=action, resolved=resolved)
