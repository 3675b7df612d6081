"""The alert life cycle by hand (list, acknowledge, resolve) and what others read of alerts
(new alerts, their records, their announcement to plugins)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from datetime import UTC, date, datetime
from typing import TYPE_CHECKING, Any

from sqlalchemy import (
    case,
    func,
    select,
)
from sqlalchemy.engine import Engine
from sqlalchemy.orm import Session, joinedload

from catenary.domain import ALERT_STATUSES
from catenary.errors import UserError
from catenary.limits import LEVELS
from catenary.plugins.types import AlertRecord
from catenary.storage.database import session_scope
from catenary.storage.models import (
    NAME_LENGTH,
    Alert,
    Line,
    Track,
)
from catenary.storage.users import record_audit
from catenary.text import utc_text

if TYPE_CHECKING:
    from catenary.plugins import PluginRegistry

__all__ = [
    "ACTIVE",
    "acknowledge_alert",
    "alert_counts",
    "alert_json",
    "alert_stretch",
    "alert_summary",
    "announce_alerts",
    "due_forecasts",
    "forecast_date",
    "iso_utc",
    "list_alerts",
    "new_alerts_since",
    "resolve_alert",
]

ACTIVE = ("open", "acknowledged")
"""Statuses of an alert still to be dealt with."""

_SEVERITY = {level: rank for rank, level in enumerate(reversed(LEVELS))}  # critical first


def list_alerts(
    session: Session,
    status: str = "active",
    line: str | None = None,
    levels: Sequence[str] = (),
    *,
    track: str | None = None,
    kinds: Sequence[str] = (),
    from_m: float | None = None,
    to_m: float | None = None,
    limit: int | None = None,
    offset: int = 0,
) -> list[Alert]:
    """Alerts as a planner reads them: most severe level first, then line, track, chainage.

    ``status``: one of ``ALERT_STATUSES``, ``active`` (open and acknowledged) or ``all``; of
    line ``line`` (and its track ``track``), of ``levels`` and ``kinds`` when given, those
    overlapping ``from_m`` to ``to_m`` [m] if given; at most ``limit`` of them (None: all)
    after the first ``offset``, each with its track and line loaded.
    """
    query = select(Alert).join(Track, Alert.track_id == Track.id).join(Line)
    if status == "active":
        query = query.where(Alert.status.in_(ACTIVE))
    elif status in ALERT_STATUSES:
        query = query.where(Alert.status == status)
    elif status != "all":
        known = ", ".join(("active", *ALERT_STATUSES, "all"))
        raise UserError(f"unknown alert status {status!r} (known: {known})")
    if line is not None:
        query = query.where(Line.code == line)
    if track is not None:
        query = query.where(Track.code == track)
    if levels:
        query = query.where(Alert.level.in_(levels))
    if kinds:
        query = query.where(Alert.kind.in_(kinds))
    if from_m is not None:
        query = query.where(Alert.end_chainage_m > from_m)
    if to_m is not None:
        query = query.where(Alert.start_chainage_m < to_m)
    severity = case(_SEVERITY, value=Alert.level, else_=len(_SEVERITY))
    kind = case({"threshold": 0}, value=Alert.kind, else_=1)
    query = query.order_by(
        severity, Line.code, Track.code, Alert.start_chainage_m, Alert.wire, kind, Alert.id
    )
    return list(
        session.scalars(
            query.limit(limit)
            .offset(offset)
            .options(joinedload(Alert.track).joinedload(Track.line))
        )
    )


def alert_json(alert: Alert) -> dict[str, Any]:
    """An alert as JSON (``catenary alerts list --format json``, the web API), its track and line
    loaded."""
    return {
        "id": alert.id,
        "line": alert.track.line.code,
        "track": alert.track.code,
        "wire_position": alert.wire,
        "mast_from": alert.mast_from,
        "mast_to": alert.mast_to,
        "start_chainage_m": alert.start_chainage_m,
        "end_chainage_m": alert.end_chainage_m,
        "rule": alert.rule,
        "level": alert.level,
        "kind": alert.kind,
        "value": alert.value,
        "threshold": alert.threshold,
        "status": alert.status,
        "raised_at": utc_text(alert.raised_at),
        "acknowledged_by": alert.acknowledged_by,
        "acknowledged_at": utc_text(alert.acknowledged_at),
        "resolved_at": utc_text(alert.resolved_at),
        "resolved_by_run_id": alert.resolved_by_run_id,
        "resolved_by_action_id": alert.resolved_by_action_id,
        "span_measurement_id": alert.span_measurement_id,
        "details": alert.details,
    }


def alert_counts(session: Session, status: str = "open") -> dict[str, int]:
    """How many alerts of ``status`` there are of each level (every level of ``LEVELS``)."""
    found = session.execute(
        select(Alert.level, func.count()).where(Alert.status == status).group_by(Alert.level)
    )
    counts = {level: 0 for level in LEVELS}
    counts.update({level: int(n) for level, n in found})
    return counts


def forecast_date(details: Mapping[str, Any] | None, key: str = "reach_at") -> date | None:
    """The (UTC) date of an ISO time in a forecast alert's ``details[key]``: ``reach_at``, when
    the limit is expected (``reach_earliest``, ``reach_latest``: its interval); None without
    one."""
    value = (details or {}).get(key)
    if not isinstance(value, str):
        return None
    try:
        moment = datetime.fromisoformat(value)
    except ValueError:
        return None
    return (moment.astimezone(UTC) if moment.tzinfo else moment).date()


def due_forecasts(session: Session, until: datetime, limit: int) -> tuple[int, list[Alert]]:
    """The open and acknowledged forecast alerts whose limit is expected (``reach_at``) by
    ``until``: how many, and the ``limit`` earliest (each with its track and line)."""
    reach_at = Alert.details["reach_at"].as_string()
    due = (Alert.kind == "forecast", Alert.status.in_(ACTIVE), reach_at <= iso_utc(until))
    total = session.scalar(select(func.count()).select_from(Alert).where(*due)) or 0
    earliest = session.scalars(
        select(Alert)
        .where(*due)
        .options(joinedload(Alert.track).joinedload(Track.line))
        .order_by(reach_at, Alert.id)
        .limit(limit)
    )
    return int(total), list(earliest)


def alert_stretch(alert: Alert) -> str:
    """Where an alert lies: ``masts M1 to M2``, or its chainages without a register."""
    if alert.mast_from is not None:
        return f"masts {alert.mast_from} to {alert.mast_to}"
    return f"{alert.start_chainage_m:.1f} to {alert.end_chainage_m:.1f} m"


def alert_summary(alert: Alert) -> str:
    """What an alert says, in one line with units: a minimum (or an anchor section's
    average) against its limit, a forecast's date, interval and wear rate, or a geometry
    check's value (height, stagger: mm; height gradient: per mille) against its limit."""
    details = alert.details or {}
    if alert.kind == "forecast":
        low, high = details.get("reach_earliest"), details.get("reach_latest")
        span = f"{(low or '-')[:10]} to {(high or 'never')[:10]}"
        return (
            f"reaches {alert.threshold:.2f} mm about {str(details.get('reach_at'))[:10]} "
            f"({span}), wear {details.get('wear_rate_mm_per_year', 0.0):.3f} "
            f"+- {details.get('wear_rate_se_mm_per_year', 0.0):.3f} mm/year"
        )
    if alert.kind == "geometry":
        check = str(details.get("check", "geometry"))
        unit = "per mille" if check == "height_gradient" else "mm"
        text = f"{check} {alert.value:.1f} {unit}, limit {alert.threshold:.1f} {unit}"
        if "design_mm" in details and "measured_mm" in details:
            text += f" (at the mast {details['measured_mm']} mm, design {details['design_mm']} mm)"
        return text
    scope = "anchor section average" if details.get("anchor_section") else "minimum"
    return f"{scope} {alert.value:.2f} mm, limit {alert.threshold:.2f} mm"


