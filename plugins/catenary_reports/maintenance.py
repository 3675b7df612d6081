"""The maintenance report: open alerts by urgency, forecasts, and the spans to visit.

Read from the database as stored (the ``alerts`` table, not the alert engine's API), for one
line (``--line``, optionally ``--track``) or every line:

- **open alerts** (status open or acknowledged) by level, critical, urgent, then plan;
- **forecasts**: the open forecast alerts by the date their limit is expected to be reached
  (the alert engine's ``details["reach_at"]``, with ``reach_earliest`` and ``reach_latest``);
- **spans to visit**: one row per stretch (line, track, chainage, masts) and wire with open
  alerts, sorted as a planner works, by line, track and chainage; the most severe level, the
  lowest value and the earliest forecast date of its alerts, and its **hot spots** (where wear
  concentrates, ``reference/wire-profiles.md``), each derived from data the database holds:

  - *registration point*: every mast is one (its steady arm); the span minimum of the alert's
    span measurement (``min_at_chainage_m``) within ``REGISTRATION_ZONE_M`` of a mast is at that
    registration point, farther is mid-span; without it the stretch's masts are named;
  - *overlap*: the track's latest complete run measured two contact wires or more in a span
    that meets the stretch;
  - *anchor-section change*: the register's ``anchor_section`` changes at a mast of the
    stretch (where one tensioning length hands over to the next);
  - *splice*, *reinforcement clamp*: a maintenance action of kind ``spliced`` or
    ``reinforced`` recorded on the stretch (and wire, or all wires).

  Crossings, connectors and phase breaks are in no table, so they are not named.

``.html`` holds all three; ``.csv``/``.xlsx``/``.parquet`` the spans to visit.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, date, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from sqlalchemy import select
from sqlalchemy.orm import Session, selectinload

from catenary.errors import UserError
from catenary.limits import LEVELS
from catenary.maintenance.alerts.lifecycle import forecast_date
from catenary.measurement.samples import export_table
from catenary.plugins import ReportRequest
from catenary.storage.database import open_database, session_scope
from catenary.storage.models import (
    Alert,
    Line,
    MaintenanceAction,
    Mast,
    Run,
    SpanMeasurement,
    Track,
)
from catenary_reports import html
from catenary_reports.html import Cell, number
from catenary_reports.request import check_output, parse_request

__all__ = ["REGISTRATION_ZONE_M", "forecast_date", "write"]

REGISTRATION_ZONE_M = 2.0
"""A span minimum this close to a mast [m] is at the mast's registration point."""

OPEN_STATUSES = ("open", "acknowledged")

HOT_SPOT_ACTIONS = {"spliced": "splice", "reinforced": "reinforcement clamp"}
"""Maintenance action kinds that leave a hot spot on the wire, and what it is called."""


@dataclass
class _Track:
    """What the hot spots of one track are derived from."""

    line: str
    code: str
    masts: list[Mast]
    latest: Run | None
    overlaps: list[tuple[float, float]]  # spans of the latest run with two wires or more
    actions: list[MaintenanceAction]
    chainage_m: np.ndarray[Any, np.dtype[np.float64]] = field(init=False)

    def __post_init__(self) -> None:
        self.chainage_m = np.array([m.chainage_m for m in self.masts], dtype=np.float64)

    def hot_spots(self, alert: Alert) -> list[str]:
        low, high = alert.start_chainage_m, alert.end_chainage_m
        found = []
        at = alert.span_measurement.min_at_chainage_m if alert.span_measurement else None
        if at is not None and self.masts:
            nearest = int(np.argmin(np.abs(self.chainage_m - at)))
            distance = abs(float(self.chainage_m[nearest]) - at)
            code = self.masts[nearest].code
            if distance <= REGISTRATION_ZONE_M:
                found.append(f"registration point at mast {code} (minimum {distance:.1f} m off)")
            else:
                found.append(f"mid-span (minimum {distance:.1f} m from mast {code})")
        else:
            codes = [m.code for m in self.masts if low <= m.chainage_m <= high]
            if codes:
                found.append(f"registration points at masts {', '.join(codes)}")
        if self.latest is not None and any(s < high and e > low for s, e in self.overlaps):
            found.append(f"overlap (two contact wires in run {self.latest.id})")
        for before, mast in itertools.pairwise(self.masts):
            if (
                low <= mast.chainage_m <= high
                and before.anchor_section
                and mast.anchor_section
                and before.anchor_section != mast.anchor_section
            ):
                found.append(
                    f"anchor-section change at mast {mast.code} "
                    f"({before.anchor_section} to {mast.anchor_section})"
                )
        for action in self.actions:
            if (
                action.from_chainage_m <= high
                and action.to_chainage_m >= low
                and action.wire in (None, alert.wire)
            ):
                found.append(
                    f"{HOT_SPOT_ACTIONS[action.kind]} at {action.from_chainage_m:.1f} m "
                    f"({action.kind} {action.performed_at:%Y-%m-%d})"
                )
        return found


