"""Runs in the database: the register's lines, tracks and masts, storing runs and their
processings, finding runs."""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy import func, select
from sqlalchemy.orm import Session, selectinload

from catenary.domain import OPTIONAL_MAST_NUMBERS, TrackRegister, VehicleGeometry
from catenary.errors import UserError
from catenary.storage.inserts import get_or_add, insert_new
from catenary.storage.models import (
    Line,
    Mast,
    Processing,
    Run,
    SpanMeasurement,
    Track,
    run_uuid,
)
from catenary.storage.rigs import register_rig_calibration

__all__ = [
    "ProcessingKey",
    "alignment_summary",
    "count_runs",
    "find_mast",
    "find_run",
    "find_stored_run",
    "find_track",
    "latest_processing",
    "list_runs",
    "pending_runs",
    "register_track",
    "settings_sha256",
    "store_processing",
    "track_masts",
    "track_register",
]


def register_track(session: Session, line_code: str, track_code: str) -> tuple[Line, Track]:
    """The line and track with these codes, added if new (``get_or_add``: a process adding
    them at the same time is no error)."""
    line = get_or_add(session, Line, {"code": line_code})
    return line, get_or_add(session, Track, {"line_id": line.id, "code": track_code})


def track_masts(session: Session, track: Track, register: TrackRegister) -> int:
    """Bring the track's masts in line with the register; returns how many changed.

    The register is the authority: a new mast is added, a mast whose chainage, wire type,
    design stagger or an optional column differ is updated (an optional column only when the
    register has it: ``anchor_section``, ``OPTIONAL_MAST_NUMBERS``); masts not in this
    register are kept (a register file may hold a part of the track). Span measurements keep
    their own mast codes and chainages, so earlier runs are unchanged. New masts are added
    with ``insert_new``: a process adding the same masts at the same time is no error (and
    the register read last is kept).
    """

    def masts() -> dict[str, Mast]:
        return {m.code: m for m in session.scalars(select(Mast).where(Mast.track_id == track.id))}

    given: dict[str, list[Any]] = {
        "chainage_m": register.chainage_m.tolist(),
        "wire_type": list(register.wire_type),
        "design_stagger_mm": [_given(v) for v in register.design_stagger_mm.tolist()],
    }
    if register.anchor_section is not None:
        given["anchor_section"] = list(register.anchor_section)
    for name in OPTIONAL_MAST_NUMBERS:
        values = getattr(register, name)
        if values is not None:
            given[name] = [_given(v) for v in values.tolist()]
    rows = [
        {"track_id": track.id, "code": code, **{name: v[k] for name, v in given.items()}}
        for k, code in enumerate(register.mast)
    ]
    stored = masts()
    new = [r for r in rows if r["code"] not in stored]
    changed = len(insert_new(session, Mast, new, ["track_id", "code"]))
    if changed:
        stored = masts()
    for row in rows:
        mast = stored[row["code"]]
        differ = {name: row[name] for name in given if getattr(mast, name) != row[name]}
        for name, value in differ.items():
            setattr(mast, name, value)
        changed += bool(differ)
    session.flush()
    return changed


def _given(value: float) -> float | None:
    """A register's number as stored: None where it gives none (NaN)."""
    return None if value != value else value


