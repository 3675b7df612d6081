"""Frames of N lines from several cameras into the run's scans, nothing shifted or invented.

A line-scan camera delivers frames of ``N`` lines (its ``Height``). :class:`ScanAssembler`
gives every frame the index of the run's scan its first line belongs to and hands out scans
in order, each camera's line where it delivered one and ``valid = False`` where it did not.

Which scan a frame starts
-------------------------
The frame's time (the camera's timestamp on the host clock) and its frame id are used
together: the **time** places a camera's first frame (and any frame after a reconnection),
the **frame id** carries it on, so a camera's lines are consecutive scans and a lost frame
(an id skipped) leaves exactly its ``N`` scans invalid for that camera, never closing up the
gap. Frame ids wrap (GigE Vision's 16-bit ids run 1-65535, then 1 again: ``frame_id_modulus``).

* Free-running lines (``quantum = 1``): the scan of a frame's first line is its time since
  the run's start times the line rate, rounded. When the ids place a camera's frames more
  than ``resync_lines`` away from where their times do, the camera is placed by time again
  (``resyncs``: its line clock drifted from the nominal rate, or it skipped frame periods
  without skipping a frame id, as Aravis's fake camera does when it oversleeps): the
  lines between are invalid, and lines it would repeat are dropped, never written twice. A
  frame is stamped late (a busy camera or host), never early: its time can only say it is
  later than its id does, and is believed when the last :data:`RESYNC_FRAMES` frames all say
  so, by as much as the least of them. Until then the frames that say so are held
  (:meth:`ScanAssembler.reached` stops before the first of them): a resync moves them with
  it (those later still, after a second skip, wait for their own frames to tell), a frame
  on time again confirms them. A camera that gives no timestamps of its own (GenTL
  producers may not) is timed by its frames' arrival on the host, which a busy host or link
  delays by any amount: its frames are never held or resynced as late, only as early.
* Encoder-triggered lines (``quantum = N``): every camera sees the same encoder pulses, so
  their frames hold the same lines; a camera's first frame goes whole frames from the frame
  of another camera nearest in time (from scan 0 at the run's start before any; from its
  own before it dropped off where every camera did), counted at the camera's current frame
  period, then its ids alone carry it (the speed varies, so
  time cannot check it, and the nominal rate would misplace a frame by the run's speed
  against it). Scan times are interpolated between the frames' times.

Scans are handed out by :meth:`ScanAssembler.take` up to an index the caller decides (every
camera past it, or a camera that dropped off given up for those scans).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Final

import numpy as np

from catenary.arrays import BoolArray, FloatArray, UInt8Array, UInt16Array

__all__ = ["AssembledScans", "CameraCounts", "ScanAssembler"]

Lines = UInt8Array | UInt16Array

RESYNC_FRAMES: Final = 32
"""Free-running: a camera is placed by time again when its last frames' times all place it
more than ``resync_lines`` after where its ids do (or one places it before)."""


@dataclass
class CameraCounts:
    """Running counts of one camera [lines unless said]."""

    delivered: int = 0  # valid lines handed out in scans
    lost: int = 0  # scans handed out without this camera's line
    incomplete_frames: int = 0  # frames that arrived incomplete (their lines invalid)
    missing_frames: int = 0  # frames that never arrived (frame ids skipped)
    late_lines: int = 0  # lines that arrived after their scans were handed out (dropped)
    resyncs: int = 0  # frames placed by time again (free-running lines)


@dataclass(frozen=True)
class AssembledScans:
    """Scans ``first .. first + n - 1``: ``time_s`` ``[n]`` since the run's start [s];
    per camera ``lines`` ``[n, W]`` and ``valid`` ``[n]``."""

    first: int
    time_s: FloatArray
    lines: dict[str, Lines]
    valid: dict[str, BoolArray]

    @property
    def scans(self) -> int:
        return int(self.time_s.shape[0])


@dataclass
class _Camera:
    width: int
    dtype: np.dtype[np.uint8] | np.dtype[np.uint16]
    frames: list[tuple[int, Lines]] = field(default_factory=list)  # (first scan, lines)
    last_id: int | None = None
    # where the next consecutive frame starts; before the first frame, below every scan: a
    # first frame wholly before scan 0 (the run starts at another camera's later frame)
    # carries the next frames on from where it ends, not from scan 0
    next_scan: int = -(2**62)
    # free-running: the frames held as late, oldest first: (first scan by id, how far [lines]
    # its time places it after that)
    held: deque[tuple[int, float]] = field(default_factory=deque)
    counts: CameraCounts = field(default_factory=CameraCounts)


def _plausible(period_s: float | None, nominal_s: float) -> float:
    """``period_s`` where it is finite and at least a quarter of ``nominal_s`` (the train at
    no more than four times its nominal speed), else ``nominal_s`` [s]."""
    if period_s is None or not math.isfinite(period_s) or period_s < 0.25 * nominal_s:
        return nominal_s
    return period_s


class ScanAssembler:
    """Places frames into scans (module docstring) and hands the scans out in order.

    Parameters
    ----------
    cameras : mapping of name to ``(width, dtype)``
        Each camera's line width ``W`` [px] and line dtype (uint8 or uint16).
    lines_per_frame : int
        ``N``, lines in every frame.
    rate_hz : float
        The nominal line rate [Hz]: free-running, the scans' rate; encoder-triggered, used
        to extrapolate times beyond the last frame, and to place a first frame whose
        period is not given.
    start_s : float
        Host time [s] of scan 0 (the run's clock zero).
    encoder : bool
        Lines triggered by the encoder (``quantum = N``, no placement by time after the first
        frame); else free-running.
    frame_id_modulus : int or None
        Frame ids run ``1 .. modulus`` and wrap (GigE Vision: 65535); None: they never wrap.
    resync_lines : float
        Free-running: how far [lines] a frame's ids may place it from its time (the stream
        allows a quarter of a frame).
    """

    def __init__(
        self,
        cameras: dict[str, tuple[int, np.dtype[np.uint8] | np.dtype[np.uint16]]],
        lines_per_frame: int,
        rate_hz: float,
        start_s: float,
        *,
        encoder: bool = False,
        frame_id_modulus: int | None = 65535,
        resync_lines: float = 2.0,
    ) -> None:
        self._cameras = {name: _Camera(w, np.dtype(dtype)) for name, (w, dtype) in cameras.items()}
        self.lines_per_frame = lines_per_frame
        self.rate_hz = rate_hz
        self.start_s = start_s
        self.encoder = encoder
        self._modulus = frame_id_modulus
        self._resync_lines = resync_lines
        self.next_scan = 0  # the first scan not handed out yet
        self._anchors: list[tuple[int, float]] = []  # encoder: (scan, time since start_s)

    def counts(self, name: str) -> CameraCounts:
        return self._cameras[name].counts

    def reached(self, name: str) -> int:
        """The scan after the last line ``name`` has delivered (placed so far), or the first
        scan of its frames held as late (module docstring)."""
        camera = self._cameras[name]
        return camera.held[0][0] if camera.held else camera.next_scan

    def restart(self, name: str) -> None:
        """Forget ``name``'s frame ids (it reconnected): its next frame is placed by time."""
        camera = self._cameras[name]
        camera.last_id = None
        camera.held.clear()

    def add(
        self,
        name: str,
        frame_id: int,
        time_s: float | None,
        lines: Lines | None,
        host_stamped: bool = False,
        period_s: float | None = None,
    ) -> None:
        """A frame of ``name``: its id, its first line's host time [s] and its lines
        ``[N, W]``; an incomplete frame has lines None (invalid) and time None (a lost
        leader leaves a buffer's stamp stale): it is placed by its id alone, if at all.
        ``host_stamped``: the time is the frame's arrival on the host, which says it came
        late, never that its lines were (no resync on it); early, it still moves it.
        ``period_s``: encoder-triggered, the camera's frame period at this frame [s] (its
        last frames'), by which a frame placed by time is placed (module docstring; None,
        or not finite, or under a quarter of ``N`` lines at the nominal rate, the train at
        over four times its nominal speed, as with a host's bunched stamps: ``N`` lines at
        the nominal rate)."""
        camera = self._cameras[name]
        n = self.lines_per_frame
        step = 0 if camera.last_id is None else frame_id - camera.last_id
        if self._modulus is not None:
            step %= self._modulus
        if camera.last_id is not None and step == 0:  # a repeated id: nothing new
            return
        # no id before, or ids gone back (half the id range back, when they wrap): a restarted
        # camera, or an incomplete frame's stale id
        by_time = camera.last_id is None or step < 0
        by_time |= self._modulus is not None and step > self._modulus // 2
        if by_time and time_s is None:
            return  # nothing to place it by: its scans stay invalid for this camera
        # the scan of its first line, by time
        measured = math.nan if time_s is None else (time_s - self.start_s) * self.rate_hz
        if by_time:
            if self.encoder:
                assert time_s is not None
                period = _plausible(period_s, n / self.rate_hz)
                first = self._frame_at(time_s - self.start_s, period)
            else:
                first = round(measured)
            camera.held.clear()
        else:
            first = camera.next_scan + (step - 1) * n
            camera.counts.missing_frames += step - 1
            if not self.encoder and time_s is not None:
                first += self._check_time(camera, measured - first, first, host_stamped)
        camera.last_id = frame_id
        if lines is None:
            camera.counts.incomplete_frames += 1
        skip = max(camera.next_scan, self.next_scan) - first  # lines already placed or out
        if lines is not None:  # lines of scans handed out already (not those before scan 0)
            camera.counts.late_lines += max(min(first + n, self.next_scan) - max(first, 0), 0)
        if skip < n and lines is not None:
            camera.frames.append((first + max(skip, 0), lines[max(skip, 0) :]))
        if self.encoder and first >= self.next_scan and time_s is not None:
            self._anchors.append((first, time_s - self.start_s))
        camera.next_scan = max(camera.next_scan, first + n)

    def _frame_at(self, elapsed_s: float, period_s: float) -> int:
        """Encoder-triggered: the scan of a frame ``elapsed_s`` after the run's start, whole
        frames of ``period_s`` from the frame nearest in time placed and not handed out yet
        (another camera's; its own before it dropped off only where no other is nearer: after
        every camera dropped off, the gap is counted at the current period), from scan 0 at
        the start where there is none."""
        scan, time_s = 0, 0.0
        if self._anchors:
            scan, time_s = min(self._anchors, key=lambda anchor: abs(anchor[1] - elapsed_s))
        return scan + self.lines_per_frame * round((elapsed_s - time_s) / period_s)

    def _check_time(self, camera: _Camera, lateness: float, first: int, host_stamped: bool) -> int:
        """How far [lines] to move a free-running frame placed at scan ``first`` by its id,
        whose time places it ``lateness`` lines later; a resync moves the frames held with it
        (module docstring)."""
        if lateness <= self._resync_lines:  # on time: the frames held were where ids put them
            camera.held.clear()
            if lateness >= -self._resync_lines:
                return 0
            camera.counts.resyncs += 1  # early: stamps never are, the camera is ahead
            return round(lateness)
        if host_stamped:  # it arrived late: a busy host or link, not lines taken late
            return 0
        camera.held.append((first, lateness))
        if len(camera.held) < RESYNC_FRAMES:
            return 0
        # stamps come late, never early, and a camera only falls further behind its ids: the
        # oldest held frame is as late as the least of them says; those later than that by
        # more than a few lines (it skipped again) stay held, for their own frames to tell
        shift = round(min(late for _, late in camera.held))
        held_from = camera.held[0][0]
        camera.frames = [
            (start + shift if start >= held_from else start, lines)
            for start, lines in camera.frames
        ]
        camera.next_scan += shift
        moved = [(start + shift, late - shift) for start, late in camera.held]
        on_time = max(k for k, (_, late) in enumerate(moved) if late <= self._resync_lines)
        camera.held = deque(moved[on_time + 1 :])
        camera.counts.resyncs += 1
        return shift

    def take(self, upto: int) -> AssembledScans:
        """Hand out scans ``next_scan .. upto - 1`` (none if ``upto <= next_scan``)."""
        first = self.next_scan
        count = max(upto - first, 0)
        lines: dict[str, Lines] = {}
        valid: dict[str, BoolArray] = {}
        for name, camera in self._cameras.items():
            block = np.zeros((count, camera.width), dtype=camera.dtype)
            seen = np.zeros(count, dtype=bool)
            kept: list[tuple[int, Lines]] = []
            for start, data in camera.frames:
                end = start + data.shape[0]
                lo, hi = max(start, first), min(end, first + count)
                if hi > lo:
                    block[lo - first : hi - first] = data[lo - start : hi - start]
                    seen[lo - first : hi - first] = True
                if end > first + count:
                    kept.append((start, data))
            camera.frames = kept
            camera.counts.delivered += int(np.count_nonzero(seen))
            camera.counts.lost += count - int(np.count_nonzero(seen))
            lines[name] = block
            valid[name] = seen
        self.next_scan = first + count
        return AssembledScans(first, self._times(first, count), lines, valid)

    def _times(self, first: int, count: int) -> FloatArray:
        scans = np.arange(first, first + count, dtype=np.float64)
        if not self.encoder or not self._anchors:
            return scans / self.rate_hz
        anchors = np.array(self._anchors, dtype=np.float64)
        index, where = np.unique(anchors[:, 0], return_inverse=True)  # cameras' mean per frame
        time_s = np.bincount(where, anchors[:, 1]) / np.bincount(where)
        time_s = np.maximum.accumulate(time_s)
        times = np.interp(scans, index, time_s)
        beyond = scans > index[-1]
        times[beyond] = time_s[-1] + (scans[beyond] - index[-1]) / self.rate_hz
        cut = max(int(np.searchsorted(index, first + count, side="right")) - 1, 0)
        self._anchors = [(int(i), float(t)) for i, t in zip(index[cut:], time_s[cut:], strict=True)]
        return times
