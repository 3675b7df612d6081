"""Reading the CAN sensors: a live python-can bus or a log file, decoded with the DBC.

:func:`open_can` (the ``can`` source, settings below), :func:`open_log` and :func:`open_bus`
return a :class:`CanSensorStream`. Its :meth:`~CanSensorStream.read` yields
:class:`~catenary_can.decode.TrackedBlock` s (flagged vehicle samples and encoder positions)
of at most ``chunk_frames`` frames each, so memory stays bounded whatever the recording's
length; :meth:`~CanSensorStream.vehicle_samples` yields just the vehicle samples and
:meth:`~CanSensorStream.encoder_readings` just the encoder's good readings (what ``catenary
record`` writes; each keeps what a call of the other decoded for it, at most
:data:`MAX_HELD_ROWS` rows of either kind, the oldest dropped beyond that).

* **Log files**: ``can.LogReader`` (python-can's formats, chosen by suffix: ``.asc``, ``.blf``,
  ``.csv``, ``.db``, ``.log``, ``.mf4``, ``.trc``, each optionally ``.gz``), read lazily as fast
  as it decodes. A file that becomes unreadable part-way ends the log there (the rest of the
  run is then without samples, so flagged by the run file reader); the problem is kept in
  :attr:`CanStatistics.last_error` and the summary.
* **Live buses**: ``can.Bus(interface=..., channel=..., ignore_config=True, ...)``: the
  interface is always passed and python-can's environment variables and ``~/.canrc`` are
  ignored, so nothing leaks into the recording from the machine's configuration. A
  ``can.Notifier`` feeds a listener that never raises (a full queue or a failure is counted,
  bus errors are counted and back off briefly); a watchdog, run on every read, restarts the
  notifier if its thread died (at most :data:`MAX_NOTIFIER_RESTARTS` times; then the stream
  ends, reported in the summary). ``read`` never waits: it takes the frames received so far.
* **Decoding**: cantools with ``decode_choices=False`` (numbers, never choice names), looked
  up by the frame's id *and* its ``is_extended_id`` (an extended frame with the id of a
  standard one is another frame). A frame id the DBC does not know, an error frame, a remote
  frame, an undecodable payload (short DLC) or a frame older than the previous one of its
  kind is counted in :class:`CanStatistics`, never raised. A lost frame shows up as a
  dropped frame in the fault detection (counter and time gaps).
* **Time**: every sample is timestamped from its frame, on the scan clock:
  ``time_s = frame.timestamp - time_zero_s``; ``time_zero_s`` defaults to the first frame's
  timestamp (any frame), so a log starts at 0 like a run's scans. Set it when the scan source
  and the CAN interface share a clock (a live rig: the host's clock at the first scan); the
  recorder does so itself through :meth:`~CanSensorStream.align_clock` when the scan source
  knows the host's UNIX time of its scan time 0 and ``time_zero_s`` is not configured. The
  frames' clock is the log's: UNIX time for BLF, CSV, canutils and live buses, seconds since
  the log's start for ASC (python-can's ``ASCReader`` default).

Settings of the ``can`` source (:func:`open_can`)
-------------------------------------------------
=========================  ===================================================================
``log``                    a CAN log file; or
``interface``              a python-can interface (``socketcan``, ``pcan``, ``kvaser``,
                           ``vector``, ``virtual``, ...), with ``channel`` (e.g. ``can0``),
                           ``bitrate`` (e.g. 500000) and ``bus_options`` (a table of further
                           keyword arguments of ``can.Bus``)
``dbc``                    another DBC with frames ``DisplacementSensors`` and ``WheelEncoder``
                           and the same signal names (default: the shipped
                           ``vehicle_sensors.dbc``)
``time_zero_s``            the frames' clock at scan time 0 (default: the first frame's)
``metres_per_pulse``       encoder scale [m] (default: a 2048-pulse encoder, 920 mm wheel)
``stuck_time_s``           shortest stuck-sensor stretch [s] (0.5)
``moving_speed_mps``       slowest speed counted as moving [m/s] (1.0)
``max_speed_mps``          faster encoder steps are a fault [m/s] (100)
``gap_factor``             an interval above this many periods is a dropped frame (1.5)
``displacement_period_s``  nominal periods [s] (default: the DBC's ``GenMsgCycleTime``)
``encoder_period_s``
``chunk_frames``           frames decoded per block (4096)
``queue_frames``           live bus: frames buffered between reads (65536)
=========================  ===================================================================
"""

