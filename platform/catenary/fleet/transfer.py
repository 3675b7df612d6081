"""Runs from a vehicle to the central side (``push``) and the register back (``pull``).

A vehicle works offline into its own database and store; in the depot ``catenary push --to
CENTRAL.toml`` sends what the central side lacks. The central config names its ``[database]``
and ``[store]``; nothing else of it is used here but its ``[limits]`` (the alerts of what
arrives are evaluated centrally, and ``pull`` copies the policy file it names).

What moves, and how a push stays whole:

- **Runs and processings by identity.** A run is its UUID (its content), a processing its
  own UUID: pushing twice, or the same run from two vehicles, stores the run once, and a run
  processed again after a push is pushed as a new processing.
- **Objects first, then one transaction per processing.** Each samples file, its envelope file
  (built from the samples for a processing stored before there were any) and its image evidence are
  put in the central store under their portable keys and read back (size and SHA-256); then one
  central transaction adds what is new of the line, track and masts, the vehicle and rig
  calibration, the run, and the processing with its span measurements, and makes the run's newest
  processing its latest. A push cut at any point (the link drops, the process is killed) leaves the
  processings committed so far, each whole, and objects nobody refers to yet; the next push finds
  the object in place (checked by reading it back) and commits the rest.
- **The register is the central one.** A processing whose spans were cut at masts that the
  central register places elsewhere (or lacks) is refused, naming the first such mast: pull
  and process again. A track the central side has no mast of takes the vehicle's masts.
- **Run files** stay on the vehicle unless asked (``run_files``): then each run's file is put
  under ``runs/RUN.h5`` in parts (``Store.put_parts``: a push cut short resumes from the parts
  in place, each checked), checked against the run's SHA-256, and the central run refers to it.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, selectinload

from catenary.config import Settings
from catenary.domain import VehicleGeometry
from catenary.errors import UserError
from catenary.measurement.envelope import write_envelopes
from catenary.measurement.evidence import evidence_prefix
from catenary.measurement.samples import StoredSamples
from catenary.storage.database import open_database, session_scope
from catenary.storage.models import (
    Line,
    Mast,
    Processing,
    Run,
    SpanMeasurement,
    Track,
)
from catenary.storage.rigs import register_rig_calibration
from catenary.storage.runs import register_track, track_masts, track_register
from catenary.storage.store import (
    ContentMismatch,
    Part,
    Store,
    StoredObject,
    envelope_key,
    open_store,
    samples_key,
)

__all__ = ["PullResult", "PushResult", "pull", "push", "run_file_key"]

CHAINAGE_TOLERANCE_M = 1e-6
"""Two registers place a mast at the same chainage within this [m]."""

RUNS_PREFIX = "runs"

_RUN_COLUMNS = ("uuid", "direction", "source_file", "source_sha256", "rig_sha256", "started_at",
                "scans", "status", "error")  # fmt: skip
_KEPT_APART = {"id", "run_id", "rig_calibration_id", "samples_key", "samples_size_bytes",
               "samples_sha256"}  # fmt: skip
_SPAN_KEPT_APART = {"id", "run_id", "processing_id", "track_id"}


def run_file_key(run_uuid: str) -> str:
    """The run file's key in the store: ``runs/RUN.h5``."""
    return f"{RUNS_PREFIX}/{run_uuid}.h5"


@dataclass
class PushResult:
    """What a push moved: runs new centrally, processings, objects and their bytes, and the
    central ids of the runs whose latest processing changed (their alerts are evaluated)."""

    runs: int = 0
    processings: int = 0
    objects: int = 0
    bytes: int = 0
    already: int = 0
    """Processings another push stored meanwhile."""
    run_ids: list[int] = field(default_factory=list)
    moved: list[tuple[str, str, int]] = field(default_factory=list)
    """Each processing stored centrally: its run's UUID, its own and its samples' bytes."""
    parts_sent: int = 0
    """Parts of run files sent."""
    parts_found: int = 0
    """Parts of run files found in place from a push cut short (not sent again)."""


@dataclass(frozen=True)
class _Outgoing:
    """One processing to send: the vehicle's rows, read before anything is sent."""

    run: Run
    processing: Processing
    spans: list[SpanMeasurement]
    line: str
    track: str | None
    masts: list[Mast]
    geometry: VehicleGeometry
    rig_name: str
    rig_text: str