def _tracks(session: Session, line: str | None, track: str | None) -> dict[int, _Track]:
    lines = list(session.scalars(select(Line).order_by(Line.code)))
    if line is not None:
        chosen = [x for x in lines if x.code == line]
        if not chosen:
            known = ", ".join(x.code for x in lines) or "none"
            raise UserError(f"no line {line!r} in the database (known: {known})")
        lines = chosen
    out: dict[int, _Track] = {}
    for line_row in lines:
        tracks = sorted(line_row.tracks, key=lambda t: t.code)
        if track is not None:
            tracks = [t for t in tracks if t.code == track]
            if not tracks:
                known = ", ".join(sorted(t.code for t in line_row.tracks)) or "none"
                raise UserError(f"line {line!r} has no track {track!r} (known: {known})")
        for t in tracks:
            out[t.id] = _track(session, line_row.code, t)
    return out


def _track(session: Session, line: str, track: Track) -> _Track:
    latest = session.scalars(
        select(Run)
        .where(Run.track_id == track.id, Run.status == "complete")
        .order_by(Run.started_at.desc(), Run.id.desc())
        .limit(1)
    ).first()
    overlaps: list[tuple[float, float]] = []
    if latest is not None:
        wires: dict[tuple[float, float], set[int]] = {}
        for s in session.scalars(
            select(SpanMeasurement).where(SpanMeasurement.processing_id == latest.processing_id)
        ):
            wires.setdefault((s.start_chainage_m, s.end_chainage_m), set()).add(s.wire)
        overlaps = sorted(k for k, v in wires.items() if len(v) > 1)
    actions = list(
        session.scalars(
            select(MaintenanceAction)
            .where(
                MaintenanceAction.track_id == track.id,
                MaintenanceAction.kind.in_(tuple(HOT_SPOT_ACTIONS)),
            )
            .order_by(MaintenanceAction.from_chainage_m)
        )
    )
    return _Track(line, track.code, list(track.masts), latest, overlaps, actions)


@dataclass(frozen=True)
class _Entry:
    """An open alert with what the report says about it."""

    alert: Alert
    track: _Track
    forecast: date | None
    hot_spots: tuple[str, ...]

    @property
    def masts(self) -> str:
        a = self.alert
        if a.mast_from:
            return f"masts {a.mast_from} to {a.mast_to}"
        return f"chainage {a.start_chainage_m:.1f} to {a.end_chainage_m:.1f} m"

    @property
    def place(self) -> str:
        return f"{self.track.line} track {self.track.code}"

    @property
    def chainage(self) -> str:
        return f"{self.alert.start_chainage_m:.1f}–{self.alert.end_chainage_m:.1f}"

    @property
    def severity(self) -> int:
        return LEVELS.index(self.alert.level)


@dataclass(frozen=True)
class _Visit:
    """A stretch and wire to visit: every open alert on it."""

    entries: tuple[_Entry, ...]

    @property
    def first(self) -> _Entry:
        return self.entries[0]

    @property
    def worst(self) -> _Entry:
        return max(self.entries, key=lambda e: (e.severity, -e.alert.value))

    @property
    def forecast(self) -> date | None:
        return min((e.forecast for e in self.entries if e.forecast), default=None)

    @property
    def hot_spots(self) -> list[str]:
        return list(dict.fromkeys(h for e in self.entries for h in e.hot_spots))


def _visits(entries: Iterable[_Entry]) -> list[_Visit]:
    groups: dict[tuple[Any, ...], list[_Entry]] = {}
    for e in entries:
        a = e.alert
        key = (e.track.line, e.track.code, a.start_chainage_m, a.end_chainage_m, a.wire)
        groups.setdefault(key, []).append(e)
    return [_Visit(tuple(groups[k])) for k in sorted(groups)]


def _status(alert: Alert) -> str:
    if alert.status == "acknowledged" and alert.acknowledged_by:
        return f"acknowledged by {alert.acknowledged_by}"
    return alert.status


def _alert_rows(entries: Sequence[_Entry]) -> list[list[Cell | str]]:
    return [
        [
            Cell(str(e.alert.id), numeric=True),
            e.alert.kind,
            Cell(e.place, keep=True),
            Cell(e.masts.removeprefix("masts "), keep=True),
            Cell(e.chainage, keep=True),
            Cell(str(e.alert.wire), numeric=True),
            number(e.alert.value),
            number(e.alert.threshold),
            Cell(e.forecast.isoformat() if e.forecast else "", keep=True),
            e.alert.rule,
            _status(e.alert),
            Cell(f"{e.alert.raised_at:%Y-%m-%d}", keep=True),
            Cell("; ".join(e.hot_spots), wide=True),
        ]
        for e in entries
    ]