from __future__ import annotations

import contextlib
import math
import queue
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from importlib.resources import files
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol, Self

import can
import cantools
import numpy as np

from catenary.domain import EncoderReadings, VehicleSamples
from catenary.errors import UserError, one_line

from .decode import (
    CHANNELS,
    DEFAULT_PERIOD_S,
    DisplacementFrames,
    EncoderFrames,
    FaultCounts,
    SensorTracker,
    TrackedBlock,
    TrackerConfig,
)

__all__ = [
    "DBC_PATH",
    "DISPLACEMENT_FRAME",
    "ENCODER_FRAME",
    "CanSensorStream",
    "CanStatistics",
    "FrameDecoder",
    "load_database",
    "open_bus",
    "open_can",
    "open_log",
]

DBC_PATH = Path(str(files("catenary_can").joinpath("vehicle_sensors.dbc")))
"""The shipped DBC (``plugins/catenary_can/vehicle_sensors.dbc``)."""
DISPLACEMENT_FRAME = "DisplacementSensors"
ENCODER_FRAME = "WheelEncoder"
DISPLACEMENT_SIGNALS = (*CHANNELS, "status", "counter")
ENCODER_SIGNALS = ("pulse_count", "status", "counter")

DEFAULT_CHUNK_FRAMES = 4096
DEFAULT_QUEUE_FRAMES = 65536
MAX_NOTIFIER_RESTARTS = 3
NOTIFIER_TIMEOUT_S = 0.1
ERROR_BACKOFF_S = 0.01
MAX_UNKNOWN_IDS = 32  # distinct unknown ids listed; beyond that they are only counted
MAX_HELD_ROWS = 1 << 20
"""Samples (or readings) of one kind held for the other reader method, at most (16 MiB of
encoder readings: 87 minutes at 200 Hz); the oldest are dropped beyond."""

_SOURCE = "source 'can'"


# --------------------------------------------------------------------------------------------
# Decoding


@dataclass
class CanStatistics:
    """Frame counts of a stream (running totals)."""

    frames: int = 0  # every frame read, of any kind
    displacement_frames: int = 0
    encoder_frames: int = 0
    unknown_frames: int = 0
    unknown_ids: dict[str, int] = field(default_factory=dict)  # "0x123" / "0x1234567x"
    error_frames: int = 0
    remote_frames: int = 0
    malformed_frames: int = 0
    out_of_order_frames: int = 0
    overflow_frames: int = 0  # live bus: frames lost because the queue was full
    bus_errors: int = 0  # live bus: errors receiving (on_error)
    listener_errors: int = 0
    notifier_restarts: int = 0
    last_error: str | None = None


