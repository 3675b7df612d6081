"""One track's data that alerts read: its span measurements, masts, repairs and alerts, and
the units evaluated (span histories and anchor sections)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import (
    BigInteger,
    ColumnElement,
    Float,
    Integer,
    and_,
    case,
    cast,
    func,
    literal,
    select,
)
from sqlalchemy.orm import Session, aliased

from catenary.arrays import FloatArray, IntArray, take
from catenary.domain import REPAIR_KINDS
from catenary.maintenance.alerts.geometry import GeometryRows, MastGeometry
from catenary.maintenance.alerts.rules import LOCAL, SECTION
from catenary.maintenance.forecast import (
    WearFit,
    years_since_epoch,
)
from catenary.maintenance.history import Repairs, SpanRows, section_measurements, span_histories
from catenary.storage.columns import fetch_columns
from catenary.storage.models import (
    MaintenanceAction,
    Mast,
    Run,
    SpanMeasurement,
)

__all__ = ["TrackData", "Units", "history_keys", "match_units", "units_of"]


def _lookup(keys: NDArray[np.generic], values: NDArray[np.generic]) -> IntArray:
    """Index of each of ``values`` in the sorted, unique ``keys``; -1 where absent."""
    if keys.shape[0] == 0:
        return np.full(values.shape, -1, dtype=np.int64)
    at = np.minimum(np.searchsorted(keys, values), keys.shape[0] - 1)
    return np.where(keys[at] == values, at, -1).astype(np.int64)


def _index_in(known: NDArray[np.generic], values: NDArray[np.generic]) -> IntArray:
    """Index into the unique ``known`` (in any order) of each of ``values``; -1 where absent."""
    order = np.argsort(known).astype(np.int64)
    return take(order, _lookup(known[order], values), -1)


_NONE = -1.0e300  # a NULL of a nullable column as ``fetch_columns`` reads it
_GEOMETRY_COLUMNS = {
    "height_min_mm": SpanMeasurement.height_min_mm,
    "height_max_mm": SpanMeasurement.height_max_mm,
    "stagger_min_mm": SpanMeasurement.stagger_min_mm,
    "stagger_max_mm": SpanMeasurement.stagger_max_mm,
    "height_start_mm": SpanMeasurement.height_at_start_mm,
    "height_end_mm": SpanMeasurement.height_at_end_mm,
    "stagger_start_mm": SpanMeasurement.stagger_at_start_mm,
}


class TrackData:
    """A track's masts and anchor sections, complete runs, span rows and repairs, and their
    geometry (``mast_geometry``, ``geometry``: rows as ``rows``).

    A span row names its masts and wire type by name; the rows are matched to the masts and
    wire types by a key: on PostgreSQL the names' 64-bit hash (``hashtextextended``: the server
    hashes each row's names instead of joining the masts twice and comparing wire type names,
    which halves the query; two names sharing a hash, about one track in 10**13, is refused),
    elsewhere the masts' ids, joined, and the wire types' indices.

    ``rows_where``: a condition on ``SpanMeasurement`` that keeps only some of the track's
    rows (one span's: ``catenary.maintenance.trends.span_trends``); masts, runs and repairs
    are the whole track's.
    """

    def __init__(
        self,
        session: Session,
        track_id: int,
        wire_type_names: Sequence[str],
        rows_where: ColumnElement[bool] | None = None,
    ) -> None:
        self.track_id = track_id
        self.hashed = session.get_bind().dialect.name == "postgresql"
        key = func.hashtextextended(Mast.code, 0) if self.hashed else Mast.id
        masts = session.execute(
            select(
                Mast.id,
                Mast.code,
                Mast.chainage_m,
                Mast.anchor_section,
                Mast.design_stagger_mm,
                Mast.design_height_mm,
                Mast.line_speed_kmh,
                key.label("key"),
            )
            .where(Mast.track_id == track_id)
            .order_by(Mast.chainage_m)
        ).all()
        self.mast_key = np.array([m.key for m in masts], dtype=np.int64)
        if np.unique(self.mast_key).shape[0] != self.mast_key.shape[0]:
            raise RuntimeError(f"track {track_id}: two mast codes share a 64-bit hash")
        self.mast_code: list[str] = [m.code for m in masts]
        self.mast_chainage = np.array([m.chainage_m for m in masts], dtype=np.float64)

        def given(values: list[float | None]) -> FloatArray:
            return np.array([np.nan if v is None else v for v in values], dtype=np.float64)

        self.mast_geometry = MastGeometry(
            design_stagger_mm=given([m.design_stagger_mm for m in masts]),
            design_height_mm=given([m.design_height_mm for m in masts]),
            line_speed_kmh=given([m.line_speed_kmh for m in masts]),
        )
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
        self.rows = self._rows(session, wire_type_names, rows_where)
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

    def _rows(
        self,
        session: Session,
        wire_type_names: Sequence[str],
        rows_where: ColumnElement[bool] | None,
    ) -> SpanRows:
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
                *(
                    cast(func.coalesce(column, _NONE), Float).label(name)
                    for name, column in _GEOMETRY_COLUMNS.items()
                ),
            )
            # through the track's runs: each run's rows lie together, read in their order
            .select_from(Run)
            .join(sm, and_(sm.run_id == Run.id, sm.processing_id == Run.processing_id))
            .where(Run.track_id == self.track_id, Run.status == "complete")
        )
        if rows_where is not None:
            query = query.where(sm.track_id == self.track_id, rows_where)
        if not self.hashed:
            query = query.outerjoin(
                start, and_(start.track_id == Run.track_id, start.code == sm.mast_from)
            ).outerjoin(end, and_(end.track_id == Run.track_id, end.code == sm.mast_to))
        c = fetch_columns(session.connection(), query)
        run = _lookup(self.run_id, c["run_id"])
        keep = np.flatnonzero(run >= 0)  # a run completed since the runs were read: left out
        run = run[keep]

        def measured(name: str) -> FloatArray:
            values = c[name][keep].astype(np.float64)
            return np.where(values == _NONE, np.nan, values)

        self.geometry = GeometryRows(**{name: measured(name) for name in _GEOMETRY_COLUMNS})

        def local(key: NDArray[np.generic], known: IntArray) -> IntArray:
            """Index into ``known`` of each kept row's ``key``; -1 for none."""
            return _index_in(known, key[keep])

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
        text = np.array(["" if c is None else c for c in codes], dtype=object)
        found = _index_in(np.array(self.mast_code, dtype=object), text)
        return np.where(np.array([c is None for c in codes], dtype=bool), -1, found)

    def run_started_at(self, run_id: int) -> datetime:
        return self.run_started[int(_lookup(self.run_id, np.array([run_id]))[0])]


# --- what is evaluated: histories and anchor sections ---------------------------------------


def history_keys(
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


def match_units(units: FloatArray, queries: FloatArray) -> IntArray:
    """The row of ``units`` (unique rows) equal to each row of ``queries``; -1 for none."""
    if queries.shape[0] == 0 or units.shape[0] == 0:
        return np.full(queries.shape[0], -1, dtype=np.int64)
    _, inverse = np.unique(np.vstack([units, queries]), axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    owner = np.full(int(inverse.max()) + 1, -1, dtype=np.int64)
    owner[inverse[: units.shape[0]]] = np.arange(units.shape[0])
    return owner[inverse[units.shape[0] :]]


@dataclass(frozen=True)
class Units:
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


def units_of(track: TrackData, run_ids: Sequence[int] | None) -> tuple[Units, Units]:
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
    local = Units(
        scope=LOCAL,
        keys=history_keys(
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
    section = Units(
        scope=SECTION,
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
