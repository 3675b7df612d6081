"""Decoded CAN sensor frames to vehicle samples and encoder positions, with fault detection.

Pure: NumPy arrays in, NumPy arrays out, no I/O. :class:`SensorTracker` carries the little
state that crosses a block boundary (the last frame of each kind, the open runs of unchanged
values) so that a recording is processed block by block in bounded memory and the result does
not depend on where the blocks are cut.

The frames (``vehicle_sensors.dbc``)
-------------------------------------
A private 500 kbit/s bus, classic CAN, 11-bit identifiers, little-endian signals, every frame
every 5 ms (DBC attribute ``GenMsgCycleTime``):

=====  ===================  ==============  ============================================
id     frame                bits            signal
=====  ===================  ==============  ============================================
0x100  WheelEncoder         0-31            ``pulse_count`` [pulses], cumulative, wraps
                                            modulo 2**32, counts down in reverse
                            48-55           ``status``: bit 0 encoder signal fault
                            56-59           ``counter``: rolling counter 0-15
0x110  DisplacementSensors  0-15            ``left_mm``  raw * 0.01 - 300 [mm], valid -250..250
                            16-31           ``right_mm`` raw * 0.01 - 300 [mm], valid -250..250
                            32-47           ``lateral_mm`` raw * 0.01 - 300 [mm], valid -200..200
                            48-55           ``status``: bit 0 left, bit 1 right, bit 2 lateral
                                            sensor invalid; bit 3 module fault (all three)
                            56-59           ``counter``: rolling counter 0-15
=====  ===================  ==============  ============================================

Unused bits are reserved (sent as 0). Raw ``0xFFFF`` (355.35 mm, "no measurement") and raw 0
(-300 mm, underflow) fall outside the valid range. Units and signs of the displacement sensors
are FORMATS.md's (vehicle compensation model).

Fault rules
-----------
A displacement sample is flagged (``VehicleSamples.fault``; the reason in
``TrackedBlock.vehicle_reasons``) when:

* **dropped frame** (:data:`DROPPED`): frames are missing before it, by the rolling counter
  (a jump of more than one) or by time (an interval longer than ``gap_factor`` times the
  nominal period, which also catches 16 or more lost frames that the counter cannot show).
  Each missing frame becomes a *placeholder* sample at its expected time (at most
  :data:`MAX_PLACEHOLDERS` per gap, evenly spaced), values NaN, flagged; the received samples
  either side keep their values. The stretch between them is
  therefore flagged, never interpolated over.
* **repeated counter** (:data:`REPEATED`): the counter did not advance (a stale frame re-sent).
* **out of range** (:data:`OUT_OF_RANGE`): a sensor outside the DBC signal's ``[min, max]``,
  or not finite.
* **status** (:data:`STATUS`): a status bit of one of the sensors, or the module fault bit.
* **stuck** (:data:`STUCK`): a sensor's value unchanged (bit for bit) over at least
  ``stuck_time_s`` (default :data:`DEFAULT_STUCK_TIME_S` = 0.5 s, i.e. 100 frames at 200 Hz)
  while the vehicle moves at ``moving_speed_mps`` (default 1 m/s) or faster throughout; every
  sample of that stretch is flagged. A working sensor with 0.01 mm resolution on a moving body
  changes within a few frames; at standstill a constant value is legitimate. Speed comes from
  the wheel encoder (the last encoder interval at or before the sample); without encoder
  frames, or when the last one is older than ``encoder_stale_s``, the vehicle counts as
  moving (so a stuck sensor is still caught). Placeholders do not break a run: a sensor stuck
  across a dropped frame is still one run.

An encoder sample is flagged (``EncoderSamples.fault``) when frames are missing before it
(counter or time, as above: :data:`DROPPED`), its counter repeats (:data:`REPEATED`), its status
bit 0 is set (:data:`STATUS`), or the pulses since the previous frame imply a speed above
``max_speed_mps`` (:data:`JUMP`). Positions stay exact across dropped frames because the count
is cumulative; ``position_m`` is the distance since the first encoder frame,
``pulses * metres_per_pulse``, signed (negative in reverse).

Faulty samples keep their decoded values (placeholders are NaN): consumers must not trust the
values where ``fault`` is set.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from catenary.arrays import BoolArray, FloatArray, IntArray, UInt8Array
from catenary.domain import VehicleSamples

__all__ = [
    "CHANNELS",
    "DEFAULT_GAP_FACTOR",
    "DEFAULT_MAX_SPEED_MPS",
    "DEFAULT_METRES_PER_PULSE",
    "DEFAULT_MOVING_SPEED_MPS",
    "DEFAULT_STUCK_TIME_S",
    "DROPPED",
    "JUMP",
    "OUT_OF_RANGE",
    "REPEATED",
    "STATUS",
    "STUCK",
    "DisplacementFrames",
    "EncoderFrames",
    "EncoderSamples",
    "FaultCounts",
    "RunState",
    "SensorTracker",
    "TrackedBlock",
    "TrackerConfig",
    "expand_missing",
    "missing_frames",
    "out_of_range",
    "speed_at",
    "status_faults",
    "stuck_verdicts",
    "unwrap_counts",
]

CHANNELS = ("left_mm", "right_mm", "lateral_mm")

# Fault reasons: bits of TrackedBlock.vehicle_reasons / encoder_reasons.
DROPPED = 1
REPEATED = 2
OUT_OF_RANGE = 4
STATUS = 8
STUCK = 16
JUMP = 32
REASON_NAMES = {
    DROPPED: "dropped",
    REPEATED: "repeated counter",
    OUT_OF_RANGE: "out of range",
    STATUS: "status",
    STUCK: "stuck",
    JUMP: "jump",
}

# Status bits of DisplacementSensors.status per channel (bit 3: module fault, all channels).
DISPLACEMENT_STATUS_BITS = {"left_mm": 0b1001, "right_mm": 0b1010, "lateral_mm": 0b1100}
ENCODER_SIGNAL_FAULT = 0b1

COUNTER_MODULO = 16
PULSE_MODULO = 1 << 32
DEFAULT_PERIOD_S = 0.005
DEFAULT_GAP_FACTOR = 1.5
DEFAULT_STUCK_TIME_S = 0.5
DEFAULT_MOVING_SPEED_MPS = 1.0
DEFAULT_MAX_SPEED_MPS = 100.0
MAX_PLACEHOLDERS = 64
"""Placeholders inserted for one gap at most: a longer gap is a stretch of flagged samples with
wider spacing (every scan inside it is still next to a flagged sample)."""
MAX_HELD_ROWS = 1 << 16
"""Samples held back at most (an open run of unchanged values whose times do not advance)."""
DEFAULT_METRES_PER_PULSE = math.pi * 0.920 / 2048
"""A 2048-pulse encoder on a new 920 mm wheel (about 1.41 mm per pulse); set your vehicle's."""


