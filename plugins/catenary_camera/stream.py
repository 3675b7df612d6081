"""The ``gige`` acquisition: the rig's cameras read together into blocks of scans.

:func:`open_gige` connects every camera, configures it and starts it, then reads
:data:`PREROLL_FRAMES` frames of each (a camera that gives none in ``timeout_s`` is one line
naming it, as is one that cannot be opened or refuses a setting; with encoder triggering,
while none gives any and all answer, the train stands: see Standing). Their (device, host) time
pairs give the offset that maps the camera's timestamps to the host clock for placing its
frames (the least-delay fit of :func:`~catenary_camera.clock.fit_clock`, its drift left out:
the scans' clock is the cameras'; with ``synchronized_clocks`` one offset from all cameras'
pairs), less ``arrival_lag_frames`` frame periods (a frame arrives, at the quickest, that
long after its first line); each frame's time is also the earliest its predecessors allow
(stamps come late, never early). The run's scan 0 is the last of those frames that comes, and
:attr:`GigeStream.clock_zero_unix_s` its host time (the recorder aligns the CAN bus to it).

One reader thread per camera pops its frames (:class:`~catenary_camera.backend.CameraBackend`),
feeds their times to a :class:`~catenary_camera.clock.ClockTracker` (offset and drift over
the run, reported), unpacks their pixels (:func:`~catenary_camera.pixels.unpack_lines`) and
queues them (a bounded queue: frames wait in the backend's buffers beyond it); the caller's
thread places them into scans (:class:`~catenary_camera.assembly.ScanAssembler`) and yields
a block whenever every connected camera has delivered its lines.

**Dropping off.** A camera that delivers nothing for ``timeout_s`` is disconnected and
reconnected every ``reconnect_interval_s``, while the others record on: the scans it misses
are handed out without its line (``valid = False``). Back, its first :data:`PREROLL_FRAMES`
frames teach its clock again (as when recording started; their lines are not kept) and the
next is placed by time.

**Standing.** With encoder triggering a camera takes a line per encoder pulse, so that while
the train stands no camera sends a frame: when none of them has for ``timeout_s``, each
reader asks its camera for a register (:meth:`~catenary_camera.backend.CameraBackend.check`)
every ``timeout_s`` instead; a camera that answers is standing, not dropped off, and its
frames go on by their ids when the train moves (nothing is lost, nothing learnt again). One
that does not answer drops off as above. A camera silent while the others went on sending
frames for half ``timeout_s`` after its last has dropped off (the encoder drives them all;
their last frames before a stop, and their first after it, arrive a few ms apart).
Recording may start with the train standing: the cameras' first frames are waited for as
long as they all answer (logged once).

**Positions.** Free-running: ``position_m`` is NaN and the stream declares
``positions_from_encoder``: the recorder interpolates the CAN encoder to the scan times.
Encoder-triggered: scan ``i`` is at ``i * metres_per_line`` (lost lines are counted by frame
id, so the index keeps counting the encoder's pulses), and the recorder checks it against
the CAN encoder.

:meth:`GigeStream.status` is the live line (lines per second, lines lost and link state per
camera), :meth:`GigeStream.summary` the final one per camera: lines, lines lost (frames
missing, frames incomplete, late lines, resyncs), reconnections, clock offset and drift.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import queue
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np

from catenary.arrays import FloatArray
from catenary.domain import CameraLines, RunHeader, ScanBlock, VehicleSamples
from catenary.errors import UserError

from .assembly import CameraCounts, ScanAssembler
from .backend import CameraBackend, CameraUnavailable, Frame
from .clock import ClockFit, ClockTracker, fit_clock
from .pixels import PIXEL_FORMATS, unpack_lines
from .settings import CameraSettings, GigeSettings, parse_settings

__all__ = ["GigeStream", "open_gige"]

_LOG = logging.getLogger(__name__)

READ_TIMEOUT_S = 0.05  # a reader's longest wait for a frame before it checks for stop
PREROLL_FRAMES = 8  # frames of each camera read into its clock tracker before recording


def _dtype(pixel_format: str) -> np.dtype[np.uint8] | np.dtype[np.uint16]:
    return np.dtype(np.uint8) if PIXEL_FORMATS[pixel_format] <= 8 else np.dtype(np.uint16)


@dataclass(frozen=True)
class _Placed:
    """A frame ready for the assembler: its id, first line's host time [s] and lines;
    ``host_stamped``: that time is the host's (``Frame.host_stamped``); ``period_s``: the
    camera's frame period there [s], for a frame placed by time (``ScanAssembler.add``)."""

    name: str
    frame_id: int
    time_s: float | None  # None: an incomplete frame, whose stamp may be stale
    lines: np.ndarray[Any, Any] | None
    host_stamped: bool = False
    period_s: float | None = None


