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
* **Invalid lines.** A block's lines marked invalid (``CameraLines.valid``: the camera
  delivered none for those scans) are written with ``/cameras/{name}/valid`` (FORMATS.md);
  the summary counts them per camera (:meth:`Recording.details`).

Positions from the encoder
--------------------------
The vehicle stream may read the wheel encoder: its optional ``encoder_readings(until_s,
final=...)`` (looked up with ``getattr``) gives the good readings, time and distance, as
``vehicle_samples`` gives samples. Two cases:

* **Free-running lines** (the scan stream's ``positions_from_encoder`` is true; its blocks'
  ``position_m`` are NaN): after each block the recorder takes the readings up to the block's
  last scan time plus :data:`VEHICLE_MARGIN_S`, writes them to ``/encoder/time_s`` and
  ``/encoder/position_m``, and writes the block once a reading lies after its last scan (or
  once the source has given scans :data:`ENCODER_WAIT_S` later: a live bus that lags), each
  scan's position the readings linearly interpolated at its time, less the reading at the
  first scan (FORMATS.md: distance since the first scan). Positions never decrease (a step
  back of the encoder holds the position); scans before the first reading or after the last
  take the nearest one's, and the summary counts them. Such a scan source without a vehicle
  source that reads the encoder is a one-line error before anything is recorded.
* **Encoder-triggered lines** (the source gives its own positions): the readings are only
  compared with them: the summary line gives both distances between the first and the last
  scan that the readings cover, e.g. "encoder check: lines give 1,000.2 m, CAN encoder
  1,000.0 m (+0.02 %)" (a scale error of one or the other, or lines lost).

One clock
---------
Scan times and vehicle sample times must share a clock. A live scan stream may have the
attribute ``clock_zero_unix_s`` (the host's UNIX time of its scan time 0, known once its first
block was yielded; None until then); the recorder passes it, after the first block and before
asking for any sample, to the vehicle stream's optional ``align_clock(clock_zero_unix_s)``.
The ``can`` stream then counts its frames' times (host UNIX time on a live bus) from it,
unless its ``time_zero_s`` was configured. Mapping each camera's own clock to the host's is
the scan source's part (``catenary_camera.clock``).

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

import math
import os
import resource
import signal
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any, Final, Self

import numpy as np

from catenary.arrays import FloatArray
from catenary.domain import (
    DEFAULT_BLOCK_SCANS,
    EncoderReadings,
    RunHeader,
    ScanBlock,
    VehicleSamples,
)
from catenary.errors import UserError
from catenary.measurement.runfile import RunFileWriter
from catenary.plugins.manager import plugin_errors
from catenary.plugins.types import ScanStream, VehicleStream

__all__ = [
    "CLOSE_MARGIN_BYTES",
    "ENCODER_WAIT_S",
    "VEHICLE_MARGIN_S",
    "DiskFull",
    "Recording",
    "record_run",
]

VEHICLE_MARGIN_S: Final = 0.5
"""Vehicle samples are written up to this long after the last scan written [s]."""
ENCODER_WAIT_S: Final = 2.0
"""Scans whose positions come from the encoder wait for readings after them until the source
has given scans this much later [s]; then they are written with the positions known."""
_CHECK_TAIL_SCANS: Final = 1 << 16  # scans kept for the encoder check until readings cover them
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
    invalid_lines: dict[str, int] = field(default_factory=dict)  # per camera, lines marked
    encoder_readings: int = 0  # written to /encoder/* (positions from the encoder)
    scans_off_encoder: int = 0  # of those, scans outside the readings (positions held)
    lines_distance_m: float | None = None  # the encoder check: the scans' own distance
    encoder_distance_m: float | None = None  # and the vehicle stream's encoder's

    def details(self) -> list[str]:
        """Clauses for the summary line: invalid lines, positions from the encoder, the
        encoder check (e.g. "encoder check: lines give 1,000.2 m, CAN encoder 1,000.0 m
        (+0.02 %)")."""
        parts = []
        lost = {name: count for name, count in self.invalid_lines.items() if count}
        if lost:
            parts.append(
                f"{sum(lost.values())} lines invalid ("
                + ", ".join(f"{name} {count}" for name, count in lost.items())
                + ")"
            )
        if self.encoder_readings:
            parts.append(f"positions from {self.encoder_readings} encoder readings")
        if self.scans_off_encoder:
            parts.append(
                f"{self.scans_off_encoder} scans outside the encoder's readings (positions held)"
            )
        if self.lines_distance_m is not None and self.encoder_distance_m is not None:
            check = (
                f"encoder check: lines give {self.lines_distance_m:,.1f} m, CAN encoder "
                f"{self.encoder_distance_m:,.1f} m"
            )
            if self.encoder_distance_m > 0:
                ratio = self.lines_distance_m / self.encoder_distance_m - 1.0
                check += f" ({ratio * 100:+.2f} %)"
            parts.append(check)
        return parts


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