# --------------------------------------------------------------------------------------------
# Arrays of decoded frames and samples


def _empty_f() -> FloatArray:
    return np.zeros(0, dtype=np.float64)


def _empty_i() -> IntArray:
    return np.zeros(0, dtype=np.int64)


@dataclass(frozen=True)
class DisplacementFrames:
    """Decoded ``DisplacementSensors`` frames in arrival order, each ``[K]``.

    ``time_s`` on the scan clock (non-decreasing); sensors in mm (physical values, DBC
    scaling applied); ``status`` and ``counter`` the raw integers.
    """

    time_s: FloatArray = field(default_factory=_empty_f)
    left_mm: FloatArray = field(default_factory=_empty_f)
    right_mm: FloatArray = field(default_factory=_empty_f)
    lateral_mm: FloatArray = field(default_factory=_empty_f)
    status: IntArray = field(default_factory=_empty_i)
    counter: IntArray = field(default_factory=_empty_i)

    @property
    def frames(self) -> int:
        return int(self.time_s.shape[0])


@dataclass(frozen=True)
class EncoderFrames:
    """Decoded ``WheelEncoder`` frames in arrival order, each ``[K]`` (raw integers)."""

    time_s: FloatArray = field(default_factory=_empty_f)
    pulse_count: IntArray = field(default_factory=_empty_i)
    status: IntArray = field(default_factory=_empty_i)
    counter: IntArray = field(default_factory=_empty_i)

    @property
    def frames(self) -> int:
        return int(self.time_s.shape[0])


