"""``catenary reprocess``: stored runs processed again from their run files, on Dask.

A fleet reprocesses its runs when a rig is recalibrated or the processor improves. The runs
are selected in the database (``Selection``), and each becomes one task on a Dask
distributed cluster: an existing one (``scheduler``, ``tcp://HOST:8786``) or a
``LocalCluster`` of worker processes on 127.0.0.1. A task (``reprocess_run``) is a pure
function of plain values (``ReprocessTask``: the config file's path, the database URL, the
run's id, the rig calibration's name and content, the processor); in its worker it:

1. **skips** a run whose latest processing is alike what it would make (``ProcessingKey``:
   processor, catenary's version, settings, rig calibration), so a second ``reprocess``, or
   a task retried after its worker died after the commit, stores nothing;
2. **finds the run file**: the path the run was recorded from, if this machine reads it, else
   the store's ``runs/RUN.h5`` (``push --run-files``), copied to a local scratch folder first
   (an HDF5 file is read at random places, and the copy is streamed once at the store's full
   rate); a run whose file is reachable neither way is skipped, saying why;
3. **processes it** as ``process --replace`` does (``ProcessRequest.into_run``): the register
   as stored now, the run's own line, track and wire type, the settings of the config, the
   file checked against the run's content; the new processing is stored in one transaction
   that checks again, the run locked, that no alike processing was stored meanwhile. A worker
   killed mid-task stores nothing (the transaction is atomic; its scratch files are tidied by
   the next process in that data directory, as after a killed ``process``), and Dask runs the
   task again on another worker (``distributed.scheduler.allowed-failures``, 3 by default).

A user's error in one run (an unreadable file, a changed file) fails that run alone, in one
line; the others go on.
"""

from __future__ import annotations

import logging
import os
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from datetime import UTC, date, datetime, timedelta
from datetime import time as day_time
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from sqlalchemy import select
from sqlalchemy.orm import Session

from catenary.config import Settings
from catenary.errors import UserError, one_line
from catenary.fleet.transfer import run_file_key
from catenary.measurement.process import (
    DEFAULT_PROCESSOR,
    ProcessRequest,
    process_run,
    processing_key,
)
from catenary.measurement.vehicle import load_vehicle_geometry
from catenary.plugins.context import CommandContext
from catenary.storage.database import open_database, session_scope
from catenary.storage.models import Run, Vehicle
from catenary.storage.rigs import latest_rig_calibration
from catenary.storage.runs import (
    ProcessingKey,
    find_run,
    latest_processing,
    list_runs,
    track_register,
)
from catenary.storage.store import Store, StoreError, open_store

if TYPE_CHECKING:
    from distributed import Client

__all__ = [
    "Outcome",
    "ReprocessTask",
    "Selection",
    "reprocess",
    "reprocess_run",
    "select_runs",
]

Status = Literal["stored", "skipped", "failed"]


@dataclass(frozen=True)
class Selection:
    """Which stored runs to process again: those ``references`` name (ids, UUIDs, prefixes;
    none: every run) and that are on ``line`` and ``track``, started on ``since`` or later and
    on ``until`` or earlier (UTC dates), measured by ``vehicle``, and, if ``stale``, whose
    latest processing is not alike what reprocessing would make now."""

    references: tuple[str, ...] = ()
    line: str | None = None
    track: str | None = None
    since: date | None = None
    until: date | None = None
    vehicle: str | None = None
    stale: bool = False


@dataclass(frozen=True)
class ReprocessTask:
    """One run to process again, in plain values (a Dask task's argument)."""

    config_path: str | None
    database_url: str
    run_id: int
    run_uuid: str
    rig_name: str
    rig_text: str
    processor: str = DEFAULT_PROCESSOR


@dataclass(frozen=True)
class Outcome:
    """What became of one run: ``stored`` (as ``processing_uuid``), ``skipped`` or ``failed``
    (``reason``); the bytes of its run file copied from the store and how long that took."""

    run_id: int
    run_uuid: str
    status: Status
    reason: str = ""
    processing_uuid: str = ""
    copied_bytes: int = 0
    copy_s: float = 0.0
    elapsed_s: float = 0.0

    def line(self) -> str:
        """One line for people."""
        head = f"run {self.run_id} ({self.run_uuid}): {self.status}"
        if self.status == "stored":
            copied = (
                f", its file copied from the store ({self.copied_bytes / 1e6:.1f} MB at "
                f"{self.copied_bytes / 1e6 / max(self.copy_s, 1e-9):.0f} MB/s)"
                if self.copied_bytes
                else ""
            )
            return f"{head} as processing {self.processing_uuid} in {self.elapsed_s:.1f} s{copied}"
        return f"{head}: {self.reason}"