class _Encoder:
    """The vehicle stream's encoder readings during a recording (module docstring, "Positions
    from the encoder"): the positions of scans at their times, or the check of the scans' own
    positions. Holds the readings still needed, and a bounded tail of scans for the check."""

    def __init__(
        self,
        readings: Callable[..., Iterable[EncoderReadings]],
        writer: RunFileWriter | None,
        source: str,
    ) -> None:
        self._readings = readings
        self._writer = writer  # positions from the encoder: the readings are written too
        self._source = source
        self._time: FloatArray = np.zeros(0)
        self._position: FloatArray = np.zeros(0)
        self.count = 0
        self.outside = 0
        self._origin_m: float | None = None
        self._last_m = 0.0
        self._tail_time: FloatArray = np.zeros(0)
        self._tail_position: FloatArray = np.zeros(0)
        self.first: tuple[float, float] | None = None  # (scans', encoder's) position
        self.last: tuple[float, float] | None = None

    @property
    def covered_s(self) -> float:
        """The time of the last reading so far (-inf: none)."""
        return float(self._time[-1]) if self._time.shape[0] else -math.inf

    def pull(self, until_s: float, *, final: bool = False) -> None:
        """Take the readings up to ``until_s``; write them when positions come from them."""
        for part in self._readings(until_s, final=final):
            time_s = np.asarray(part.time_s, dtype=np.float64)
            position_m = np.asarray(part.position_m, dtype=np.float64)
            if time_s.ndim != 1 or position_m.shape != time_s.shape:
                raise UserError(f"{self._source}: encoder readings of mismatched lengths")
            if time_s.shape[0] == 0:
                continue
            previous = self._time[-1:]
            if not (
                np.isfinite(time_s).all()
                and np.isfinite(position_m).all()
                and (np.diff(np.concatenate((previous, time_s))) >= 0).all()
            ):
                raise UserError(
                    f"{self._source}: encoder readings must be finite, their times non-decreasing"
                )
            if self._writer is not None:
                try:
                    self._writer.append_encoder(time_s, position_m)
                except ValueError as exc:
                    raise UserError(f"{self._source}: invalid encoder readings: {exc}") from None
            self._time = np.concatenate((self._time, time_s))
            self._position = np.concatenate((self._position, position_m))
            self.count += int(time_s.shape[0])

    def positions(self, time_s: FloatArray) -> FloatArray:
        """Scans' distances since the first scan [m] at ``time_s`` ``[n]``: the readings
        interpolated, non-decreasing (a step back holds the position); outside the readings
        (none yet, or none after) the nearest one's (counted in ``outside``)."""
        t, p = self._time, self._position
        if t.shape[0] == 0:
            self.outside += int(time_s.shape[0])
            return np.full(time_s.shape, self._last_m)
        self.outside += int(np.count_nonzero((time_s < t[0]) | (time_s > t[-1])))
        reading = np.interp(time_s, t, p)
        if self._origin_m is None:
            self._origin_m = float(reading[0]) - self._last_m
        position = np.maximum.accumulate(np.maximum(reading - self._origin_m, self._last_m))
        self._last_m = float(position[-1])
        self._forget_before(float(time_s[-1]))
        return position

    def check(self, time_s: FloatArray, position_m: FloatArray) -> None:
        """Note the first and the last scan the readings cover, with both positions; scans
        after the last reading wait (at most :data:`_CHECK_TAIL_SCANS`) for later ones."""
        t = np.concatenate((self._tail_time, time_s))
        p = np.concatenate((self._tail_position, position_m))
        if self._time.shape[0]:
            covered = np.flatnonzero((t >= self._time[0]) & (t <= self._time[-1]))
            if covered.shape[0]:
                ends = covered[[0, -1]]
                encoder = np.interp(t[ends], self._time, self._position)
                if self.first is None:
                    self.first = (float(p[ends[0]]), float(encoder[0]))
                self.last = (float(p[ends[1]]), float(encoder[1]))
            later = t > self._time[-1]
            t, p = t[later], p[later]
        self._tail_time = t[-_CHECK_TAIL_SCANS:]
        self._tail_position = p[-_CHECK_TAIL_SCANS:]
        if self._tail_time.shape[0]:
            self._forget_before(float(self._tail_time[0]))
        elif time_s.shape[0]:
            self._forget_before(float(time_s[-1]))

    def _forget_before(self, time_s: float) -> None:
        """Drop the readings no later time needs (keeping one at or before ``time_s``)."""
        keep = max(0, int(np.searchsorted(self._time, time_s, side="right")) - 1)
        self._time = self._time[keep:]
        self._position = self._position[keep:]

    def distances_m(self) -> tuple[float | None, float | None]:
        """The check: the distance between the first and last scans covered, by the scans'
        positions and by the encoder (None: no scan covered)."""
        if self.first is None or self.last is None:
            return None, None
        return self.last[0] - self.first[0], self.last[1] - self.first[1]


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