def store_processing(
    session: Session,
    *,
    line: str,
    track: str,
    register: TrackRegister | None,
    geometry: VehicleGeometry,
    rig_name: str,
    rig_text: str,
    replacing: int | None,
    run_values: Mapping[str, Any],
    processing_values: Mapping[str, Any],
    span_rows: Sequence[SpanMeasurement],
) -> tuple[Run, Processing]:
    """Store a processing of a run in the caller's transaction.

    Adds what is new of its line, track and masts (``register``), its vehicle and rig
    calibration (versioned by content) and the run (``run_values``: ``Run`` columns), or,
    ``replacing`` (a stored run's id), updates that run (its identity stays, whatever the
    calibration: ``catenary reprocess`` may use a newer one); then the processing
    (``processing_values``: ``Processing`` columns) with its span measurements, which becomes
    the run's latest: its earlier processings stay, unseen by alerts, reports and exports.
    Returns both, flushed (they have their ids).

    A new run is inserted without looking for it: if another transaction stored it
    meanwhile, the insert breaks the identity's unique key (``IntegrityError``).
    """
    line_row, track_row = register_track(session, line, track)
    if register is not None:
        track_masts(session, track_row, register)
    calibration = register_rig_calibration(session, geometry, rig_name, rig_text)
    run = None if replacing is None else session.get(Run, replacing, with_for_update=True)
    if replacing is not None and run is None:
        raise UserError(f"run {replacing}, to process again, is no longer stored: process it anew")
    if run is None:
        run = Run(
            uuid=run_uuid(run_values["source_sha256"], calibration.sha256),
            rig_sha256=calibration.sha256,
            line=line_row,
            track=track_row,
            vehicle=calibration.vehicle,
            rig_calibration=calibration,
        )
        session.add(run)
    for name, value in run_values.items():
        setattr(run, name, value)
    processing = Processing(run=run, rig_calibration=calibration, **processing_values)
    processing.span_measurements = list(span_rows)
    session.add(processing)
    session.flush()
    run.processing = processing
    session.flush()
    session.expire(run, ["span_measurements"])
    return run, processing


def latest_processing(run: Run) -> Processing:
    """The run's latest processing (every stored run has one)."""
    if run.processing is None:
        raise UserError(f"run {run.id} has no processing: process its run file again")
    return run.processing


def alignment_summary(processing: Processing) -> str:
    """How the processing found its chainage, in words: aligned to the register (through how
    many registration points, the residual RMS [m], the encoder's error), or start chainage
    plus encoder distance; empty for a processing stored before this was recorded."""
    if processing.chainage_aligned:
        return (
            f"aligned to the register through {processing.alignment_matched} registration points "
            f"(residual RMS {processing.alignment_rms_m or 0.0:.2f} m, encoder error "
            f"{1.0 / (processing.encoder_scale or 1.0) - 1.0:+.3%})"
        )
    if processing.chainage_aligned is not None:
        return "start chainage + encoder distance (not aligned to a register)"
    return ""


@dataclass(frozen=True)
class ProcessingKey:
    """What makes two processings of a run alike: the processor, catenary's version, the
    settings' SHA-256 and the rig calibration's content SHA-256 (``catenary reprocess`` makes
    none that the run's latest processing already is)."""

    processor: str
    package_version: str
    settings_sha256: str
    rig_sha256: str

    @classmethod
    def of(cls, processing: Processing) -> ProcessingKey:
        return cls(
            processing.processor,
            processing.package_version,
            processing.settings_sha256,
            processing.rig_calibration.sha256,
        )


def find_stored_run(session: Session, source_sha256: str, rig_sha256: str) -> Run | None:
    """The run of this file content measured with this rig calibration content, if stored."""
    return session.scalars(
        select(Run).where(Run.source_sha256 == source_sha256, Run.rig_sha256 == rig_sha256)
    ).one_or_none()