@dataclass(frozen=True)
class EncoderSamples:
    """Wheel encoder positions, each ``[K]``: ``position_m`` since the first encoder frame."""

    time_s: FloatArray
    position_m: FloatArray
    fault: BoolArray


@dataclass(frozen=True)
class TrackedBlock:
    """What :meth:`SensorTracker.push` releases: samples whose faults are decided.

    ``vehicle`` may hold placeholder samples (NaN, flagged) for dropped frames;
    ``vehicle_reasons`` and ``encoder_reasons`` (uint8 ``[K]``) are the fault reasons as bits
    (:data:`DROPPED`, :data:`REPEATED`, :data:`OUT_OF_RANGE`, :data:`STATUS`, :data:`STUCK`,
    :data:`JUMP`), zero for a good sample.
    """

    vehicle: VehicleSamples
    vehicle_reasons: UInt8Array
    encoder: EncoderSamples
    encoder_reasons: UInt8Array

    @property
    def empty(self) -> bool:
        return bool(self.vehicle.time_s.shape[0] == 0 and self.encoder.time_s.shape[0] == 0)


@dataclass
class FaultCounts:
    """Running totals over the samples released so far."""

    displacement_samples: int = 0  # received frames (placeholders not included)
    dropped_displacement_frames: int = 0  # frames missing (counter or time)
    placeholders: int = 0  # placeholder samples released (at most MAX_PLACEHOLDERS per gap)
    faulty_displacement_samples: int = 0  # flagged samples, placeholders not included
    encoder_samples: int = 0
    dropped_encoder_frames: int = 0
    faulty_encoder_samples: int = 0
    displacement_reasons: dict[str, int] = field(default_factory=dict)
    encoder_reasons: dict[str, int] = field(default_factory=dict)

    @staticmethod
    def _tally(reasons: UInt8Array, target: dict[str, int]) -> None:
        """Add the samples of ``reasons`` with each reason bit to ``target`` (by name)."""
        for bit, name in REASON_NAMES.items():
            count = int(np.count_nonzero(reasons & bit))
            if count:
                target[name] = target.get(name, 0) + count


# --------------------------------------------------------------------------------------------
# Pure vectorised helpers


def missing_frames(
    counter: IntArray,
    time_s: FloatArray,
    *,
    period_s: float,
    gap_factor: float = DEFAULT_GAP_FACTOR,
    modulo: int = COUNTER_MODULO,
    previous: tuple[int, float] | None = None,
) -> tuple[IntArray, BoolArray]:
    """Frames missing just before each frame, and frames whose counter did not advance.

    Parameters
    ----------
    counter : int array ``[K]``
        Rolling counters, ``0 .. modulo - 1``, +1 per frame sent.
    time_s : float array ``[K]``
        Receive times [s], non-decreasing.
    period_s : float
        Nominal period of the frame [s].
    gap_factor : float
        An interval longer than ``gap_factor * period_s`` means frames are missing.
    previous : (counter, time_s), optional
        The frame before ``counter[0]`` (from the previous block); none: nothing is missing
        before the first frame.

    Returns
    -------
    missing : int array ``[K]``
        By the counter, ``(counter - previous - 1) mod modulo``; where the interval is too long,
        at least ``round(interval / period_s) - 1`` (16 or more lost frames wrap the counter).
    repeated : bool array ``[K]``
        The counter equals the previous frame's (a stale frame sent again; nothing missing).
    """
    k = counter.shape[0]
    if k == 0:
        return _empty_i(), np.zeros(0, dtype=bool)
    prev_c = np.empty(k, dtype=np.int64)
    prev_t = np.empty(k, dtype=np.float64)
    prev_c[1:] = counter[:-1]
    prev_t[1:] = time_s[:-1]
    has_prev = np.ones(k, dtype=bool)
    if previous is None:
        prev_c[0] = counter[0] - 1
        prev_t[0] = time_s[0]
        has_prev[0] = False
    else:
        prev_c[0], prev_t[0] = previous
    repeated = has_prev & (counter == prev_c)
    by_counter = np.where(repeated, 0, (counter - prev_c - 1) % modulo)
    interval = time_s - prev_t
    late = has_prev & (interval > gap_factor * period_s)
    by_time = np.where(late, np.rint(interval / period_s).astype(np.int64) - 1, 0)
    missing = np.where(late, np.maximum(by_counter, np.maximum(by_time, 1)), by_counter)
    return missing.astype(np.int64), repeated