class _Activity:
    """When any of the rig's cameras last sent a frame [s, ``time.monotonic``], which every
    reader updates: with encoder triggering, all silent is the train standing (module
    docstring)."""

    def __init__(self) -> None:
        self.last_frame_s = time.monotonic()

    def left_behind(self, settings: GigeSettings, last_s: float) -> bool:
        """Whether a camera silent for ``timeout_s`` since ``last_s`` (its last frame or
        answer) has dropped off: always when free-running; with encoder triggering when the
        others sent frames half ``timeout_s`` after it."""
        if settings.trigger != "encoder":
            return True
        return self.last_frame_s - last_s > 0.5 * settings.timeout_s

    def standing(self, settings: GigeSettings, now: float) -> bool:
        """Whether the train may be standing: no camera has sent a frame for ``timeout_s``
        (with encoder triggering: ``left_behind`` decides first)."""
        return now - self.last_frame_s > settings.timeout_s


@dataclass(frozen=True)
class _Link:
    """A camera's link changed state (``up`` after a (re)connection, ``down``)."""

    name: str
    state: str
    reason: str = ""


class _Reader(threading.Thread):
    """Reads one camera, reconnecting it when it drops off (module docstring)."""

    def __init__(
        self,
        camera: CameraSettings,
        backend: CameraBackend,
        settings: GigeSettings,
        out: queue.Queue[_Placed | _Link],
        clock: ClockTracker,
        activity: _Activity,
    ) -> None:
        super().__init__(name=f"gige-{camera.name}", daemon=True)
        self.camera = camera
        self.backend = backend
        self._settings = settings
        self._out = out
        self._activity = activity
        self.standing = False  # the train stands (module docstring): shown by the status
        self.stop = threading.Event()
        self.clock = clock
        # the mapping that places frames: the clock's fit when recording started (its later
        # refits are reported, not used, so frames never move as estimates settle); shared by
        # every camera when their clocks are synchronized; None: the next frame's fit
        self.placing: ClockFit | None = None
        self.reconnections = 0
        self.last_error = ""
        self.last_device_s = math.nan  # the device time of the last frame [s]

    def place(
        self, frame: Frame, *, tracked: bool = False, period_s: float | None = None
    ) -> _Placed:
        """Map the frame's time to the host clock (``tracked``: its times are in the
        tracker already) and unpack its lines (``period_s``: :class:`_Placed`)."""
        if not frame.complete:  # a lost leader leaves the buffer's stamps stale
            return _Placed(self.camera.name, frame.frame_id, None, None)
        if not tracked:
            self.clock.add(frame.device_time_s, frame.host_time_s)
        self.last_device_s = frame.device_time_s
        lines = None
        if frame.complete and frame.data is not None:
            try:
                lines = unpack_lines(frame.data, self.camera.pixel_format, self.camera.width)
            except ValueError as exc:  # a payload of another size: counted as incomplete
                self.last_error = str(exc)
            if lines is not None and lines.shape[0] != self._settings.lines_per_frame:
                self.last_error = f"frame of {lines.shape[0]} lines"
                lines = None
        time_s = self._host_s(frame.device_time_s)
        return _Placed(
            self.camera.name, frame.frame_id, time_s, lines, frame.host_stamped, period_s
        )

    def _host_s(self, device_s: float) -> float:
        assert self.placing is not None  # set from the pre-roll (GigeStream) or settling
        return float(self.placing.to_host(device_s))

    def _send(self, item: _Placed | _Link) -> None:
        """Queue ``item``, waiting while the queue is full (the frames then wait in the
        backend's buffers, and are lost, as id gaps, once those run out) unless stopped."""
        while not self.stop.is_set():
            try:
                self._out.put(item, timeout=READ_TIMEOUT_S)
                return
            except queue.Full:
                continue

    def run(self) -> None:
        settings = self._settings
        connected, last_frame = True, time.monotonic()  # open_gige connected it
        learning: _Learning | None = None  # after a reconnection: its clock learnt again
        while not self.stop.is_set():
            if not connected:
                try:
                    self.backend.connect()
                except (CameraUnavailable, UserError) as exc:
                    self.last_error = str(exc)
                    self.stop.wait(settings.reconnect_interval_s)
                    continue
                connected, last_frame = True, time.monotonic()
                self.reconnections += 1
                if not settings.synchronized_clocks:  # a restarted camera's own clock
                    self.clock, self.placing = ClockTracker(), None  # may have been reset
                learning = _Learning(settings, self.clock, self.backend.frame_id_modulus)
            try:
                frame = self.backend.read(READ_TIMEOUT_S)
                now = time.monotonic()
                if frame is None and now - last_frame > settings.timeout_s:
                    if self._activity.left_behind(settings, last_frame):
                        raise CameraUnavailable(f"no frame for {settings.timeout_s:g} s")
                    if self._activity.standing(settings, now):  # else: the others stopped
                        self.backend.check()  # with it; it answers: standing
                        self.standing, last_frame = True, now
            except CameraUnavailable as exc:
                self.backend.disconnect()
                connected, self.standing = False, False
                self.last_error = str(exc)
                self._send(_Link(self.camera.name, "down", str(exc)))
                continue
            if frame is None:
                continue
            last_frame = self._activity.last_frame_s = time.monotonic()
            self.standing = False
            if learning is None:
                self._send(self.place(frame))
                continue
            learning.add(frame)  # back: its clock is learnt again as when recording started
            if learning.done and learning.last is not None:
                if self.placing is None:
                    self.placing = _placing(*learning.pairs(), settings)
                self._send(_Link(self.camera.name, "up"))
                self._send(self.place(learning.last, tracked=True, period_s=learning.period_s))
                learning = None
        self.backend.disconnect()