def select_runs(
    session: Session,
    selection: Selection,
    settings: Settings,
    rig: tuple[str, str] | None,
    processor: str = DEFAULT_PROCESSOR,
) -> list[tuple[Run, str, str]]:
    """The runs ``selection`` names, oldest first, each with the rig calibration to process it
    with (its name and content): ``rig``, else its vehicle's latest."""
    runs = list_runs(session, line=selection.line, track=selection.track)
    if selection.references:
        named = {find_run(session, reference).id for reference in selection.references}
        runs = [run for run in runs if run.id in named]
    if selection.since is not None:
        start = datetime.combine(selection.since, day_time(), UTC)
        runs = [run for run in runs if run.started_at >= start]
    if selection.until is not None:
        end = datetime.combine(selection.until + timedelta(days=1), day_time(), UTC)
        runs = [run for run in runs if run.started_at < end]
    if selection.vehicle is not None:
        if session.scalar(select(Vehicle.id).where(Vehicle.name == selection.vehicle)) is None:
            raise UserError(f"no vehicle {selection.vehicle!r} in the database")
        runs = [run for run in runs if run.vehicle.name == selection.vehicle]
    chosen = []
    latest_rigs: dict[int, tuple[str, str]] = {}
    for run in runs:
        if rig is None:
            if run.vehicle_id not in latest_rigs:
                calibration = latest_rig_calibration(session, run.vehicle_id)
                latest_rigs[run.vehicle_id] = calibration.name, calibration.content_toml
            name, text = latest_rigs[run.vehicle_id]
        else:
            name, text = rig
        latest = run.processing  # None: half stored; its task says so
        if (
            selection.stale
            and latest is not None
            and ProcessingKey.of(latest)
            == processing_key(settings, processor, latest.wire_type, text)
        ):
            continue
        chosen.append((run, name, text))
    return chosen


def reprocess(
    settings: Settings,
    selection: Selection,
    *,
    rig_path: Path | None = None,
    processor: str = DEFAULT_PROCESSOR,
    scheduler: str | None = None,
    workers: int | None = None,
    on_selected: Callable[[int], None] = lambda runs: None,
    on_outcome: Callable[[Outcome], None] = lambda outcome: None,
) -> list[Outcome]:
    """Process the selected runs again on Dask (module docstring); each run's outcome is
    given to ``on_outcome`` as it finishes, and all are returned in that order. The workers
    read ``settings``' config file (at the same path) and database URL."""
    rig = None
    if rig_path is not None:
        try:
            rig = rig_path.stem, rig_path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise UserError(f"{rig_path}: cannot read the rig calibration ({exc})") from None
    with open_database(settings) as engine, session_scope(engine, read_only=True) as session:
        chosen = select_runs(session, selection, settings, rig, processor)
    on_selected(len(chosen))
    if not chosen:
        return []
    config = None if settings.config_path is None else str(settings.config_path.resolve())
    tasks = [
        ReprocessTask(config, settings.database_url, run.id, run.uuid, name, text, processor)
        for run, name, text in chosen
    ]
    with _dask_client(scheduler, workers or os.cpu_count() or 1) as client:
        return _run_tasks(client, tasks, on_outcome)


@contextmanager
def _dask_client(scheduler: str | None, workers: int) -> Iterator[Client]:
    """A client of the scheduler at ``scheduler``, else of a new ``LocalCluster`` of
    ``workers`` single-threaded worker processes on 127.0.0.1."""
    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=10)  # type: ignore[no-untyped-call]
        except (OSError, TimeoutError) as exc:
            raise UserError(
                f"cannot reach the Dask scheduler {scheduler}: {one_line(exc)}"
            ) from None
        with client:
            yield client
        return
    with (
        LocalCluster(  # type: ignore[no-untyped-call]
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
            silence_logs=logging.ERROR,
        ) as cluster,
        Client(cluster) as client,  # type: ignore[no-untyped-call]
    ):
        yield client


def _run_tasks(
    client: Client, tasks: Sequence[ReprocessTask], on_outcome: Callable[[Outcome], None]
) -> list[Outcome]:
    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    futures = {client.submit(reprocess_run, task, pure=False): task for task in tasks}
    outcomes = []
    for future in as_completed(futures):  # type: ignore[no-untyped-call]
        task = futures[future]
        try:
            outcome = future.result()
        except KilledWorker:
            outcome = _failed(
                task, "the workers running it died (distributed.scheduler.allowed-failures)", 0.0
            )
        except Exception as exc:  # the task could not run (a worker without catenary...)
            outcome = _failed(task, one_line(exc), 0.0)
        on_outcome(outcome)
        outcomes.append(outcome)
    return outcomes