def expand_missing(
    time_s: FloatArray, missing: IntArray, previous_time_s: float | None
) -> tuple[FloatArray, BoolArray, IntArray]:
    """Insert a placeholder for every missing frame, evenly spaced before the frame it precedes.

    Parameters
    ----------
    time_s : ``[K]``
        Times of the received frames.
    missing : ``[K]``
        Frames missing before each (:func:`missing_frames`); ``missing[0]`` needs
        ``previous_time_s``.
    previous_time_s : float, optional
        Time of the frame before ``time_s[0]``.

    Returns
    -------
    times : ``[K + sum(missing)]``
        Received and placeholder times, in order.
    received : bool ``[K + sum(missing)]``
        True for a received frame.
    owner : int ``[K + sum(missing)]``
        Index into ``time_s`` of the received frame each row is (or precedes).
    """
    k = time_s.shape[0]
    if k == 0 or not missing.any():
        return time_s.copy(), np.ones(k, dtype=bool), np.arange(k, dtype=np.int64)
    if previous_time_s is None and missing[0] > 0:
        raise ValueError("missing[0] > 0 needs previous_time_s")
    prev_t = np.empty(k, dtype=np.float64)
    prev_t[1:] = time_s[:-1]
    prev_t[0] = time_s[0] if previous_time_s is None else previous_time_s
    counts = missing + 1
    owner = np.repeat(np.arange(k, dtype=np.int64), counts)
    first_row = np.cumsum(counts) - counts
    j = np.arange(owner.shape[0], dtype=np.int64) - first_row[owner]
    received = j == missing[owner]
    fraction = (j + 1) / counts[owner]
    times = np.where(
        received, time_s[owner], prev_t[owner] + (time_s[owner] - prev_t[owner]) * fraction
    )
    return times, received, owner


def out_of_range(values: FloatArray, minimum: float, maximum: float) -> BoolArray:
    """Values outside ``[minimum, maximum]`` or not finite, ``[K]``."""
    with np.errstate(invalid="ignore"):
        inside = (values >= minimum) & (values <= maximum)
    return ~inside


def status_faults(status: IntArray, mask: int) -> BoolArray:
    """Samples whose ``status`` has any bit of ``mask`` set, ``[K]``."""
    faults: BoolArray = (status & mask) != 0
    return faults


@dataclass(frozen=True)
class RunState:
    """The open run of unchanged values of one sensor at the end of a block."""

    value: float
    start_s: float
    stuck: bool


