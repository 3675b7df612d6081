"""Runs in the database: the register's lines, tracks and masts, storing, finding and replacing
runs."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from catenary.domain import TrackRegister, VehicleGeometry
from catenary.errors import UserError
from catenary.storage.inserts import get_or_add, insert_new
from catenary.storage.models import Line, Mast, RigCalibration, Run, SpanMeasurement, Track
from catenary.storage.rigs import register_rig_calibration

__all__ = [
    "find_run",
    "find_stored_run",
    "pending_runs",
    "register_track",
    "store_run",
    "track_masts",
]


def register_track(session: Session, line_code: str, track_code: str) -> tuple[Line, Track]:
    """The line and track with these codes, added if new (``get_or_add``: a process adding
    them at the same time is no error)."""
    line = get_or_add(session, Line, {"code": line_code})
    return line, get_or_add(session, Track, {"line_id": line.id, "code": track_code})


def track_masts(session: Session, track: Track, register: TrackRegister) -> int:
    """Bring the track's masts in line with the register; returns how many changed.

    The register is the authority: a new mast is added, a mast whose chainage, wire type,
    design stagger or anchor section differ is updated (the anchor section only when the
    register has that column); masts not in this register are kept (a register file may hold a
    part of the track). Span measurements keep their own mast codes and chainages, so earlier
    runs are unchanged. New masts are added with ``insert_new``: a process adding the same
    masts at the same time is no error (and the register read last is kept).
    """

    def masts() -> dict[str, Mast]:
        return {m.code: m for m in session.scalars(select(Mast).where(Mast.track_id == track.id))}

    sections = register.anchor_section
    rows = [
        {
            "track_id": track.id,
            "code": code,
            "chainage_m": chainage,
            "wire_type": wire_type,
            "design_stagger_mm": None if stagger != stagger else stagger,  # NaN: not given
            "anchor_section": None if sections is None else sections[k],
        }
        for k, (code, chainage, wire_type, stagger) in enumerate(
            zip(
                register.mast,
                register.chainage_m.tolist(),
                register.wire_type,
                register.design_stagger_mm.tolist(),
                strict=True,
            )
        )
    ]
    stored = masts()
    new = [r for r in rows if r["code"] not in stored]
    changed = len(insert_new(session, Mast, new, ["track_id", "code"]))
    if changed:
        stored = masts()
    for row in rows:
        mast = stored[row["code"]]
        section = mast.anchor_section if sections is None else row["anchor_section"]
        values = (row["chainage_m"], row["wire_type"], row["design_stagger_mm"], section)
        if (mast.chainage_m, mast.wire_type, mast.design_stagger_mm, mast.anchor_section) != values:
            mast.chainage_m, mast.wire_type, mast.design_stagger_mm, mast.anchor_section = values
            changed += 1
    session.flush()
    return changed


def store_run(
    session: Session,
    *,
    line: str,
    track: str,
    register: TrackRegister | None,
    geometry: VehicleGeometry,
    rig_name: str,
    rig_text: str,
    replacing: int | None,
    values: Mapping[str, Any],
    span_rows: Sequence[SpanMeasurement],
) -> tuple[Run, str | None]:
    """Store a processed run in the caller's transaction.

    Adds what is new of its line, track and masts (``register``), its vehicle and rig
    calibration (versioned by content), and the run with ``values`` (``Run`` columns) and its
    span measurements. A run processed again (``replacing``: its id) keeps its id and loses its
    earlier span measurements. Returns the run, flushed (it has its id), and the samples key it
    had before (None: none).
    """
    line_row, track_row = register_track(session, line, track)
    if register is not None:
        track_masts(session, track_row, register)
    calibration = register_rig_calibration(session, geometry, rig_name, rig_text)
    run = None if replacing is None else session.get(Run, replacing)
    old_samples = None
    if run is None:
        run = Run()
    else:
        old_samples = run.samples_path
        session.execute(delete(SpanMeasurement).where(SpanMeasurement.run_id == run.id))
        session.expire(run, ["span_measurements"])
    for name, value in values.items():
        setattr(run, name, value)
    run.line, run.track = line_row, track_row
    run.vehicle, run.rig_calibration = calibration.vehicle, calibration
    run.span_measurements = list(span_rows)
    session.add(run)
    session.flush()
    return run, old_samples


def find_stored_run(
    session: Session, source_sha256: str, vehicle: str, rig_sha256: str
) -> Run | None:
    """The run already stored from this file content with this rig calibration content."""
    return session.scalars(
        select(Run)
        .join(RigCalibration, Run.rig_calibration_id == RigCalibration.id)
        .where(Run.source_sha256 == source_sha256, RigCalibration.sha256 == rig_sha256)
        .where(RigCalibration.vehicle.has(name=vehicle))
    ).first()


def find_run(session: Session, reference: str) -> Run:
    """The run with id ``reference``, or the last processed with ``latest``."""
    if reference == "latest":
        run = session.scalars(select(Run).order_by(Run.id.desc()).limit(1)).first()
        if run is None:
            raise UserError("no run in the database yet: catenary process RUN.h5 stores one")
        return run
    try:
        number = int(reference)
    except ValueError:
        raise UserError(f"run {reference!r}: give a run id (a number) or 'latest'") from None
    run = session.get(Run, number)
    if run is None:
        raise UserError(f"no run {number} in the database")
    return run


def pending_runs(session: Session, *, line: str | None = None) -> list[int]:
    """The complete runs (on ``line``: of it) whose alerts are not evaluated yet, by id."""
    query = select(Run.id).where(
        Run.status == "complete", Run.track_id.is_not(None), Run.alerts_evaluated_at.is_(None)
    )
    if line is not None:
        query = query.join(Line, Run.line_id == Line.id).where(Line.code == line)
    return list(session.scalars(query.order_by(Run.id)))