def load_database(path: str | Path = DBC_PATH) -> Any:
    """Load a DBC and check it has the two sensor frames and their signals (``UserError``)."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: no such DBC file")
    try:
        database: Any = cantools.database.load_file(str(path), database_format="dbc")
    except Exception as exc:
        raise UserError(f"{path}: not a readable DBC file ({one_line(exc)})") from None
    for frame, signals in (
        (DISPLACEMENT_FRAME, DISPLACEMENT_SIGNALS),
        (ENCODER_FRAME, ENCODER_SIGNALS),
    ):
        try:
            message = database.get_message_by_name(frame)
        except KeyError:
            raise UserError(f"{path}: no frame {frame!r}") from None
        names = {s.name for s in message.signals}
        missing = [s for s in signals if s not in names]
        if missing:
            raise UserError(f"{path}: frame {frame!r} lacks signal(s) {', '.join(missing)}")
    return database


class FrameDecoder:
    """Decodes frames with cantools into column buffers of the two sensor frames.

    :meth:`add` never raises for a bad frame: it counts it in ``statistics``. :meth:`take`
    returns the buffered frames as arrays and empties the buffers.
    """

    def __init__(self, database: Any, statistics: CanStatistics) -> None:
        self.statistics = statistics
        self._messages: dict[tuple[int, bool], Any] = {
            (int(m.frame_id), bool(m.is_extended_frame)): m for m in database.messages
        }
        displacement = database.get_message_by_name(DISPLACEMENT_FRAME)
        encoder = database.get_message_by_name(ENCODER_FRAME)
        self._displacement_key = (int(displacement.frame_id), bool(displacement.is_extended_frame))
        self._encoder_key = (int(encoder.frame_id), bool(encoder.is_extended_frame))
        self._disp: dict[str, list[float]] = {
            name: [] for name in ("time_s", *DISPLACEMENT_SIGNALS)
        }
        self._enc: dict[str, list[float]] = {name: [] for name in ("time_s", *ENCODER_SIGNALS)}
        self._last_t = {self._displacement_key: -math.inf, self._encoder_key: -math.inf}

    @property
    def buffered(self) -> int:
        return len(self._disp["time_s"]) + len(self._enc["time_s"])

    def add(self, msg: can.Message, time_s: float) -> None:
        """Decode one frame received at ``time_s`` (scan clock) into the buffers."""
        stats = self.statistics
        stats.frames += 1
        if msg.is_error_frame:
            stats.error_frames += 1
            return
        if msg.is_remote_frame:
            stats.remote_frames += 1
            return
        key = (int(msg.arbitration_id), bool(msg.is_extended_id))
        message = self._messages.get(key)
        if message is None or key not in self._last_t:
            stats.unknown_frames += 1
            name = f"0x{key[0]:08X}x" if key[1] else f"0x{key[0]:03X}"
            if name in stats.unknown_ids or len(stats.unknown_ids) < MAX_UNKNOWN_IDS:
                stats.unknown_ids[name] = stats.unknown_ids.get(name, 0) + 1
            return
        if not math.isfinite(time_s):
            stats.malformed_frames += 1
            return
        if time_s < self._last_t[key]:
            stats.out_of_order_frames += 1
            return
        try:
            signals = message.decode(bytes(msg.data), decode_choices=False, scaling=True)
            if key == self._displacement_key:
                row = [float(signals[name]) for name in DISPLACEMENT_SIGNALS]
                columns = self._disp
                stats.displacement_frames += 1
            else:
                row = [float(signals[name]) for name in ENCODER_SIGNALS]
                columns = self._enc
                stats.encoder_frames += 1
        except Exception as exc:  # short payload, a signal missing: a frame lost, not a crash
            stats.malformed_frames += 1
            stats.last_error = f"frame 0x{key[0]:X}: {one_line(exc)}"
            return
        self._last_t[key] = time_s
        names = list(columns)
        columns["time_s"].append(time_s)
        for name, value in zip(names[1:], row, strict=True):
            columns[name].append(value)

    def take(self) -> tuple[DisplacementFrames, EncoderFrames]:
        """The buffered frames as arrays; the buffers are emptied."""
        d = self._disp
        e = self._enc
        displacement = DisplacementFrames(
            time_s=np.asarray(d["time_s"], dtype=np.float64),
            left_mm=np.asarray(d["left_mm"], dtype=np.float64),
            right_mm=np.asarray(d["right_mm"], dtype=np.float64),
            lateral_mm=np.asarray(d["lateral_mm"], dtype=np.float64),
            status=np.asarray(d["status"], dtype=np.int64),
            counter=np.asarray(d["counter"], dtype=np.int64),
        )
        encoder = EncoderFrames(
            time_s=np.asarray(e["time_s"], dtype=np.float64),
            pulse_count=np.asarray(e["pulse_count"], dtype=np.int64),
            status=np.asarray(e["status"], dtype=np.int64),
            counter=np.asarray(e["counter"], dtype=np.int64),
        )
        for columns in (d, e):
            for values in columns.values():
                values.clear()
        return displacement, encoder


def tracker_config(database: Any, **overrides: Any) -> TrackerConfig:
    """Fault-detection settings: limits and periods from the DBC, ``overrides`` on top."""
    displacement = database.get_message_by_name(DISPLACEMENT_FRAME)
    encoder = database.get_message_by_name(ENCODER_FRAME)
    limits: dict[str, tuple[float, float]] = {}
    for name in CHANNELS:
        signal = displacement.get_signal_by_name(name)
        low = -math.inf if signal.minimum is None else float(signal.minimum)
        high = math.inf if signal.maximum is None else float(signal.maximum)
        limits[name] = (low, high)

    def period(message: Any) -> float:
        cycle_ms = message.cycle_time
        return DEFAULT_PERIOD_S if not cycle_ms else float(cycle_ms) / 1000.0

    values: dict[str, Any] = {
        "limits_mm": limits,
        "displacement_period_s": period(displacement),
        "encoder_period_s": period(encoder),
    }
    values.update({k: v for k, v in overrides.items() if v is not None})
    return TrackerConfig(**values)


# --------------------------------------------------------------------------------------------
# Where frames come from


class _Feed(Protocol):
    description: str
    exhausted: bool  # no frame will ever come again
    error: str | None

    def poll(self) -> can.Message | None: ...  # the next frame now, or None

    def check(self, statistics: CanStatistics) -> None: ...  # watchdog, statistics update

    def close(self) -> None: ...


class _LogFeed:
    """Frames of a log file, lazily, in file order."""

    def __init__(self, path: Path) -> None:
        self.description = f"log {path}"
        self.exhausted = False
        self.error: str | None = None
        if not path.is_file():
            raise UserError(f"{path}: no such CAN log file")
        try:
            self._reader: Any = can.LogReader(path)
        except ValueError as exc:
            raise UserError(
                f"{path}: not a CAN log python-can reads ({exc}; known: .asc, .blf, .csv, "
                ".db, .log, .mf4, .trc, optionally .gz)"
            ) from None
        except Exception as exc:
            raise UserError(f"{path}: cannot read CAN log ({one_line(exc)})") from None
        self._path = path
        self._frames = 0
        self._iter: Iterator[can.Message] = iter(self._reader)

    def poll(self) -> can.Message | None:
        if self.exhausted:
            return None
        try:
            msg = next(self._iter)
        except StopIteration:
            self.exhausted = True
            return None
        except Exception as exc:
            self.exhausted = True
            self.error = f"{self._path}: unreadable after frame {self._frames} ({one_line(exc)})"
            return None
        self._frames += 1
        return msg

    def check(self, statistics: CanStatistics) -> None:
        if self.error is not None:
            statistics.last_error = self.error

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._reader.stop()


class _QueueListener(can.Listener):
    """Puts frames on a bounded queue. Never raises: problems are counted."""

    def __init__(self, maxsize: int) -> None:
        self.queue: queue.Queue[can.Message] = queue.Queue(maxsize)
        self.overflow = 0
        self.errors = 0
        self.bus_errors = 0
        self.last_error: str | None = None

    def on_message_received(self, msg: can.Message) -> None:
        try:
            self.queue.put_nowait(msg)
        except queue.Full:
            self.overflow += 1
        except Exception as exc:
            self.errors += 1
            self.last_error = one_line(exc)

    def on_error(self, exc: Exception) -> None:
        # Called in the notifier's thread when receiving fails; handled here (so the thread
        # carries on) with a short back-off, so a bus that went down does not spin a core.
        with contextlib.suppress(Exception):
            self.bus_errors += 1
            self.last_error = f"bus error: {one_line(exc)}"
            time.sleep(ERROR_BACKOFF_S)

    def stop(self) -> None:
        pass


class _BusFeed:
    """Frames of a live bus, received by a ``can.Notifier`` thread, watched by a watchdog."""

    def __init__(self, interface: str, channel: Any, bus_options: Mapping[str, Any], maxsize: int):
        where = f"interface={interface!r}" + (f", channel={channel!r}" if channel else "")
        self.description = f"bus {where}"
        self.exhausted = False
        self.error: str | None = None
        kwargs = dict(bus_options)
        if channel is not None:
            kwargs["channel"] = channel
        try:
            self._bus: Any = can.Bus(interface=interface, ignore_config=True, **kwargs)
        except Exception as exc:  # unknown interface, missing driver, no such channel, ...
            raise UserError(f"CAN {where}: cannot open ({one_line(exc)})") from None
        self._listener = _QueueListener(maxsize)
        self._notifier = self._start_notifier()
        self._restarts = 0
        self._reported_error: str | None = None
        self._closed = False

    def _start_notifier(self) -> can.Notifier:
        return can.Notifier(self._bus, [self._listener], timeout=NOTIFIER_TIMEOUT_S)

    def _notifier_alive(self) -> bool:
        readers = getattr(self._notifier, "_readers", [])
        threads = [r for r in readers if isinstance(r, threading.Thread)]
        return all(t.is_alive() for t in threads)

    def poll(self) -> can.Message | None:
        try:
            return self._listener.queue.get_nowait()
        except queue.Empty:
            return None

    def check(self, statistics: CanStatistics) -> None:
        """The watchdog: restart a dead notifier thread; copy the listener's counters."""
        listener = self._listener
        statistics.overflow_frames = listener.overflow
        statistics.listener_errors = listener.errors
        statistics.bus_errors = listener.bus_errors
        if listener.last_error is not None and listener.last_error != self._reported_error:
            statistics.last_error = self._reported_error = listener.last_error
        if self._closed or self.exhausted or self._notifier_alive():
            return
        cause = self._notifier.exception
        reason = f" ({one_line(cause)})" if cause is not None else ""
        with contextlib.suppress(Exception):
            self._notifier.stop(timeout=NOTIFIER_TIMEOUT_S)
        if self._restarts >= MAX_NOTIFIER_RESTARTS:
            self.exhausted = True
            self.error = (
                f"CAN {self.description}: receive thread stopped{reason}, "
                f"given up after {self._restarts} restarts"
            )
            statistics.last_error = self.error
            return
        self._restarts += 1
        statistics.notifier_restarts = self._restarts
        statistics.last_error = f"CAN {self.description}: receive thread restarted{reason}"
        self._notifier = self._start_notifier()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._notifier.stop(timeout=1.0)
        finally:
            self._bus.shutdown()


