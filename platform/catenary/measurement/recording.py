"""Recording a run file from a scan source and, optionally, a vehicle sensor
source, through the one :class:`~catenary.measurement.runfile.RunFileWriter`.

How the sources combine
-----------------------
* The **scan source** (``--source NAME``: ``simulator`` now, cameras later; ``recorded``
  replays a run file) is a registered :class:`~catenary.plugins.types.Source` whose stream
  has a ``header`` and ``blocks(block_scans)`` (:class:`~catenary.plugins.types.ScanStream`).
  Its header becomes the run's root attributes and cameras; its blocks' positions, times and
  lines are appended as they come.
* The **vehicle sensor source** (``--vehicle-source NAME``, optional: ``can``, live bus or
  log) is a registered ``VehicleSource`` whose stream is a ``VehicleStream``: it gives no
  scans but timestamped displacement samples on the scan clock, with ``fault`` set where
  they must not be trusted. After each block of scans the recorder writes its samples up to
  the block's last scan time plus :data:`VEHICLE_MARGIN_S` (so every scan has samples on
  both sides), and at the end asks for the rest with ``final=True``. Without a vehicle
  source, the scan source's own ``block.vehicle`` samples are written (at the scan times).
  The two kinds are registered apart, so naming one in the other's role is a one-line error
  before anything is opened.
* Every call into a source runs inside the plugins' error boundary
  (``catenary.plugins.manager.plugin_errors``): a source's own failure is one line naming it
  and its plugin.
* **Faults.** The run file has no fault column: a sample the source flags is written as NaN,
  which the reader (:mod:`catenary.measurement.runfile`) takes as a faulty reading and flags every
  scan between the valid samples either side of it.

Stopping
--------
At the source's end, after ``--max-scans``, or on Ctrl-C or SIGTERM. Either signal (or a
``KeyboardInterrupt`` from a source) while waiting on the source stops at once; arriving while
a block is being written, it lets that block finish and stops after it, so the file never
holds half a block. Either way the blocks written so far are kept, the vehicle samples up to
the last scan are written, and the file is closed as complete (FORMATS.md's recording
state: ``complete = True`` with ``completed_scans`` and ``completed_at``) for the scans it
holds; the command prints one line with the number of scans kept and exits with status 130
(the shell's convention for Ctrl-C; 143 for SIGTERM). The file is created with
``complete = False``: SIGKILL leaves the blocks flushed before it, marked so. An error (a
source failing, bad data from a source) closes the file leaving ``complete = False`` (it
reads as interrupted, with one warning) and is reported in one line saying how many scans
were kept. A run file with no scan is removed (a source that gives no scan at all
is an error).

A full disk
-----------
HDF5 cannot close a file whose writes failed: its metadata on disk would then claim what the
file does not hold. So the recorder never lets a write fail for want of room: each block is
flushed to the file, and before writing the next one it checks that the file may grow by
twice the larger of that block's bytes and the last block's growth, plus
:data:`CLOSE_MARGIN_BYTES` for closing (the room is the file system's free space and the
process's file size limit, ``RLIMIT_FSIZE``). When it may not, the recording stops there like
Ctrl-C: the file is closed as complete for the blocks it holds, and a
:class:`DiskFull` error says so. A write that fails all the same (another process filled the
disk in between) is an error as above, and the file may then be unreadable.

Configuration
-------------
A ``[record]`` section may hold ``source``, ``source_options`` (a table), ``vehicle_source``,
``vehicle_options``, ``max_scans`` and ``block_scans``; command-line options win, and a
section's options apply only to the source it names. ``KEY=VALUE`` options are read as TOML
values (``20``, ``1.5``, ``true``, ``{a = 1}``), else as plain strings (``can0``,
``/data/run.blf``); quote a string that looks like a number: ``track='"1"'``.
"""

from __future__ import annotations

import os
import resource
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any, Final, Self

import numpy as np

