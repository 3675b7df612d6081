"""Alert evaluation: raise, update and resolve the alerts of the tracks that runs measured
(the rules, forecasts and life cycle: the package's docstring)."""

from __future__ import annotations

import hashlib
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np
from sqlalchemy import (
    select,
    text,
    update,
)
from sqlalchemy.engine import Engine
from sqlalchemy.orm import Session, aliased

from catenary.arrays import BoolArray, FloatArray, IntArray
from catenary.config import Settings
from catenary.errors import UserError, one_line
from catenary.limits import LEVELS, STANDARD_POLICY, GeometryRule, LimitPolicy, choose_policy
from catenary.maintenance.forecast import (
    CONFIDENCE,
    ReachTimes,
    moment_of,
    reach_times,
    years_since_epoch,
)
from catenary.maintenance.notifications import (
    NotificationConfig,
    notification_config,
    queue_notifications,
)
from catenary.storage.database import session_scope
from catenary.storage.inserts import insert_new
from catenary.storage.models import (
    Alert,
    Line,
    MaintenanceAction,
    Run,
    Track,
)
from catenary.wiretype import WireType

if TYPE_CHECKING:
    from catenary.plugins import PluginRegistry
from catenary.maintenance.alerts.geometry import GEOMETRY_MARGIN_MM, Checked, check, running
from catenary.maintenance.alerts.lifecycle import ACTIVE, announce_alerts, iso_utc
from catenary.maintenance.alerts.rules import (
    DEFAULT_HORIZON_DAYS,
    LOCAL,
    SECTION,
    Rule,
    check_policy,
    geometry_rules_of,
    horizon_days,
    line_speeds,
    rules_of,
)
from catenary.maintenance.alerts.trackdata import (
    TrackData,
    Units,
    history_keys,
    match_units,
    units_of,
)

__all__ = [
    "RESOLVE_MARGIN_MM",
    "Evaluation",
    "RunAlerting",
    "TrackFailure",
    "evaluate_alerts",
    "evaluate_all",
    "evaluate_stored_run",
    "evaluate_tracks",
    "run_alerting",
    "run_alerts_lines",
]


RESOLVE_MARGIN_MM = 0.1
"""A threshold alert is resolved by a run only when its value is this far back above the
threshold [mm]: the measurement's worst-case error (DESIGN.md's 0.10 mm)."""

_KEY_LENGTH = 255  # Alert.condition_key
_DAYS_PER_YEAR = 365.25

# --- existing alerts ------------------------------------------------------------------------


@dataclass(frozen=True)
class _Existing:
    """A track's alerts: each condition's latest generation (its number, status and when it
    was closed, in years), and the active alerts (rows of ``load``'s query)."""

    latest: dict[str, tuple[int, str, float]]
    active: list[Any]

    @classmethod
    def load(cls, session: Session, track_id: int) -> _Existing:
        by_run, by_action = aliased(Run), aliased(MaintenanceAction)
        rows = session.execute(
            select(
                Alert.id,
                Alert.condition_key,
                Alert.status,
                Alert.kind,
                Alert.rule,
                Alert.level,
                Alert.wire,
                Alert.mast_from,
                Alert.mast_to,
                Alert.start_chainage_m,
                Alert.end_chainage_m,
                Alert.span_measurement_id,
                Alert.value,
                Alert.threshold,
                Alert.details,
                Alert.resolved_at,
                by_run.started_at.label("run_started_at"),
                by_action.performed_at.label("action_performed_at"),
            )
            .outerjoin(by_run, Alert.resolved_by_run_id == by_run.id)
            .outerjoin(by_action, Alert.resolved_by_action_id == by_action.id)
            .where(Alert.track_id == track_id)
        ).all()
        latest: dict[str, tuple[int, str, float]] = {}
        for row in rows:
            base, _, number = row.condition_key.rpartition("/g")
            closed = row.action_performed_at or row.run_started_at or row.resolved_at
            years = float(years_since_epoch([closed])[0]) if closed is not None else np.inf
            if base not in latest or int(number) > latest[base][0]:
                latest[base] = (int(number), row.status, years)
        return cls(latest=latest, active=[r for r in rows if r.status in ACTIVE])

    def active_of(
        self, kind: str, rule: str, units: Units, track: TrackData
    ) -> tuple[IntArray, list[Any]]:
        """The units that have an active alert of ``kind`` and ``rule``, and those alerts."""
        alerts = [
            a
            for a in self.active
            if a.kind == kind and a.rule == rule and (a.details or {}).get("scope") == units.scope
        ]
        if not alerts:
            return np.zeros(0, dtype=np.int64), []
        if units.scope == SECTION:
            index = {code: k for k, code in enumerate(track.section_code)}
            section = [index.get(str((a.details or {}).get("anchor_section")), -1) for a in alerts]
            keys = np.column_stack([section, [a.wire for a in alerts]]).astype(np.float64)
        else:
            mast_from = track.mast_index([a.mast_from for a in alerts])
            mast_to = track.mast_index([a.mast_to for a in alerts])
            keys = history_keys(
                mast_from,
                mast_to,
                np.array([a.start_chainage_m for a in alerts], dtype=np.float64),
                np.array([a.end_chainage_m for a in alerts], dtype=np.float64),
                np.array([a.wire for a in alerts], dtype=np.int64),
            )
            named = np.array([a.mast_from is not None for a in alerts], dtype=bool)
            keys[named & (mast_from < 0), 0] = -1.0  # a mast no longer known: matches nothing
        unit = match_units(units.keys, keys)
        found = np.flatnonzero(unit >= 0)
        return unit[found], [alerts[i] for i in found.tolist()]


