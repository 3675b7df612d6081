"""A camera's clock mapped to the host's: offset and drift from timestamp pairs.

Pure: NumPy in, NumPy out. A pair is a frame's device timestamp and the host's time of its
arrival. The arrival is the true time plus a delay that is never negative (transmission,
interrupt coalescing, scheduling) and often long, so a plain least-squares line through the
pairs is late by the mean delay and its slope is bent by bursts. The fit follows the lower
envelope instead: the pairs are cut into windows of device time, the pair of least delay in
each window is kept (the one below the current line by the most), and a least-squares line
through those minima gives

    host_s = offset_s + device_s * (1 + drift_ppm * 1e-6)

With ``m`` pairs per window and delays of mean ``d`` the minimum's delay is about ``d / m``
(for exponential delays), so the envelope is biased by that much at most. ``residual_s`` is
the RMS of the minima about the line: the jitter of the fastest path, not the mean delay.

:class:`ClockTracker` does this incrementally in bounded memory (the minima of the latest
``max_windows`` windows), so it follows a drift that changes with temperature;
:func:`fit_clock` fits a whole set of pairs at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import ArrayLike

from catenary.arrays import FloatArray, IntArray

__all__ = ["ClockFit", "ClockTracker", "fit_clock"]

DEFAULT_WINDOW_S: Final = 1.0
"""Device time per window of :class:`ClockTracker` [s]."""
DEFAULT_MAX_WINDOWS: Final = 600
"""Windows :class:`ClockTracker` keeps (10 minutes at one second each)."""
FIT_WINDOWS: Final = 64
"""Windows :func:`fit_clock` cuts the pairs' span into (fewer with few pairs)."""
MIN_PAIRS_PER_WINDOW: Final = 8


@dataclass(frozen=True)
class ClockFit:
    """``host_s = offset_s + device_s * (1 + drift_ppm * 1e-6)``; ``residual_s`` the RMS of
    the least-delay pairs about it [s]; ``samples`` the pairs it was fitted from."""

    offset_s: float
    drift_ppm: float
    residual_s: float
    samples: int

    def to_host(self, device_s: ArrayLike) -> FloatArray:
        """Host times [s] of device times [s], any shape."""
        device = np.asarray(device_s, dtype=np.float64)
        return self.offset_s + device * (1.0 + self.drift_ppm * 1e-6)


def _pairs(device_s: ArrayLike, host_s: ArrayLike) -> tuple[FloatArray, FloatArray]:
    device = np.asarray(device_s, dtype=np.float64).reshape(-1)
    host = np.asarray(host_s, dtype=np.float64).reshape(-1)
    if device.shape != host.shape:
        raise ValueError(f"{device.shape[0]} device times but {host.shape[0]} host times")
    if not (np.isfinite(device).all() and np.isfinite(host).all()):
        raise ValueError("clock pairs must be finite")
    return device, host