def push(
    local: Settings,
    central: Settings,
    *,
    run_files: bool = False,
    progress: Callable[[int], None] = lambda done: None,
    on_plan: Callable[[int, int], None] = lambda processings, total_bytes: None,
) -> PushResult:
    """Send every run and processing the central side lacks (module docstring).

    ``on_plan`` is told how many processings will move and their samples' bytes before the
    first moves; ``progress`` each processing's bytes once it is committed centrally.
    """
    result = PushResult()
    local_store, central_store = open_store(local), open_store(central)
    with (
        open_database(local) as local_engine,
        open_database(central, batch=True) as central_engine,
    ):
        outgoing = _outgoing(local_engine, central_engine)
        sizes = [o.processing.samples_size_bytes or 0 for o in outgoing]
        on_plan(len(outgoing), sum(sizes))
        changed: dict[int, None] = {}
        with tempfile.TemporaryDirectory(prefix="catenary-push-") as scratch:
            for item, size in zip(outgoing, sizes, strict=True):
                placed = _send_samples(item, local_store, central_store, Path(scratch))
                evidence = _send_evidence(item.processing.uuid, local_store, central_store)
                evidence += _send_envelopes(item.processing, placed.key, local_store, central_store)
                result.objects += 1 + len(evidence)
                result.bytes += placed.size_bytes + sum(e.size_bytes for e in evidence)
                run_id, stored, latest = _commit(central_engine, item, placed)
                if stored:
                    result.processings += 1
                    result.moved.append((item.run.uuid, item.processing.uuid, placed.size_bytes))
                    result.runs += stored == "run"
                else:
                    result.already += 1
                if latest:
                    changed[run_id] = None
                progress(size)
            if run_files:
                for run in _runs_without_file(local_engine, central_engine):
                    source = _send_run_file(run, central_store, result)
                    _set_run_file(central_engine, run.uuid, source.key)
                    result.objects += 1
                    result.bytes += source.size_bytes
        result.run_ids = list(changed)
    return result


def _outgoing(local_engine: Engine, central_engine: Engine) -> list[_Outgoing]:
    """The vehicle's processings the central side lacks, oldest first."""
    with session_scope(central_engine, read_only=True) as session:
        have = set(session.scalars(select(Processing.uuid)))
    found = []
    with session_scope(local_engine, read_only=True) as session:
        lacking = [
            number
            for number, made in session.execute(
                select(Processing.id, Processing.uuid)
                .join(Run, Run.id == Processing.run_id)
                .where(Run.status == "complete")
            )
            if made not in have
        ]
        processings = session.scalars(
            select(Processing)
            .where(Processing.id.in_(lacking))
            .options(selectinload(Processing.span_measurements))
            .order_by(Processing.processed_at, Processing.id)
        ).all()
        for processing in processings:
            run = processing.run
            if not processing.samples_key:
                raise UserError(f"run {run.uuid}: processing {processing.uuid} has no samples")
            rig = processing.rig_calibration
            vehicle = rig.vehicle
            found.append(
                _Outgoing(
                    run=run,
                    processing=processing,
                    spans=list(processing.span_measurements),
                    line=run.line.code,
                    track=run.track.code if run.track else None,
                    masts=list(run.track.masts) if run.track else [],
                    geometry=VehicleGeometry(
                        vehicle.name,
                        vehicle.roof_height_mm,
                        vehicle.sensor_height_mm,
                        vehicle.sensor_baseline_mm,
                    ),
                    rig_name=rig.name,
                    rig_text=rig.content_toml,
                )
            )
    return found


def _send_samples(item: _Outgoing, local: Store, central: Store, scratch: Path) -> StoredObject:
    """Put the processing's samples file in the central store (unless it is there already,
    read back whole) and give its key, size and SHA-256."""
    processing = item.processing
    assert processing.samples_key is not None
    key = samples_key(item.line, item.track or "", item.run.uuid, processing.uuid)
    size, sha256 = processing.samples_size_bytes, processing.samples_sha256
    if size is None or sha256 is None:  # stored before its size and hash were kept
        known = local.digest(processing.samples_key)
        size, sha256 = known.size_bytes, known.sha256
    if central.verify(key, size, sha256):
        return StoredObject(key, size, sha256)
    with local.readable(processing.samples_key, scratch) as path:
        placed = central.put_file(path, key)
    if (placed.size_bytes, placed.sha256) != (size, sha256):
        central.delete(key)
        raise UserError(
            f"{local.describe(processing.samples_key)}: the samples file changed since it was "
            f"stored ({placed.size_bytes} bytes, SHA-256 {placed.sha256}; the database says "
            f"{size} bytes, {sha256})"
        )
    return placed