def _append_scans(
    writer: RunFileWriter, block: ScanBlock, n: int, position_m: FloatArray, source: str
) -> None:
    lines = {name: camera.lines[:n] for name, camera in block.cameras.items()}
    valid = {
        name: camera.valid[:n] for name, camera in block.cameras.items() if camera.valid is not None
    }
    try:
        writer.append(position_m, block.time_s[:n], lines, valid)
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
    from_encoder = bool(getattr(scans, "positions_from_encoder", False))
    readings = getattr(vehicle, "encoder_readings", None) if vehicle is not None else None
    if from_encoder and not callable(readings):
        raise UserError(
            f"{scan_source} takes its scans' positions from the wheel encoder: it needs a "
            "vehicle source that reads the encoder (--vehicle-source can)"
            + ("" if vehicle is None else f", which {vehicle_source} does not")
        )
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
                    offsets_px=header.camera_offset_px,
                    overwrite=overwrite,
                )
            except ValueError as exc:
                raise UserError(f"{scan_source}: invalid run header: {exc}") from None
        samples = _VehicleWriter(writer, vehicle_source if vehicle is not None else scan_source)
        encoder = (
            _Encoder(readings, writer if from_encoder else None, vehicle_source)
            if callable(readings)
            else None
        )
        loop = _Loop(
            writer, samples, encoder, guard, vehicle, progress, scan_source, vehicle_source
        )
        try:
            loop.run(scans, max_scans, block_scans, from_encoder)
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
    if loop.full:
        raise DiskFull(path, writer.scans)
    if writer.scans == 0 and not guard.requested:
        raise UserError(f"{scan_source} gave no scans: nothing recorded")
    lines_m, encoder_m = (None, None) if encoder is None else encoder.distances_m()
    return Recording(
        path,
        writer.scans,
        samples.samples,
        samples.flagged,
        guard.requested,
        guard.terminated,
        invalid_lines=writer.invalid_lines,
        encoder_readings=encoder.count if encoder is not None and from_encoder else 0,
        scans_off_encoder=encoder.outside if encoder is not None else 0,
        lines_distance_m=lines_m,
        encoder_distance_m=encoder_m,
    )