from catenary.domain import DEFAULT_BLOCK_SCANS, RunHeader, ScanBlock, VehicleSamples
from catenary.errors import UserError
from catenary.measurement.runfile import RunFileWriter
from catenary.plugins.manager import plugin_errors
from catenary.plugins.types import ScanStream, VehicleStream

__all__ = [
    "CLOSE_MARGIN_BYTES",
    "VEHICLE_MARGIN_S",
    "DiskFull",
    "Recording",
    "record_run",
]

VEHICLE_MARGIN_S: Final = 0.5
"""Vehicle samples are written up to this long after the last scan written [s]."""
CLOSE_MARGIN_BYTES: Final = 4 << 20
"""Room kept for closing a run file (its last vehicle samples, state and metadata) [bytes]."""


class DiskFull(UserError):
    """The disk (or the file size limit) has no room for the next block: the run file was
    closed as complete for the blocks it holds (none: it was removed)."""

    def __init__(self, path: Path, scans: int) -> None:
        kept = f"kept {scans} complete scans" if scans else "nothing recorded"
        super().__init__(f"disk full writing {path} after {scans} scans: {kept}")


def _room_bytes(path: Path) -> int:
    """How many bytes the file ``path`` may still grow by: the free space of its file system
    (for this user) and the process's file size limit."""
    stat = os.statvfs(path)
    room = stat.f_bavail * stat.f_frsize
    limit, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
    if limit != resource.RLIM_INFINITY:
        room = min(room, limit - path.stat().st_size)
    return room


class _Room:
    """Whether the next block fits (module docstring, "A full disk")."""

    def __init__(self, path: Path) -> None:
        self._path = path
        self._size = path.stat().st_size
        self._growth = 0

    def fits(self, block: ScanBlock, n: int) -> bool:
        lines = sum(camera.lines[:n].nbytes for camera in block.cameras.values())
        # + position and time, and a vehicle sample (time and three sensors) per scan at most
        need = 2 * max(self._growth, lines + 48 * n) + CLOSE_MARGIN_BYTES
        return _room_bytes(self._path) >= need

    def written(self) -> None:
        """Note the file's growth by the block just written and flushed."""
        size = self._path.stat().st_size
        self._growth, self._size = size - self._size, size


@dataclass(frozen=True)
class Recording:
    """What :func:`record_run` wrote."""

    path: Path
    scans: int
    vehicle_samples: int
    flagged_vehicle_samples: int  # samples the source flagged (written as NaN)
    interrupted: bool  # stopped by Ctrl-C or SIGTERM
    terminated: bool = False  # stopped by SIGTERM


class _VehicleWriter:
    """Appends vehicle samples, the flagged ones (and missing readings) as NaN."""

    def __init__(self, writer: RunFileWriter, source: str) -> None:
        self._writer = writer
        self._source = source
        self.samples = 0
        self.flagged = 0

    def push(self, samples: VehicleSamples) -> None:
        time_s = np.asarray(samples.time_s, dtype=np.float64)
        series = [
            np.asarray(samples.left_mm, dtype=np.float64),
            np.asarray(samples.right_mm, dtype=np.float64),
            np.asarray(samples.lateral_mm, dtype=np.float64),
        ]
        if time_s.ndim != 1 or any(v.shape != time_s.shape for v in series):
            raise UserError(f"{self._source}: vehicle samples of mismatched lengths")
        if time_s.shape[0] == 0:
            return
        values = np.stack(series)
        fault = np.asarray(samples.fault, dtype=bool)
        if fault.shape != time_s.shape:
            fault = np.zeros(time_s.shape, dtype=bool)
        fault = fault | ~np.isfinite(values).all(axis=0)  # a missing reading is a fault too
        self.samples += int(time_s.shape[0])
        self.flagged += int(np.count_nonzero(fault))
        values = np.where(fault, np.nan, values)
        try:
            self._writer.append_vehicle(time_s, values[0], values[1], values[2])
        except ValueError as exc:
            raise UserError(f"{self._source}: invalid vehicle samples: {exc}") from None