def _failed(task: ReprocessTask, reason: str, elapsed_s: float) -> Outcome:
    return Outcome(task.run_id, task.run_uuid, "failed", reason, elapsed_s=elapsed_s)


@lru_cache(maxsize=4)
def _context(config_path: str | None, database_url: str) -> CommandContext:
    """The worker's settings and plugin registry for these settings (made once a process)."""
    return CommandContext(None if config_path is None else Path(config_path), database_url)


def reprocess_run(task: ReprocessTask) -> Outcome:
    """Process one stored run again (the Dask task: module docstring); never raises for a
    run's own problems: they are its outcome."""
    started = time.monotonic()
    try:
        return _reprocess_run(task, started)
    except UserError as exc:
        return _failed(task, str(exc), time.monotonic() - started)
    except Exception as exc:  # a bug, or a fault of the machine: this run's, in one line
        return _failed(task, one_line(exc), time.monotonic() - started)


def _reprocess_run(task: ReprocessTask, started: float) -> Outcome:
    context = _context(task.config_path, task.database_url)
    settings, registry = context.settings, context.registry

    def outcome(
        status: Status, reason: str = "", processing_uuid: str = "", copied: int = 0
    ) -> Outcome:
        return Outcome(
            task.run_id,
            task.run_uuid,
            status,
            reason,
            processing_uuid,
            copied,
            copy_s if copied else 0.0,
            time.monotonic() - started,
        )

    copy_s = 0.0

    with (
        open_database(settings, batch=True) as engine,
        session_scope(engine, read_only=True) as session,
    ):
        run = session.get(Run, task.run_id)
        if run is None:
            return outcome("skipped", "no longer stored")
        latest = latest_processing(run)
        if ProcessingKey.of(latest) == processing_key(
            settings, task.processor, latest.wire_type, task.rig_text
        ):
            return outcome("skipped", f"already processed so (processing {latest.uuid})")
        track = run.track
        request = ProcessRequest(
            run_path=Path(run.source_file),
            rig_path=Path(),
            register=track_register(run.line.code, track.code, track.masts)
            if track is not None and track.masts
            else None,
            wire_type=latest.wire_type,
            line=run.line.code,
            track=None if track is None else track.code,
            processor=task.processor,
            into_run=run.id,
        )
        vehicle, store_key = run.vehicle.name, run.source_key or run_file_key(run.uuid)
    store = open_store(settings)
    with tempfile.TemporaryDirectory(prefix="catenary-reprocess-") as scratch:
        rig_path = Path(scratch) / f"{task.rig_name}.toml"
        rig_path.write_text(task.rig_text, encoding="utf-8")
        rig_vehicle = load_vehicle_geometry(rig_path).name
        if rig_vehicle != vehicle:
            return outcome(
                "failed",
                f"rig calibration {task.rig_name!r} is of vehicle {rig_vehicle!r}; the run was "
                f"measured by {vehicle!r}",
            )
        copy_s = time.monotonic()
        try:
            with _run_file(request.run_path, store, store_key, Path(scratch)) as (path, copied):
                copy_s = time.monotonic() - copy_s
                made = replace(request, run_path=path, rig_path=rig_path)
                result = process_run(made, settings, registry)
        except _Unreachable as exc:
            return outcome("skipped", str(exc))
    if result.already_stored:
        return outcome("skipped", "processed so meanwhile (by another task)")
    return outcome("stored", processing_uuid=result.processing_uuid, copied=copied)


class _Unreachable(Exception):
    """The run file is reachable neither where it was recorded nor in the store."""


@contextmanager
def _run_file(recorded: Path, store: Store, key: str, scratch: Path) -> Iterator[tuple[Path, int]]:
    """The run file as a local path and the bytes copied for it: the recorded file if this
    machine reads it, else the store's ``key`` (copied into ``scratch`` unless the store is a
    folder here); ``_Unreachable`` if neither."""
    if recorded.is_file() and os.access(recorded, os.R_OK):
        yield recorded, 0
        return
    try:
        in_store = store.exists(key)
    except StoreError as exc:
        raise _Unreachable(f"{recorded} is not readable here, and {exc}") from None
    if not in_store:
        raise _Unreachable(
            f"{recorded} is not readable here and the store has no {store.describe(key)} "
            "(catenary push --run-files sends it)"
        )
    with store.readable(key, scratch) as path:
        yield path, 0 if store.local_path(key) is not None else path.stat().st_size