class ClockTracker:
    """Pairs accumulated as frames arrive, the clock refitted on demand; memory bounded by
    ``max_windows`` (module docstring).

    Parameters
    ----------
    window_s : float
        Device time per window [s]: several frames each, and short enough that the drift
        over one (``window_s * drift``) is well below the delays to be told apart.
    max_windows : int
        Windows kept, the latest; older ones are forgotten.
    drift_ppm : float
        The drift assumed until the first fit (to pick each window's least delay).
    """

    def __init__(
        self,
        window_s: float = DEFAULT_WINDOW_S,
        max_windows: int = DEFAULT_MAX_WINDOWS,
        drift_ppm: float = 0.0,
    ) -> None:
        if not (math.isfinite(window_s) and window_s > 0):
            raise ValueError(f"window_s must be positive, got {window_s!r}")
        if max_windows < 2:
            raise ValueError(f"max_windows must be at least 2, got {max_windows!r}")
        self.window_s = float(window_s)
        self.max_windows = int(max_windows)
        self._slope = float(drift_ppm) * 1e-6
        self._origin: tuple[float, float] | None = None  # (device, host) of the first pair
        self._window: IntArray = np.zeros(0, dtype=np.int64)
        self._device: FloatArray = np.zeros(0)  # relative to the origin
        self._host: FloatArray = np.zeros(0)
        self.samples = 0
        self._fit: ClockFit | None = None

    @property
    def windows(self) -> int:
        """Windows holding a pair (at most ``max_windows``)."""
        return int(self._window.shape[0])

    def add(self, device_s: ArrayLike, host_s: ArrayLike) -> None:
        """Add pairs (each ``[k]`` or a scalar): device timestamps [s] and host arrival
        times [s] of the same frames."""
        device, host = _pairs(device_s, host_s)
        if device.shape[0] == 0:
            return
        if self._origin is None:
            self._origin = (float(device[0]), float(host[0]))
        d0, h0 = self._origin
        x = np.concatenate((self._device, device - d0))
        y = np.concatenate((self._host, host - h0))
        window = np.concatenate((self._window, np.floor((device - d0) / self.window_s)))
        window = window.astype(np.int64)
        below = y - x * (1.0 + self._slope)  # the delay, up to a constant
        order = np.lexsort((below, window))
        first = np.ones(order.shape[0], dtype=bool)
        first[1:] = window[order][1:] != window[order][:-1]
        keep = order[first][-self.max_windows :]
        self._window, self._device, self._host = window[keep], x[keep], y[keep]
        self.samples += int(device.shape[0])
        self._fit = None
        if self._window.shape[0] >= 2:
            self._slope = self._line()[1]

    def _line(self) -> tuple[float, float, float]:
        """Least squares through the minima relative to the origin: intercept, slope - 1
        (the drift) and the RMS residual."""
        x = self._device
        y = self._host - x
        xm = x.mean()
        span = x - xm
        denominator = float(span @ span)
        if denominator == 0.0:
            raise ValueError("clock pairs span no device time: the drift is unknown")
        slope = float(span @ (y - y.mean())) / denominator
        intercept = float(y.mean() - slope * xm)
        residual = y - intercept - slope * x
        return intercept, slope, float(np.sqrt(np.mean(residual**2)))

    def fit(self) -> ClockFit | None:
        """The clock from the windows kept; None before two windows have pairs."""
        if self._window.shape[0] < 2 or self._origin is None:
            return None
        if self._fit is None:
            intercept, slope, residual = self._line()
            d0, h0 = self._origin
            self._fit = ClockFit(
                offset_s=h0 + intercept - d0 * (1.0 + slope),
                drift_ppm=slope * 1e6,
                residual_s=residual,
                samples=self.samples,
            )
        return self._fit


def fit_clock(device_s: ArrayLike, host_s: ArrayLike) -> ClockFit:
    """The clock from pairs ``[n]`` (device timestamps and host arrival times [s]): the
    lower envelope over up to :data:`FIT_WINDOWS` windows of at least
    :data:`MIN_PAIRS_PER_WINDOW` pairs each on average (module docstring). ``ValueError``
    for fewer than two pairs or pairs that span no device time."""
    device, host = _pairs(device_s, host_s)
    n = device.shape[0]
    if n < 2:
        raise ValueError(f"a clock fit needs two pairs at least, got {n}")
    span = float(device.max() - device.min())
    if span == 0.0:
        raise ValueError("clock pairs span no device time: the drift is unknown")
    windows = max(2, min(FIT_WINDOWS, n // MIN_PAIRS_PER_WINDOW))
    # the least-squares drift of every pair picks each window's least delay; the window
    # span is nudged up so that the last pair falls in the last window
    x = device - device.mean()
    slope = float(x @ (host - device - (host - device).mean())) / float(x @ x)
    tracker = ClockTracker(span / windows * (1 + 1e-9), windows + 1, drift_ppm=slope * 1e6)
    order = np.argsort(device, kind="stable")
    tracker.add(device[order], host[order])
    fit = tracker.fit()
    assert fit is not None  # two windows at least hold pairs: the span is cut in two or more
    return fit