# --------------------------------------------------------------------------------------------
# The stream


class CanSensorStream:
    """An open CAN sensor acquisition (log file or live bus); a context manager.

    Attributes
    ----------
    description : str
        ``"log PATH"`` or ``"bus interface=..., channel=..."``.
    statistics : CanStatistics
        Frame counts so far.
    counts : FaultCounts
        Sample and fault counts so far (:mod:`catenary_can.decode`).
    """

    def __init__(
        self,
        feed: _Feed,
        database: Any,
        config: TrackerConfig,
        *,
        time_zero_s: float | None = None,
        chunk_frames: int = DEFAULT_CHUNK_FRAMES,
    ) -> None:
        self._feed = feed
        self.description = feed.description
        self.statistics = CanStatistics()
        self._decoder = FrameDecoder(database, self.statistics)
        self._tracker = SensorTracker(config)
        self.config = config
        self.time_zero_s = time_zero_s
        self._time_zero_configured = time_zero_s is not None
        self._chunk_frames = chunk_frames
        # what vehicle_samples decoded for encoder_readings, and the other way round
        self._held_vehicle: list[VehicleSamples] = []
        self._held_encoder: list[EncoderReadings] = []
        self._next: can.Message | None = None  # read but later than the last ``until_s``
        self._closed = False

    @property
    def counts(self) -> FaultCounts:
        return self._tracker.counts

    @property
    def exhausted(self) -> bool:
        """No frame will come any more (the log's end, or a live bus given up)."""
        return self._next is None and self._feed.exhausted

    def read(self, until_s: float = math.inf, *, final: bool = False) -> Iterator[TrackedBlock]:
        """Decode the frames up to ``until_s`` (scan clock) available now, block by block.

        A log is read up to ``until_s`` (to its end by default); a live bus gives what it has
        received. Samples whose fault verdict needs later frames (an open run of unchanged
        values) are held back, unless ``final`` or the log ended. Later calls continue.
        """
        if self._closed:
            raise ValueError(f"CAN {self.description}: stream is closed")
        return self._read(float(until_s), final)

    def _read(self, until_s: float, final: bool) -> Iterator[TrackedBlock]:
        self._feed.check(self.statistics)
        while True:
            paused = self._fill(until_s)
            end = paused and (final or self.exhausted)
            if self._decoder.buffered or end:
                displacement, encoder = self._decoder.take()
                block = self._tracker.push(displacement, encoder, final=end)
                if not block.empty:
                    yield block
            if paused:
                self._feed.check(self.statistics)
                return

    def _fill(self, until_s: float) -> bool:
        """Decode frames until a block is full (False) or none is left up to ``until_s``."""
        while self._decoder.buffered < self._chunk_frames:
            msg = self._next if self._next is not None else self._feed.poll()
            self._next = None
            if msg is None:
                return True
            if self.time_zero_s is None:
                self.time_zero_s = float(msg.timestamp)
            time_s = float(msg.timestamp) - self.time_zero_s
            if time_s > until_s:
                self._next = msg
                return True
            self._decoder.add(msg, time_s)
        return False

    def align_clock(self, clock_zero_unix_s: float) -> None:
        """Put scan time 0 at the frames' clock reading ``clock_zero_unix_s`` (a live scan
        source's host UNIX time of its first scan), unless ``time_zero_s`` was configured.
        Called before any frame is read (``ValueError`` after)."""
        if self._time_zero_configured:
            return
        if self.time_zero_s is not None:
            raise ValueError(f"CAN {self.description}: clock aligned after frames were read")
        if not math.isfinite(clock_zero_unix_s):
            raise ValueError(f"CAN {self.description}: clock zero {clock_zero_unix_s!r}")
        self.time_zero_s = float(clock_zero_unix_s)

    def vehicle_samples(self, until_s: float, *, final: bool = False) -> Iterator[VehicleSamples]:
        """The flagged displacement samples of :meth:`read` (what ``catenary record`` writes),
        those an :meth:`encoder_readings` call decoded first."""
        held, self._held_vehicle = self._held_vehicle, []
        yield from held
        for block in self.read(until_s, final=final):
            self._hold(self._held_encoder, _good_readings(block))
            if block.vehicle.time_s.shape[0]:
                yield block.vehicle

    def encoder_readings(self, until_s: float, *, final: bool = False) -> Iterator[EncoderReadings]:
        """The encoder's readings of :meth:`read`, faulty ones left out (``VehicleStream``'s
        optional method), those a :meth:`vehicle_samples` call decoded first."""
        held, self._held_encoder = self._held_encoder, []
        yield from held
        for block in self.read(until_s, final=final):
            if block.vehicle.time_s.shape[0]:
                self._hold(self._held_vehicle, block.vehicle)
            readings = _good_readings(block)
            if readings.time_s.shape[0]:
                yield readings

    @staticmethod
    def _hold(held: list[Any], part: VehicleSamples | EncoderReadings) -> None:
        """Keep ``part`` for the other method; drop the oldest beyond :data:`MAX_HELD_ROWS`."""
        if part.time_s.shape[0] == 0:
            return
        held.append(part)
        rows = sum(p.time_s.shape[0] for p in held)
        while rows > MAX_HELD_ROWS and len(held) > 1:
            rows -= held.pop(0).time_s.shape[0]

    def summary(self) -> str:
        """One line: frames read, frames lost, samples flagged and why."""
        s = self.statistics
        c = self.counts
        parts = [
            f"{s.frames} frames ({s.displacement_frames} displacement, {s.encoder_frames} encoder)",
            f"{c.dropped_displacement_frames + c.dropped_encoder_frames} dropped",
        ]
        for label, value in (
            ("unknown", s.unknown_frames),
            ("error frames", s.error_frames),
            ("malformed", s.malformed_frames),
            ("out of order", s.out_of_order_frames),
            ("overflowed", s.overflow_frames),
            ("bus errors", s.bus_errors),
        ):
            if value:
                parts.append(f"{value} {label}")
        reasons = ", ".join(
            f"{k} {v}" for k, v in sorted(c.displacement_reasons.items()) if k != "dropped"
        )
        flagged = (
            f"{c.faulty_displacement_samples} of {c.displacement_samples} sensor samples flagged"
            + (f" ({reasons})" if reasons else "")
        )
        line = f"CAN {self.description}: {', '.join(parts)}; {flagged}"
        if s.last_error:
            line += f"; last problem: {s.last_error}"
        return line

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._feed.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<CanSensorStream {self.description}>"


