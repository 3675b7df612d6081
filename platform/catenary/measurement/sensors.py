"""The car body's displacement sensors as a stream: stretches, zero-phase smoothing, scan times.

The three sensors (FORMATS.md ``/vehicle/*``: ``left_mm``, ``right_mm``, ``lateral_mm``) are
sampled on their own clock. :class:`SensorStream` reads them forward in chunks and gives their
values at increasing scan times; memory is bounded whatever the run's length.

* **Stretches.** A sample whose three values are finite is valid; a non-finite value records a
  faulty or missing reading (a recorder's flag). A *stretch* is a run of consecutive valid
  samples with no faulty sample between them and no interval longer than ``max_gap_s``.
* **Smoothing** (:class:`SensorSmoother`, optional): each stretch is low-pass filtered on its
  own, without phase lag, so that neither a fault's value nor the value held across a gap
  reaches a neighbour.
* **Scan times.** The (smoothed) valid samples are linearly interpolated to each scan's time.
  A scan is a fault when it lies before the first or after the last valid sample (the edge
  sample's value is held), or between two stretches (interpolated across); a scan exactly at a
  valid sample is not. With no valid sample at all every scan is a fault and the values are 0
  (nominal ride). Values where the fault flag is true are a best guess and must not be trusted.

Why smooth, and the default cut-off :data:`DEFAULT_FILTER_HZ` = 5 Hz
--------------------------------------------------------------------
Laser displacement sensors typically carry about 0.3 mm of white noise per sample. Through the
lever arm from the sensors to the wire (``roof_height_mm - sensor_height_mm`` plus the wire's
height above the roof: 4-5 m) over the ``sensor_baseline_mm`` (about 1.8 m), the roll noise of
``sqrt(2) 0.3 mm`` becomes 1.0-1.3 mm RMS of stagger, 4-5 mm at the worst of a run, every sample
independently. The car body's own motion is slow: it rides on its secondary suspension, whose
rigid-body modes (bounce, pitch, lower and upper sway, i.e. roll with lateral, yaw) are tuned to
about 0.5-2 Hz for ride comfort, and the quasi-static roll and shift in curves is slower still;
the body's first bending mode is kept above about 8 Hz by design and is not a rigid-body motion
the FORMATS.md model could represent. Above a few hertz the sensors show their own noise (and
the rails' short-wave irregularities under them, which do not move the wire). The default
cut-off, 5 Hz, is 2.5 times the highest rigid-body mode: the filter (a 4th-order Butterworth
run forward and backward, gain ``1 / (1 + (f / fc)^8)``, no delay at any frequency) passes 2 Hz
with 0.07 % less amplitude (0.01 mm of a 15 mm sway) and keeps 30 % of white noise sampled at
100 Hz, 21 % at 200 Hz, 15 % at 400 Hz. ``[processing] vehicle_filter_hz`` changes it (0: off).

Each stretch is extended at its ends along the least-squares line of its first and last
:attr:`SensorSmoother.edge_fit` samples (a twentieth of a second at 5 Hz: ``fs / (2 fc)``) by
:attr:`SensorSmoother.margin` samples (over which the filter's slowest pole decays by 1e-13:
2.5 s at 5 Hz) and filtered forward and backward (``scipy.signal.sosfiltfilt`` of the extended
stretch, each pass started in the steady state of its first value); a stretch longer than the
buffer is filtered in windows overlapping by ``margin`` samples on either side, so the streamed
values equal the whole stretch's to rounding, whatever the chunks. The line keeps the trend at
an end without pinning the filter to the end sample's own noise (as ``sosfiltfilt``'s odd
extension would): within a few tenths of a second of a fault, a gap or the run's ends the
values are less smoothed than inside a stretch, and off by the body's curvature over the
line's samples. Simulated (the simulator's body motion, 0.3 mm of noise), the worst stagger
error the sensors give in the first 0.3 s of a stretch is 1.4 mm at 200 Hz and 1.8 mm at
100 Hz (odd extension: 2.6 mm; unsmoothed: 3.9 mm), against 1.0 mm inside.

The sensors' noise is estimated from what the filter removes: the RMS of ``raw - smoothed`` over
every filtered sample, divided by the square root of the share of white noise's power the
residual keeps (``mean((1 - G)^2)`` over the band, ``G`` the forward-backward gain).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Final

import numpy as np
from scipy.signal import butter, sosfilt, sosfilt_zi, sosfreqz

from catenary.arrays import BoolArray, FloatArray
from catenary.domain import VehicleSamples

__all__ = ["DEFAULT_FILTER_HZ", "SENSOR_NAMES", "SensorSmoother", "SensorStream"]

DEFAULT_FILTER_HZ: Final = 5.0
"""Default cut-off of the sensors' zero-phase low-pass [Hz] (module docstring)."""