class GigeStream:
    """An open ``gige`` acquisition (the ``ScanStream`` protocol; module docstring)."""

    def __init__(
        self,
        settings: GigeSettings,
        backends: Mapping[str, CameraBackend],
        learnt: Mapping[str, _Learning],
    ) -> None:
        self.settings = settings
        self.positions_from_encoder = settings.trigger == "free"
        # frames in flight between the readers and the assembly: a few per camera buffer
        self._queue: queue.Queue[_Placed | _Link] = queue.Queue(
            maxsize=settings.buffers * len(backends)
        )
        cameras = {c.name: c for c in settings.cameras}
        activity = _Activity()
        self._readers = {
            name: _Reader(
                cameras[name], backend, settings, self._queue, learnt[name].clock, activity
            )
            for name, backend in backends.items()
        }
        pairs = {name: learning.pairs() for name, learning in learnt.items()}
        shared = None
        if settings.synchronized_clocks:  # one mapping for all: the cameras' pairs together
            shared = _placing(
                np.concatenate([device for device, _ in pairs.values()]),
                np.concatenate([host for _, host in pairs.values()]),
                settings,
            )
        for name, reader in self._readers.items():
            reader.placing = shared or _placing(*pairs[name], settings)
        placed = [
            self._readers[name].place(learning.last, tracked=True, period_s=learning.period_s)
            for name, learning in learnt.items()
            if learning.last is not None
        ]
        self.clock_zero_unix_s = max(p.time_s for p in placed if p.time_s is not None)
        modulus = {backend.frame_id_modulus for backend in backends.values()}
        self._assembler = ScanAssembler(
            {c.name: (c.width, _dtype(c.pixel_format)) for c in settings.cameras},
            settings.lines_per_frame,
            settings.nominal_rate_hz,
            self.clock_zero_unix_s,
            encoder=settings.trigger == "encoder",
            frame_id_modulus=modulus.pop() if len(modulus) == 1 else None,
            resync_lines=max(2.0, settings.lines_per_frame / 4),
        )
        self._links = {name: "up" for name in backends}
        self._started = time.monotonic()
        self._rate: dict[str, tuple[float, int]] = {}  # name: (monotonic, delivered) last read
        started_at = datetime.fromtimestamp(self.clock_zero_unix_s, UTC)
        self.header = RunHeader(
            line=settings.line,
            track=settings.track,
            vehicle=settings.vehicle,
            direction=settings.direction,
            start_chainage_m=settings.start_chainage_m,
            started_at=started_at.isoformat(timespec="microseconds").replace("+00:00", "Z"),
            scan_rate_hz=settings.nominal_rate_hz,
            scans=0,  # live: unknown
            camera_pixels={c.name: c.width for c in settings.cameras},
            camera_bit_depth={c.name: PIXEL_FORMATS[c.pixel_format] for c in settings.cameras},
            camera_offset_px={c.name: c.offset_px for c in settings.cameras},
        )
        for frame in placed:
            self._add(frame)
        for reader in self._readers.values():
            reader.start()
        self._closed = False

    # -- scans ---------------------------------------------------------------------------

    def _drain(self, wait_s: float) -> None:
        """Take what the readers queued (waiting up to ``wait_s`` for the first item)."""
        try:
            item = self._queue.get(timeout=wait_s)
        except queue.Empty:
            return
        while True:
            if isinstance(item, _Link):
                self._links[item.name] = item.state
                if item.state == "up":
                    self._assembler.restart(item.name)
            else:
                self._add(item)
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                return

    def _add(self, placed: _Placed) -> None:
        """Hand a placed frame to the assembler."""
        self._assembler.add(
            placed.name,
            placed.frame_id,
            placed.time_s,
            placed.lines,
            placed.host_stamped,
            placed.period_s,
        )

    def _ready(self) -> int:
        """Scans every connected camera has delivered (a camera that is down holds none
        back); none while every camera is down."""
        up = [self._assembler.reached(n) for n, state in self._links.items() if state == "up"]
        return min(up) if up else self._assembler.next_scan

    def blocks(self, block_scans: int) -> Iterator[ScanBlock]:
        """Stream the acquisition in blocks of ``block_scans`` scans until closed."""
        if isinstance(block_scans, bool) or not isinstance(block_scans, int) or block_scans < 1:
            raise ValueError(f"block_scans must be a positive integer, got {block_scans!r}")
        if self._closed:
            raise ValueError("gige stream is closed")
        return self._blocks(block_scans)

    def _blocks(self, block_scans: int) -> Iterator[ScanBlock]:
        assembler = self._assembler
        while not self._closed:
            self._drain(READ_TIMEOUT_S)
            while self._ready() - assembler.next_scan >= block_scans:
                yield self._block(assembler.next_scan + block_scans)

    def _block(self, upto: int) -> ScanBlock:
        scans = self._assembler.take(upto)
        settings = self.settings
        index = np.arange(scans.first, scans.first + scans.scans, dtype=np.float64)
        position_m = (
            index * settings.metres_per_line
            if settings.metres_per_line is not None
            else np.full(scans.scans, np.nan)
        )
        cameras = {
            c.name: CameraLines(
                scans.lines[c.name],
                PIXEL_FORMATS[c.pixel_format],
                c.offset_px,
                valid=scans.valid[c.name],
            )
            for c in settings.cameras
        }
        empty = np.zeros(0, dtype=np.float64)
        return ScanBlock(
            first_scan=scans.first,
            position_m=position_m,
            time_s=scans.time_s,
            cameras=cameras,
            vehicle=VehicleSamples(empty, empty, empty, empty),
        )

    # -- reporting -----------------------------------------------------------------------

    def counts(self) -> dict[str, CameraCounts]:
        """Each camera's running counts (lines delivered and lost, incomplete frames, ...)."""
        return {name: self._assembler.counts(name) for name in self._readers}

    def clock_fits(self) -> dict[str, ClockFit | None]:
        """Each camera's clock against the host's (offset, drift, residual), if fitted."""
        return {name: reader.clock.fit() for name, reader in self._readers.items()}

    def status(self) -> str:
        """The live line: per camera its lines per second since the last call, lines lost
        and link state (``cam1 5300/s lost 0 up``; ``standing`` while the train stands)."""
        now = time.monotonic()
        parts = []
        for name, state in self._links.items():
            counts = self._assembler.counts(name)
            then, before = self._rate.get(name, (self._started, 0))
            rate = (counts.delivered - before) / max(now - then, 1e-9)
            self._rate[name] = (now, counts.delivered)
            if state == "up" and self._readers[name].standing:
                state = "standing"
            parts.append(f"{name} {rate:,.0f}/s lost {counts.lost:,} {state}")
        return " | ".join(parts)

    def summary(self) -> str:
        """One line per camera: lines delivered and lost, incomplete frames, resyncs,
        reconnections, its clock against the host's (offset at its last frame, drift and
        the residual of the least-delay frames)."""
        lines = []
        for name, reader in self._readers.items():
            counts = self._assembler.counts(name)
            fit = reader.clock.fit() or reader.placing
            now = reader.last_device_s
            clock = (
                f"clock offset {float(fit.to_host(now)) - now:+.6f} s, drift "
                f"{fit.drift_ppm:+.2f} ppm, "
                f"residual {fit.residual_s * 1e6:.0f} µs"
                if fit is not None
                else "clock not fitted"
            )
            lines.append(
                f"camera {reader.camera.device}: {counts.delivered:,} lines, {counts.lost:,} "
                f"lost ({counts.missing_frames} missing and {counts.incomplete_frames} "
                f"incomplete frames, {counts.late_lines} late lines, {counts.resyncs} resyncs), "
                f"{reader.reconnections} reconnections, "
                f"{clock}" + (f"; last problem: {reader.last_error}" if reader.last_error else "")
            )
        return "\n".join(lines)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for reader in self._readers.values():
            reader.stop.set()
        for reader in self._readers.values():
            reader.join()