class _InterruptGuard:
    """Ctrl-C and SIGTERM during a recording.

    Installed as the SIGINT and SIGTERM handler (in the main thread only). The first signal
    sets ``requested`` (and ``terminated`` for SIGTERM); it also raises ``KeyboardInterrupt``
    unless a write is under way (:meth:`deferred`), in which case the recording stops after
    the write. Later ones only set ``requested``, so the file is always closed properly.
    """

    def __init__(self) -> None:
        self.requested = False
        self.terminated = False
        self._deferring = 0
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> Self:
        if threading.current_thread() is threading.main_thread():
            self._previous = {
                number: signal.signal(number, self._handle)
                for number in (signal.SIGINT, signal.SIGTERM)
            }
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        for number, previous in self._previous.items():
            # None: a handler not installed from Python; SIGINT's is then Python's own
            fallback = signal.default_int_handler if number == signal.SIGINT else signal.SIG_DFL
            signal.signal(number, previous if previous is not None else fallback)
        self._previous = {}

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        first = not self.requested
        self.requested = True
        if first:
            self.terminated = signum == signal.SIGTERM
        if first and not self._deferring:
            raise KeyboardInterrupt

    @contextmanager
    def deferred(self) -> Iterator[None]:
        """Ctrl-C inside only sets ``requested``."""
        self._deferring += 1
        try:
            yield
        finally:
            self._deferring -= 1


def _append_scans(writer: RunFileWriter, block: ScanBlock, n: int, source: str) -> None:
    lines = {name: camera.lines[:n] for name, camera in block.cameras.items()}
    try:
        writer.append(block.position_m[:n], block.time_s[:n], lines)
    except ValueError as exc:
        raise UserError(f"{source}: invalid block of scans: {exc}") from None


def _slice_vehicle(samples: VehicleSamples, n: int) -> VehicleSamples:
    return VehicleSamples(
        time_s=samples.time_s[:n],
        left_mm=samples.left_mm[:n],
        right_mm=samples.right_mm[:n],
        lateral_mm=samples.lateral_mm[:n],
        fault=samples.fault[:n],
    )