FILTER_ORDER: Final = 4
"""Order of the Butterworth low-pass (run twice: forward and backward)."""

SENSOR_NAMES: Final = ("left_mm", "right_mm", "lateral_mm")

_SETTLED: Final = 1e-13
"""How far the filter's slowest transient decays over the overlap of two windows."""

Samples = tuple[FloatArray, FloatArray, BoolArray]
"""``(time_s [k], values [3, k], starts [k])``: valid samples, ``starts`` true where a sample
does not continue the stretch of the sample before it."""


def _empty() -> Samples:
    return np.zeros(0), np.zeros((3, 0)), np.zeros(0, dtype=bool)


class SensorSmoother:
    """Zero-phase low-pass of the sensors' valid samples, stretch by stretch, streamed.

    Parameters
    ----------
    cutoff_hz : float
        Cut-off [Hz] (``-3 dB`` of each pass, ``-6 dB`` of both); 0 turns smoothing off.
    interval_s : float or None
        The samples' median interval [s] (None: fewer than two sample times).

    Smoothing is off (samples pass unchanged) when ``cutoff_hz`` is 0, when there is no
    interval, or when the samples hold nothing above the cut-off (``cutoff_hz`` at or above
    half the sample rate). :meth:`describe` says which.

    Notes
    -----
    :meth:`push` valid samples in time order, then :meth:`finish`; each returns the samples now
    final (fewer than pushed: an open stretch's last :attr:`margin` samples wait for the
    samples after them). Holds at most ``2 margin`` samples plus one push.
    """

    def __init__(self, cutoff_hz: float, interval_s: float | None) -> None:
        if not (math.isfinite(cutoff_hz) and cutoff_hz >= 0.0):
            raise ValueError(f"cut-off must be 0 (off) or a positive number of Hz, got {cutoff_hz}")
        self.cutoff_hz = float(cutoff_hz)
        rate = math.nan if interval_s is None else 1.0 / interval_s
        self.rate_hz = None if interval_s is None else rate
        self.active = 0.0 < self.cutoff_hz < 0.5 * rate
        self.margin = 0
        self.edge_fit = 0
        self._sum_squares = np.zeros(3)
        self._count = 0
        self._t, self._v, self._starts = _empty()
        self._done = 0  # buffer index of the first sample not given out
        if not self.active:
            return
        self._sos = np.asarray(butter(FILTER_ORDER, self.cutoff_hz, fs=rate, output="sos"))
        self._zi = np.asarray(sosfilt_zi(self._sos))  # [sections, 2]
        _, poles, _ = butter(FILTER_ORDER, self.cutoff_hz, fs=rate, output="zpk")
        slowest = float(np.max(np.abs(poles)))
        self.margin = math.ceil(math.log(_SETTLED) / math.log(slowest))
        self.edge_fit = max(2, round(0.5 * rate / self.cutoff_hz))
        _, response = sosfreqz(self._sos, worN=8192)
        gain = np.abs(response) ** 2  # forward and backward
        self._residual_gain = float(np.mean((1.0 - gain) ** 2))

    def push(self, time_s: FloatArray, values: FloatArray, starts: BoolArray) -> Samples:
        """Add valid samples (``time_s [k]``, ``values [3, k]``, ``starts [k]``: true where a
        sample begins a stretch; the first sample ever must); return those now final."""
        if not self.active:
            return time_s, values, starts
        self._t = np.concatenate((self._t, time_s))
        self._v = np.concatenate((self._v, values), axis=1)
        self._starts = np.concatenate((self._starts, starts))
        return self._release(final=False)

    def finish(self) -> Samples:
        """The samples still held (the last stretch ends with them)."""
        if not self.active:
            return _empty()
        return self._release(final=True)

    @property
    def noise_mm(self) -> FloatArray | None:
        """Estimated white noise of ``left``, ``right``, ``lateral`` [mm] ``[3]`` (None before
        any sample was smoothed)."""
        if not self.active or self._count == 0:
            return None
        return np.asarray(np.sqrt(self._sum_squares / self._count / self._residual_gain))

    def describe(self) -> str:
        """One line: the filter applied and the noise estimated, or why there was none."""
        if self.cutoff_hz == 0.0:
            return "not filtered (vehicle_filter_hz = 0)"
        if self.rate_hz is None:
            return "not filtered: fewer than two sample times"
        if not self.active:
            return (
                f"not filtered: sampled at {self.rate_hz:.4g} Hz, not above twice the "
                f"{self.cutoff_hz:g} Hz cut-off"
            )
        text = f"sampled at {self.rate_hz:.4g} Hz, low-pass {self.cutoff_hz:g} Hz (zero phase)"
        noise = self.noise_mm
        if noise is None:
            return f"{text}; no valid sample"
        left, right, lateral = noise
        return f"{text}; noise left {left:.3f}, right {right:.3f}, lateral {lateral:.3f} mm RMS"

    def _release(self, *, final: bool) -> Samples:
        n = self._t.shape[0]
        starts = self._starts
        edges = np.concatenate(([0], np.flatnonzero(starts[1:]) + 1, [n]))
        out = np.empty((3, n))
        done = stop = self._done
        for first, end in zip(edges[:-1].tolist(), edges[1:].tolist(), strict=True):
            if end <= done:
                continue
            closed = final or end < n  # a later stretch has begun
            a = max(first, done)
            b = end if closed else end - self.margin
            if b <= a:
                continue
            lo = max(first, a - self.margin)
            smoothed = _zero_phase(
                self._sos,
                self._zi,
                self._v[:, lo:end],
                at_start=lo == first and bool(starts[first]),
                at_end=closed,
                pad=self.margin,
                fit=self.edge_fit,
            )
            out[:, a:b] = smoothed[:, a - lo : b - lo]
            stop = b
        residual = self._v[:, done:stop] - out[:, done:stop]
        self._sum_squares += np.sum(residual**2, axis=1)
        self._count += stop - done
        released = (self._t[done:stop], out[:, done:stop], starts[done:stop])
        # keep the open stretch's samples the next windows reach back to
        if stop < n:
            stretch = int(edges[np.searchsorted(edges, stop, side="right") - 1])
            keep = max(stop - self.margin, stretch)
        else:
            keep = n
        self._t, self._v, self._starts = self._t[keep:], self._v[:, keep:], starts[keep:]
        self._done = stop - keep
        return released


