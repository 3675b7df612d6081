"""A camera clock recovered from frame timestamps and their arrival times on the host."""

from __future__ import annotations

import numpy as np
import pytest

from catenary_camera.clock import ClockFit, ClockTracker, fit_clock
from catenary_camera.settings import parse_settings
from catenary_camera.stream import _placing

OFFSET_S = 1.0
DRIFT_PPM = 40.0
MEAN_DELAY_S = 200e-6


def synthetic(n: int, duration_s: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Device timestamps of frames at a jittered rate, and their arrival on a host whose
    clock is 1 s ahead and runs 40 ppm fast, after exponential delays of mean 200 µs."""
    rng = np.random.default_rng(seed)
    device = np.sort(rng.uniform(0.0, duration_s, n)) + 1234.5
    host = OFFSET_S + device * (1 + DRIFT_PPM * 1e-6) + rng.exponential(MEAN_DELAY_S, n)
    return device, host


def assert_recovered(fit: ClockFit, device: np.ndarray) -> None:
    assert abs(fit.drift_ppm - DRIFT_PPM) < 2.0
    truth = OFFSET_S + device * (1 + DRIFT_PPM * 1e-6)
    assert np.max(np.abs(fit.to_host(device) - truth)) < 50e-6


def test_fit_follows_the_lower_envelope() -> None:
    device, host = synthetic(20_000, 60.0, seed=1)
    fit = fit_clock(device, host)
    assert fit.samples == 20_000
    assert_recovered(fit, device)
    assert fit.residual_s < MEAN_DELAY_S / 4
    # a plain least-squares line is late by the mean delay: what the envelope avoids
    slope, intercept = np.polyfit(device - device[0], host, 1)
    plain = intercept + slope * (device - device[0])
    truth = OFFSET_S + device * (1 + DRIFT_PPM * 1e-6)
    assert np.mean(plain - truth) > 150e-6


def test_tracker_refits_incrementally_in_bounded_memory() -> None:
    device, host = synthetic(60_000, 300.0, seed=2)
    tracker = ClockTracker(window_s=1.0, max_windows=120)
    assert tracker.fit() is None
    for part in np.array_split(np.arange(device.shape[0]), 300):  # frames as they come
        tracker.add(device[part], host[part])
    fit = tracker.fit()
    assert fit is not None and fit.samples == 60_000
    assert tracker.windows == 120  # the minima of the latest 120 windows only
    assert_recovered(fit, device[-24_000:])  # the span it was fitted over


def test_tracker_follows_a_drift_that_changes() -> None:
    device, host = synthetic(40_000, 200.0, seed=3)
    later = device > device[0] + 100.0
    host = host + np.where(later, (device - device[0] - 100.0) * 20e-6, 0.0)  # +20 ppm
    tracker = ClockTracker(window_s=1.0, max_windows=60)
    for part in np.array_split(np.arange(device.shape[0]), 200):
        tracker.add(device[part], host[part])
    fit = tracker.fit()
    assert fit is not None
    assert abs(fit.drift_ppm - (DRIFT_PPM + 20.0)) < 2.0


def test_single_scalar_pairs() -> None:
    tracker = ClockTracker(window_s=0.5)
    tracker.add(10.0, 11.0)
    assert tracker.fit() is None  # one window: no drift yet
    tracker.add(20.0, 21.0002)
    fit = tracker.fit()
    assert fit is not None
    assert fit.drift_ppm == pytest.approx(20.0)
    assert fit.to_host(np.array([10.0, 20.0])) == pytest.approx([11.0, 21.0002], abs=1e-9)


def test_bad_pairs_are_refused() -> None:
    with pytest.raises(ValueError, match="two pairs at least, got 1"):
        fit_clock([1.0], [2.0])
    with pytest.raises(ValueError, match="span no device time"):
        fit_clock([1.0, 1.0, 1.0], [2.0, 2.1, 2.2])
    with pytest.raises(ValueError, match="3 device times but 2 host times"):
        fit_clock([1.0, 2.0, 3.0], [2.0, 3.0])
    with pytest.raises(ValueError, match="finite"):
        fit_clock([1.0, np.nan], [2.0, 3.0])


@pytest.mark.parametrize("lag_frames", [0.0, 1.0])
def test_frames_are_placed_at_their_first_line(lag_frames: float) -> None:
    """Frames stamped at their first line arrive, at the quickest, ``arrival_lag_frames``
    frame periods later (after 200 µs mean delays): the placing maps a stamp to the host
    time of its first line, not to its arrival."""
    settings = parse_settings(
        {
            "cameras": {"cam1": {"address": "10.0.0.1", "width": 8}},
            "line_rate_hz": 5300,
            "lines_per_frame": 106,
            "arrival_lag_frames": lag_frames,
        }
    )
    rng = np.random.default_rng(2)
    device = 1234.5 + np.arange(50) * settings.frame_period_s  # a second of frames
    first_line = OFFSET_S + device  # on the host's clock
    arrival = first_line + lag_frames * settings.frame_period_s
    placing = _placing(device, arrival + rng.exponential(MEAN_DELAY_S, device.size), settings)
    assert np.max(np.abs(placing.to_host(device) - first_line)) < 50e-6
