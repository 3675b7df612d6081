"""Maintenance alerts: the operator's wear limits evaluated on the fleet's span histories.

**Rules.** Each rule of the configured policy (``catenary.limits``, ``[limits]``) is a
residual thickness per wire type (``thresholds``). A ``local`` rule is met by a history
(``catenary.maintenance.history``: a span and wire across runs, from its last repair on) when the
span's
minimum residual thickness at its latest run reaches the threshold; an
``anchor_section_average`` rule by an anchor section when the samples-weighted mean residual
thickness of its spans, at the latest run that measured it, does. (That is the thickness of
the average, not the average worn fraction: where wear is concentrated in a few spans the
section's average worn fraction is somewhat higher.)

**Forecasts.** Each local rule also has a forecast (``catenary.maintenance.forecast``): the
history's wear
rate (least squares over its runs, with its standard error) and the date its line reaches the
threshold, with an interval from the rate's 95 % confidence interval. A forecast alert is
raised when that date falls within the planning horizon (``[maintenance] horizon_days``,
default 365 days from the evaluation) while the threshold is not met; it is resolved when
even the interval's earliest date lies beyond the horizon, or when the threshold is met (the
threshold alert takes over).

**Life cycle.** open -> acknowledged (by whom, when) -> resolved: by a later run whose value is
back above the threshold by ``RESOLVE_MARGIN_MM`` (so that noise at the threshold does not
open and close alerts in turn), by a repair covering it (``catenary.maintenance.actions``), or by
hand. A condition's ``condition_key`` is
``{kind}/{policy}#{rule}/t{track id}/w{position}/{stretch}/g{generation}``, the stretch being
``masts:{from}>{to}``, ``m:{start}>{end}`` (chainages, spans measured without a register) or
``section:{code}``; the generation counts the condition's earlier alerts, all resolved, so a
recurrence after a resolution is a new alert, raised only from a run that started after that
resolution (the repair's time, the resolving run's, or the moment it was resolved by hand).
An open or acknowledged alert is updated (latest value), never raised again, whatever runs are
evaluated in whatever order or twice; an evaluation that finds nothing new writes nothing.

**Scale.** One track at a time: its span measurements in one query (binary COPY on PostgreSQL,
``catenary.storage.columns``), then vectorised over its rows and histories; Python work is per
alert, never per span (``benchmarks/alerts_fleet.py``).
"""

from __future__ import annotations

import hashlib
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import (
    BigInteger,
    Float,
    Integer,
    and_,
    case,
    cast,
    func,
    literal,
    select,
    text,
    update,
)
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.engine import Engine
from sqlalchemy.orm import Session, aliased, joinedload

from catenary.config import Settings
from catenary.errors import UserError
from catenary.limits import LEVELS, LimitPolicy, LimitRule, choose_policy, thresholds
from catenary.maintenance.actions import REPAIR_KINDS
from catenary.maintenance.forecast import (
    CONFIDENCE,
    ReachTimes,
    WearFit,
    moment_of,
    reach_times,
    years_since_epoch,
)
from catenary.maintenance.history import Repairs, SpanRows, section_measurements, span_histories
from catenary.maintenance.notifications import notification_config, queue_notifications
from catenary.storage.columns import fetch_columns
from catenary.storage.database import session_scope
from catenary.storage.models import (
    ALERT_STATUSES,
    NAME_LENGTH,
    Alert,
    Line,
    MaintenanceAction,
    Mast,
    Run,
    SpanMeasurement,
    Track,
)
from catenary.wiretype import WireType

if TYPE_CHECKING:
    from catenary.plugins import PluginRegistry