def _alert(session: Session, alert_id: int) -> Alert:
    alert = session.get(Alert, alert_id)
    if alert is None:
        raise UserError(f"no alert {alert_id} in the database")
    return alert


def _name(by: str) -> str:
    name = by.strip()
    if not name:
        raise UserError("give a name (--by NAME)")
    if len(name) > NAME_LENGTH:
        raise UserError(f"name {name[:40]!r}...: at most {NAME_LENGTH} characters")
    return name


def acknowledge_alert(
    session: Session, alert_id: int, by: str, now: datetime, *, actor: str
) -> Alert:
    """Mark open alert ``alert_id`` acknowledged by ``by`` at ``now``; in the audit trail as
    ``actor``'s change (a signed-in user, or ``system_actor()`` on the command line)."""
    name = _name(by)
    alert = _alert(session, alert_id)
    if alert.status == "acknowledged":
        raise UserError(
            f"alert {alert_id} is already acknowledged (by {alert.acknowledged_by} at "
            f"{iso_utc(alert.acknowledged_at)})"
        )
    if alert.status == "resolved":
        raise UserError(f"alert {alert_id} is resolved (at {iso_utc(alert.resolved_at)})")
    alert.status, alert.acknowledged_by, alert.acknowledged_at = "acknowledged", name, now
    session.flush()
    details = {"by": name, "status": "acknowledged"}
    record_audit(session, actor, "alert.acknowledge", f"alert {alert.id}", details, at=now)
    return alert