def _good_readings(block: TrackedBlock) -> EncoderReadings:
    """The block's encoder readings that are not faulty."""
    good = ~block.encoder.fault
    return EncoderReadings(block.encoder.time_s[good], block.encoder.position_m[good])


# --------------------------------------------------------------------------------------------
# Opening


def open_log(
    path: str | Path,
    *,
    dbc: str | Path = DBC_PATH,
    time_zero_s: float | None = None,
    chunk_frames: int = DEFAULT_CHUNK_FRAMES,
    **tracker: Any,
) -> CanSensorStream:
    """Read a CAN log file; ``tracker`` overrides :class:`TrackerConfig` fields."""
    database = load_database(dbc)
    config = tracker_config(database, **tracker)
    return CanSensorStream(
        _LogFeed(Path(path)), database, config, time_zero_s=time_zero_s, chunk_frames=chunk_frames
    )


def open_bus(
    interface: str,
    channel: Any = None,
    *,
    bitrate: int | None = None,
    bus_options: Mapping[str, Any] | None = None,
    dbc: str | Path = DBC_PATH,
    time_zero_s: float | None = None,
    chunk_frames: int = DEFAULT_CHUNK_FRAMES,
    queue_frames: int = DEFAULT_QUEUE_FRAMES,
    **tracker: Any,
) -> CanSensorStream:
    """Listen to a live bus (``can.Bus(interface=..., channel=..., bitrate=..., ...)``)."""
    database = load_database(dbc)
    config = tracker_config(database, **tracker)
    options = dict(bus_options or {})
    if bitrate is not None:
        options["bitrate"] = bitrate
    feed = _BusFeed(interface, channel, options, queue_frames)
    return CanSensorStream(
        feed, database, config, time_zero_s=time_zero_s, chunk_frames=chunk_frames
    )