def _placing(device_s: FloatArray, host_s: FloatArray, settings: GigeSettings) -> ClockFit:
    """The mapping that places frames (the host time of a frame's first line), from a few
    (device, host) time pairs [s]: their clock fit's offset at the last of them, less the
    frames' least time from first line to arrival (``arrival_lag_frames`` frame periods),
    drift none. A second of pairs says little of the drift (a few ms of delays over it are
    thousands of ppm), and the scans' clock is the cameras' own: the drift only matters to
    the run's host time, fitted over the run."""
    fit = fit_clock(device_s, host_s)
    last = float(device_s.max())
    lag_s = settings.arrival_lag_frames * settings.frame_period_s
    return ClockFit(float(fit.to_host(last)) - last - lag_s, 0.0, fit.residual_s, fit.samples)


def _steadied(frame: Frame, before: Frame, settings: GigeSettings, modulus: int | None) -> Frame:
    """``frame`` with the earliest device time that it or ``before`` (already steadied)
    gives it, counting free-running lines by frame id: a frame is stamped when it is sent,
    which a busy camera or host delays, never advances. None of this for a frame id gap of
    more than one frame (nothing to count on), nor for a frame half a period or more later
    than the count: a camera that skipped a period without counting its frame id up (Aravis's
    fake camera does when its thread oversleeps) exposed its lines then."""
    step = frame.frame_id - before.frame_id
    if modulus is not None:
        step %= modulus
    if step != 1:
        return frame
    period_s = settings.lines_per_frame / settings.nominal_rate_hz
    expected = before.device_time_s + period_s
    if frame.device_time_s - expected >= 0.5 * period_s:
        return frame
    return dataclasses.replace(frame, device_time_s=min(frame.device_time_s, expected))