def record_run(
    path: str | Path,
    scans: ScanStream,
    *,
    vehicle: VehicleStream | None = None,
    max_scans: int | None = None,
    block_scans: int = DEFAULT_BLOCK_SCANS,
    overwrite: bool = False,
    progress: Callable[[int], None] | None = None,
    scan_source: str = "scan source",
    vehicle_source: str = "vehicle source",
) -> Recording:
    """Record ``scans`` (and ``vehicle``'s samples) into the run file ``path``.

    Parameters
    ----------
    path : path-like
        The run file to create (``UserError`` if it exists, unless ``overwrite``).
    scans : ScanStream
        The open scan source: its ``header`` and ``blocks(block_scans)``.
    vehicle : VehicleStream, optional
        The open vehicle sensor source; none: the scan blocks' own vehicle samples.
    max_scans : int, optional
        Stop after this many scans.
    block_scans : int
        Scans asked of the source per block.
    progress : callable, optional
        Called with the number of scans written after each block.
    scan_source, vehicle_source : str
        Names for messages (``"source 'simulator'"``).

    Returns the :class:`Recording`; ``interrupted`` is true when Ctrl-C or SIGTERM stopped it
    (``terminated``: SIGTERM; the file
    is complete for the scans it holds). Errors: module docstring. The streams are not closed.
    """
    path = Path(path)
    if max_scans is not None and max_scans < 1:
        raise ValueError(f"max_scans must be positive, got {max_scans}")
    if path.exists() and not overwrite:
        raise UserError(f"{path}: already exists (not overwritten)")
    if not path.parent.is_dir():
        raise UserError(f"{path.parent}: no such directory")
    header: RunHeader = scans.header
    cameras = {
        name: (pixels, header.camera_bit_depth[name])
        for name, pixels in header.camera_pixels.items()
    }
    with _InterruptGuard() as guard:
        with guard.deferred():
            try:
                writer = RunFileWriter(
                    path,
                    line=header.line,
                    track=header.track,
                    vehicle=header.vehicle,
                    direction=header.direction,
                    start_chainage_m=header.start_chainage_m,
                    started_at=header.started_at,
                    scan_rate_hz=header.scan_rate_hz,
                    cameras=cameras,
                    overwrite=overwrite,
                )
            except ValueError as exc:
                raise UserError(f"{scan_source}: invalid run header: {exc}") from None
        samples = _VehicleWriter(writer, vehicle_source if vehicle is not None else scan_source)
        try:
            full = _stream_blocks(
                writer,
                samples,
                guard,
                scans,
                vehicle,
                max_scans,
                block_scans,
                progress,
                scan_source,
                vehicle_source,
            )
        except BaseException as exc:
            kept = writer.scans
            writer.abort()
            if kept == 0:
                path.unlink(missing_ok=True)
            if isinstance(exc, UserError | OSError) and kept:
                reason = str(exc) if isinstance(exc, UserError) else f"{exc.strerror or exc}"
                raise UserError(
                    f"{reason}; kept {kept} scans in {path} (marked complete = false: reads "
                    "as interrupted)"
                ) from None
            raise
    if writer.scans == 0:  # nothing to keep: leave no empty run behind
        path.unlink(missing_ok=True)
    if full:
        raise DiskFull(path, writer.scans)
    if writer.scans == 0 and not guard.requested:
        raise UserError(f"{scan_source} gave no scans: nothing recorded")
    return Recording(
        path, writer.scans, samples.samples, samples.flagged, guard.requested, guard.terminated
    )


def _stream_blocks(
    writer: RunFileWriter,
    samples: _VehicleWriter,
    guard: _InterruptGuard,
    scans: ScanStream,
    vehicle: VehicleStream | None,
    max_scans: int | None,
    block_scans: int,
    progress: Callable[[int], None] | None,
    scan_source: str,
    vehicle_source: str,
) -> bool:
    """The recording loop of :func:`record_run`; closes the writer as complete at the end,
    on Ctrl-C (``guard.requested``) or when the next block does not fit (then returns True),
    raises on errors."""
    last_time_s: float | None = None
    blocks: Iterator[ScanBlock] | None = None
    room = _Room(writer.path)
    full = False
    try:
        with plugin_errors(scan_source):
            blocks = iter(scans.blocks(block_scans))
        while not guard.requested and (max_scans is None or writer.scans < max_scans):
            with plugin_errors(scan_source):
                block = next(blocks, None)  # Ctrl-C raises here while the source waits
            if block is None:
                break
            n = block.scans if max_scans is None else min(block.scans, max_scans - writer.scans)
            if n == 0:
                continue
            if not room.fits(block, n):
                full = True
                break
            with guard.deferred():  # Ctrl-C here only sets guard.requested
                _append_scans(writer, block, n, scan_source)
                last_time_s = float(block.time_s[n - 1])
                if vehicle is None:
                    samples.push(_slice_vehicle(block.vehicle, n))
                else:
                    with plugin_errors(vehicle_source):
                        for part in vehicle.vehicle_samples(last_time_s + VEHICLE_MARGIN_S):
                            samples.push(part)
                writer.flush()
                room.written()
            if progress is not None:
                progress(n)
    except KeyboardInterrupt:
        guard.requested = True
    with guard.deferred():
        close = getattr(blocks, "close", None)
        if callable(close):
            with plugin_errors(scan_source):
                close()
        if vehicle is not None and last_time_s is not None:
            with plugin_errors(vehicle_source):
                for part in vehicle.vehicle_samples(last_time_s + VEHICLE_MARGIN_S, final=True):
                    samples.push(part)
        writer.close()
    return full