# --- evaluation -----------------------------------------------------------------------------


@dataclass(frozen=True)
class TrackFailure:
    """A track whose evaluation failed (nothing of it written; its runs stay pending)."""

    line: str
    track: str
    reason: str

    def __str__(self) -> str:
        return f"line {self.line} track {self.track}: {self.reason}"


@dataclass
class Evaluation:
    """What an evaluation did: the histories (span-wires) and anchor sections it looked at,
    the ids of the alerts it raised, how many it updated and resolved, how many runs it
    evaluated for the first time (``runs``), notes on what it could not evaluate (each said
    once) and the tracks whose evaluation failed."""

    policy: str
    spans: int = 0
    sections: int = 0
    new: list[int] = field(default_factory=list)
    new_levels: Counter[str] = field(default_factory=Counter)
    updated: int = 0
    resolved: int = 0
    runs: int = 0
    notes: list[str] = field(default_factory=list)
    failed: list[TrackFailure] = field(default_factory=list)

    def summary(self) -> str:
        """E.g. ``2 new (1 urgent, 1 plan), 1 updated, 0 resolved``."""
        levels = ", ".join(
            f"{self.new_levels[level]} {level}"
            for level in reversed(LEVELS)
            if self.new_levels[level]
        )
        new = f"{len(self.new)} new" + (f" ({levels})" if levels else "")
        return f"{new}, {self.updated} updated, {self.resolved} resolved"

    def note(self, text: str) -> None:
        if text not in self.notes:
            self.notes.append(text)

    def add(self, other: Evaluation) -> None:
        """Count in ``other``, an evaluation of other tracks with the same policy."""
        self.spans += other.spans
        self.sections += other.sections
        self.new += other.new
        self.new_levels += other.new_levels
        self.updated += other.updated
        self.resolved += other.resolved
        self.runs += other.runs
        for note in other.notes:
            self.note(note)
        self.failed += other.failed