class _Learning:
    """A camera's clock learnt from its first frames after a start: the first one (which
    some cameras, Aravis's fake one among them, send off their frame period's grid) and
    incomplete ones (whose stamps may be stale) are not learnt from; the others' (device,
    host) times go into ``clock`` (a :class:`ClockTracker`) and each one's time is the
    earliest its predecessors allow (:func:`_steadied`). ``last`` is the last frame learnt
    from (the first to record), ``done`` once :data:`PREROLL_FRAMES` were."""

    PERIOD_FRAMES = 4
    """The last frames learnt whose periods give ``period_s``."""

    def __init__(self, settings: GigeSettings, clock: ClockTracker, modulus: int | None) -> None:
        self._settings = settings
        self.clock = clock
        self._modulus = modulus
        self._started = False
        self._times: list[tuple[float, float]] = []
        self._ids: list[int] = []
        self.last: Frame | None = None

    @property
    def done(self) -> bool:
        return len(self._times) >= PREROLL_FRAMES

    def add(self, frame: Frame) -> None:
        if not (self._started and frame.complete):
            self._started = True
            return
        self.clock.add(frame.device_time_s, frame.host_time_s)
        self._times.append((frame.device_time_s, frame.host_time_s))
        self._ids.append(frame.frame_id)
        if self._settings.trigger == "free" and self.last is not None:
            frame = _steadied(frame, self.last, self._settings, self._modulus)
        self.last = frame

    @property
    def period_s(self) -> float | None:
        """The camera's frame period at its last frames learnt [s]: the median of their
        device times' steps per frame id (``PERIOD_FRAMES``; ids gone back apart); None
        before two (``ScanAssembler.add`` also sets aside an implausible one)."""
        ids = np.array(self._ids[-self.PERIOD_FRAMES :], dtype=np.int64)
        device = np.array([t for t, _ in self._times[-self.PERIOD_FRAMES :]])
        step = np.diff(ids)
        usable = step > 0
        if self._modulus is not None:
            step %= self._modulus
            usable = (step > 0) & (step <= self._modulus // 2)
        if not usable.any():
            return None
        return float(np.median(np.diff(device)[usable] / step[usable]))

    def pairs(self) -> tuple[FloatArray, FloatArray]:
        """The (device, host) times [s] learnt from, each ``[k]``."""
        device, host = np.array(self._times, dtype=np.float64).reshape(-1, 2).T
        return device, host


def _preroll(settings: GigeSettings, backends: Mapping[str, CameraBackend]) -> dict[str, _Learning]:
    """Every camera's clock learnt from its first frames (:class:`_Learning`), read from all
    of them in turn until each has :data:`PREROLL_FRAMES`, so that the host times of the
    frames recorded do not move as the first estimates of the clock offset settle.
    ``UserError`` naming a camera that gives no frame in ``timeout_s``, or, while the train
    stands (module docstring), that does not answer."""
    cameras = {c.name: c for c in settings.cameras}
    learnt = {
        name: _Learning(settings, ClockTracker(), backend.frame_id_modulus)
        for name, backend in backends.items()
    }
    activity = _Activity()
    waiting_since = dict.fromkeys(backends, activity.last_frame_s)
    waited = False
    while not all(learning.done for learning in learnt.values()):
        for name, backend in backends.items():
            frame = backend.read(0.01)
            now = time.monotonic()
            if frame is None:
                if now - waiting_since[name] <= settings.timeout_s:
                    continue
                if activity.left_behind(settings, waiting_since[name]):
                    raise UserError(
                        f"source 'gige': camera {cameras[name].device} delivered no frame in "
                        f"{settings.timeout_s:g} s (trigger {settings.trigger!r})"
                    )
                if not activity.standing(settings, now):
                    continue
                try:
                    backend.check()
                except CameraUnavailable as exc:
                    raise UserError(f"source 'gige': {exc}") from None
                if not waited:
                    waited = True
                    _LOG.warning(
                        "source 'gige': no camera has sent a frame for %g s and all answer: "
                        "waiting for the train to move (trigger 'encoder')",
                        settings.timeout_s,
                    )
                waiting_since[name] = now
                continue
            learnt[name].add(frame)
            waiting_since[name] = activity.last_frame_s = now
    return learnt


def _backend(name: str) -> Callable[[CameraSettings, GigeSettings], CameraBackend]:
    """The camera backend called ``name`` in the settings (imported only when chosen)."""
    if name == "gentl":
        from .gentl import GenTLCamera

        return GenTLCamera
    from .aravis import AravisCamera

    return AravisCamera


def open_gige(
    settings: Mapping[str, Any],
    backend: Callable[[CameraSettings, GigeSettings], CameraBackend] | None = None,
) -> GigeStream:
    """Open the ``gige`` source (settings: :mod:`catenary_camera.settings`).

    ``backend`` makes a camera's backend (default: the settings' ``backend``).
    """
    parsed = parse_settings(settings)
    if backend is None:
        backend = _backend(parsed.backend)
    backends: dict[str, CameraBackend] = {}
    try:
        for camera in parsed.cameras:
            backends[camera.name] = backend(camera, parsed)
            try:
                backends[camera.name].connect()
            except CameraUnavailable as exc:
                raise UserError(f"source 'gige': {exc}") from None
        learnt = _preroll(parsed, backends)
    except BaseException:
        for opened in backends.values():
            opened.disconnect()
        raise
    return GigeStream(parsed, backends, learnt)
