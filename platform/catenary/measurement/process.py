"""``catenary process``: a recorded run into per-span wear in the database (the main job).

1. **Check** everything a user gives before anything is written: the run file's layout
   (opened once, so that its warnings are given once), the rig calibration (read by the
   processor) and, if the processor is a ``RunChecker``, that the run fits it (line widths,
   regions of interest, cameras; a ``WireTypesUser`` is told the run's wire types), the mast
   register and its wire types, the wire
   type, the line and track, the database's migration; a run already stored from the same
   file content and rig calibration is said so and left alone (``--replace`` processes it
   again and replaces it).
2. **Measure** (pass 1): the run streams in blocks, its vehicle sensors smoothed without
   phase lag (:mod:`catenary.measurement.sensors`, ``[processing] vehicle_filter_hz``, 5 Hz
   unless told otherwise), through the processor (a plugin: the
   ``linescan-stereo`` one unless told otherwise) and the measurement chain
   (:mod:`catenary.measurement.chain`: vehicle compensation, stagger-angle correction) into an
   intermediate Parquet file; the stagger's turning points (the registration points) are
   found on the way (:mod:`catenary.measurement.chainage`). With ``workers`` above 1 and a
   processor that is a ``StagedProcessor``, the stage of successive blocks runs in worker
   processes (:mod:`catenary.measurement.parallel`) and the rest in order here; the results
   are the same. The run file is hashed in a thread from the start; the check that the run
   is not stored already (step 1) waits for it before the first block with one worker, and
   is made beside the workers as soon as it is known otherwise.
3. **Align** the encoder's positions to chainage: to the mast register's masts through the
   registration points (fitting the encoder's scale error and the start chainage's error),
   or ``start + position`` without a register.
4. **Finish** (pass 2): each sample's chainage, span (the register's masts, or the turning
   points without one), wire type and residual thickness, written to the run's samples file
   (:mod:`catenary.measurement.samples`), and the span statistics
   (:mod:`catenary.measurement.spans`) of the samples that have neither a vehicle sensor
   fault nor ``selection_uncertain`` (the processor could not decide that the point is the
   contact wire; nor do such samples find turning points in pass 1). A run in which no wire
   was measured at all (a vehicle that did not move, cameras that saw nothing) is refused:
   nothing is stored. One that measured no span (too little track covered) is stored and
   the command warns.
5. **Store** in one transaction: the line, track and masts, the vehicle and rig calibration
   (versioned), the run and its span measurements. The samples file, and its envelope file
   beside it (:mod:`catenary.measurement.envelope`, built before the transaction), are put in
   the store inside that transaction; the samples file gets the run's name
   (``run-{id}-{token}.parquet``) there, as a second name beside the
   hidden one that names this process, which goes once the run is committed; a failure
   anywhere leaves neither a row nor a file behind, and a process killed between the two
   names leaves a pair the next ``process`` resolves by asking the database whether the run
   was committed (``remove_abandoned_scratch``). That transaction checks again that the run
   is not stored: the same run processed twice at once is stored once, and the other process
   says it is already stored (on SQLite it waits for the first's write lock; on PostgreSQL
   its insert breaks the unique key, which is turned into "already stored") and removes its
   samples file. Ctrl-C and
   SIGTERM are held while that transaction runs and delivered once its outcome is known: an
   interruption never removes the samples file of a run it did not stop from being stored,
   and one delivered after the commit is raised as ``StoredThenInterrupted``.

The alerts a stored run raises are not evaluated here (measurement knows nothing of
maintenance): the command that processes the run evaluates them once it is committed
(:func:`catenary.maintenance.alerts.evaluate_stored_run`).

Memory stays flat whatever the run's length: blocks of scans, bounded buffers, Parquet row
groups (``benchmarks/process_memory.py``).
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import math
import os
import socket
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import AbstractContextManager, ExitStack, closing, suppress
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from sqlalchemy import Engine, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from catenary.config import Settings, did_you_mean
from catenary.domain import (
    CODE_LENGTH,
    NAME_LENGTH,
    PATH_LENGTH,
    RunHeader,
    ScanBlock,
    TrackRegister,
    VehicleGeometry,
    WireObservations,
)
from catenary.errors import UserError
from catenary.measurement.chain import MeasurementChain, TrackSamples
from catenary.measurement.chainage import ChainageAlignment, TurningPointFinder, align_to_register
from catenary.measurement.envelope import envelope_bytes
from catenary.measurement.evidence import (
    HALF_LENGTH_M,
    POINTS,
    Cut,
    EvidencePoint,
    SpanMinima,
    cut_pngs,
    evidence_key,
    evidence_prefix,
    point_columns,
)
from catenary.measurement.masts import read_register
from catenary.measurement.parallel import interruptions_held, staged_blocks, with_run
from catenary.measurement.runfile import RunFile, open_run
from catenary.measurement.samples import SampleWriter, read_sample_batches, trusted
from catenary.measurement.sensors import DEFAULT_FILTER_HZ, SensorSmoother
from catenary.measurement.spans import SpanAccumulator, SpanLayout, SpanStatistics
from catenary.measurement.vehicle import load_vehicle_geometry
from catenary.plugins import (
    BlockProcessor,
    ImageLocator,
    PluginRegistry,
    RunChecker,
    StagedProcessor,
    WireTypesUser,
)
from catenary.positions import wire_positions
from catenary.storage.database import open_database, session_scope
from catenary.storage.models import Processing, Run, SpanMeasurement, run_uuid
from catenary.storage.runs import (
    ProcessingKey,
    find_stored_run,
    settings_sha256,
    store_processing,
)
from catenary.storage.store import (
    ENVELOPES_PREFIX,
    Store,
    StoreError,
    envelope_key,
    open_store,
    samples_key,
)
from catenary.text import length_problem
from catenary.wiretype import WireType

__all__ = [
    "DEFAULT_PROCESSOR",
    "ProcessRequest",
    "ProcessResult",
    "StoredThenInterrupted",
    "database_fingerprint",
    "process_run",
    "processing_key",
    "processing_settings",
    "remove_abandoned_scratch",
]


DEFAULT_PROCESSOR = "linescan-stereo"
PACKAGE_VERSION = importlib.metadata.version("catenary")
"""The version recorded with each processing (``Processing.package_version``)."""
BLOCK_SCANS = 1024
EVIDENCE_CUT = 16
"""Image evidence points cut at a time (a worker's task with ``--workers`` above 1)."""
SAMPLES_DIR = "samples"
LEGACY_SCRATCH_AGE_S = 86400.0
"""Age [s] past which a hidden file that names no process is taken as abandoned."""

_MEASURED_SCHEMA = pa.schema(
    [
        ("scan", pa.int64()),
        ("position_m", pa.float64()),
        ("wire", pa.int32()),
        ("height_mm", pa.float64()),
        ("stagger_mm", pa.float64()),
        ("wear_width_mm", pa.float64()),
        ("cameras", pa.int16()),
        ("vehicle_fault", pa.bool_()),
        ("selection_uncertain", pa.bool_()),
        ("x_roof_mm", pa.float64()),
        ("z_roof_mm", pa.float64()),
    ]
)
"""Pass 1's intermediate file: the measurement chain's rows, before chainage and thickness."""


@dataclass(frozen=True)
class ProcessRequest:
    """What ``catenary process`` was asked to do."""

    run_path: Path
    rig_path: Path
    register_path: Path | None = None
    wire_type: str | None = None
    line: str | None = None
    track: str | None = None
    processor: str = DEFAULT_PROCESSOR
    replace: bool = False
    register: TrackRegister | None = None
    """The register of the run's track already read (the stored one), instead of
    ``register_path``."""
    workers: int = 1
    """Processes staging blocks at once (``catenary.measurement.parallel``) when the processor
    is a ``StagedProcessor``; 1: every block in this process."""
    into_run: int | None = None
    """The stored run to process again (``catenary reprocess``): the run file must have its
    content; a new processing of it is made unless its latest is alike (``ProcessingKey``:
    then ``already_stored``), whatever the rig calibration; its recorded file path is kept."""


STILL_M = 0.05
"""A run whose encoder advanced less than this did not move (its length prints as 0.0 m)."""


def _covered(length_m: float) -> str:
    still = ": the vehicle did not move" if length_m < STILL_M else ""
    return f"{length_m:.1f} m{still}"


@dataclass(frozen=True)
class ProcessResult:
    """What was stored (or found already stored: ``already_stored``, and then whether its
    alerts are still to be evaluated: ``alerts_pending``)."""

    run_id: int
    run_uuid: str
    already_stored: bool
    processing_uuid: str = ""
    alerts_pending: bool = False
    replaced: bool = False
    header: RunHeader | None = None
    line: str = ""
    track: str = ""
    length_m: float = 0.0
    chainage_range_m: tuple[float, float] = (math.nan, math.nan)
    alignment: ChainageAlignment | None = None
    spans: int = 0
    span_rows: int = 0
    samples: int = 0
    outside_spans: int = 0
    faulty: int = 0
    uncertain: int = 0
    """Samples the processor could not decide are the contact wire (``selection_uncertain``)."""
    minimum: SpanMeasurement | None = None
    samples_key: str | None = None
    """The samples file's key in the store."""
    samples_where: str = ""
    """The samples file's store and key, for people."""
    evidence: int = 0
    """Crops of image evidence stored (one per span and wire)."""
    evidence_where: str = ""
    sensors: str = ""
    """The vehicle sensors' filter and estimated noise (``SensorSmoother.describe``)."""

    def warning(self, run_path: Path) -> str | None:
        """The line to warn with when the run measured no span (it covered too little track,
        or none: the vehicle did not move), else None."""
        if self.spans:
            return None
        return f"warning: run {run_path} covers {_covered(self.length_m)}; no span measured"

    def summary_lines(self) -> list[str]:
        """The short summary of a stored run (the command adds its alerts and its id)."""
        header = self.header
        assert header is not None
        low, high = self.chainage_range_m
        lines = [
            f"run        line {self.line} track {self.track or '-'}, {header.direction} "
            f"chainage, {header.scans} scans, {self.length_m:.1f} m ({low:.1f} to {high:.1f} m)"
        ]
        alignment = self.alignment
        if alignment is not None and alignment.aligned:
            lines.append(
                f"chainage   aligned to the register: {alignment.matched} of "
                f"{alignment.turning_points} registration points on masts, residual RMS "
                f"{alignment.residual_rms_m:.2f} m (encoder error {1 / alignment.scale - 1:+.3%}, "
                f"start {header.start_chainage_m:.1f} m -> "
                f"{alignment.chainage_m(np.zeros(1))[0]:.1f} m)"
            )
        elif alignment is not None:
            lines.append(f"chainage   start + encoder distance ({alignment.reason})")
        wires = "" if self.span_rows == self.spans else f" ({self.span_rows} span-wires)"
        lines.append(f"spans      {self.spans}{wires}")
        if self.minimum is not None:
            m = self.minimum
            where = (
                f"span {m.span}" if m.mast_from is None else f"masts {m.mast_from} to {m.mast_to}"
            )
            lines.append(
                f"minimum    residual thickness {m.min_residual_thickness_mm:.2f} mm "
                f"({m.wire_type}) at chainage {m.min_at_chainage_m:.1f} m, {where}, "
                f"wire {m.wire}"
            )
        notes = []
        if self.outside_spans:
            notes.append(f"{self.outside_spans} outside the register's spans")
        if self.faulty:
            notes.append(f"{self.faulty} with a vehicle sensor fault (not in the span figures)")
        if self.uncertain:
            notes.append(
                f"{self.uncertain} not surely the contact wire (selection_uncertain; not in the "
                "span figures)"
            )
        extra = f" ({'; '.join(notes)})" if notes else ""
        lines.append(f"samples    {self.samples} in {self.samples_where}{extra}")
        if self.evidence:
            lines.append(f"evidence   {self.evidence} image crops in {self.evidence_where}")
        if self.sensors:
            lines.append(f"sensors    {self.sensors}")
        if self.replaced:
            lines.append("replaced   the run's earlier results (kept as its earlier processings)")
        return lines


PROCESSING_KEYS = frozenset({"vehicle_filter_hz"})
"""Keys of the config's ``[processing]`` section."""


def vehicle_filter_hz(settings: Settings) -> float:
    """``[processing] vehicle_filter_hz``: the cut-off of the vehicle sensors' zero-phase
    low-pass [Hz] (``catenary.measurement.sensors``; default ``DEFAULT_FILTER_HZ``, 0: off).
    A bad section, key or value is a ``UserError`` naming the config file, key and value."""
    where = settings.config_path or "config"
    section = settings.sections.get("processing", {})
    if not isinstance(section, Mapping):
        raise UserError(f"{where}: [processing] must be a table")
    unknown = sorted(set(section) - PROCESSING_KEYS)
    if unknown:
        hint = did_you_mean(unknown[0], PROCESSING_KEYS)
        raise UserError(f"{where}: unknown key processing.{unknown[0]}{hint}")
    value = section.get("vehicle_filter_hz", DEFAULT_FILTER_HZ)
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 <= value < math.inf:
        raise UserError(
            f"{where}: processing.vehicle_filter_hz must be 0 (off) or a positive number of "
            f"hertz, not {value!r}"
        )
    return float(value)


@dataclass(frozen=True)
class _Inputs:
    """Everything checked before anything is written."""

    header: RunHeader
    vehicle_filter_hz: float
    line: str
    track: str
    register: TrackRegister | None
    wire_types: dict[str, WireType]
    rig_text: str


def file_sha256(path: Path, stop: threading.Event | None = None) -> str:
    """SHA-256 of a file's content ("" once ``stop`` is set), read in 1 MiB pieces into one
    buffer: a fresh piece each time (``read``) would cost more than the hashing, in page
    faults of the new memory."""
    digest = hashlib.sha256()
    piece = memoryview(bytearray(1 << 20))
    with path.open("rb", buffering=0) as handle:
        while size := handle.readinto(piece):
            if stop is not None and stop.is_set():
                return ""
            digest.update(piece[:size])
    return digest.hexdigest()


def _line_and_track(
    request: ProcessRequest, header: RunHeader, register_tracks: list[tuple[str, str]]
) -> tuple[str, str]:
    line = request.line or header.line
    track = request.track or header.track
    if not (line and track) and len(register_tracks) == 1:
        line, track = line or register_tracks[0][0], track or register_tracks[0][1]
    if not line:
        raise UserError(
            f"{request.run_path}: the run names no line (root attribute 'line' is empty): "
            "give --line"
        )
    if not track and register_tracks:
        raise UserError(
            f"{request.run_path}: the run names no track (root attribute 'track' is empty): "
            "give --track"
        )
    for field, value, given in (("line", line, request.line), ("track", track, request.track)):
        where = f"--{field}" if given else f"{request.run_path}: root attribute {field!r}"
        problem = length_problem(where, value, CODE_LENGTH)
        if problem is not None:
            raise UserError(problem if given else f"{problem}: give --{field}")
    return line, track


def _check_names(request: ProcessRequest) -> None:
    """The rig calibration's name (its file's stem) and the run file's path fit their columns."""
    for problem in (
        length_problem(
            f"{request.rig_path}: the rig calibration's name (the file name without .toml)",
            request.rig_path.stem,
            NAME_LENGTH,
        ),
        length_problem(
            f"{request.run_path}: the run file's full path",
            str(request.run_path.resolve()),
            PATH_LENGTH,
        ),
    ):
        if problem is not None:
            raise UserError(problem)


def _check_inputs(
    request: ProcessRequest, header: RunHeader, settings: Settings, registry: PluginRegistry
) -> _Inputs:
    _check_names(request)
    filter_hz = vehicle_filter_hz(settings)
    if header.scans == 0:
        raise UserError(f"{request.run_path}: the run holds no scan")
    wire_types = registry.wire_types()
    if request.wire_type is not None and request.wire_type not in wire_types:
        known = ", ".join(sorted(wire_types))
        raise UserError(f"unknown wire type {request.wire_type!r} (known: {known})")
    register_file = None
    if request.register_path is not None:
        register_file = read_register(request.register_path, wire_types)
    given = request.register
    tracks = (
        sorted(register_file.tracks)
        if register_file
        else [(given.line, given.track)]
        if given
        else []
    )
    line, track = _line_and_track(request, header, tracks)
    register = register_file.track(line, track) if register_file else given
    if request.wire_type is None and register is None:
        raise UserError(
            "no wire type for the residual thickness: give --wire-type NAME, or a mast "
            "register (--masts) whose masts name their wire type"
        )
    try:
        rig_text = request.rig_path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UserError(f"{request.rig_path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"{request.rig_path}: cannot read the rig calibration ({exc})") from None
    return _Inputs(
        header=header,
        vehicle_filter_hz=filter_hz,
        line=line,
        track=track,
        register=register,
        wire_types=wire_types,
        rig_text=rig_text,
    )


def _processor(
    request: ProcessRequest, inputs: _Inputs, registry: PluginRegistry, settings: Settings
) -> tuple[BlockProcessor, VehicleGeometry]:
    """The processor (created: it reads and checks the rig; if it is a ``RunChecker``, it
    checks that the run fits the rig; if it is a ``WireTypesUser``, it is told the run's wire
    types) and the vehicle geometry."""
    found = registry.processors().get(request.processor)
    if found is None:
        known = ", ".join(sorted(registry.processors())) or "none"
        raise UserError(f"unknown processor {request.processor!r} (known: {known})")
    options = settings.sections.get("processors", {}).get(request.processor, {})
    if not isinstance(options, Mapping):
        raise UserError(f"{settings.config_path}: [processors.{request.processor}] must be a table")
    geometry = load_vehicle_geometry(request.rig_path)
    with registry.boundary("processor", request.processor):
        processor = found.create(request.rig_path, options)
        if isinstance(processor, RunChecker):
            try:
                processor.check_run(inputs.header)
            except UserError as exc:
                raise UserError(f"{request.run_path}: {exc}") from None
        if isinstance(processor, WireTypesUser):
            names = _run_wire_types(request.wire_type, inputs.register)
            processor.expect_wire_types([inputs.wire_types[name] for name in names])
    return processor, geometry


def _run_wire_types(wire_type: str | None, register: TrackRegister | None) -> list[str]:
    """The wire types a run may hold, sorted: its ``--wire-type``, else its track's in the
    mast register (one of the two is given: ``_check_inputs``)."""
    if wire_type is not None:
        return [wire_type]
    assert register is not None
    return sorted(set(register.wire_type))


def processing_settings(
    settings: Settings, processor: str, wire_type: str | None
) -> dict[str, Any]:
    """What a processing is made with besides the run file, the rig calibration and the
    package (``Processing.settings``): the processor's options (``[processors.NAME]``), the
    vehicle sensors' filter and the wire type given for the whole run."""
    options = settings.sections.get("processors", {}).get(processor, {})
    return {
        "processor_options": dict(options),
        "vehicle_filter_hz": vehicle_filter_hz(settings),
        "wire_type": wire_type,
    }


def processing_key(
    settings: Settings, processor: str, wire_type: str | None, rig_text: str
) -> ProcessingKey:
    """The ``ProcessingKey`` of a processing made now with these settings, processor, run wire
    type and rig calibration (its content)."""
    made_with = processing_settings(settings, processor, wire_type)
    return ProcessingKey(
        processor,
        PACKAGE_VERSION,
        settings_sha256(made_with),
        hashlib.sha256(rig_text.encode("utf-8")).hexdigest(),
    )


def _measure(
    run: RunFile,
    processor: BlockProcessor,
    boundary: Callable[[], AbstractContextManager[None]],
    chain: MeasurementChain,
    writer: SampleWriter,
    progress: Callable[[int], None],
    filter_hz: float,
    workers: int,
) -> tuple[TurningPointFinder, float, SensorSmoother]:
    """Pass 1: every block, its vehicle sensors smoothed below ``filter_hz``, through the
    processor (each call inside ``boundary``; the stage of ``workers`` blocks at once in
    worker processes unless 1: ``_workers``) and the chain; returns the turning points found,
    the run's last encoder position [m] and the sensors' smoother (their noise).
    ``progress`` is called after each block."""
    finder = TurningPointFinder()
    last_position = 0.0

    def keep(rows: TrackSamples) -> None:
        writer.write({f.name: getattr(rows, f.name) for f in _MEASURED_SCHEMA})
        good = ~rows.vehicle_fault & ~rows.selection_uncertain
        finder.push(rows.wire[good], rows.position_m[good], rows.stagger_mm[good])

    def observations(call: Callable[..., object], *args: object) -> WireObservations:
        with boundary():
            value = call(*args)
            if not isinstance(value, WireObservations):
                raise TypeError(f"returned {type(value).__name__}, not WireObservations")
        return value

    smoother = SensorSmoother(filter_hz, run.vehicle_interval_s)
    with ExitStack() as stack:
        processed: Iterator[tuple[ScanBlock, Callable[[], WireObservations]]]
        if workers == 1:
            processed = (
                (block, partial(processor.process, block))
                for block in run.blocks(BLOCK_SCANS, smoother=smoother)
            )
        else:
            assert isinstance(processor, StagedProcessor)
            pool = staged_blocks(
                run.path,
                processor.stage,
                run.blocks(BLOCK_SCANS, smoother=smoother, lines=False),
                workers,
            )
            processed = (
                (block, partial(_process_staged, processor, block, staged))
                for block, staged in stack.enter_context(closing(pool))
            )
        for block, process in processed:
            keep(chain.push(block, observations(process)))
            if block.scans:
                last_position = float(block.position_m[-1])
            progress(block.scans)
    keep(chain.finish(observations(processor.finish)))
    return finder, last_position, smoother


def _process_staged(
    processor: StagedProcessor, block: ScanBlock, staged: Future[Any]
) -> WireObservations:
    """``process_staged`` of ``block`` once its stage is done (its error raised here)."""
    return processor.process_staged(block, staged.result())


def _workers(request: ProcessRequest, processor: BlockProcessor, scans: int) -> int:
    """Worker processes for the run: ``request.workers``, no more than its blocks, and 1
    (in this process) for a processor that is not a ``StagedProcessor``."""
    if not isinstance(processor, StagedProcessor):
        return 1
    return max(1, min(request.workers, math.ceil(scans / BLOCK_SCANS)))


def _align(
    inputs: _Inputs, finder: TurningPointFinder, last_position_m: float
) -> tuple[ChainageAlignment, SpanLayout, np.ndarray[Any, Any]]:
    header = inputs.header
    turning = finder.finish()
    if inputs.register is None:
        alignment = ChainageAlignment.unaligned(
            header.start_chainage_m, header.direction, "no mast register"
        )
    else:
        alignment = align_to_register(
            turning, inputs.register.chainage_m, header.start_chainage_m, header.direction
        )
    ends = alignment.chainage_m(np.array([0.0, last_position_m]))
    if inputs.register is not None:
        layout = SpanLayout.from_register(inputs.register)
    else:
        layout = SpanLayout.from_turning_points(
            alignment.chainage_m(turning), (float(ends[0]), float(ends[1]))
        )
    return alignment, layout, ends


def _finish(
    measured: Path,
    writer: SampleWriter,
    alignment: ChainageAlignment,
    layout: SpanLayout,
    wire_types: dict[str, WireType],
    run_wire_type: str | None,
    crops: Mapping[str, SpanMinima],
) -> tuple[SpanAccumulator, int, int, int]:
    """Pass 2: chainage, span, wire type and residual thickness of every sample; returns
    the span statistics, the samples outside every span, the faulty ones and the uncertain
    ones (``selection_uncertain``). Faulty and uncertain samples are not in the statistics;
    ``crops`` get each span's and wire's thinnest of them (``minimum``) and the one nearest
    its first mast within ``HALF_LENGTH_M`` (``mast``)."""
    spans = SpanAccumulator(layout.boundaries_m)
    outside = faulty = uncertain = 0
    names = sorted({n for n in (*layout.wire_type, run_wire_type) if n is not None})
    for batch in read_sample_batches(measured):
        chainage = alignment.chainage_m(batch["position_m"])
        index = layout.index(chainage)
        if run_wire_type is not None:  # the whole run's, outside the spans too
            type_of_row = np.full(index.shape, names.index(run_wire_type))
        else:  # the register's: the span's first mast's
            per_span = np.array([names.index(str(n)) for n in layout.wire_type])
            type_of_row = np.where(index >= 0, per_span[index], -1)
        width = batch["wear_width_mm"]
        thickness = np.full(width.shape, np.nan)
        for k, name in enumerate(names):  # a loop per wire type
            rows = type_of_row == k
            wire = wire_types[name]
            thickness[rows] = wire.residual_thickness_mm(np.clip(width[rows], 0.0, wire.width_mm))
        fault = batch["vehicle_fault"]
        unsure = batch["selection_uncertain"]
        number = np.where(index >= 0, layout.number[index], -1)
        writer.write(
            {
                **batch,
                "chainage_m": chainage,
                "residual_thickness_mm": thickness,
                "span": number,
            }
        )
        usable = trusted(batch)
        usable &= np.isfinite(batch["height_mm"]) & np.isfinite(batch["stagger_mm"])
        outside += int(np.count_nonzero(index < 0))
        faulty += int(np.count_nonzero(fault))
        uncertain += int(np.count_nonzero(unsure))
        use = usable & (index >= 0)
        spans.add(
            index[use],
            batch["wire"][use],
            chainage[use],
            thickness[use],
            batch["height_mm"][use],
            batch["stagger_mm"][use],
        )
        from_mast = np.abs(chainage[use] - layout.boundaries_m[index[use]])
        for point, value in (
            ("minimum", thickness[use]),
            ("mast", np.where(from_mast <= HALF_LENGTH_M, from_mast, np.nan)),
        ):
            crops[point].add(
                index[use],
                batch["wire"][use],
                value,
                batch["scan"][use],
                batch["x_roof_mm"][use],
                batch["z_roof_mm"][use],
            )
    return spans, outside, faulty, uncertain


def _put_evidence(
    run_file: RunFile,
    processor: BlockProcessor,
    boundary: Callable[[], AbstractContextManager[None]],
    points: Mapping[str, list[EvidencePoint]],
    layout: SpanLayout,
    last_position_m: float,
    store: Store,
    processing_uuid: str,
    workers: int,
) -> int:
    """Pass 3: the image evidence at each of ``points`` (by ``POINTS``), put in the store
    (``catenary.measurement.evidence``), cut ``EVIDENCE_CUT`` points at a time in
    ``workers`` worker processes (no more than the cuts) unless 1 (the store written here
    meanwhile); returns how many crops."""
    header = run_file.header
    metres_per_scan = abs(last_position_m) / max(header.scans - 1, 1)
    cameras = sorted(header.camera_pixels)
    cuts: list[Cut] = []
    wheres: list[str] = []
    for where, chosen in points.items():
        columns = None
        if isinstance(processor, ImageLocator):
            with boundary():
                columns = point_columns(chosen, processor.image_columns)
        for first in range(0, len(chosen), EVIDENCE_CUT):
            cuts.append(
                Cut(
                    header.scans,
                    metres_per_scan,
                    chosen[first : first + EVIDENCE_CUT],
                    None if columns is None else columns[first : first + EVIDENCE_CUT],
                    cameras,
                )
            )
            wheres.append(where)
    with ExitStack() as stack:
        pngs: Iterator[list[bytes]]
        if min(workers, len(cuts)) <= 1:  # no pool started for what one process does
            pngs = (cut_pngs(run_file, cut) for cut in cuts)
        else:
            pool = with_run(run_file.path, cut_pngs, cuts, min(workers, len(cuts)))
            pngs = (done.result() for _, done in stack.enter_context(closing(pool)))
        count = 0
        for where, cut, cut_pngs_of in zip(wheres, cuts, pngs, strict=True):
            for point, png in zip(cut.points, cut_pngs_of, strict=True):
                span = int(layout.number[point.span])
                store.put_bytes(png, evidence_key(processing_uuid, span, point.wire, where))
                count += 1
    return count


def _span_rows(
    results: list[SpanStatistics],
    layout: SpanLayout,
    run_wire_type: str | None,
    increasing: bool,
) -> list[SpanMeasurement]:
    """The span measurements of the spans with a thickness, each wire with its position
    (``catenary.positions``: the run's direction is ``increasing`` chainage or not)."""
    kept = [s for s in results if s.thickness_samples > 0]
    middle = np.array([s.stagger_min_mm + s.stagger_max_mm for s in kept], dtype=np.float64)
    positions = wire_positions(
        np.zeros(len(kept), dtype=np.int64),
        np.array([s.span for s in kept], dtype=np.int64),
        middle if increasing else -middle,
        np.array([s.wire for s in kept], dtype=np.int64),
    )
    rows = []
    for s, position in zip(kept, positions.tolist(), strict=True):
        wire_type = run_wire_type or layout.wire_type[s.span]
        assert wire_type is not None
        rows.append(
            SpanMeasurement(
                span=int(layout.number[s.span]),
                mast_from=layout.mast_from[s.span],
                mast_to=layout.mast_to[s.span],
                start_chainage_m=float(layout.boundaries_m[s.span]),
                end_chainage_m=float(layout.boundaries_m[s.span + 1]),
                wire=s.wire,
                wire_position=position,
                wire_type=wire_type,
                min_residual_thickness_mm=s.min_residual_thickness_mm,
                min_at_chainage_m=s.min_at_chainage_m,
                mean_residual_thickness_mm=s.mean_residual_thickness_mm,
                height_min_mm=s.height_min_mm,
                height_max_mm=s.height_max_mm,
                stagger_min_mm=s.stagger_min_mm,
                stagger_max_mm=s.stagger_max_mm,
                samples=s.samples,
                height_at_start_mm=_or_none(s.height_at_start_mm),
                height_at_end_mm=_or_none(s.height_at_end_mm),
                stagger_at_start_mm=_or_none(s.stagger_at_start_mm),
            )
        )
    return rows


def _or_none(value_mm: float) -> float | None:
    return value_mm if math.isfinite(value_mm) else None


def _scratch_name(kind: str, token: str) -> str:
    """A hidden file of this process in the samples folder: ``.{kind}-{host}-{pid}-{token}``,
    so that another process can tell whether its writer is still alive."""
    return f".{kind}-{socket.gethostname()}-{os.getpid()}-{token}.parquet"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def database_fingerprint(engine: Engine) -> str:
    """8 hex digits naming ``engine``'s database (its URL without the password) in the names
    of the samples files it stores, so that a process can tell its own database's files."""
    url = engine.url.render_as_string(hide_password=True)
    return hashlib.sha256(url.encode("utf-8")).hexdigest()[:8]


def remove_abandoned_scratch(
    folder: Path,
    now_s: float | None = None,
    *,
    engine: Engine | None = None,
    store: Store | None = None,
) -> list[str]:
    """Remove the hidden files that processes of this host left in the samples folder when
    they were killed (``kill -9``, a power cut) and return them (paths, and store keys); a
    file whose process still runs, or another host's, is left alone. A file named without its
    process (written before the names carried one) is removed once ``LEGACY_SCRATCH_AGE_S``
    old.

    A process killed while it stored its run may have put the samples file, its envelope file and
    image evidence in the store (under its processing's UUID, which its hidden files' token begins
    with) without committing the processing. With ``engine`` and ``store``, for a hidden samples
    file of the database (the token ends with its ``database_fingerprint``) whose processing is not
    in the database, those objects are removed from the store; another database's hidden samples
    file is left for its own next process, and so is every one without ``engine`` and ``store``.
    """
    host, now_s = socket.gethostname(), time.time() if now_s is None else now_s
    database = "" if engine is None else database_fingerprint(engine)
    removed: list[str] = []
    for path in [*folder.glob(".pass1-*.parquet"), *folder.glob(".samples-*.parquet")]:
        kind, named = path.name[1 : -len(".parquet")].split("-", 1)
        parts = named.rsplit("-", 2)
        if len(parts) == 3 and parts[1].isdigit():
            abandoned = parts[0] == host and not _alive(int(parts[1]))
        else:
            try:
                abandoned = now_s - path.stat().st_mtime > LEGACY_SCRATCH_AGE_S
            except FileNotFoundError:
                continue
        if not abandoned:
            continue
        token = parts[-1]
        if kind == "samples" and len(token) == TOKEN_LENGTH:
            if engine is None or store is None or not token.endswith(database):
                continue  # for its own database's next process to tell if it was committed
            made = str(uuid.UUID(token[:32]))
            if not _committed(engine, made):
                stray = [
                    k
                    for prefix in (SAMPLES_DIR, ENVELOPES_PREFIX)
                    for k in store.keys(prefix)
                    if k.endswith(f"/{made}.parquet")
                ]
                stray += store.keys(evidence_prefix(made))
                for key in stray:
                    store.delete(key)
                removed.extend(stray)
        path.unlink(missing_ok=True)
        removed.append(str(path))
    return removed


TOKEN_LENGTH = 40
"""The token in the hidden files' names: the processing's UUID (32 hex digits) and the
database's fingerprint (8)."""


def _committed(engine: Engine, processing_uuid: str) -> bool:
    """Whether the database holds the processing ``processing_uuid``."""
    with session_scope(engine, read_only=True) as session:
        found = session.scalar(select(Processing.id).where(Processing.uuid == processing_uuid))
        return found is not None


def _run_to_process_again(session: Session, request: ProcessRequest, source_sha256: str) -> Run:
    """The stored run ``request.into_run``; a ``UserError`` if it is gone or the run file is
    not its content."""
    run = session.get(Run, request.into_run)
    if run is None:
        raise UserError(f"run {request.into_run} is no longer stored")
    if run.source_sha256 != source_sha256:
        raise UserError(
            f"{request.run_path}: its content is not that of run {run.uuid} (SHA-256 "
            f"{source_sha256}, the run's {run.source_sha256})"
        )
    return run


def _started_at(header: RunHeader) -> datetime:
    moment = datetime.fromisoformat(header.started_at.replace("Z", "+00:00"))
    return moment if moment.tzinfo is not None else moment.replace(tzinfo=UTC)


class StoredThenInterrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM (``interruption``) arrived while the run was stored: it is stored
    as ``run_id``, and nothing after the commit was done."""

    def __init__(self, run_id: int, interruption: KeyboardInterrupt) -> None:
        super().__init__(run_id)
        self.run_id = run_id
        self.interruption = interruption


class _StoredMeanwhile(Exception):
    """Another process stored the same run while this one measured it."""

    def __init__(self, run_id: int, run_uuid: str) -> None:
        super().__init__(run_id)
        self.run_id, self.run_uuid = run_id, run_uuid


def process_run(
    request: ProcessRequest,
    settings: Settings,
    registry: PluginRegistry,
    progress: Callable[[int], None] = lambda scans: None,
    on_start: Callable[[RunHeader], None] = lambda header: None,
) -> ProcessResult:
    """Process one run file into the database (module docstring); see ``ProcessResult``.

    The run file is opened once (its warnings, e.g. an interrupted recording, are given once)
    and stays open until the run is stored. Its SHA-256 is computed in a thread from the
    start: with ``request.workers`` 1 the run is checked against the stored ones once it is
    known, before the first block; else beside the workers, as soon as it is known (a run
    found stored then stops being measured)."""
    stop = threading.Event()
    with open_run(request.run_path) as run_file, ThreadPoolExecutor(1) as hasher:
        try:
            hashing = hasher.submit(file_sha256, request.run_path, stop)
            return _process_open_run(
                run_file, hashing, request, settings, registry, progress, on_start
            )
        finally:
            stop.set()  # a hash still running ends with its current piece


class _FoundStored(Exception):
    """The run is stored already, alike (``result``): nothing to do."""

    def __init__(self, result: ProcessResult) -> None:
        super().__init__(result.run_id)
        self.result = result


def _process_open_run(
    run_file: RunFile,
    hashing: Future[str],
    request: ProcessRequest,
    settings: Settings,
    registry: PluginRegistry,
    progress: Callable[[int], None],
    on_start: Callable[[RunHeader], None],
) -> ProcessResult:
    inputs = _check_inputs(request, run_file.header, settings, registry)
    processor, geometry = _processor(request, inputs, registry, settings)
    workers = _workers(request, processor, inputs.header.scans)
    made_with = processing_settings(settings, request.processor, request.wire_type)
    alike_key = processing_key(settings, request.processor, request.wire_type, inputs.rig_text)
    rig_sha256 = alike_key.rig_sha256
    store = open_store(settings)
    with open_database(settings, batch=True) as engine:

        def replacing() -> int | None:
            """The stored run this processing replaces (None: a new run), once the run file
            is hashed; ``_FoundStored`` if it is stored alike."""
            with session_scope(engine, read_only=True) as session:
                stored: Run | None
                if request.into_run is not None:
                    stored = _run_to_process_again(session, request, hashing.result())
                    latest = stored.processing
                    alike = latest is not None and ProcessingKey.of(latest) == alike_key
                else:
                    stored = find_stored_run(session, hashing.result(), rig_sha256)
                    alike = not request.replace
                if stored is not None and alike:
                    raise _FoundStored(
                        ProcessResult(
                            run_id=stored.id,
                            run_uuid=stored.uuid,
                            already_stored=True,
                            alerts_pending=stored.alerts_evaluated_at is None,
                            header=inputs.header,
                        )
                    )
                return None if stored is None else stored.id

        checked: list[int | None] = []  # replacing(), once known
        if workers == 1:
            try:
                checked.append(replacing())
            except _FoundStored as found:
                return found.result

        def advanced(scans: int) -> None:
            progress(scans)
            if not checked and hashing.done():
                checked.append(replacing())

        on_start(inputs.header)
        folder = settings.data_dir / SAMPLES_DIR
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UserError(
                f"{folder}: cannot create the samples folder ({exc.strerror})"
            ) from None
        remove_abandoned_scratch(folder, engine=engine, store=store)
        made = uuid.uuid4()
        token = made.hex + database_fingerprint(engine)
        measured = folder / _scratch_name("pass1", token)
        unstored = folder / _scratch_name("samples", token)
        placed: str | None = None  # the samples file in the store, until the commit
        kept: str | None = None
        try:
            with SampleWriter(measured, _MEASURED_SCHEMA) as writer:
                finder, last_position, smoother = _measure(
                    run_file,
                    processor,
                    lambda: registry.boundary("processor", request.processor),
                    MeasurementChain(geometry),
                    writer,
                    advanced,
                    inputs.vehicle_filter_hz,
                    workers,
                )
            if not checked:
                checked.append(replacing())
            replaced = checked[0]
            source_sha256 = hashing.result()
            key = samples_key(
                inputs.line, inputs.track, run_uuid(source_sha256, rig_sha256), str(made)
            )
            alignment, layout, ends = _align(inputs, finder, last_position)
            crops = {point: SpanMinima() for point in POINTS}
            with SampleWriter(unstored) as writer:
                spans, outside, faulty, uncertain = _finish(
                    measured,
                    writer,
                    alignment,
                    layout,
                    inputs.wire_types,
                    request.wire_type,
                    crops,
                )
                samples = writer.rows
            measured.unlink()
            if samples == 0:  # nothing at all to keep
                raise UserError(
                    f"run {request.run_path} covers {_covered(float(abs(ends[1] - ends[0])))}; "
                    "no wire was measured in it: nothing stored"
                )
            span_rows = _span_rows(
                spans.results(),
                layout,
                request.wire_type,
                inputs.header.direction == "increasing",
            )
            cropped = _put_evidence(
                run_file,
                processor,
                lambda: registry.boundary("processor", request.processor),
                {point: found.points() for point, found in crops.items()},
                layout,
                last_position,
                store,
                str(made),
                workers,
            )
            levels = envelope_bytes(unstored)
            header = inputs.header
            try:
                with interruptions_held():
                    with session_scope(engine) as session:
                        # the check that counts is in the transaction that stores: on SQLite it
                        # holds the write lock, so a concurrent process of the same run waits
                        # for it here and then finds the run stored
                        if replaced is None:
                            stored = find_stored_run(session, source_sha256, rig_sha256)
                            if stored is not None:
                                raise _StoredMeanwhile(stored.id, stored.uuid)
                        elif request.into_run is not None:  # the run locked till the commit
                            stored = session.get(Run, replaced, with_for_update=True)
                            latest = None if stored is None else stored.processing
                            if latest is not None and ProcessingKey.of(latest) == alike_key:
                                assert stored is not None
                                raise _StoredMeanwhile(stored.id, stored.uuid)
                        run, processing = store_processing(
                            session,
                            line=inputs.line,
                            track=inputs.track,
                            register=inputs.register,
                            geometry=geometry,
                            rig_name=request.rig_path.stem,
                            rig_text=inputs.rig_text,
                            replacing=replaced,
                            span_rows=span_rows,
                            run_values=dict(
                                direction=header.direction,
                                source_sha256=source_sha256,
                                started_at=_started_at(header),
                                scans=header.scans,
                                status="complete",
                                error=None,
                                alerts_evaluated_at=None,  # new or replaced spans: pending
                            )
                            | (
                                {}  # processed again from wherever: the run's file stays
                                if request.into_run is not None
                                else {"source_file": str(request.run_path.resolve())}
                            ),
                            processing_values=dict(
                                uuid=str(made),
                                processor=request.processor,
                                package_version=PACKAGE_VERSION,
                                settings=made_with,
                                settings_sha256=settings_sha256(made_with),
                                processed_at=datetime.now(UTC),
                                wire_type=request.wire_type,
                                length_m=float(abs(ends[1] - ends[0])),
                                chainage_aligned=alignment.aligned,
                                chainage_offset_m=alignment.offset_m,
                                encoder_scale=alignment.scale,
                                alignment_matched=alignment.matched,
                                alignment_rms_m=alignment.residual_rms_m
                                if alignment.aligned
                                else None,
                            ),
                        )
                        # into the store before the commit; the hidden file names this
                        # process and the processing until the commit, so that a kill
                        # before or after it is told apart and tidied
                        # (remove_abandoned_scratch)
                        placed = key
                        written = store.put_file(unstored, key)
                        processing.samples_key = written.key
                        processing.samples_size_bytes = written.size_bytes
                        processing.samples_sha256 = written.sha256
                        store.put_bytes(levels, envelope_key(key))
                        session.flush()
                        stored_ids = run.id, run.uuid, processing.uuid
                    kept, placed = placed, None  # the stored run's: never removed from here on
            except IntegrityError:
                # PostgreSQL: a concurrent process stored the same run first; this insert
                # waited for its commit and then broke a unique key
                with session_scope(engine, read_only=True) as session:
                    stored = find_stored_run(session, source_sha256, rig_sha256)
                if stored is None or replaced is not None:
                    raise
                raise _StoredMeanwhile(stored.id, stored.uuid) from None
            unstored.unlink()
        except BaseException as exc:
            for path in (measured, unstored):
                path.unlink(missing_ok=True)
            with suppress(StoreError):  # unreachable: the next process removes them
                if placed is not None:
                    store.delete(placed)
                if kept is None:
                    for key in store.keys(evidence_prefix(str(made))):
                        store.delete(key)
                if placed is not None:  # last: the folder it would be in may be the fault
                    store.delete(envelope_key(placed))
            if isinstance(exc, _FoundStored):
                return exc.result
            if isinstance(exc, _StoredMeanwhile):
                return ProcessResult(
                    run_id=exc.run_id,
                    run_uuid=exc.run_uuid,
                    already_stored=True,
                    header=inputs.header,
                )
            if isinstance(exc, KeyboardInterrupt) and kept is not None:
                raise StoredThenInterrupted(stored_ids[0], exc) from None
            raise
    run_id, stored_uuid, processing_uuid = stored_ids
    registry.run_stored(run_id, settings.database_url)
    minimum = min(span_rows, key=lambda r: r.min_residual_thickness_mm, default=None)
    return ProcessResult(
        run_id=run_id,
        run_uuid=stored_uuid,
        processing_uuid=processing_uuid,
        already_stored=False,
        replaced=replaced is not None,
        header=inputs.header,
        line=inputs.line,
        track=inputs.track,
        length_m=float(abs(ends[1] - ends[0])),
        chainage_range_m=(float(min(ends)), float(max(ends))),
        alignment=alignment,
        spans=len({r.span for r in span_rows}),
        span_rows=len(span_rows),
        samples=samples,
        outside_spans=outside,
        faulty=faulty,
        uncertain=uncertain,
        minimum=minimum,
        samples_key=kept,
        samples_where=store.describe(kept),
        evidence=cropped,
        evidence_where=store.describe(evidence_prefix(processing_uuid)),
        sensors=smoother.describe(),
    )