def _same_keys(rows: list[dict[str, Any]]) -> list[list[dict[str, Any]]]:
    """``rows`` grouped by their set of keys (one executemany takes one set)."""
    groups: dict[tuple[str, ...], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault(tuple(sorted(row)), []).append(row)
    return list(groups.values())


class _Track:
    """One track's evaluation: its units, the decisions per rule, and the writes."""

    def __init__(
        self,
        session: Session,
        track_id: int,
        rules: list[Rule],
        geometry: list[tuple[str, GeometryRule]],
        wire_types: Sequence[WireType],
        now: datetime,
        horizon_days: float,
        line_speeds: Mapping[str, float],
    ) -> None:
        self.session, self.rules, self.wire_types, self.now = session, rules, wire_types, now
        self.geometry, self.line_speeds = geometry, line_speeds
        self.data = TrackData(session, track_id, [w.name for w in wire_types])
        self.existing = _Existing.load(session, track_id)
        self.horizon_end_years = float(years_since_epoch([now])[0]) + horizon_days / _DAYS_PER_YEAR
        self.horizon_days = horizon_days
        self.inserts: list[dict[str, Any]] = []
        self.updates: list[dict[str, Any]] = []
        self.resolved = 0

    def evaluate(self, run_ids: Sequence[int] | None, result: Evaluation) -> None:
        if self.data.rows.rows == 0:
            return
        local, section = units_of(self.data, run_ids)
        result.spans += local.count
        result.sections += section.count
        if np.any(local.wire_type < 0):
            result.note("span measurements of a wire type no plugin registers are not evaluated")
        if np.any(section.wire_type == -2):
            result.note("anchor sections whose spans are of different wire types are not evaluated")
        for rule in self.rules:
            units = local if rule.rule.scope == LOCAL else section
            limit = rule.limit(units.wire_type)
            applies = np.isfinite(limit)
            met = rule.met(units.value_mm, limit) & applies
            clear = applies & (units.value_mm > limit + RESOLVE_MARGIN_MM)
            engaged = self._cycle(
                "threshold",
                rule.name,
                units,
                limit,
                met,
                clear,
                partial(self._columns, "threshold", rule, units, limit=limit, reach=None),
            )
            if units.fit is None:
                continue
            reach = reach_times(units.fit, np.where(applies, limit, np.nan))
            within = reach.central <= self.horizon_end_years
            beyond = reach.low > self.horizon_end_years
            self._cycle(
                "forecast",
                rule.name,
                units,
                limit,
                within & ~engaged,
                beyond | engaged,
                partial(self._columns, "forecast", rule, units, limit=limit, reach=reach),
                engaged,
            )
        self._geometry(local)

    def _geometry(self, units: Units) -> None:
        """The policy's geometry rules on the histories ``units`` (``alerts.geometry``)."""
        data, rows = self.data, self.data.rows
        if not self.geometry or units.count == 0:
            return
        at_start = running(rows.run_id, rows.mast_from, rows.span, data.geometry.height_start_mm)
        at_end = running(rows.run_id, rows.mast_to, rows.span, data.geometry.height_end_mm)
        row = units.row
        mast_from = rows.mast_from[row]
        length_m = rows.end_m[row] - rows.start_m[row]
        masts = data.mast_geometry
        if self.line_speeds:  # the configuration's, where the register gives none
            line = self.session.scalar(
                select(Line.code)
                .join(Track, Track.line_id == Line.id)
                .where(Track.id == data.track_id)
            )
            if line is not None and line in self.line_speeds:
                speed = masts.line_speed_kmh
                masts = replace(
                    masts, line_speed_kmh=np.where(np.isnan(speed), self.line_speeds[line], speed)
                )
        for name, rule in self.geometry:
            checked = check(
                rule,
                data.geometry,
                masts,
                row,
                units.run_id,
                mast_from,
                length_m,
                rows.direction[row],
                at_start,
                at_end,
            )
            self._cycle(
                "geometry",
                name,
                units,
                checked.limit,
                checked.met(),
                checked.clear(),
                partial(self._geometry_columns, name, rule, units, checked=checked),
            )

    def _geometry_columns(
        self, name: str, rule: GeometryRule, units: Units, unit: int, checked: Checked
    ) -> dict[str, Any]:
        """A geometry alert's columns for one unit."""
        row = int(units.row[unit])
        rows = self.data.rows
        run_id = int(units.run_id[unit])
        details: dict[str, Any] = {
            "scope": units.scope,
            "policy": name.rpartition("#")[0],
            "rule_number": name.rpartition("#")[2],
            "check": rule.check,
            "criterion": rule.criterion,
            "action": rule.action,
            "run_id": run_id,
            "run_wire": int(rows.wire[row]),
            "run_started_at": iso_utc(self.data.run_started_at(run_id)),
            "beyond_mm": round(float(checked.excess_mm[unit]), 1),
        }
        for key, values in (
            ("measured_mm", checked.measured_mm),
            ("design_mm", checked.design_mm),
            ("line_speed_kmh", checked.line_speed_kmh),
        ):
            if np.isfinite(values[unit]):
                details[key] = round(float(values[unit]), 1)
        return {
            **self._where(row),
            "wire": int(units.position[unit]),
            "rule": name,
            "level": rule.level,
            "kind": "geometry",
            "value": float(checked.value[unit]),
            "threshold": float(checked.limit[unit]),
            "details": details,
        }

    def _where(self, row: int) -> dict[str, Any]:
        data, rows = self.data, self.data.rows
        mast_from, mast_to = int(rows.mast_from[row]), int(rows.mast_to[row])
        return {
            "mast_from": data.mast_code[mast_from] if mast_from >= 0 else None,
            "mast_to": data.mast_code[mast_to] if mast_to >= 0 else None,
            "start_chainage_m": float(rows.start_m[row]),
            "end_chainage_m": float(rows.end_m[row]),
            "span_measurement_id": int(rows.measurement_id[row]),
        }

    def _cycle(
        self,
        kind: str,
        rule_name: str,
        units: Units,
        limit: FloatArray,
        raise_: BoolArray,
        resolve: BoolArray,
        columns_of: Callable[[int], dict[str, Any]],
        engaged: BoolArray | None = None,
    ) -> BoolArray:
        """Raise, update and resolve the alerts of one rule and kind over ``units`` (a unit's
        columns: ``columns_of``); returns which units have an alert after it (or, for
        thresholds, have their condition met)."""
        at, alerts = self.existing.active_of(kind, rule_name, units, self.data)
        has_alert = np.zeros(units.count, dtype=bool)
        has_alert[at] = True
        for unit, alert in zip(at.tolist(), alerts, strict=True):
            if not np.isfinite(limit[unit]):
                continue  # the rule no longer applies (another wire type): left as it is
            columns = columns_of(unit)
            if resolve[unit]:
                if kind == "threshold":
                    reason = "value back above the threshold"
                elif kind == "geometry":
                    reason = f"back within the limit by {GEOMETRY_MARGIN_MM} mm"
                elif engaged is not None and engaged[unit]:
                    reason = "threshold met (the threshold alert takes over)"
                else:
                    reason = "forecast beyond the planning horizon"
                self._resolve(alert, columns, int(units.run_id[unit]), reason)
            elif any(getattr(alert, name) != value for name, value in columns.items()):
                self.updates.append({"id": alert.id, **columns})
        for unit in np.flatnonzero(raise_ & ~has_alert).tolist():
            base = _base(
                kind,
                rule_name,
                self.data.track_id,
                int(units.position[unit]),
                self._stretch(units, unit),
            )
            generation = 0
            if base in self.existing.latest:
                number, status, closed_years = self.existing.latest[base]
                if status in ACTIVE or units.time_years[unit] <= closed_years:
                    continue  # still active under other masts, or not measured since resolved
                generation = number + 1
            self.inserts.append(
                {
                    **columns_of(unit),
                    "track_id": self.data.track_id,
                    "status": "open",
                    "raised_at": self.now,
                    "condition_key": f"{base}/g{generation}",
                }
            )
        return raise_ | (has_alert & ~resolve)

    def _resolve(self, alert: Any, columns: dict[str, Any], run_id: int, reason: str) -> None:
        self.updates.append(
            {
                "id": alert.id,
                **columns,
                "details": {**columns["details"], "resolution": reason},
                "status": "resolved",
                "resolved_at": self.now,
                "resolved_by_run_id": run_id,
            }
        )
        self.resolved += 1

    def _stretch(self, units: Units, unit: int) -> str:
        data = self.data
        if units.scope == SECTION:
            return f"section:{data.section_code[int(units.section[unit])]}"
        row = int(units.row[unit])
        mast_from, mast_to = int(data.rows.mast_from[row]), int(data.rows.mast_to[row])
        if mast_from >= 0 and mast_to >= 0:
            return f"masts:{data.mast_code[mast_from]}>{data.mast_code[mast_to]}"
        return f"m:{data.rows.start_m[row]:.2f}>{data.rows.end_m[row]:.2f}"

    def _columns(
        self,
        kind: str,
        rule: Rule,
        units: Units,
        unit: int,
        limit: FloatArray,
        reach: ReachTimes | None,
    ) -> dict[str, Any]:
        """An alert's columns for one unit: where, what, and the details."""
        data = self.data
        value, threshold = float(units.value_mm[unit]), float(limit[unit])
        wire_type = self.wire_types[int(units.wire_type[unit])]
        worn = wire_type.worn_fraction(
            wire_type.wear_width_mm(
                np.clip(value, wire_type.min_residual_thickness_mm, wire_type.height_mm)
            )
        )
        run_id = int(units.run_id[unit])
        details: dict[str, Any] = {
            "scope": units.scope,
            "policy": rule.name.rpartition("#")[0],
            "rule_number": rule.number,
            "criterion": rule.rule.criterion,
            "action": rule.rule.action,
            "wire_type": wire_type.name,
            "worn_fraction": round(float(worn), 4),
            "threshold_worn_fraction": round(float(rule.worn_fraction[units.wire_type[unit]]), 4),
            "run_id": run_id,
            "run_started_at": iso_utc(data.run_started_at(run_id)),
        }
        if units.scope == SECTION:
            section = int(units.section[unit])
            first, end = int(data.section_first[section]), int(data.section_end[section])
            details |= {
                "anchor_section": data.section_code[section],
                "coverage": round(float(units.coverage[unit]), 3),
            }
            where: dict[str, Any] = {
                "mast_from": data.mast_code[first],
                "mast_to": data.mast_code[end],
                "start_chainage_m": float(data.mast_chainage[first]),
                "end_chainage_m": float(data.mast_chainage[end]),
                "span_measurement_id": None,
            }
        else:
            row = int(units.row[unit])
            details["run_wire"] = int(data.rows.wire[row])
            where = self._where(row)
        if kind == "forecast":
            assert reach is not None and units.fit is not None
            fit = units.fit
            details |= {
                "wear_rate_mm_per_year": round(float(fit.wear_rate_mm_per_year[unit]), 4),
                "wear_rate_se_mm_per_year": round(float(fit.slope_se_mm_per_year[unit]), 4),
                "runs": int(fit.runs[unit]),
                "reach_at": iso_utc(moment_of(float(reach.central[unit]))),
                "reach_earliest": iso_utc(moment_of(float(reach.low[unit]))),
                "reach_latest": iso_utc(moment_of(float(reach.high[unit]))),
                "confidence": CONFIDENCE,
                "horizon_days": self.horizon_days,
            }
        return {
            **where,
            "wire": int(units.position[unit]),
            "rule": rule.name,
            "level": rule.rule.level,
            "kind": kind,
            "value": value,
            "threshold": threshold,
            "details": details,
        }

    def flush(self, result: Evaluation) -> None:
        """Write the track's updates and new alerts (a condition raised meanwhile by another
        evaluation is left to it: ON CONFLICT DO NOTHING)."""
        session = self.session
        for changes in _same_keys(self.updates):
            session.execute(update(Alert), changes)
        level = {row["condition_key"]: row["level"] for row in self.inserts}
        key = ["condition_key"]
        for row in insert_new(session, Alert, self.inserts, key, returning=("id", *key)):
            result.new.append(int(row.id))
            result.new_levels[level[row.condition_key]] += 1
        result.updated += len(self.updates) - self.resolved
        result.resolved += self.resolved


def _base(kind: str, rule: str, track_id: int, position: int, stretch: str) -> str:
    """A condition's key without its generation (a digest when it would not fit)."""
    base = f"{kind}/{rule}/t{track_id}/w{position}/{stretch}"
    if len(base) + 12 > _KEY_LENGTH:  # room for "/g<generation>"
        return "sha256:" + hashlib.sha256(base.encode("utf-8")).hexdigest()
    return base


def _mark_evaluated(
    session: Session, run_ids: IntArray, only: Sequence[int] | None, now: datetime
) -> int:
    """Mark the pending runs of ``run_ids`` (the runs a track's evaluation read; ``only``: of
    these) evaluated at ``now``; returns how many."""
    chosen = set(run_ids.tolist()) if only is None else set(run_ids.tolist()) & set(only)
    if not chosen:
        return 0
    marked = session.connection().execute(
        update(Run)
        .where(Run.id.in_(sorted(chosen)), Run.alerts_evaluated_at.is_(None))
        .values(alerts_evaluated_at=now)
    )
    return marked.rowcount


@dataclass(frozen=True)
class _Setup:
    """What every track of one evaluation is evaluated with."""

    rules: list[Rule]
    geometry: list[tuple[str, GeometryRule]]
    types: list[WireType]
    now: datetime
    horizon_days: float
    line_speeds: Mapping[str, float]

    @classmethod
    def of(
        cls,
        policy: LimitPolicy,
        wire_types: Mapping[str, WireType],
        now: datetime | None,
        horizon_days: float,
        line_speeds: Mapping[str, float] | None,
    ) -> _Setup:
        types = [wire_types[n] for n in sorted(wire_types)]
        return cls(
            rules_of(policy, types),
            geometry_rules_of(policy),
            types,
            now or datetime.now(UTC),
            horizon_days,
            dict(line_speeds or {}),
        )

    def evaluate(
        self,
        session: Session,
        tracks: Sequence[int],
        run_ids: Sequence[int] | None,
        result: Evaluation,
    ) -> None:
        """Evaluate ``tracks`` in the caller's transaction and mark the runs evaluated."""
        if session.get_bind().dialect.name == "postgresql":
            # compiling each track's scan costs a tenth of a second and saves nothing on it
            session.execute(text("SET LOCAL jit = off"))
        for track_id in tracks:
            track = _Track(
                session,
                track_id,
                self.rules,
                self.geometry,
                self.types,
                self.now,
                self.horizon_days,
                self.line_speeds,
            )
            track.evaluate(run_ids, result)
            track.flush(result)
            result.runs += _mark_evaluated(session, track.data.run_id, run_ids, self.now)

    def note_unmeasured_sections(self, result: Evaluation) -> None:
        if result.sections == 0:
            for rule in self.rules:
                if rule.rule.scope == SECTION:
                    result.note(
                        f"rule {rule.name} ({rule.rule.criterion}, anchor section average) was "
                        "evaluated on nothing: no anchor section measured (the mast register's "
                        "column anchor_section names them)"
                    )


def _tracks_of(
    session: Session, run_ids: Sequence[int] | None, result: Evaluation
) -> list[tuple[int, str, str]]:
    """The tracks that runs ``run_ids`` measured (None: every track with a complete run), as
    (id, line code, track code); raises ``UserError`` for a run id that does not exist."""
    query = select(Track.id, Line.code, Track.code).join(Line, Track.line_id == Line.id)
    if run_ids is None:
        measured = select(Run.id).where(Run.track_id == Track.id, Run.status == "complete")
        query = query.where(measured.exists())
    else:
        found = dict(session.execute(select(Run.id, Run.track_id).where(Run.id.in_(run_ids))).all())
        missing = sorted(set(run_ids) - set(found))
        if missing:
            raise UserError(f"no run {missing[0]} in the database")
        if any(track is None for track in found.values()):
            result.note("runs without a track are not evaluated (alerts are kept per track)")
        query = query.where(Track.id.in_({t for t in found.values() if t is not None}))
    return [(int(t), line, code) for t, line, code in session.execute(query.order_by(Track.id))]


def evaluate_alerts(
    session: Session,
    policy: LimitPolicy,
    wire_types: Mapping[str, WireType],
    *,
    run_ids: Sequence[int] | None = None,
    now: datetime | None = None,
    horizon_days: float = DEFAULT_HORIZON_DAYS,
    line_speeds: Mapping[str, float] | None = None,
) -> Evaluation:
    """Evaluate ``policy`` on the spans runs ``run_ids`` measured (None: every span of the
    fleet) at ``now`` (default: the current time), forecasting ``horizon_days`` ahead, and
    mark the runs evaluated (those of ``run_ids``, or every run of the tracks evaluated).
    ``line_speeds`` [km/h] by line code stand in for the register's ``line_speed_kmh``.

    Runs in the caller's transaction (see the module docstring for what it raises, updates and
    resolves). Raises ``UserError`` for a run id that does not exist, or a policy limit that a
    wire type cannot reach.
    """
    setup = _Setup.of(policy, wire_types, now, horizon_days, line_speeds)
    result = Evaluation(policy=policy.name)
    tracks = [t for t, _, _ in _tracks_of(session, run_ids, result)]
    setup.evaluate(session, tracks, run_ids, result)
    setup.note_unmeasured_sections(result)
    return result


def evaluate_tracks(
    engine: Engine,
    policy: LimitPolicy,
    wire_types: Mapping[str, WireType],
    *,
    run_ids: Sequence[int] | None = None,
    now: datetime | None = None,
    horizon_days: float = DEFAULT_HORIZON_DAYS,
    notifications: NotificationConfig | None = None,
    line_speeds: Mapping[str, float] | None = None,
) -> Evaluation:
    """``evaluate_alerts`` with each track in a transaction of its own, the new alerts'
    notifications queued in it (``notifications``: the channels; None: not queued).

    A track whose evaluation raises is rolled back, left pending and listed in ``failed``
    (line and track codes, the reason); the other tracks are still evaluated and committed.
    Announce the new alerts once it returns (``announce_alerts``).
    """
    setup = _Setup.of(policy, wire_types, now, horizon_days, line_speeds)
    result = Evaluation(policy=policy.name)
    with session_scope(engine, read_only=True) as session:
        tracks = _tracks_of(session, run_ids, result)
    for track_id, line, code in tracks:
        part = Evaluation(policy=policy.name)
        try:
            with session_scope(engine) as session:
                setup.evaluate(session, [track_id], run_ids, part)
                if notifications is not None and part.new:
                    queue_notifications(session, notifications)
        except Exception as exc:  # a rule, a plugin or the track's data: the others go on
            result.failed.append(TrackFailure(line, code, one_line(exc)))
            continue
        result.add(part)
    setup.note_unmeasured_sections(result)
    return result


def evaluate_all(
    engine: Engine, settings: Settings, registry: PluginRegistry, now: datetime
) -> Evaluation | None:
    """Every span of the fleet with the configured policy (``[limits]``) and horizon
    (``[maintenance]``) at ``now``, a track at a time with the new alerts' notifications
    queued (``evaluate_tracks``): the scheduler's job. None without a policy (no ``[limits]``
    and no wire types for the standard limits). Announce the new
    alerts once it returns (``announce_alerts``)."""
    policy = choose_policy(settings, registry.limit_policies(), wire_types=registry.wire_types())
    if policy is None:
        return None
    return evaluate_tracks(
        engine,
        policy,
        registry.wire_types(),
        now=now,
        horizon_days=horizon_days(settings),
        notifications=notification_config(settings),
        line_speeds=line_speeds(settings),
    )


@dataclass(frozen=True)
class RunAlerting:
    """What a run's alerts are evaluated with once it is stored: the wear-limit policy (None:
    none configured), checked against the wire types before the run is processed, and the
    planning horizon [days] and the configured line speeds [km/h] by line code."""

    policy: LimitPolicy | None
    wire_types: Mapping[str, WireType]
    horizon_days: float
    line_speeds: Mapping[str, float] = field(default_factory=dict)


def run_alerting(
    settings: Settings, registry: PluginRegistry, policy: LimitPolicy | None = None
) -> RunAlerting:
    """The alerting of the runs a command stores: ``policy``, else the config's ``[limits]``,
    else the wire types' standard limits (``standard_policy``); raises ``UserError`` for a
    limit a wire type cannot reach, before anything is written."""
    wire_types = registry.wire_types()
    policy = policy or choose_policy(settings, registry.limit_policies(), wire_types=wire_types)
    if policy is not None:
        check_policy(policy, wire_types)
    return RunAlerting(policy, wire_types, horizon_days(settings), line_speeds(settings))


def evaluate_stored_run(
    alerting: RunAlerting,
    engine: Engine,
    settings: Settings,
    registry: PluginRegistry,
    run_id: int,
) -> Evaluation | None:
    """Evaluate a committed run's spans (None without a policy), in a transaction of its own
    with the new alerts' notifications queued, then announce the new alerts. A failure of its
    track's evaluation is in ``failed`` (the run stays pending)."""
    if alerting.policy is None:
        return None
    result = evaluate_tracks(
        engine,
        alerting.policy,
        alerting.wire_types,
        run_ids=[run_id],
        horizon_days=alerting.horizon_days,
        notifications=notification_config(settings),
        line_speeds=alerting.line_speeds,
    )
    announce_alerts(engine, registry, result.new)
    return result


def run_alerts_lines(result: Evaluation | None) -> list[str]:
    """The alert lines of a stored run's summary."""
    if result is None:
        return ["alerts     not evaluated: no wear-limit policy ([limits] policy in the config)"]
    if result.failed:
        return ["alerts     not evaluated"]
    standard = (
        ["           no [limits] policy in the config: each wire type's standard limit "
         "(catenary wire-types NAME)"]
        if result.policy == STANDARD_POLICY
        else []
    )  # fmt: skip
    return [
        f"alerts     {result.summary()} (policy {result.policy})",
        *standard,
        *(f"           {note}" for note in result.notes),
    ]