_ALERT_HEADERS = [
    "alert",
    "kind",
    "line, track",
    "masts",
    "chainage m",
    "wire_position",
    "value mm",
    "threshold mm",
    "forecast",
    "rule",
    "status",
    "raised",
    "hot spots",
]

_VISIT_SCHEMA = pa.schema(
    [
        ("line", pa.string()),
        ("track", pa.string()),
        ("from_m", pa.float64()),
        ("to_m", pa.float64()),
        ("mast_from", pa.string()),
        ("mast_to", pa.string()),
        ("wire_position", pa.int64()),
        ("level", pa.string()),
        ("kinds", pa.string()),
        ("value_mm", pa.float64()),
        ("threshold_mm", pa.float64()),
        ("forecast_date", pa.string()),
        ("status", pa.string()),
        ("hot_spots", pa.string()),
        ("alert_ids", pa.string()),
        ("rules", pa.string()),
    ]
)


def _visit_table(visits: Sequence[_Visit]) -> pa.Table:
    rows = []
    for v in visits:
        a, worst = v.first.alert, v.worst.alert
        rows.append(
            {
                "line": v.first.track.line,
                "track": v.first.track.code,
                "from_m": a.start_chainage_m,
                "to_m": a.end_chainage_m,
                "mast_from": a.mast_from,
                "mast_to": a.mast_to,
                "wire_position": a.wire,
                "level": worst.level,
                "kinds": ";".join(sorted({e.alert.kind for e in v.entries})),
                "value_mm": min(e.alert.value for e in v.entries),
                "threshold_mm": worst.threshold,
                "forecast_date": v.forecast.isoformat() if v.forecast else None,
                "status": ";".join(sorted({e.alert.status for e in v.entries})),
                "hot_spots": "; ".join(v.hot_spots),
                "alert_ids": ";".join(str(e.alert.id) for e in v.entries),
                "rules": ";".join(dict.fromkeys(e.alert.rule for e in v.entries)),
            }
        )
    return pa.Table.from_pylist(rows, schema=_VISIT_SCHEMA)


def _interval(details: Mapping[str, Any] | None) -> str:
    """A forecast's interval, ``earliest to latest`` (empty when not known)."""
    low, high = forecast_date(details, "reach_earliest"), forecast_date(details, "reach_latest")
    return f"{low} to {high}" if low and high else ""


def _detail(details: Mapping[str, Any] | None, key: str, decimals: int) -> Cell:
    """A numeric cell of ``details[key]`` (empty when not a number)."""
    value = (details or {}).get(key)
    if isinstance(value, bool) or not isinstance(value, int | float):
        return number(None)
    return number(float(value), decimals)