def resolve_alert(
    session: Session,
    alert_id: int,
    by: str,
    now: datetime,
    note: str | None = None,
    *,
    actor: str,
) -> Alert:
    """Resolve alert ``alert_id`` by hand: by ``by`` at ``now``, with an optional ``note``; in
    the audit trail as ``actor``'s change.

    The condition is raised again (a new alert) only from a run that starts after ``now``.
    """
    name = _name(by)
    alert = _alert(session, alert_id)
    if alert.status == "resolved":
        raise UserError(f"alert {alert_id} is already resolved (at {iso_utc(alert.resolved_at)})")
    alert.status, alert.resolved_at = "resolved", now
    extra = {"resolution": "by hand", "resolved_by": name} | ({"note": note} if note else {})
    alert.details = {**(alert.details or {}), **extra}
    session.flush()
    details = {"by": name, "status": "resolved"} | ({"note": note} if note else {})
    record_audit(session, actor, "alert.resolve", f"alert {alert.id}", details, at=now)
    return alert


def new_alerts_since(session: Session, after_id: int = 0) -> list[Alert]:
    """Alerts raised after alert ``after_id`` (ids grow), in the order they were raised: what
    a notifier that remembers the last id it sent has to send."""
    return list(session.scalars(select(Alert).where(Alert.id > after_id).order_by(Alert.id)))


def announce_alerts(engine: Engine, registry: PluginRegistry, alert_ids: Sequence[int]) -> None:
    """Call every plugin's ``catenary_alert_raised`` hook with each committed alert of
    ``alert_ids`` (its ``AlertRecord``), in the order they were raised."""
    chunk = 5000  # bound the IN list (SQLite's limit on variables)
    for start in range(0, len(alert_ids), chunk):
        with session_scope(engine) as session:
            found = session.scalars(
                select(Alert)
                .where(Alert.id.in_(alert_ids[start : start + chunk]))
                .options(joinedload(Alert.track).joinedload(Track.line))
                .order_by(Alert.id)
            )
            records = [AlertRecord.of(alert) for alert in found]
        for record in records:
            registry.alert_raised(record)


def iso_utc(moment: datetime | None) -> str | None:
    return None if moment is None else moment.astimezone(UTC).isoformat(timespec="seconds")
