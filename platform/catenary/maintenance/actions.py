"""Maintenance actions: what a repair covers, and recording one (which resolves its alerts).

A repair (``REPAIR_KINDS``: the wire replaced, reinforced or spliced) changes the worn
profile, so it ends the alerts on the wire it covers and starts that wire's history afresh
(only runs after it count, for thresholds and forecasts alike). An adjustment (``adjusted``:
the wire's height or stagger set right) ends the geometry alerts it covers and leaves the wear
alerts and histories as they are; an inspection is recorded and changes nothing. An action
covers

- a **span**: when it touches it, i.e. overlaps it by more than ``COVER_TOLERANCE_M`` or lies
  inside it (a splice at one point covers the span it is in, a replacement from mast 14 to
  mast 22 the spans between them but not those beyond either mast);
- an **anchor section**: when it contains it, to ``COVER_TOLERANCE_M`` at either end;

and the wire it names (``wire``: the wire's position in the span, see
``catenary.maintenance.history``), or every wire when it names none.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime

import numpy as np
from numpy.typing import ArrayLike
from sqlalchemy import select
from sqlalchemy.orm import Session

from catenary.arrays import BoolArray
from catenary.domain import MAINTENANCE_KINDS, REPAIR_KINDS
from catenary.errors import UserError
from catenary.storage.models import Alert, MaintenanceAction, Track
from catenary.storage.runs import find_mast
from catenary.storage.users import record_audit

__all__ = [
    "ADJUSTED",
    "COVER_TOLERANCE_M",
    "REPAIR_KINDS",
    "Recorded",
    "contains",
    "list_maintenance",
    "record_maintenance",
    "touches",
]

ADJUSTED = "adjusted"
"""The maintenance kind that sets a wire's geometry right (resolves geometry alerts)."""

COVER_TOLERANCE_M = 0.5
"""How far an action's end may miss a span's or section's end [m] (chainages aligned to the
register agree to a few decimetres)."""


def touches(from_m: ArrayLike, to_m: ArrayLike, start_m: ArrayLike, end_m: ArrayLike) -> BoolArray:
    """Whether actions ``[from_m, to_m]`` touch spans ``[start_m, end_m]`` (broadcast) [m]."""
    a, b = np.asarray(from_m, dtype=np.float64), np.asarray(to_m, dtype=np.float64)
    start, end = np.asarray(start_m, dtype=np.float64), np.asarray(end_m, dtype=np.float64)
    return np.asarray((a < end - COVER_TOLERANCE_M) & (b > start + COVER_TOLERANCE_M))


def contains(from_m: ArrayLike, to_m: ArrayLike, start_m: ArrayLike, end_m: ArrayLike) -> BoolArray:
    """Whether actions ``[from_m, to_m]`` contain stretches ``[start_m, end_m]`` (broadcast)."""
    a, b = np.asarray(from_m, dtype=np.float64), np.asarray(to_m, dtype=np.float64)
    start, end = np.asarray(start_m, dtype=np.float64), np.asarray(end_m, dtype=np.float64)
    return np.asarray((a <= start + COVER_TOLERANCE_M) & (b >= end - COVER_TOLERANCE_M))


@dataclass(frozen=True)
class Recorded:
    """An action recorded and the ids of the alerts it resolved."""

    action: MaintenanceAction
    resolved: tuple[int, ...]


def mast_stretch(
    session: Session, track: Track, from_mast: str, to_mast: str
) -> tuple[float, float, tuple[str | None, str | None]]:
    """The stretch between two masts of ``track``'s register: its chainages [m], lower first,
    and the masts' codes in that order; a ``UserError`` for a mast the register lacks."""
    first, last = find_mast(session, track, from_mast), find_mast(session, track, to_mast)
    if first.chainage_m > last.chainage_m:
        first, last = last, first
    return first.chainage_m, last.chainage_m, (first.code, last.code)