def _html(
    tracks: Mapping[int, _Track], entries: Sequence[_Entry], visits: Sequence[_Visit], where: str
) -> str:
    now = datetime.now(UTC)
    counts = {level: sum(1 for e in entries if e.alert.level == level) for level in LEVELS}
    latest = [
        f"{t.line} track {t.code}: "
        + (f"run {t.latest.id} of {html.stamp(t.latest.started_at)}" if t.latest else "no run")
        for t in tracks.values()
    ]
    summary = "".join(
        f'<li class="{level}"><b>{counts[level]}</b>{level}</li>' for level in reversed(LEVELS)
    )
    parts = [
        html.section(
            "Summary",
            html.facts(
                [
                    ("Lines and tracks", where),
                    ("Generated", html.stamp(now)),
                    ("Latest runs", "; ".join(latest) or "none"),
                    ("Open alerts", str(len(entries))),
                    ("Stretches to visit", str(len(visits))),
                ]
            ),
            f'<ul class="counts" id="counts">{summary}</ul>',
            section_id="summary",
        )
    ]
    by_level = []
    for level in reversed(LEVELS):
        chosen = sorted(
            (e for e in entries if e.alert.level == level),
            key=lambda e: (e.track.line, e.track.code, e.alert.start_chainage_m, e.alert.wire),
        )
        by_level.append(f"<h3>{html.tag(level)} {len(chosen)}</h3>")
        by_level.append(
            html.table(
                _ALERT_HEADERS,
                _alert_rows(chosen),
                row_classes=[level] * len(chosen),
                table_id=f"alerts-{level}",
                empty=f"No open {level} alert.",
            )
        )
    parts.append(html.section("Open alerts by urgency", *by_level, section_id="alerts"))
    forecasts = sorted(
        (e for e in entries if e.alert.kind == "forecast"),
        key=lambda e: (e.forecast or date.max, -e.severity),
    )
    parts.append(
        html.section(
            "Forecasts",
            html.note("When each limit is expected to be reached, earliest first."),
            html.table(
                [
                    "date",
                    "interval",
                    "level",
                    "line, track",
                    "masts",
                    "wire position",
                    "value mm",
                    "threshold mm",
                    "wear rate mm/year",
                    "runs",
                    "rule",
                ],
                [
                    [
                        Cell(e.forecast.isoformat() if e.forecast else "unknown", keep=True),
                        Cell(_interval(e.alert.details), keep=True),
                        Cell(markup=html.tag(e.alert.level)),
                        Cell(e.place, keep=True),
                        Cell(e.masts.removeprefix("masts "), keep=True),
                        Cell(str(e.alert.wire), numeric=True),
                        number(e.alert.value),
                        number(e.alert.threshold),
                        _detail(e.alert.details, "wear_rate_mm_per_year", 3),
                        _detail(e.alert.details, "runs", 0),
                        e.alert.rule,
                    ]
                    for e in forecasts
                ],
                table_id="forecasts",
                empty="No open forecast.",
            ),
            section_id="forecast",
        )
    )
    rows: list[list[Cell | str]] = []
    for v in visits:
        a, worst = v.first, v.worst
        rows.append(
            [
                Cell(a.track.line, keep=True),
                Cell(a.track.code, keep=True),
                number(a.alert.start_chainage_m, 1),
                number(a.alert.end_chainage_m, 1),
                Cell(a.masts, keep=True),
                Cell(str(a.alert.wire), numeric=True),
                Cell(markup=html.tag(worst.alert.level)),
                number(min(e.alert.value for e in v.entries)),
                number(worst.alert.threshold),
                Cell(v.forecast.isoformat() if v.forecast else "", keep=True),
                Cell("; ".join(v.hot_spots), wide=True),
                ", ".join(str(e.alert.id) for e in v.entries),
            ]
        )
    parts.append(
        html.section(
            "Spans to visit",
            html.note(
                "By line, track and chainage; one row per stretch and contact wire with the "
                "most severe level, the lowest value and the earliest forecast of its open "
                "alerts."
            ),
            html.table(
                [
                    "line",
                    "track",
                    "from m",
                    "to m",
                    "masts",
                    "wire position",
                    "level",
                    "value mm",
                    "threshold mm",
                    "forecast date",
                    "hot spots",
                    "alerts",
                ],
                rows,
                row_classes=[v.worst.alert.level for v in visits],
                table_id="visits",
                empty="Nothing to visit: no open alert.",
            ),
            section_id="visit",
        )
    )
    parts.append(
        html.section(
            "Where the hot spots come from",
            "<ul>"
            f"<li>Registration point: every mast is one; a span minimum within "
            f"{REGISTRATION_ZONE_M:g} m of a mast (from the alert's span measurement) is at "
            "it, farther is mid-span.</li>"
            "<li>Overlap: two contact wires or more in a span of the track's latest run.</li>"
            "<li>Anchor-section change: the mast register's anchor section changes at a mast "
            "of the stretch.</li>"
            "<li>Splice, reinforcement clamp: a maintenance action of kind spliced or "
            "reinforced recorded on the stretch.</li>"
            "<li>Crossings, connectors and phase breaks are not in the database and are not "
            "named.</li></ul>",
            section_id="sources",
        )
    )
    title = f"Maintenance: {where}"
    return html.page(title, f"generated {html.stamp(now)}", parts)


def write(raw: ReportRequest, output: Path) -> Path:
    """Write the maintenance report of ``raw['line']`` (every line when None) to ``output``."""
    request = parse_request("maintenance", raw, line=True)
    suffix = check_output(output, (".html", ".csv", ".xlsx", ".parquet"))
    with (
        open_database(request.settings) as engine,
        session_scope(engine, read_only=True) as session,
    ):
        tracks = _tracks(session, request.line, request.track)
        alerts = session.scalars(
            select(Alert)
            .where(Alert.track_id.in_(tuple(tracks)), Alert.status.in_(OPEN_STATUSES))
            .options(selectinload(Alert.span_measurement))
            .order_by(Alert.id)
        )
        entries = [
            _Entry(
                a,
                tracks[a.track_id],
                forecast_date(a.details),
                tuple(tracks[a.track_id].hot_spots(a)),
            )
            for a in alerts
        ]
    visits = _visits(entries)
    if suffix != ".html":
        export_table(iter([_visit_table(visits)]), _VISIT_SCHEMA, output)
        return output
    if request.line is None:
        where = "every line"
    else:
        where = f"line {request.line}" + (f" track {request.track}" if request.track else "")
    return html.write_text(output, _html(tracks, entries, visits, where))