def _setting_error(key: str, value: Any, expected: str) -> UserError:
    return UserError(f"{_SOURCE}: setting {key} = {value!r}: expected {expected}")


def _number(settings: Mapping[str, Any], key: str, *, minimum: float, strict: bool) -> float | None:
    if key not in settings or settings[key] is None:
        return None
    value = settings[key]
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise _setting_error(key, value, "a number")
    if value < minimum or (strict and value == minimum):
        raise _setting_error(key, value, f"a number {'>' if strict else '>='} {minimum:g}")
    return float(value)


def _integer(settings: Mapping[str, Any], key: str, default: int) -> int:
    value = settings.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise _setting_error(key, value, "a positive integer")
    return value


_TRACKER_SETTINGS = {
    "metres_per_pulse": (0.0, True),
    "stuck_time_s": (0.0, True),
    "moving_speed_mps": (0.0, False),
    "max_speed_mps": (0.0, True),
    "gap_factor": (1.0, True),
    "displacement_period_s": (0.0, True),
    "encoder_period_s": (0.0, True),
}
_KNOWN = {
    "log",
    "interface",
    "channel",
    "bitrate",
    "bus_options",
    "dbc",
    "time_zero_s",
    "chunk_frames",
    "queue_frames",
    *_TRACKER_SETTINGS,
}


