"""The API's maintenance actions: ``GET /maintenance-actions`` (by line, track and chainage,
latest performed first) and ``POST /maintenance-actions`` (a planner records one, as ``catenary
maintenance record``: ``record_maintenance``, which resolves the alerts a repair covers; in
the audit trail as the signed-in user's change)."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated, Literal, get_args

from fastapi import APIRouter, HTTPException, Query, Request
from pydantic import AwareDatetime, BaseModel, Field

from catenary.domain import MAINTENANCE_KINDS
from catenary.maintenance.actions import list_maintenance, mast_stretch, record_maintenance
from catenary.storage.database import session_scope
from catenary.web.api.runs import errors, track_of
from catenary.web.api.spans import MAX_LIMIT, MaintenanceActionOut, chainage_query, check_range
from catenary.web.app import state
from catenary.web.auth import Principal, requires

__all__ = ["MaintenanceActionIn", "RecordedOut", "router"]

router = APIRouter(tags=["maintenance"], responses=errors())

Kind = Literal["wire_replaced", "reinforced", "spliced", "inspected", "adjusted"]
assert set(get_args(Kind)) == set(MAINTENANCE_KINDS)
Chainage = Annotated[float, Field(allow_inf_nan=False, ge=-1.0e7, le=1.0e7)]
CodeField = Annotated[str, Field(min_length=1, max_length=64)]


class MaintenanceActionIn(BaseModel):
    """A maintenance action: where (``from_mast`` and ``to_mast`` of the register, or
    ``from_m`` and ``to_m``), what, when, on which wire position (None: every wire)."""

    line: CodeField
    track: CodeField
    kind: Kind
    from_mast: CodeField | None = None
    to_mast: CodeField | None = None
    from_m: Chainage | None = None
    to_m: Chainage | None = None
    performed_at: AwareDatetime
    wire_position: Annotated[int, Field(ge=0, le=100)] | None = None
    note: Annotated[str, Field(max_length=2000)] | None = None


class RecordedOut(BaseModel):
    """The action recorded and the alerts it resolved."""

    action: MaintenanceActionOut
    resolved_alerts: list[int]


@router.get("/maintenance-actions", responses=errors({404: "No such line or track."}))
def maintenance_actions(
    request: Request,
    user: Annotated[Principal, requires("viewer")],
    line: Annotated[str | None, Query(max_length=64, description="With track.")] = None,
    track: Annotated[str | None, Query(max_length=64, description="With line.")] = None,
    from_m: Annotated[float | None, chainage_query("Actions ending after this.")] = None,
    to_m: Annotated[float | None, chainage_query("Actions starting before this.")] = None,
    limit: Annotated[int, Query(ge=1, le=MAX_LIMIT)] = 100,
    offset: Annotated[int, Query(ge=0)] = 0,
) -> list[MaintenanceActionOut]:
    """The maintenance actions of a track (or all), touching a chainage range, latest
    performed first."""
    check_range(from_m, to_m)
    if (line is None) != (track is None):
        raise HTTPException(422, "give line and track together")
    with session_scope(state(request).engine, read_only=True) as session:
        found = track_of(session, line, track) if line and track else None
        actions = list_maintenance(session, found, from_m, to_m, limit=limit, offset=offset)
        return [MaintenanceActionOut.of(a) for a in actions]


@router.post(
    "/maintenance-actions",
    status_code=201,
    responses=errors({400: "No such mast.", 404: "No such line or track."}),
)
def record(
    request: Request, body: MaintenanceActionIn, user: Annotated[Principal, requires("planner")]
) -> RecordedOut:
    """Record a maintenance action as the signed-in user (a planner); a repair resolves the
    alerts it covers, an adjustment the geometry alerts."""
    masts, chainages = (body.from_mast, body.to_mast), (body.from_m, body.to_m)
    by_masts = None not in masts and chainages == (None, None)
    if not by_masts and (None in chainages or masts != (None, None)):
        raise HTTPException(422, "give from_mast and to_mast, or from_m and to_m")
    check_range(body.from_m, body.to_m)
    with session_scope(state(request).engine) as session:
        track = track_of(session, body.line, body.track)
        codes: tuple[str | None, str | None] = (None, None)
        if body.from_mast is not None and body.to_mast is not None:
            from_m, to_m, codes = mast_stretch(session, track, body.from_mast, body.to_mast)
        else:
            assert body.from_m is not None and body.to_m is not None
            from_m, to_m = body.from_m, body.to_m
        done = record_maintenance(
            session,
            track,
            body.kind,
            from_m,
            to_m,
            body.performed_at,
            user.name,
            now=datetime.now(UTC),
            mast_from=codes[0],
            mast_to=codes[1],
            wire=body.wire_position,
            note=body.note,
            actor=user.name,
        )
        return RecordedOut(
            action=MaintenanceActionOut.of(done.action), resolved_alerts=list(done.resolved)
        )