def record_maintenance(
    session: Session,
    track: Track,
    kind: str,
    from_m: float,
    to_m: float,
    performed_at: datetime,
    recorded_by: str,
    *,
    now: datetime,
    mast_from: str | None = None,
    mast_to: str | None = None,
    wire: int | None = None,
    note: str | None = None,
    actor: str,
) -> Recorded:
    """Add a maintenance action on ``track`` from ``from_m`` to ``to_m`` [m]; a repair resolves
    the open and acknowledged alerts it covers, an adjustment the geometry alerts it covers
    (``resolved_at = now``). In the audit trail as ``actor``'s change.

    Raises ``UserError`` for an unknown kind, a chainage that is not finite (an infinite
    stretch would restart every span's history of the track), a negative wire or an empty
    name.
    """
    if kind not in MAINTENANCE_KINDS:
        raise UserError(
            f"unknown maintenance kind {kind!r} (known: {', '.join(MAINTENANCE_KINDS)})"
        )
    for option, chainage_m in (("--from-m", from_m), ("--to-m", to_m)):
        if not math.isfinite(chainage_m):
            raise UserError(f"{option} {chainage_m}: not a finite chainage [m]")
    if wire is not None and wire < 0:
        raise UserError(f"wire must be 0 or more, not {wire}")
    if not recorded_by.strip():
        raise UserError("give who did the work (--by NAME)")
    low, high = sorted((float(from_m), float(to_m)))
    action = MaintenanceAction(
        track=track,
        kind=kind,
        from_chainage_m=low,
        to_chainage_m=high,
        mast_from=mast_from,
        mast_to=mast_to,
        wire=wire,
        performed_at=performed_at,
        recorded_by=recorded_by.strip(),
        note=note,
    )
    session.add(action)
    session.flush()
    resolved = _resolve_covered(session, action, now) if kind in (*REPAIR_KINDS, ADJUSTED) else []
    details = {
        "by": action.recorded_by,
        "kind": kind,
        "line": track.line.code,
        "track": track.code,
        "from_chainage_m": low,
        "to_chainage_m": high,
        "mast_from": mast_from,
        "mast_to": mast_to,
        "wire": wire,
        "performed_at": performed_at.isoformat(),
        "resolved_alerts": resolved,
    }
    target = f"maintenance action {action.id}"
    record_audit(session, actor, "maintenance.record", target, details, at=now)
    return Recorded(action=action, resolved=tuple(resolved))


def list_maintenance(
    session: Session,
    track: Track | None = None,
    from_m: float | None = None,
    to_m: float | None = None,
    *,
    limit: int | None = None,
    offset: int = 0,
) -> list[MaintenanceAction]:
    """The maintenance actions (on ``track``; touching ``from_m`` to ``to_m`` [m] as
    ``touches`` has it), latest performed first; ``limit`` of them from ``offset`` on."""
    query = select(MaintenanceAction)
    if track is not None:
        query = query.where(MaintenanceAction.track_id == track.id)
    if from_m is not None:
        query = query.where(MaintenanceAction.to_chainage_m > from_m + COVER_TOLERANCE_M)
    if to_m is not None:
        query = query.where(MaintenanceAction.from_chainage_m < to_m - COVER_TOLERANCE_M)
    query = query.order_by(MaintenanceAction.performed_at.desc(), MaintenanceAction.id.desc())
    return list(session.scalars(query.limit(limit).offset(offset)))


def _resolve_covered(session: Session, action: MaintenanceAction, now: datetime) -> list[int]:
    """Resolve the open and acknowledged alerts ``action`` covers (an adjustment: geometry
    alerts only); their ids."""
    low, high = action.from_chainage_m, action.to_chainage_m
    query = select(Alert).where(
        Alert.track_id == action.track.id,
        Alert.status.in_(("open", "acknowledged")),
        Alert.start_chainage_m < high + COVER_TOLERANCE_M,
        Alert.end_chainage_m > low - COVER_TOLERANCE_M,
    )
    if action.wire is not None:
        query = query.where(Alert.wire == action.wire)
    if action.kind == ADJUSTED:
        query = query.where(Alert.kind == "geometry")
    candidates = list(session.scalars(query.order_by(Alert.id)))
    section = np.array(
        [(a.details or {}).get("scope") == "anchor_section_average" for a in candidates]
    )
    starts = np.array([a.start_chainage_m for a in candidates])
    ends = np.array([a.end_chainage_m for a in candidates])
    covered = np.where(section, contains(low, high, starts, ends), touches(low, high, starts, ends))
    resolved = []
    for alert, hit in zip(candidates, covered.tolist(), strict=True):
        if hit:
            alert.status = "resolved"
            alert.resolved_at = now
            alert.resolved_by_action = action
            alert.details = {**(alert.details or {}), "resolution": f"{action.kind} (maintenance)"}
            resolved.append(alert.id)
    session.flush()
    return resolved
