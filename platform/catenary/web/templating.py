"""The pages' templates (Jinja2, auto-escaped) and the filters they share: numbers with their
units at the export columns' precision, chainage, times in UTC."""

from __future__ import annotations

import math
from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from fastapi import Request
from fastapi.templating import Jinja2Templates
from starlette.responses import Response

from catenary.web.auth import CSRF_FIELD

__all__ = ["TEMPLATES", "render"]

TEMPLATES = Jinja2Templates(directory=Path(__file__).parent / "templates")
TEMPLATES.env.autoescape = True


def _number(value: float | None, digits: int = 2, unit: str = "") -> str:
    """``value`` with ``digits`` decimals and its unit; an en dash for nothing."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return f"{value:,.{digits}f}{f' {unit}' if unit else ''}"


def _chainage(value_m: float | None) -> str:
    """A chainage as kilometres + metres (``12+345.6``)."""
    if value_m is None or not math.isfinite(value_m):
        return "–"
    sign = "-" if value_m < 0 else ""
    km, m = divmod(abs(value_m), 1000.0)
    return f"{sign}{int(km)}+{m:05.1f}"


def _utc(moment: datetime | None) -> str:
    if moment is None:
        return "–"
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=UTC)
    return moment.astimezone(UTC).strftime("%Y-%m-%d %H:%M UTC")


TEMPLATES.env.filters.update(number=_number, chainage=_chainage, utc=_utc)


def render(
    request: Request,
    name: str,
    context: Mapping[str, Any] | None = None,
    status: int = 200,
    headers: Mapping[str, str] | None = None,
) -> Response:
    """Template ``name`` with ``context``, the signed-in user (``user``, if any) and the
    session's CSRF token (``csrf_field``, ``csrf_token``)."""
    sessions = request.app.state.web.sessions
    data = sessions.read(request)
    values = {
        "user": getattr(request.state, "principal", None),
        "csrf_field": CSRF_FIELD,
        "csrf_token": data.csrf if data is not None else "",
        **(context or {}),
    }
    return TEMPLATES.TemplateResponse(
        request, name, values, status_code=status, headers=dict(headers or {})
    )