class _Loop:
    """The recording loop of :func:`record_run`: :meth:`run` closes the writer as complete
    at the end, on Ctrl-C (``guard.requested``) or when the next block does not fit (then
    ``full``), and raises on errors. Blocks whose positions come from the encoder wait in
    ``pending`` for readings after their last scan (at most :data:`ENCODER_WAIT_S`)."""

    def __init__(
        self,
        writer: RunFileWriter,
        samples: _VehicleWriter,
        encoder: _Encoder | None,
        guard: _InterruptGuard,
        vehicle: VehicleStream | None,
        progress: Callable[[int], None] | None,
        scan_source: str,
        vehicle_source: str,
    ) -> None:
        self.writer = writer
        self.samples = samples
        self.encoder = encoder
        self.guard = guard
        self.vehicle = vehicle
        self.progress = progress
        self.scan_source = scan_source
        self.vehicle_source = vehicle_source
        self.room = _Room(writer.path)
        self.full = False
        self.last_time_s: float | None = None
        self.pending: deque[tuple[ScanBlock, int]] = deque()

    def run(
        self, scans: ScanStream, max_scans: int | None, block_scans: int, from_encoder: bool
    ) -> None:
        blocks: Iterator[ScanBlock] | None = None
        taken = 0  # scans taken from the source: written and pending
        try:
            with plugin_errors(self.scan_source):
                blocks = iter(scans.blocks(block_scans))
            while not self.guard.requested and (max_scans is None or taken < max_scans):
                with plugin_errors(self.scan_source):
                    block = next(blocks, None)  # Ctrl-C raises here while the source waits
                if block is None:
                    break
                n = block.scans if max_scans is None else min(block.scans, max_scans - taken)
                if n == 0:
                    continue
                if taken == 0:
                    self._align_clock(scans)
                taken += n
                newest_s = float(block.time_s[n - 1])
                if self.encoder is not None:
                    with self.guard.deferred(), plugin_errors(self.vehicle_source):
                        self.encoder.pull(newest_s + VEHICLE_MARGIN_S)
                self.pending.append((block, n))
                waited = newest_s - ENCODER_WAIT_S
                while self.pending and not self.full:
                    first, k = self.pending[0]
                    end_s = float(first.time_s[k - 1])
                    if (
                        from_encoder
                        and self.encoder is not None
                        and end_s > max(self.encoder.covered_s, waited)
                    ):
                        break  # wait for readings after it
                    self._write(*self.pending.popleft(), from_encoder)
                if self.full:
                    break
        except KeyboardInterrupt:
            self.guard.requested = True
        with self.guard.deferred():
            close = getattr(blocks, "close", None)
            if callable(close):
                with plugin_errors(self.scan_source):
                    close()
            until = self.last_time_s
            if self.pending:
                last_block, k = self.pending[-1]
                until = float(last_block.time_s[k - 1])
            if self.encoder is not None and until is not None:
                with plugin_errors(self.vehicle_source):
                    self.encoder.pull(until + VEHICLE_MARGIN_S, final=True)
                if not from_encoder:  # the scans that waited for these readings
                    self.encoder.check(np.zeros(0), np.zeros(0))
            while self.pending and not self.full:
                self._write(*self.pending.popleft(), from_encoder)
            if self.vehicle is not None and self.last_time_s is not None:
                with plugin_errors(self.vehicle_source):
                    for part in self.vehicle.vehicle_samples(
                        self.last_time_s + VEHICLE_MARGIN_S, final=True
                    ):
                        self.samples.push(part)
            self.writer.close()

    def _align_clock(self, scans: ScanStream) -> None:
        """One clock: the scan source's UNIX time of scan time 0 to the vehicle stream."""
        zero = getattr(scans, "clock_zero_unix_s", None)
        align = getattr(self.vehicle, "align_clock", None)
        if zero is not None and callable(align):
            with plugin_errors(self.vehicle_source):
                align(float(zero))

    def _write(self, block: ScanBlock, n: int, from_encoder: bool) -> None:
        """Append ``n`` scans of ``block`` and the vehicle samples up to them, then flush;
        sets ``full`` instead when they do not fit."""
        if not self.room.fits(block, n):
            self.full = True
            return
        with self.guard.deferred():  # Ctrl-C here only sets guard.requested
            time_s = block.time_s[:n]
            if from_encoder:
                assert self.encoder is not None
                position_m = self.encoder.positions(time_s)
            else:
                position_m = block.position_m[:n]
            _append_scans(self.writer, block, n, position_m, self.scan_source)
            if self.encoder is not None and not from_encoder:
                self.encoder.check(time_s, position_m)
            self.last_time_s = float(time_s[n - 1])
            if self.vehicle is None:
                self.samples.push(_slice_vehicle(block.vehicle, n))
            else:
                with plugin_errors(self.vehicle_source):
                    for part in self.vehicle.vehicle_samples(self.last_time_s + VEHICLE_MARGIN_S):
                        self.samples.push(part)
            self.writer.flush()
            self.room.written()
        if self.progress is not None:
            self.progress(n)