def settings_sha256(settings: Mapping[str, Any] | None) -> str:
    """SHA-256 of a processing's settings as canonical JSON (keys sorted, no spaces)."""
    text = json.dumps(settings, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


UUID_PREFIX_MIN = 4
"""The shortest prefix of a run's UUID that ``find_run`` looks up."""


def find_run(session: Session, reference: str) -> Run:
    """The run that ``reference`` names: its id (a number), its UUID or a prefix of it that
    only it has (``UUID_PREFIX_MIN`` characters at least), or ``latest`` (the run processed
    last)."""
    if reference == "latest":
        run = session.scalars(
            select(Run)
            .join(Processing, Processing.id == Run.processing_id)
            .order_by(Processing.processed_at.desc(), Run.id.desc())
            .limit(1)
        ).first()
        if run is None:
            raise UserError("no run in the database yet: catenary process RUN.h5 stores one")
        return run
    if reference.isdigit():
        run = session.get(Run, int(reference))
        if run is not None:
            return run
    prefix = reference.lower()
    if len(prefix) < UUID_PREFIX_MIN or prefix.strip("0123456789abcdef-"):
        if reference.isdigit():
            raise UserError(f"no run {reference} in the database")
        raise UserError(
            f"run {reference!r}: give a run id (a number), its UUID (or the first "
            f"{UUID_PREFIX_MIN} characters or more of it) or 'latest'"
        )
    found = list(session.scalars(select(Run).where(Run.uuid.startswith(prefix)).limit(2)))
    if not found:
        raise UserError(f"no run {reference} in the database")
    if len(found) > 1:
        raise UserError(f"run {reference!r}: several runs' UUIDs begin so: give more of it")
    return found[0]


def pending_runs(session: Session, *, line: str | None = None) -> list[int]:
    """The complete runs (on ``line``: of it) whose alerts are not evaluated yet, by id."""
    query = select(Run.id).where(
        Run.status == "complete", Run.track_id.is_not(None), Run.alerts_evaluated_at.is_(None)
    )
    if line is not None:
        query = query.join(Line, Run.line_id == Line.id).where(Line.code == line)
    return list(session.scalars(query.order_by(Run.id)))


def _runs_of(query: Any, line: str | None, track: str | None) -> Any:
    query = query.join(Line, Run.line_id == Line.id).outerjoin(Track, Run.track_id == Track.id)
    if line is not None:
        query = query.where(Line.code == line)
    if track is not None:
        query = query.where(Track.code == track)
    return query


def list_runs(
    session: Session,
    *,
    line: str | None = None,
    track: str | None = None,
    newest_first: bool = False,
    limit: int | None = None,
    offset: int = 0,
) -> list[Run]:
    """The stored runs by id (oldest first, or ``newest_first``), of line ``line`` and track
    ``track`` if given, at most ``limit`` of them (None: all) after the first ``offset``;
    each with its line, track, vehicle and latest processing loaded."""
    query = (
        _runs_of(select(Run), line, track)
        .options(
            selectinload(Run.line),
            selectinload(Run.track),
            selectinload(Run.vehicle),
            selectinload(Run.processing),
        )
        .order_by(Run.id.desc() if newest_first else Run.id)
        .limit(limit)
        .offset(offset)
    )
    return list(session.scalars(query))


def count_runs(session: Session, *, line: str | None = None, track: str | None = None) -> int:
    """How many runs ``list_runs`` lists without ``limit``."""
    return int(session.scalar(_runs_of(select(func.count(Run.id)), line, track)) or 0)


def track_register(line: str, track: str, masts: Sequence[Mast]) -> TrackRegister:
    """Stored masts as a ``TrackRegister`` (sorted by chainage), every column given."""
    ordered = sorted(masts, key=lambda m: m.chainage_m)

    def numbers(name: str) -> np.ndarray[Any, np.dtype[np.float64]]:
        values = [getattr(m, name) for m in ordered]
        return np.array([math.nan if v is None else v for v in values], dtype=np.float64)

    return TrackRegister(
        line=line,
        track=track,
        mast=tuple(m.code for m in ordered),
        chainage_m=numbers("chainage_m"),
        wire_type=tuple(m.wire_type for m in ordered),
        design_stagger_mm=numbers("design_stagger_mm"),
        anchor_section=tuple(m.anchor_section for m in ordered),
        **{name: numbers(name) for name in OPTIONAL_MAST_NUMBERS},
    )


def find_track(session: Session, line: str, track: str) -> Track:
    """Track ``track`` of line ``line``; a ``UserError`` if the database has none."""
    found = session.scalars(
        select(Track).join(Line).where(Line.code == line, Track.code == track)
    ).one_or_none()
    if found is None:
        raise UserError(f"no track {track!r} on line {line!r} in the database")
    return found


def find_mast(session: Session, track: Track, code: str) -> Mast:
    """Mast ``code`` of ``track``; a ``UserError`` if the register has none."""
    found = session.scalars(
        select(Mast).where(Mast.track_id == track.id, Mast.code == code)
    ).one_or_none()
    if found is None:
        raise UserError(
            f"no mast {code!r} on line {track.line.code!r} track {track.code!r} in the register"
        )
    return found