def stuck_verdicts(
    time_s: FloatArray,
    values: FloatArray,
    moving: BoolArray,
    stuck_time_s: float,
    carried: RunState | None = None,
) -> tuple[BoolArray, BoolArray, RunState | None, bool | None]:
    """Stuck-sensor verdicts over one sensor's received samples.

    A run is a maximal stretch of consecutive samples with the same value while moving (a
    sample not moving breaks it). A run lasting ``stuck_time_s`` or more is stuck.

    Parameters
    ----------
    time_s, values : ``[K]``
        One sensor's received samples [s], [mm].
    moving : bool ``[K]``
        Whether the vehicle moves at each sample.
    stuck_time_s : float
        Shortest stuck duration [s].
    carried : RunState, optional
        The open run before ``values[0]`` (from the previous block).

    Returns
    -------
    stuck : bool ``[K]``
    decided : bool ``[K]``
        False for the samples of the open run at the end that is not (yet) stuck: more
        samples could still extend it.
    carried_out : RunState or None
        The open run at the end (none if the last sample is not moving).
    carried_verdict : bool or None
        For the samples of ``carried`` held undecided so far: True stuck, False not stuck,
        None still undecided.
    """
    k = values.shape[0]
    if k == 0:
        return np.zeros(0, dtype=bool), np.zeros(0, dtype=bool), carried, None
    same = np.empty(k, dtype=bool)
    continues = carried is not None and bool(moving[0]) and bool(values[0] == carried.value)
    same[0] = continues
    same[1:] = (values[1:] == values[:-1]) & moving[1:] & moving[:-1]
    seg_start = np.flatnonzero(~same)
    if continues:
        seg_start = np.concatenate(([0], seg_start)).astype(np.int64)
    seg_end = np.append(seg_start[1:], k) - 1
    start_t = time_s[seg_start].astype(np.float64)
    if continues:
        assert carried is not None
        start_t[0] = carried.start_s
    duration = time_s[seg_end] - start_t
    seg_stuck = moving[seg_start] & (duration >= stuck_time_s)
    if continues:
        assert carried is not None
        seg_stuck[0] |= carried.stuck
    seg_id = np.repeat(np.arange(seg_start.shape[0]), seg_end - seg_start + 1)
    stuck = seg_stuck[seg_id]
    decided = np.ones(k, dtype=bool)
    last = seg_start.shape[0] - 1
    open_tail = bool(moving[-1])
    if open_tail and not seg_stuck[last]:
        decided[seg_start[last] :] = False
    carried_out = (
        RunState(float(values[-1]), float(start_t[last]), bool(seg_stuck[last]))
        if open_tail
        else None
    )
    if carried is None:
        verdict: bool | None = None
    elif not continues:
        verdict = carried.stuck
    else:
        verdict = bool(seg_stuck[0]) if (seg_stuck[0] or last > 0 or not open_tail) else None
    return stuck, decided, carried_out, verdict


def unwrap_counts(
    pulse_count: IntArray, previous: int | None, modulo: int = PULSE_MODULO
) -> IntArray:
    """Signed pulse increments ``[K]`` of a counter that wraps modulo ``modulo``.

    ``previous`` is the count before ``pulse_count[0]``; none: the first increment is 0.
    Increments are taken in ``[-modulo/2, modulo/2)`` (the encoder counts down in reverse).
    """
    k = pulse_count.shape[0]
    if k == 0:
        return _empty_i()
    prev = np.empty(k, dtype=np.int64)
    prev[1:] = pulse_count[:-1]
    prev[0] = pulse_count[0] if previous is None else previous
    half = modulo // 2
    return ((pulse_count - prev + half) % modulo - half).astype(np.int64)


def speed_at(
    time_s: FloatArray,
    encoder_time_s: FloatArray,
    encoder_speed_mps: FloatArray,
    *,
    stale_s: float,
) -> FloatArray:
    """Encoder speed [m/s] at ``time_s`` ``[n]``.

    ``encoder_speed_mps[i]`` ``[m]`` is the speed over the interval ending at
    ``encoder_time_s[i]`` (NaN when unknown). A time takes the speed of the interval it falls
    in (that of the first encoder sample at or after it; after the last sample, the last
    speed). NaN where that encoder sample is more than ``stale_s`` away, or there is none.
    """
    m = encoder_time_s.shape[0]
    n = time_s.shape[0]
    if m == 0 or n == 0:
        return np.full(n, np.nan)
    i = np.searchsorted(encoder_time_s, time_s, side="left")
    i = np.minimum(i, m - 1)
    speed: FloatArray = encoder_speed_mps[i].copy()
    speed[np.abs(encoder_time_s[i] - time_s) > stale_s] = np.nan
    return speed