def open_can(settings: Mapping[str, Any]) -> CanSensorStream:
    """Open the ``can`` source from its settings (module docstring); ``UserError`` if bad."""
    unknown = sorted(set(settings) - _KNOWN)
    if unknown:
        raise UserError(
            f"{_SOURCE}: unknown setting {unknown[0]!r} (known: {', '.join(sorted(_KNOWN))})"
        )
    log = settings.get("log")
    interface = settings.get("interface")
    if (log is None) == (interface is None):
        raise UserError(f"{_SOURCE}: give either 'log' (a CAN log file) or 'interface' (a bus)")
    tracker: dict[str, Any] = {}
    for key, (minimum, strict) in _TRACKER_SETTINGS.items():
        value = _number(settings, key, minimum=minimum, strict=strict)
        if value is not None:
            tracker[key] = value
    time_zero = settings.get("time_zero_s")
    if time_zero is not None and (
        isinstance(time_zero, bool)
        or not isinstance(time_zero, int | float)
        or not math.isfinite(time_zero)
    ):
        raise _setting_error("time_zero_s", time_zero, "a number")
    dbc = settings.get("dbc", DBC_PATH)
    if not isinstance(dbc, str | Path) or not str(dbc):
        raise _setting_error("dbc", dbc, "a DBC file path")
    common: dict[str, Any] = {
        "dbc": dbc,
        "time_zero_s": None if time_zero is None else float(time_zero),
        "chunk_frames": _integer(settings, "chunk_frames", DEFAULT_CHUNK_FRAMES),
        **tracker,
    }
    if log is not None:
        if not isinstance(log, str | Path) or not str(log):
            raise _setting_error("log", log, "a CAN log file path")
        for key in ("channel", "bitrate", "bus_options", "queue_frames"):
            if key in settings:
                raise UserError(f"{_SOURCE}: setting {key!r} is for a live bus, not a log")
        return open_log(log, **common)
    if not isinstance(interface, str) or not interface:
        raise _setting_error("interface", interface, "a python-can interface name")
    channel = settings.get("channel")
    if channel is not None and (isinstance(channel, bool) or not isinstance(channel, str | int)):
        raise _setting_error("channel", channel, "a channel name or number")
    bitrate = settings.get("bitrate")
    if bitrate is not None and (isinstance(bitrate, bool) or not isinstance(bitrate, int)):
        raise _setting_error("bitrate", bitrate, "an integer (bit/s)")
    bus_options = settings.get("bus_options", {})
    if not isinstance(bus_options, Mapping):
        raise _setting_error("bus_options", bus_options, "a table of can.Bus arguments")
    return open_bus(
        interface,
        channel,
        bitrate=bitrate,
        bus_options=bus_options,
        queue_frames=_integer(settings, "queue_frames", DEFAULT_QUEUE_FRAMES),
        **common,
    )