__all__ = [
    "ACTIVE",
    "DEFAULT_HORIZON_DAYS",
    "RESOLVE_MARGIN_MM",
    "Evaluation",
    "RunAlerting",
    "acknowledge_alert",
    "alert_record",
    "announce_alerts",
    "check_policy",
    "evaluate_alerts",
    "evaluate_all",
    "evaluate_stored_run",
    "horizon_days",
    "list_alerts",
    "new_alerts_since",
    "resolve_alert",
    "run_alerting",
    "run_alerts_lines",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

RESOLVE_MARGIN_MM = 0.1
"""A threshold alert is resolved by a run only when its value is this far back above the
threshold [mm]: the measurement's worst-case error (DESIGN.md's 0.10 mm)."""

DEFAULT_HORIZON_DAYS = 365.0
"""Planning horizon of the forecasts without ``[maintenance] horizon_days``."""

ACTIVE = ("open", "acknowledged")
"""Statuses of an alert still to be dealt with."""

_MAINTENANCE_KEYS = {"horizon_days"}
_KEY_LENGTH = 255  # Alert.condition_key
_DAYS_PER_YEAR = 365.25
_LOCAL, _SECTION = "local", "anchor_section_average"


# --- configuration --------------------------------------------------------------------------


def horizon_days(settings: Settings) -> float:
    """The planning horizon [days]: ``[maintenance] horizon_days``, default 365."""
    section = settings.sections.get("maintenance")
    if section is None:
        return DEFAULT_HORIZON_DAYS
    where = f"{settings.config_path or 'config'}: [maintenance]"
    if not isinstance(section, Mapping):
        raise UserError(f"{where} must be a table")
    unknown = sorted(set(section) - _MAINTENANCE_KEYS)
    if unknown:
        known = ", ".join(sorted(_MAINTENANCE_KEYS))
        raise UserError(f"{where}: unknown key {unknown[0]!r} (known: {known})")
    value = section.get("horizon_days", DEFAULT_HORIZON_DAYS)
    if isinstance(value, bool) or not isinstance(value, int | float) or not 1 <= value <= 36525:
        raise UserError(
            f"{where}: horizon_days must be a number of days from 1 to 36525, not {value!r}"
        )
    return float(value)


# --- the rules ------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Rule:
    """A policy rule with its threshold per wire type (index into the evaluation's wire type
    names; NaN where the rule does not apply)."""

    number: int
    rule: LimitRule
    name: str  # "policy#number", Alert.rule
    thickness_mm: FloatArray  # (w,)
    worn_fraction: FloatArray  # (w,)

    def limit(self, wire_type: IntArray) -> FloatArray:
        """The threshold [mm] for each wire type index (-1 and -2: NaN)."""
        known = wire_type >= 0
        return np.where(known, self.thickness_mm[np.where(known, wire_type, 0)], np.nan)

    def met(self, value_mm: FloatArray, limit_mm: FloatArray) -> BoolArray:
        return np.asarray(value_mm <= limit_mm if self.rule.inclusive else value_mm < limit_mm)


def _rules(policy: LimitPolicy, wire_types: Sequence[WireType]) -> list[_Rule]:
    if len(policy.name) + 8 > NAME_LENGTH:
        raise UserError(
            f"policy name {policy.name[:40]!r}...: at most {NAME_LENGTH - 8} characters"
        )
    count = len(wire_types)
    thickness = {n: np.full(count, np.nan) for n in range(1, len(policy.rules) + 1)}
    fraction = {n: np.full(count, np.nan) for n in range(1, len(policy.rules) + 1)}
    for index, wire in enumerate(wire_types):
        for t in thresholds(wire, policy):
            thickness[t.rule_number][index] = t.residual_thickness_mm
            fraction[t.rule_number][index] = t.worn_fraction
    return [
        _Rule(n, rule, f"{policy.name}#{n}", thickness[n], fraction[n])
        for n, rule in enumerate(policy.rules, 1)
    ]


def check_policy(policy: LimitPolicy, wire_types: Mapping[str, WireType]) -> None:
    """Raise ``UserError`` unless every rule of ``policy`` can be evaluated on every wire type
    (before anything is written: ``evaluate_alerts`` would refuse it)."""
    _rules(policy, [wire_types[name] for name in sorted(wire_types)])


# --- one track's data -----------------------------------------------------------------------


def _lookup(keys: IntArray, values: NDArray[np.generic]) -> IntArray:
    """Index of each of ``values`` in the sorted, unique ``keys``; -1 where absent."""
    if keys.shape[0] == 0:
        return np.full(values.shape, -1, dtype=np.int64)
    at = np.minimum(np.searchsorted(keys, values), keys.shape[0] - 1)
    return np.where(keys[at] == values, at, -1).astype(np.int64)


class _TrackData:
    """A track's masts and anchor sections, complete runs, span rows and repairs.

    A span row names its masts and wire type by name; the rows are matched to the masts and
    wire types by a key: on PostgreSQL the names' 64-bit hash (``hashtextextended``: the server
    hashes each row's names instead of joining the masts twice and comparing wire type names,
    which halves the query; two names sharing a hash, about one track in 10**13, is refused),
    elsewhere the masts' ids, joined, and the wire types' indices.
    """

    def __init__(self, session: Session, track_id: int, wire_type_names: Sequence[str]) -> None:
        self.track_id = track_id
        self.hashed = session.get_bind().dialect.name == "postgresql"
        key = func.hashtextextended(Mast.code, 0) if self.hashed else Mast.id
        masts = session.execute(
            select(Mast.id, Mast.code, Mast.chainage_m, Mast.anchor_section, key.label("key"))
            .where(Mast.track_id == track_id)
            .order_by(Mast.chainage_m)
        ).all()
        self.mast_key = np.array([m.key for m in masts], dtype=np.int64)
        if np.unique(self.mast_key).shape[0] != self.mast_key.shape[0]:
            raise RuntimeError(f"track {track_id}: two mast codes share a 64-bit hash")
        self.mast_code: list[str] = [m.code for m in masts]
        self.mast_chainage = np.array([m.chainage_m for m in masts], dtype=np.float64)
        self._sections([m.anchor_section for m in masts])
        runs = session.execute(
            select(Run.id, Run.started_at, Run.direction)
            .where(Run.track_id == track_id, Run.status == "complete")
            .order_by(Run.id)
        ).all()
        self.run_id = np.array([r.id for r in runs], dtype=np.int64)
        self.run_started: list[datetime] = [r.started_at for r in runs]
        self.run_years = years_since_epoch(self.run_started)
        self.run_sign = np.array([-1.0 if r.direction == "decreasing" else 1.0 for r in runs])
        self.rows = self._rows(session, wire_type_names)
        repairs = session.execute(
            select(
                MaintenanceAction.from_chainage_m,
                MaintenanceAction.to_chainage_m,
                MaintenanceAction.wire,
                MaintenanceAction.performed_at,
            ).where(
                MaintenanceAction.track_id == track_id, MaintenanceAction.kind.in_(REPAIR_KINDS)
            )
        ).all()
        self.repairs = Repairs(
            from_m=np.array([a.from_chainage_m for a in repairs], dtype=np.float64),
            to_m=np.array([a.to_chainage_m for a in repairs], dtype=np.float64),
            wire=np.array([-1 if a.wire is None else a.wire for a in repairs], dtype=np.int64),
            time_years=years_since_epoch([a.performed_at for a in repairs]),
        )

    def _sections(self, codes: list[str | None]) -> None:
        """Each section's code, first mast and end mast (the one after its last mast)."""
        self.section_code = sorted({c for c in codes if c is not None})
        index = {code: k for k, code in enumerate(self.section_code)}
        self.mast_section = np.array([-1 if c is None else index[c] for c in codes], np.int64)
        k = len(self.section_code)
        named = np.flatnonzero(self.mast_section >= 0)
        first = np.full(k, len(codes), dtype=np.int64)
        last = np.full(k, -1, dtype=np.int64)
        np.minimum.at(first, self.mast_section[named], named)
        np.maximum.at(last, self.mast_section[named], named)
        self.section_first = first
        self.section_end = np.minimum(last + 1, len(codes) - 1)
        self.section_length_m = (
            self.mast_chainage[self.section_end] - self.mast_chainage[first] if k else np.zeros(0)
        )

    def _rows(self, session: Session, wire_type_names: Sequence[str]) -> SpanRows:
        sm = SpanMeasurement
        start, end = aliased(Mast), aliased(Mast)
        if self.hashed:
            keys = [
                cast(func.coalesce(func.hashtextextended(name, 0), 0), BigInteger).label(label)
                for name, label in (
                    (sm.mast_from, "mast_from"),
                    (sm.mast_to, "mast_to"),
                    (sm.wire_type, "wire_type"),
                )
            ]
            hashes = [func.hashtextextended(literal(n), 0) for n in wire_type_names]
            names = session.execute(select(*hashes)).one() if hashes else ()
            type_key = np.array(names, dtype=np.int64)
        else:
            wire_type = case(
                {name: number for number, name in enumerate(wire_type_names)},
                value=sm.wire_type,
                else_=-1,
            )
            keys = [
                func.coalesce(start.id, 0).label("mast_from"),
                func.coalesce(end.id, 0).label("mast_to"),
                cast(wire_type, Integer).label("wire_type"),
            ]
            type_key = np.arange(len(wire_type_names), dtype=np.int64)
        if np.unique(type_key).shape[0] != type_key.shape[0]:
            raise RuntimeError("two wire type names share a 64-bit hash")
        query = (
            select(
                sm.id,
                sm.run_id,
                sm.span,
                sm.wire,
                *keys,
                sm.start_chainage_m,
                sm.end_chainage_m,
                sm.min_residual_thickness_mm,
                sm.mean_residual_thickness_mm,
                sm.samples,
                cast(sm.stagger_min_mm + sm.stagger_max_mm, Float).label("stagger_sum_mm"),
            )
            # through the track's runs: each run's rows lie together, read in their order
            .select_from(Run)
            .join(sm, sm.run_id == Run.id)
            .where(Run.track_id == self.track_id, Run.status == "complete")
        )
        if not self.hashed:
            query = query.outerjoin(
                start, and_(start.track_id == Run.track_id, start.code == sm.mast_from)
            ).outerjoin(end, and_(end.track_id == Run.track_id, end.code == sm.mast_to))
        c = fetch_columns(session.connection(), query)
        run = _lookup(self.run_id, c["run_id"])
        keep = np.flatnonzero(run >= 0)  # a run completed since the runs were read: left out
        run = run[keep]

        def local(key: NDArray[np.generic], known: IntArray) -> IntArray:
            """Index into ``known`` of each kept row's ``key``; -1 for none."""
            order = np.argsort(known)
            found = _lookup(known[order], key[keep])
            return np.where(found >= 0, order[np.maximum(found, 0)], -1).astype(np.int64)

        return SpanRows(
            measurement_id=c["id"][keep].astype(np.int64),
            run_id=c["run_id"][keep].astype(np.int64),
            span=c["span"][keep].astype(np.int64),
            wire=c["wire"][keep].astype(np.int64),
            mast_from=local(c["mast_from"], self.mast_key),
            mast_to=local(c["mast_to"], self.mast_key),
            start_m=c["start_chainage_m"][keep].astype(np.float64),
            end_m=c["end_chainage_m"][keep].astype(np.float64),
            min_thickness_mm=c["min_residual_thickness_mm"][keep].astype(np.float64),
            mean_thickness_mm=c["mean_residual_thickness_mm"][keep].astype(np.float64),
            samples=c["samples"][keep].astype(np.int64),
            stagger_sum_mm=c["stagger_sum_mm"][keep].astype(np.float64),
            wire_type=local(c["wire_type"], type_key),
            time_years=self.run_years[run],
            direction=self.run_sign[run],
        )

    def mast_index(self, codes: Sequence[str | None]) -> IntArray:
        """Index into this track's masts of each mast code; -1 for None or an unknown code."""
        order = np.argsort(np.array(self.mast_code, dtype=object))
        known = np.array(self.mast_code, dtype=object)[order]
        text = np.array(["" if c is None else c for c in codes], dtype=object)
        if known.shape[0] == 0:
            return np.full(text.shape[0], -1, dtype=np.int64)
        at = np.minimum(np.searchsorted(known, text), known.shape[0] - 1)
        hit = (known[at] == text) & np.array([c is not None for c in codes], dtype=bool)
        return np.where(hit, order[at], -1).astype(np.int64)

    def run_started_at(self, run_id: int) -> datetime:
        return self.run_started[int(_lookup(self.run_id, np.array([run_id]))[0])]


# --- what is evaluated: histories and anchor sections ---------------------------------------


def _history_keys(
    mast_from: IntArray,
    mast_to: IntArray,
    start_m: FloatArray,
    end_m: FloatArray,
    position: IntArray,
) -> FloatArray:
    """Identity of a span and position, ``(k, 4)``: (0, mast indices) or, measured without a
    register, (1, chainages); then the position."""
    by_masts = mast_from >= 0
    return np.column_stack(
        [
            (~by_masts).astype(np.float64),
            np.where(by_masts, mast_from, start_m),
            np.where(by_masts, mast_to, end_m),
            position.astype(np.float64),
        ]
    )


def _match(units: FloatArray, queries: FloatArray) -> IntArray:
    """The row of ``units`` (unique rows) equal to each row of ``queries``; -1 for none."""
    if queries.shape[0] == 0 or units.shape[0] == 0:
        return np.full(queries.shape[0], -1, dtype=np.int64)
    _, inverse = np.unique(np.vstack([units, queries]), axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    owner = np.full(int(inverse.max()) + 1, -1, dtype=np.int64)
    owner[inverse[: units.shape[0]]] = np.arange(units.shape[0])
    return owner[inverse[units.shape[0] :]]


@dataclass(frozen=True)
class _Units:
    """What one scope evaluates on a track, one entry per unit ``(k,)``: the histories
    (``local``) or anchor sections (``anchor_section_average``) and their latest value.

    ``keys`` ``(k, c)`` identify them (to match the active alerts); ``row`` is a history's
    latest span row and ``fit`` its line, ``section`` a section's index (-1 for a history).
    """

    scope: str
    keys: FloatArray
    position: IntArray
    run_id: IntArray
    time_years: FloatArray
    value_mm: FloatArray
    wire_type: IntArray
    row: IntArray
    section: IntArray
    coverage: FloatArray
    fit: WearFit | None

    @property
    def count(self) -> int:
        return int(self.position.shape[0])


def _units(track: _TrackData, run_ids: Sequence[int] | None) -> tuple[_Units, _Units]:
    """The track's histories and anchor sections: all, or those runs ``run_ids`` measured."""
    rows = track.rows
    hist = span_histories(rows, track.repairs)
    sections = section_measurements(rows, hist, track.mast_section, track.section_length_m)
    chosen = hist.latest >= 0
    chosen_sections = np.ones(sections.section.shape[0], dtype=bool)
    if run_ids is not None:
        in_run = np.isin(rows.run_id, np.asarray(run_ids, dtype=np.int64))
        touched = np.zeros(hist.histories, dtype=bool)
        touched[hist.row_history[in_run & (hist.row_history >= 0)]] = True
        chosen &= touched
        with_mast = in_run & (rows.mast_from >= 0)
        chosen_sections = np.isin(sections.section, track.mast_section[rows.mast_from[with_mast]])
    h = np.flatnonzero(chosen)
    row = hist.latest[h]
    local = _Units(
        scope=_LOCAL,
        keys=_history_keys(
            hist.mast_from[h],
            hist.mast_to[h],
            rows.start_m[row],
            rows.end_m[row],
            hist.position[h],
        ),
        position=hist.position[h],
        run_id=rows.run_id[row],
        time_years=rows.time_years[row],
        value_mm=rows.min_thickness_mm[row],
        wire_type=rows.wire_type[row],
        row=row,
        section=np.full(h.shape[0], -1, dtype=np.int64),
        coverage=np.ones(h.shape[0]),
        fit=hist.fit.take(h),
    )
    s = np.flatnonzero(chosen_sections)
    section = _Units(
        scope=_SECTION,
        keys=np.column_stack([sections.section[s], sections.position[s]]).astype(np.float64),
        position=sections.position[s],
        run_id=sections.run_id[s],
        time_years=sections.time_years[s],
        value_mm=sections.mean_thickness_mm[s],
        wire_type=sections.wire_type[s],
        row=np.full(s.shape[0], -1, dtype=np.int64),
        section=sections.section[s],
        coverage=sections.coverage[s],
        fit=None,
    )
    return local, section


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
        self, kind: str, rule: str, units: _Units, track: _TrackData
    ) -> tuple[IntArray, list[Any]]:
        """The units that have an active alert of ``kind`` and ``rule``, and those alerts."""
        alerts = [
            a
            for a in self.active
            if a.kind == kind and a.rule == rule and (a.details or {}).get("scope") == units.scope
        ]
        if not alerts:
            return np.zeros(0, dtype=np.int64), []
        if units.scope == _SECTION:
            index = {code: k for k, code in enumerate(track.section_code)}
            section = [index.get(str((a.details or {}).get("anchor_section")), -1) for a in alerts]
            keys = np.column_stack([section, [a.wire for a in alerts]]).astype(np.float64)
        else:
            mast_from = track.mast_index([a.mast_from for a in alerts])
            mast_to = track.mast_index([a.mast_to for a in alerts])
            keys = _history_keys(
                mast_from,
                mast_to,
                np.array([a.start_chainage_m for a in alerts], dtype=np.float64),
                np.array([a.end_chainage_m for a in alerts], dtype=np.float64),
                np.array([a.wire for a in alerts], dtype=np.int64),
            )
            named = np.array([a.mast_from is not None for a in alerts], dtype=bool)
            keys[named & (mast_from < 0), 0] = -1.0  # a mast no longer known: matches nothing
        unit = _match(units.keys, keys)
        found = np.flatnonzero(unit >= 0)
        return unit[found], [alerts[i] for i in found.tolist()]


# --- evaluation -----------------------------------------------------------------------------


@dataclass
class Evaluation:
    """What an evaluation did: the histories (span-wires) and anchor sections it looked at,
    the ids of the alerts it raised, how many it updated and resolved, and notes on what it
    could not evaluate (each said once)."""

    policy: str
    spans: int = 0
    sections: int = 0
    new: list[int] = field(default_factory=list)
    new_levels: Counter[str] = field(default_factory=Counter)
    updated: int = 0
    resolved: int = 0
    notes: list[str] = field(default_factory=list)

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
        rules: list[_Rule],
        wire_types: Sequence[WireType],
        now: datetime,
        horizon_days: float,
    ) -> None:
        self.session, self.rules, self.wire_types, self.now = session, rules, wire_types, now
        self.data = _TrackData(session, track_id, [w.name for w in wire_types])
        self.existing = _Existing.load(session, track_id)
        self.horizon_end_years = float(years_since_epoch([now])[0]) + horizon_days / _DAYS_PER_YEAR
        self.horizon_days = horizon_days
        self.inserts: list[dict[str, Any]] = []
        self.updates: list[dict[str, Any]] = []
        self.resolved = 0

    def evaluate(self, run_ids: Sequence[int] | None, result: Evaluation) -> None:
        if self.data.rows.rows == 0:
            return
        local, section = _units(self.data, run_ids)
        result.spans += local.count
        result.sections += section.count
        if np.any(local.wire_type < 0):
            result.note("span measurements of a wire type no plugin registers are not evaluated")
        if np.any(section.wire_type == -2):
            result.note("anchor sections whose spans are of different wire types are not evaluated")
        for rule in self.rules:
            units = local if rule.rule.scope == _LOCAL else section
            limit = rule.limit(units.wire_type)
            applies = np.isfinite(limit)
            met = rule.met(units.value_mm, limit) & applies
            clear = applies & (units.value_mm > limit + RESOLVE_MARGIN_MM)
            engaged = self._cycle("threshold", rule, units, limit, met, clear, None)
            if units.fit is None:
                continue
            reach = reach_times(units.fit, np.where(applies, limit, np.nan))
            within = reach.central <= self.horizon_end_years
            beyond = reach.low > self.horizon_end_years
            self._cycle(
                "forecast", rule, units, limit, within & ~engaged, beyond | engaged, reach, engaged
            )

    def _cycle(
        self,
        kind: str,
        rule: _Rule,
        units: _Units,
        limit: FloatArray,
        raise_: BoolArray,
        resolve: BoolArray,
        reach: ReachTimes | None,
        engaged: BoolArray | None = None,
    ) -> BoolArray:
        """Raise, update and resolve the alerts of one rule and kind over ``units``; returns
        which units have an alert after it (or, for thresholds, have their condition met)."""
        at, alerts = self.existing.active_of(kind, rule.name, units, self.data)
        has_alert = np.zeros(units.count, dtype=bool)
        has_alert[at] = True
        for unit, alert in zip(at.tolist(), alerts, strict=True):
            if not np.isfinite(limit[unit]):
                continue  # the rule no longer applies (another wire type): left as it is
            columns = self._columns(kind, rule, units, unit, limit, reach)
            if resolve[unit]:
                if kind == "threshold":
                    reason = "value back above the threshold"
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
                rule.name,
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
                    **self._columns(kind, rule, units, unit, limit, reach),
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

    def _stretch(self, units: _Units, unit: int) -> str:
        data = self.data
        if units.scope == _SECTION:
            return f"section:{data.section_code[int(units.section[unit])]}"
        row = int(units.row[unit])
        mast_from, mast_to = int(data.rows.mast_from[row]), int(data.rows.mast_to[row])
        if mast_from >= 0 and mast_to >= 0:
            return f"masts:{data.mast_code[mast_from]}>{data.mast_code[mast_to]}"
        return f"m:{data.rows.start_m[row]:.2f}>{data.rows.end_m[row]:.2f}"

    def _columns(
        self,
        kind: str,
        rule: _Rule,
        units: _Units,
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
            "run_started_at": _iso(data.run_started_at(run_id)),
        }
        if units.scope == _SECTION:
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
            rows = data.rows
            mast_from, mast_to = int(rows.mast_from[row]), int(rows.mast_to[row])
            details["run_wire"] = int(rows.wire[row])
            where = {
                "mast_from": data.mast_code[mast_from] if mast_from >= 0 else None,
                "mast_to": data.mast_code[mast_to] if mast_to >= 0 else None,
                "start_chainage_m": float(rows.start_m[row]),
                "end_chainage_m": float(rows.end_m[row]),
                "span_measurement_id": int(rows.measurement_id[row]),
            }
        if kind == "forecast":
            assert reach is not None and units.fit is not None
            fit = units.fit
            details |= {
                "wear_rate_mm_per_year": round(float(fit.wear_rate_mm_per_year[unit]), 4),
                "wear_rate_se_mm_per_year": round(float(fit.slope_se_mm_per_year[unit]), 4),
                "runs": int(fit.runs[unit]),
                "reach_at": _iso(moment_of(float(reach.central[unit]))),
                "reach_earliest": _iso(moment_of(float(reach.low[unit]))),
                "reach_latest": _iso(moment_of(float(reach.high[unit]))),
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
        if self.inserts:
            dialect = postgresql if session.get_bind().dialect.name == "postgresql" else sqlite
            statement = (
                dialect.insert(Alert)
                .on_conflict_do_nothing(index_elements=["condition_key"])
                .returning(Alert.id, Alert.condition_key)
            )
            level = {row["condition_key"]: row["level"] for row in self.inserts}
            for row in session.execute(statement, self.inserts).all():
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


def _iso(moment: datetime | None) -> str | None:
    return None if moment is None else moment.astimezone(UTC).isoformat(timespec="seconds")


def evaluate_alerts(
    session: Session,
    policy: LimitPolicy,
    wire_types: Mapping[str, WireType],
    *,
    run_ids: Sequence[int] | None = None,
    now: datetime | None = None,
    horizon_days: float = DEFAULT_HORIZON_DAYS,
) -> Evaluation:
    """Evaluate ``policy`` on the spans runs ``run_ids`` measured (None: every span of the
    fleet) at ``now`` (default: the current time), forecasting ``horizon_days`` ahead.

    Runs in the caller's transaction (see the module docstring for what it raises, updates and
    resolves). Raises ``UserError`` for a run id that does not exist, or a policy limit that a
    wire type cannot reach.
    """
    now = now or datetime.now(UTC)
    names = sorted(wire_types)
    types = [wire_types[n] for n in names]
    rules = _rules(policy, types)
    result = Evaluation(policy=policy.name)
    tracks: list[int]
    if run_ids is None:
        tracks = list(
            session.scalars(
                select(Run.track_id.cast(Integer))
                .where(Run.track_id.is_not(None), Run.status == "complete")
                .distinct()
                .order_by(Run.track_id)
            )
        )
    else:
        found = dict(session.execute(select(Run.id, Run.track_id).where(Run.id.in_(run_ids))).all())
        missing = sorted(set(run_ids) - set(found))
        if missing:
            raise UserError(f"no run {missing[0]} in the database")
        if any(track is None for track in found.values()):
            result.note("runs without a track are not evaluated (alerts are kept per track)")
        tracks = sorted({t for t in found.values() if t is not None})
    if session.get_bind().dialect.name == "postgresql":
        # compiling each track's scan costs a tenth of a second and saves nothing on it
        session.execute(text("SET LOCAL jit = off"))
    for track_id in tracks:
        track = _Track(session, track_id, rules, types, now, horizon_days)
        track.evaluate(run_ids, result)
        track.flush(result)
    if result.sections == 0:
        for rule in rules:
            if rule.rule.scope == _SECTION:
                result.note(
                    f"rule {rule.name} ({rule.rule.criterion}, anchor section average) was "
                    "evaluated on nothing: no anchor section measured (the mast register's "
                    "column anchor_section names them)"
                )
    return result


def evaluate_all(
    session: Session, settings: Settings, registry: PluginRegistry, now: datetime
) -> Evaluation | None:
    """Every span of the fleet with the configured policy (``[limits]``) and horizon
    (``[maintenance]``) at ``now``: the scheduler's job. None without a policy. Runs in the
    caller's transaction; announce the new alerts once it is committed (``announce_alerts``)."""
    policy = choose_policy(settings, registry.limit_policies())
    if policy is None:
        return None
    return evaluate_alerts(
        session, policy, registry.wire_types(), now=now, horizon_days=horizon_days(settings)
    )


@dataclass(frozen=True)
class RunAlerting:
    """What a run's alerts are evaluated with once it is stored: the wear-limit policy (None:
    none configured), checked against the wire types before the run is processed, and the
    planning horizon [days]."""

    policy: LimitPolicy | None
    wire_types: Mapping[str, WireType]
    horizon_days: float


def run_alerting(
    settings: Settings, registry: PluginRegistry, policy: LimitPolicy | None = None
) -> RunAlerting:
    """The alerting of the runs a command stores: ``policy``, else the config's ``[limits]``;
    raises ``UserError`` for a limit a wire type cannot reach, before anything is written."""
    policy = policy or choose_policy(settings, registry.limit_policies())
    wire_types = registry.wire_types()
    if policy is not None:
        check_policy(policy, wire_types)
    return RunAlerting(policy, wire_types, horizon_days(settings))


def evaluate_stored_run(
    alerting: RunAlerting,
    engine: Engine,
    settings: Settings,
    registry: PluginRegistry,
    run_id: int,
) -> Evaluation | None:
    """Evaluate a committed run's spans (None without a policy), in a transaction of its own
    with the new alerts' notifications queued, then announce the new alerts."""
    if alerting.policy is None:
        return None
    with session_scope(engine) as session:
        result = evaluate_alerts(
            session,
            alerting.policy,
            alerting.wire_types,
            run_ids=[run_id],
            horizon_days=alerting.horizon_days,
        )
        queue_notifications(session, notification_config(settings))
    announce_alerts(engine, registry, result.new)
    return result


def run_alerts_lines(result: Evaluation | None) -> list[str]:
    """The alert lines of a stored run's summary."""
    if result is None:
        return ["alerts     not evaluated: no wear-limit policy ([limits] policy in the config)"]
    return [
        f"alerts     {result.summary()} (policy {result.policy})",
        *(f"           {note}" for note in result.notes),
    ]


# --- the life cycle by hand, and what others read ---------------------------------------


_SEVERITY = {level: rank for rank, level in enumerate(reversed(LEVELS))}  # critical first


def list_alerts(
    session: Session,
    status: str = "active",
    line: str | None = None,
    levels: Sequence[str] = (),
) -> list[Alert]:
    """Alerts as a planner reads them: most severe level first, then line, track, chainage.

    ``status``: one of ``ALERT_STATUSES``, ``active`` (open and acknowledged) or ``all``.
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
    if levels:
        query = query.where(Alert.level.in_(levels))
    severity = case(_SEVERITY, value=Alert.level, else_=len(_SEVERITY))
    kind = case({"threshold": 0}, value=Alert.kind, else_=1)
    return list(
        session.scalars(
            query.order_by(
                severity, Line.code, Track.code, Alert.start_chainage_m, Alert.wire, kind, Alert.id
            )
        )
    )


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


def acknowledge_alert(session: Session, alert_id: int, by: str, now: datetime) -> Alert:
    """Mark open alert ``alert_id`` acknowledged by ``by`` at ``now``."""
    name = _name(by)
    alert = _alert(session, alert_id)
    if alert.status == "acknowledged":
        raise UserError(
            f"alert {alert_id} is already acknowledged (by {alert.acknowledged_by} at "
            f"{_iso(alert.acknowledged_at)})"
        )
    if alert.status == "resolved":
        raise UserError(f"alert {alert_id} is resolved (at {_iso(alert.resolved_at)})")
    alert.status, alert.acknowledged_by, alert.acknowledged_at = "acknowledged", name, now
    session.flush()
    return alert


def resolve_alert(
    session: Session, alert_id: int, by: str, now: datetime, note: str | None = None
) -> Alert:
    """Resolve alert ``alert_id`` by hand: by ``by`` at ``now``, with an optional ``note``.

    The condition is raised again (a new alert) only from a run that starts after ``now``.
    """
    name = _name(by)
    alert = _alert(session, alert_id)
    if alert.status == "resolved":
        raise UserError(f"alert {alert_id} is already resolved (at {_iso(alert.resolved_at)})")
    alert.status, alert.resolved_at = "resolved", now
    extra = {"resolution": "by hand", "resolved_by": name} | ({"note": note} if note else {})
    alert.details = {**(alert.details or {}), **extra}
    session.flush()
    return alert


def new_alerts_since(session: Session, after_id: int = 0) -> list[Alert]:
    """Alerts raised after alert ``after_id`` (ids grow), in the order they were raised: what
    a notifier that remembers the last id it sent has to send."""
    return list(session.scalars(select(Alert).where(Alert.id > after_id).order_by(Alert.id)))


def alert_record(alert: Alert) -> dict[str, Any]:
    """An alert's stored fields, with its line and track codes (``line``, ``track``): what
    the ``catenary_alert_raised`` hook receives."""
    record = {c.key: getattr(alert, c.key) for c in Alert.__table__.columns}
    record["line"], record["track"] = alert.track.line.code, alert.track.code
    return record


def announce_alerts(engine: Engine, registry: PluginRegistry, alert_ids: Sequence[int]) -> None:
    """Call every plugin's ``catenary_alert_raised`` hook with each committed alert of
    ``alert_ids`` (``alert_record``), in the order they were raised."""
    chunk = 5000  # bound the IN list (SQLite's limit on variables)
    for start in range(0, len(alert_ids), chunk):
        with session_scope(engine) as session:
            found = session.scalars(
                select(Alert)
                .where(Alert.id.in_(alert_ids[start : start + chunk]))
                .options(joinedload(Alert.track).joinedload(Track.line))
                .order_by(Alert.id)
            )
            records = [alert_record(alert) for alert in found]
        for record in records:
            registry.alert_raised(record)