# --------------------------------------------------------------------------------------------
# Streaming


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of the fault detection (module docstring).

    ``limits_mm`` maps each of :data:`CHANNELS` to its valid ``(min, max)`` [mm] (the DBC's).
    """

    limits_mm: dict[str, tuple[float, float]]
    displacement_period_s: float = DEFAULT_PERIOD_S
    encoder_period_s: float = DEFAULT_PERIOD_S
    gap_factor: float = DEFAULT_GAP_FACTOR
    stuck_time_s: float = DEFAULT_STUCK_TIME_S
    moving_speed_mps: float = DEFAULT_MOVING_SPEED_MPS
    max_speed_mps: float = DEFAULT_MAX_SPEED_MPS
    metres_per_pulse: float = DEFAULT_METRES_PER_PULSE
    encoder_stale_s: float | None = None  # default: 20 encoder periods

    @property
    def stale_s(self) -> float:
        return (
            20.0 * self.encoder_period_s if self.encoder_stale_s is None else self.encoder_stale_s
        )


@dataclass
class _Pending:
    """Displacement rows not released yet (the open runs), each ``[N]`` (values ``[3, N]``)."""

    time_s: FloatArray
    values: FloatArray
    received: BoolArray
    moving: BoolArray
    reasons: UInt8Array
    stuck: BoolArray  # [3, N]
    undecided: BoolArray  # [3, N]

    @classmethod
    def empty(cls) -> _Pending:
        return cls(
            _empty_f(),
            np.zeros((3, 0)),
            np.zeros(0, dtype=bool),
            np.zeros(0, dtype=bool),
            np.zeros(0, dtype=np.uint8),
            np.zeros((3, 0), dtype=bool),
            np.zeros((3, 0), dtype=bool),
        )

    @property
    def rows(self) -> int:
        return int(self.time_s.shape[0])


class SensorTracker:
    """Turns decoded frames, block by block, into flagged vehicle samples and encoder positions.

    Call :meth:`push` with each block's frames (both kinds up to the same time, so that the
    encoder's speed is known where the displacement samples need it) and ``final=True`` at
    the end. Samples in an open run of unchanged values are held until the run ends or is
    long enough to be stuck (at most ``stuck_time_s`` of samples), so the output does not
    depend on how the frames are cut into blocks. :attr:`counts` holds running totals.
    """

    def __init__(self, config: TrackerConfig) -> None:
        missing = sorted(set(CHANNELS) - set(config.limits_mm))
        if missing:
            raise ValueError(f"limits_mm lacks {', '.join(missing)}")
        self.config = config
        self.counts = FaultCounts()
        self._pending = _Pending.empty()
        self._runs: list[RunState | None] = [None, None, None]
        self._last_disp: tuple[int, float] | None = None
        self._last_enc: tuple[int, float] | None = None
        self._last_pulses: int | None = None
        self._total_pulses = 0
        self._enc_time = _empty_f()  # the last encoder sample (0 or 1), for speed look-ups
        self._enc_speed = _empty_f()

    # -- encoder ----------------------------------------------------------------------------

    def _encoder(self, frames: EncoderFrames) -> tuple[EncoderSamples, UInt8Array, FloatArray]:
        cfg = self.config
        k = frames.frames
        if k == 0:
            empty = EncoderSamples(_empty_f(), _empty_f(), np.zeros(0, dtype=bool))
            return empty, np.zeros(0, dtype=np.uint8), _empty_f()
        t = frames.time_s
        missing, repeated = missing_frames(
            frames.counter,
            t,
            period_s=cfg.encoder_period_s,
            gap_factor=cfg.gap_factor,
            previous=self._last_enc,
        )
        steps = unwrap_counts(frames.pulse_count, self._last_pulses)
        total = self._total_pulses + np.cumsum(steps)
        position_m = (total * cfg.metres_per_pulse).astype(np.float64)
        prev_t = np.empty(k)
        prev_t[1:] = t[:-1]
        prev_t[0] = np.nan if self._last_enc is None else self._last_enc[1]
        interval = t - prev_t
        with np.errstate(invalid="ignore", divide="ignore"):
            speed = np.where(interval > 0, steps * cfg.metres_per_pulse / interval, np.nan)
        jump = np.abs(np.nan_to_num(speed)) > cfg.max_speed_mps
        reasons = np.zeros(k, dtype=np.uint8)
        reasons[missing > 0] |= DROPPED
        reasons[repeated] |= REPEATED
        reasons[status_faults(frames.status, ENCODER_SIGNAL_FAULT)] |= STATUS
        reasons[jump] |= JUMP
        fault = reasons != 0
        speed = np.where(fault & (reasons != DROPPED), np.nan, speed)

        self._last_enc = (int(frames.counter[-1]), float(t[-1]))
        self._last_pulses = int(frames.pulse_count[-1])
        self._total_pulses = int(total[-1])
        self.counts.encoder_samples += k
        self.counts.dropped_encoder_frames += int(missing.sum())
        self.counts.faulty_encoder_samples += int(np.count_nonzero(fault))
        self.counts._tally(reasons, self.counts.encoder_reasons)
        return EncoderSamples(t.copy(), position_m, fault), reasons, speed

    # -- displacement -----------------------------------------------------------------------

    def _moving(self, time_s: FloatArray, enc_time: FloatArray, enc_speed: FloatArray) -> BoolArray:
        speed = speed_at(time_s, enc_time, enc_speed, stale_s=self.config.stale_s)
        with np.errstate(invalid="ignore"):
            still = np.abs(speed) < self.config.moving_speed_mps
        return ~still  # NaN (unknown): moving

    def _add_displacement(
        self, frames: DisplacementFrames, enc_time: FloatArray, enc_speed: FloatArray
    ) -> None:
        cfg = self.config
        if frames.frames == 0:
            return
        missing, repeated = missing_frames(
            frames.counter,
            frames.time_s,
            period_s=cfg.displacement_period_s,
            gap_factor=cfg.gap_factor,
            previous=self._last_disp,
        )
        self.counts.dropped_displacement_frames += int(missing.sum())
        previous_t = None if self._last_disp is None else self._last_disp[1]
        times, received, owner = expand_missing(
            frames.time_s, np.minimum(missing, MAX_PLACEHOLDERS), previous_t
        )
        n = times.shape[0]
        raw = np.stack([frames.left_mm, frames.right_mm, frames.lateral_mm])
        values = np.where(received, raw[:, owner], np.nan)
        reasons = np.zeros(n, dtype=np.uint8)
        reasons[~received] |= DROPPED
        bad_range = np.zeros(frames.frames, dtype=bool)
        bad_status = np.zeros(frames.frames, dtype=bool)
        for row, name in enumerate(CHANNELS):
            low, high = cfg.limits_mm[name]
            bad_range |= out_of_range(raw[row], low, high)
            bad_status |= status_faults(frames.status, DISPLACEMENT_STATUS_BITS[name])
        per_frame = np.zeros(frames.frames, dtype=np.uint8)
        per_frame[bad_range] |= OUT_OF_RANGE
        per_frame[bad_status] |= STATUS
        per_frame[repeated] |= REPEATED
        reasons[received] |= per_frame
        moving = np.ones(n, dtype=bool)
        moving[received] = self._moving(frames.time_s, enc_time, enc_speed)
        self._last_disp = (int(frames.counter[-1]), float(frames.time_s[-1]))

        p = self._pending
        self._pending = _Pending(
            time_s=np.concatenate((p.time_s, times)),
            values=np.concatenate((p.values, values), axis=1),
            received=np.concatenate((p.received, received)),
            moving=np.concatenate((p.moving, moving)),
            reasons=np.concatenate((p.reasons, reasons)),
            stuck=np.concatenate((p.stuck, np.zeros((3, n), dtype=bool)), axis=1),
            undecided=np.concatenate((p.undecided, np.zeros((3, n), dtype=bool)), axis=1),
        )
        self._judge_stuck(p.rows)

    def _judge_stuck(self, first_new: int) -> None:
        """Stuck verdicts for the rows from ``first_new``; settle held rows of open runs."""
        p = self._pending
        new_rows = np.arange(first_new, p.rows)
        rows = new_rows[p.received[first_new:]]
        for ch in range(3):
            stuck, decided, carried_out, verdict = stuck_verdicts(
                p.time_s[rows],
                p.values[ch, rows],
                p.moving[rows],
                self.config.stuck_time_s,
                self._runs[ch],
            )
            held = p.undecided[ch, :first_new]
            if verdict is not None and held.any():
                p.stuck[ch, :first_new] |= held & verdict
                p.undecided[ch, :first_new] = False
            p.stuck[ch, rows] = stuck
            p.undecided[ch, rows] = ~decided
            if rows.shape[0]:
                self._runs[ch] = carried_out

    def _release(self, final: bool) -> tuple[VehicleSamples, UInt8Array]:
        p = self._pending
        if final:
            stop = p.rows
        else:
            undecided = p.undecided.any(axis=0)
            stop = int(np.argmax(undecided)) if undecided.any() else p.rows
        reasons = p.reasons[:stop].copy()
        reasons[p.stuck[:, :stop].any(axis=0)] |= STUCK
        received = p.received[:stop]
        fault = reasons != 0
        samples = VehicleSamples(
            time_s=p.time_s[:stop].copy(),
            left_mm=p.values[0, :stop].copy(),
            right_mm=p.values[1, :stop].copy(),
            lateral_mm=p.values[2, :stop].copy(),
            fault=fault,
        )
        self.counts.displacement_samples += int(np.count_nonzero(received))
        self.counts.placeholders += int(np.count_nonzero(~received))
        self.counts.faulty_displacement_samples += int(np.count_nonzero(fault & received))
        self.counts._tally(reasons, self.counts.displacement_reasons)
        self._pending = _Pending(
            time_s=p.time_s[stop:],
            values=p.values[:, stop:],
            received=p.received[stop:],
            moving=p.moving[stop:],
            reasons=p.reasons[stop:],
            stuck=p.stuck[:, stop:],
            undecided=p.undecided[:, stop:],
        )
        return samples, reasons

    # -- the block ----------------------------------------------------------------------------

    def push(
        self,
        displacement: DisplacementFrames | None = None,
        encoder: EncoderFrames | None = None,
        *,
        final: bool = False,
    ) -> TrackedBlock:
        """Add a block's frames; return the samples whose faults are now decided.

        Frames of each kind must continue the previous block's (times non-decreasing).
        ``final``: no more frames follow (for now): release everything held.
        """
        enc_samples, enc_reasons, speed = self._encoder(encoder or EncoderFrames())
        enc_time = np.concatenate((self._enc_time, enc_samples.time_s))
        enc_speed = np.concatenate((self._enc_speed, speed))
        self._add_displacement(displacement or DisplacementFrames(), enc_time, enc_speed)
        if enc_time.shape[0]:
            self._enc_time = enc_time[-1:]
            self._enc_speed = enc_speed[-1:]
        # Held rows are bounded by stuck_time_s of samples, unless times stop advancing (a
        # log without timestamps): then they are released undecided past MAX_HELD_ROWS.
        vehicle, reasons = self._release(final or self._pending.rows > MAX_HELD_ROWS)
        return TrackedBlock(vehicle, reasons, enc_samples, enc_reasons)