def _send_evidence(processing_uuid: str, local: Store, central: Store) -> list[StoredObject]:
    """Put the processing's image evidence in the central store (each crop not there yet,
    or not the same, read back whole)."""
    sent = []
    for key in local.keys(evidence_prefix(processing_uuid)):
        crop = local.digest(key)
        if central.verify(key, crop.size_bytes, crop.sha256):
            continue
        with local.open_input(key) as source:
            sent.append(central.put_bytes(source.read(), key))
    return sent


def _send_envelopes(
    processing: Processing, central_key: str, local: Store, central: Store
) -> list[StoredObject]:
    """Put the envelope file of the processing's samples (now at ``central_key``) in the
    central store: the vehicle's, unless the same is there; built from the vehicle's samples
    where the vehicle has none (a processing stored before envelope files) and the central
    store neither."""
    assert processing.samples_key is not None
    mine, theirs = envelope_key(processing.samples_key), envelope_key(central_key)
    if not local.exists(mine):
        if central.exists(theirs):
            return []
        return [write_envelopes(central, central_key, StoredSamples(local, processing.samples_key))]
    made = local.digest(mine)
    if central.verify(theirs, made.size_bytes, made.sha256):
        return []
    with local.open_input(mine) as source:
        return [central.put_bytes(source.read(), theirs)]


def _send_run_file(run: Run, central: Store, result: PushResult) -> StoredObject:
    """Put the run's file in the central store in parts (resuming a push cut short), checked
    against the run's SHA-256, unless it is there already (read back whole); its parts
    counted in ``result``."""
    path = Path(run.source_file)
    if not path.is_file():
        raise UserError(f"{path}: the file of run {run.uuid} is no longer here (--run-files)")
    key, size = run_file_key(run.uuid), path.stat().st_size
    if central.verify(key, size, run.source_sha256):  # a push cut before it was recorded
        return StoredObject(key, size, run.source_sha256)

    def count(part: Part) -> None:
        if part.sent:
            result.parts_sent += 1
        else:
            result.parts_found += 1

    try:
        return central.put_parts(path, key, sha256=run.source_sha256, on_part=count)
    except ContentMismatch:
        raise UserError(f"{path}: its content is no longer that of run {run.uuid}") from None


def _runs_without_file(local_engine: Engine, central_engine: Engine) -> list[Run]:
    """The vehicle's runs that the central side has without their run file."""
    with session_scope(central_engine, read_only=True) as session:
        lacking = set(session.scalars(select(Run.uuid).where(Run.source_key.is_(None))).all())
    with session_scope(local_engine, read_only=True) as session:
        return [run for run in session.scalars(select(Run).order_by(Run.id)) if run.uuid in lacking]


def _set_run_file(engine: Engine, run_uuid: str, key: str) -> None:
    with session_scope(engine) as session:
        run = session.scalars(select(Run).where(Run.uuid == run_uuid)).one()
        run.source_key = key


def _commit(engine: Engine, item: _Outgoing, placed: StoredObject) -> tuple[int, str, bool]:
    """Store the processing centrally in one transaction; returns the central run's id, what
    was new ("run", "processing" or "" if another push stored it meanwhile) and whether the
    run's latest processing changed. A concurrent push of the same run is waited for and
    retried once (the identity's unique keys)."""
    for attempt in (1, 2):
        try:
            with session_scope(engine) as session:
                return _store(session, item, placed)
        except IntegrityError:
            if attempt == 2:
                raise
    raise AssertionError("unreachable")


def _store(session: Session, item: _Outgoing, placed: StoredObject) -> tuple[int, str, bool]:
    processing = item.processing
    line, track = (
        register_track(session, item.line, item.track)
        if item.track is not None
        else (_line(session, item.line), None)
    )
    if track is not None:
        _check_register(session, track, item)
    calibration = register_rig_calibration(session, item.geometry, item.rig_name, item.rig_text)
    run = session.scalars(select(Run).where(Run.uuid == item.run.uuid)).one_or_none()
    new = "processing"
    if run is None:
        run = Run(
            **{name: getattr(item.run, name) for name in _RUN_COLUMNS},
            line=line,
            track=track,
            vehicle=calibration.vehicle,
            rig_calibration=calibration,
        )
        session.add(run)
        new = "run"
    elif session.scalar(select(Processing.id).where(Processing.uuid == processing.uuid)):
        return run.id, "", False  # another push stored it meanwhile
    made = Processing(
        **_columns(processing, _KEPT_APART),
        run=run,
        rig_calibration=calibration,
        samples_key=placed.key,
        samples_size_bytes=placed.size_bytes,
        samples_sha256=placed.sha256,
    )
    made.span_measurements = [SpanMeasurement(**_columns(s, _SPAN_KEPT_APART)) for s in item.spans]
    session.add(made)
    session.flush()
    latest = run.processing
    if latest is None or made.processed_at >= latest.processed_at:
        run.processing = made
        run.alerts_evaluated_at = None  # its spans changed: pending
        session.flush()
        return run.id, new, True
    return run.id, new, False