def _line(y: FloatArray, at: FloatArray) -> FloatArray:
    """The least-squares line through ``y [3, L]`` (at sample indices ``0 .. L - 1``; a
    constant for one sample) evaluated at indices ``at [p]``: ``[3, p]``."""
    count = y.shape[1]
    k = np.arange(count) - 0.5 * (count - 1)
    mean = np.mean(y, axis=1, keepdims=True)
    slope = (y - mean) @ k / max(float(k @ k), 1.0)
    return np.asarray(mean + slope[:, None] * (at - 0.5 * (count - 1)))


def _zero_phase(
    sos: FloatArray,
    zi: FloatArray,
    x: FloatArray,
    *,
    at_start: bool,
    at_end: bool,
    pad: int,
    fit: int,
) -> FloatArray:
    """Forward-backward filter of ``x [3, n]`` (``scipy.signal.sosfiltfilt`` without its own
    padding), extended by ``pad`` samples at the ends that are a stretch's (``at_start``,
    ``at_end``) along the least-squares line of the ``fit`` samples there; each pass starts in
    the steady state of its first value."""
    parts = [x]
    if at_start:
        parts.insert(0, _line(x[:, :fit], np.arange(-pad, 0.0)))
    if at_end:
        end = x[:, -fit:]
        parts.append(_line(end, np.arange(pad, dtype=np.float64) + end.shape[1]))
    extended = np.concatenate(parts, axis=1)
    forward, _ = sosfilt(sos, extended, axis=1, zi=zi[:, None, :] * extended[None, :, :1])
    backward, _ = sosfilt(sos, forward[:, ::-1], axis=1, zi=zi[:, None, :] * forward[None, :, -1:])
    start = pad if at_start else 0
    return np.asarray(backward[:, ::-1][:, start : start + x.shape[1]])