def _columns(row: Processing | SpanMeasurement, leave: set[str]) -> dict[str, Any]:
    """A row's column values but those in ``leave`` (its keys and owners)."""
    return {c.key: getattr(row, c.key) for c in type(row).__table__.c if c.key not in leave}


def _line(session: Session, code: str) -> Line:
    line = session.scalars(select(Line).where(Line.code == code)).one_or_none()
    if line is None:
        line = Line(code=code)
        session.add(line)
        session.flush()
    return line


def _check_register(session: Session, track: Track, item: _Outgoing) -> None:
    """Refuse a processing whose spans were cut at masts the central register places
    elsewhere or lacks; a track without masts centrally takes the vehicle's."""
    masts = {m.code: m for m in session.scalars(select(Mast).where(Mast.track_id == track.id))}
    if not masts:
        if item.masts:
            track_masts(session, track, track_register(item.line, track.code, item.masts))
        return
    for span in sorted(item.spans, key=lambda s: s.start_chainage_m):
        for code, chainage in ((span.mast_from, span.start_chainage_m),
                               (span.mast_to, span.end_chainage_m)):  # fmt: skip
            if code is None:
                continue
            central = masts.get(code)
            if central is None:
                problem = "is not in the central register"
            elif abs(central.chainage_m - chainage) > CHAINAGE_TOLERANCE_M:
                problem = f"is at {chainage} m here, {central.chainage_m} m centrally"
            else:
                continue
            raise UserError(
                f"run {item.run.uuid} (line {item.line} track {track.code}) was processed "
                f"against another register than the central one: mast {code} {problem} "
                "(catenary pull --from CENTRAL.toml, then process it again with --replace)"
            )


@dataclass
class PullResult:
    """What a pull brought: tracks and masts changed, the policy file copied (its path), and
    the wire types the register names that no plugin installs here."""

    tracks: int = 0
    masts_changed: int = 0
    masts_removed: int = 0
    policy_file: Path | None = None
    missing_wire_types: list[str] = field(default_factory=list)


def pull(local: Settings, central: Settings, installed_wire_types: Sequence[str]) -> PullResult:
    """Copy the central register (lines with their names, tracks, masts with every column)
    over the vehicle's, and the policy file the central ``[limits]`` names into the vehicle's
    data directory. A vehicle's mast that the central register lacks is removed from its
    track (span measurements keep their own mast codes and chainages)."""
    result = PullResult()
    with open_database(central) as engine, session_scope(engine, read_only=True) as session:
        lines = {line.code: line.name for line in session.scalars(select(Line))}
        registers = [
            track_register(track.line.code, track.code, track.masts)
            for track in session.scalars(
                select(Track).options(selectinload(Track.masts), selectinload(Track.line))
            )
        ]
    with open_database(local) as engine, session_scope(engine) as session:
        for code, name in lines.items():
            line = _line(session, code)
            if name is not None and line.name != name:
                line.name = name
        for register in registers:
            _, track = register_track(session, register.line, register.track)
            result.tracks += 1
            result.masts_changed += track_masts(session, track, register)
            extra = session.scalars(
                select(Mast).where(Mast.track_id == track.id, Mast.code.not_in(register.mast))
            ).all()
            for mast in extra:
                session.delete(mast)
            result.masts_removed += len(extra)
    named = {t for register in registers for t in register.wire_type}
    result.missing_wire_types = sorted(named - set(installed_wire_types))
    result.policy_file = _copy_policy(local, central)
    return result


def _copy_policy(local: Settings, central: Settings) -> Path | None:
    """The central ``[limits] file``, copied into the vehicle's data directory."""
    section: Any = central.sections.get("limits") or {}
    name = section.get("file") if isinstance(section, dict) else None
    if not isinstance(name, str):
        return None
    source = Path(name).expanduser()
    if not source.is_absolute() and central.config_path is not None:
        source = central.config_path.parent / source
    target = local.data_dir / "policies" / source.name
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(source, target)
    except OSError as exc:
        raise UserError(f"{source}: cannot copy the central policy file ({exc.strerror})") from None
    return target