class SensorStream:
    """The sensors read forward in chunks and given at increasing scan times (module docstring).

    Parameters
    ----------
    read : callable
        ``read(first, stop)`` gives samples ``first:stop``: ``(time_s [k], values [3, k])``,
        the values in :data:`SENSOR_NAMES` order [mm].
    samples : int
        Number of samples ``K``.
    max_gap_s : float
        The longest interval between two samples of one stretch [s].
    chunk : int
        Samples read at a time.
    smoother : SensorSmoother, optional
        Smooths each stretch before the interpolation.
    """

    def __init__(
        self,
        read: Callable[[int, int], tuple[FloatArray, FloatArray]],
        samples: int,
        max_gap_s: float,
        chunk: int,
        smoother: SensorSmoother | None = None,
    ) -> None:
        self._read = read
        self._samples = samples
        self._max_gap_s = max_gap_s
        self._chunk = chunk
        self._smoother = smoother
        self._next = 0
        self._last_valid_s: float | None = None  # time of the last valid sample read
        self._fault_pending = False  # a faulty sample read since it
        self._t, self._v, self._starts = _empty()

    def _read_more(self) -> bool:
        """Read the next chunk, keeping only the last sample held. False at the end."""
        if self._next >= self._samples:
            return False
        first = self._next
        last = min(first + self._chunk, self._samples)
        t, v = self._read(first, last)
        valid = np.isfinite(v).all(axis=0)
        faulty = np.cumsum(~valid)  # faulty samples up to each one
        kept = np.flatnonzero(valid)
        tk = t[kept]
        # a faulty sample or too long an interval since the previous valid sample
        starts = np.diff(faulty[kept], prepend=0) > 0
        if kept.size:
            starts[0] |= self._fault_pending or self._last_valid_s is None
            previous = tk[0] if self._last_valid_s is None else self._last_valid_s
            starts |= np.diff(tk, prepend=previous) > self._max_gap_s
            self._last_valid_s = float(tk[-1])
            self._fault_pending = bool(faulty[-1] > faulty[kept[-1]])
        else:
            self._fault_pending |= bool(faulty[-1])
        self._next = last
        t_new, v_new, starts_new = tk, v[:, kept], starts
        if self._smoother is not None:
            t_new, v_new, starts_new = self._smoother.push(t_new, v_new, starts_new)
            if self._next >= self._samples:
                t_end, v_end, starts_end = self._smoother.finish()
                t_new = np.concatenate((t_new, t_end))
                v_new = np.concatenate((v_new, v_end), axis=1)
                starts_new = np.concatenate((starts_new, starts_end))
        self._t = np.concatenate((self._t[-1:], t_new))
        self._v = np.concatenate((self._v[:, -1:], v_new), axis=1)
        self._starts = np.concatenate((self._starts[-1:], starts_new))
        return True

    def at(self, scan_time_s: FloatArray) -> VehicleSamples:
        """The sensors at non-decreasing ``scan_time_s`` ``[n]`` (after any earlier call's)."""
        n = scan_time_s.shape[0]
        values = np.zeros((3, n), dtype=np.float64)
        fault = np.ones(n, dtype=bool)
        i = 0
        while i < n:
            while (self._t.size == 0 or self._t[-1] < scan_time_s[i]) and self._read_more():
                pass
            if self._t.size == 0:
                break  # no valid sample at all: zeros, every scan a fault
            exhausted = self._next >= self._samples
            j = n if exhausted else int(np.searchsorted(scan_time_s, self._t[-1], side="right"))
            j = max(j, i + 1)
            self._interpolate(scan_time_s[i:j], values[:, i:j], fault[i:j])
            i = j
        return VehicleSamples(
            time_s=scan_time_s.copy(),
            left_mm=values[0],
            right_mm=values[1],
            lateral_mm=values[2],
            fault=fault,
        )

    def _interpolate(self, t: FloatArray, out: FloatArray, fault: BoolArray) -> None:
        st, sv = self._t, self._v
        m = st.shape[0]
        left = np.searchsorted(st, t, side="right") - 1
        before = left < 0
        left = np.clip(left, 0, m - 1)
        right = np.minimum(left + 1, m - 1)
        t_left = st[left]
        t_right = st[right]
        exact = t_left == t
        after = (right == left) & ~exact & ~before  # past the last sample
        span = t_right - t_left
        weight = np.where(span > 0, (t - t_left) / np.where(span > 0, span, 1.0), 0.0)
        weight = np.where(before, 0.0, weight)
        out[...] = sv[:, left] + weight * (sv[:, right] - sv[:, left])
        between = ~exact & (right > left) & self._starts[right]  # two stretches apart
        fault[...] = before | after | between
