"""The displacement sensor stream: zero-phase smoothing by stretch, streamed, faults kept."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import butter, sosfiltfilt

from catenary.config import Settings
from catenary.errors import UserError
from catenary.measurement.process import vehicle_filter_hz
from catenary.measurement.sensors import (
    DEFAULT_FILTER_HZ,
    FILTER_ORDER,
    SensorSmoother,
    SensorStream,
)

RATE_HZ = 200.0


def body_motion(t: np.ndarray, seed: int = 1) -> np.ndarray:
    """``[3, k]`` sensor values [mm]: sums of sinusoids of 0.2-2 Hz (the car body's modes)."""
    rng = np.random.default_rng(seed)
    omega = 2 * np.pi * rng.uniform(0.2, 2.0, (3, 8))
    phase = rng.uniform(0, 2 * np.pi, (3, 8))
    amplitude = rng.uniform(1.0, 4.0, (3, 8))
    return np.sum(amplitude[..., None] * np.sin(omega[..., None] * t + phase[..., None]), axis=1)


def stretches_of(t: np.ndarray, v: np.ndarray, max_gap_s: float) -> list[slice]:
    """The index ranges of the valid samples' stretches (faulty samples and gaps split)."""
    valid = np.isfinite(v).all(axis=0)
    bounds, first = [], None
    for k in range(t.shape[0]):  # the reference: plain, sample by sample
        if not valid[k]:
            if first is not None:
                bounds.append(slice(first, k))
            first = None
            continue
        if first is not None and t[k] - t[k - 1] > max_gap_s:
            bounds.append(slice(first, k))
            first = None
        if first is None:
            first = k
    if first is not None:
        bounds.append(slice(first, t.shape[0]))
    return bounds


def whole_series(t: np.ndarray, v: np.ndarray, smoother: SensorSmoother) -> np.ndarray:
    """Each stretch at once: extended by ``margin`` samples along the least-squares line of
    its ``edge_fit`` end samples (``np.polyfit``), filtered by ``scipy.signal.sosfiltfilt``
    without padding of its own (NaN elsewhere)."""
    sos = butter(FILTER_ORDER, DEFAULT_FILTER_HZ, fs=RATE_HZ, output="sos")
    pad, fit = smoother.margin, smoother.edge_fit
    out = np.full_like(v, np.nan)
    for part in stretches_of(t, v, 2.5 / RATE_HZ):
        x = v[:, part]
        n = x.shape[1]
        ends = []
        for y, at in (
            (x[:, :fit], np.arange(-pad, 0)),
            (x[:, -fit:], np.arange(pad) + min(n, fit)),
        ):
            if y.shape[1] == 1:
                ends.append(np.repeat(y, pad, axis=1))
                continue
            slope, intercept = np.polyfit(np.arange(y.shape[1]), y.T, 1)
            ends.append(intercept[:, None] + slope[:, None] * at)
        extended = np.concatenate([ends[0], x, ends[1]], axis=1)
        out[:, part] = sosfiltfilt(sos, extended, axis=1, padtype=None)[:, pad : pad + n]
    return out


def faulty_series(seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """60 s at 200 Hz with 0.3 mm noise: faulty samples alone and in a row, a time gap, a
    stretch of three samples and one of one."""
    rng = np.random.default_rng(seed)
    t = np.arange(12_000) / RATE_HZ
    t[7000:] += 0.5  # a 0.505 s interval: a gap
    v = body_motion(t) + 0.3 * rng.standard_normal((3, t.shape[0]))
    v[0, 2000] = np.nan
    v[1, 5000:5040] = np.inf
    v[:, 9000] = np.nan
    v[2, 9004] = np.nan  # samples 9001-9003: a stretch of three
    v[0, 9006] = np.nan  # sample 9005 alone
    return t, v


def stream(
    t: np.ndarray, v: np.ndarray, chunk: int, smoother: SensorSmoother | None
) -> SensorStream:
    read = lambda a, b: (t[a:b], v[:, a:b])  # noqa: E731
    return SensorStream(read, t.shape[0], 2.5 / RATE_HZ, chunk, smoother)


@pytest.mark.parametrize("chunk", [1, 37, 500, 4096, 100_000])
def test_streamed_equals_each_stretch_filtered_whole(chunk: int) -> None:
    t, v = faulty_series()
    smoother = SensorSmoother(DEFAULT_FILTER_HZ, 1 / RATE_HZ)
    expected = whole_series(t, v, smoother)
    # the samples themselves: scans exactly at every sample time
    got = stream(t, v, chunk, smoother).at(t)
    valid = np.isfinite(v).all(axis=0)
    scale = np.nanmax(np.abs(expected))
    for k, name in enumerate(("left_mm", "right_mm", "lateral_mm")):
        np.testing.assert_allclose(
            getattr(got, name)[valid], expected[k, valid], rtol=1e-9, atol=1e-9 * scale
        )
    assert not got.fault[valid].any()
    assert got.fault[~valid].all()


def test_memory_is_the_margin_and_one_chunk_whatever_the_length() -> None:
    smoother = SensorSmoother(DEFAULT_FILTER_HZ, 1 / RATE_HZ)
    assert 400 < smoother.margin < 600  # the slowest pole's 1e-13 at 200 Hz: 2.5 s
    rng = np.random.default_rng(0)
    held, given = [], 0
    for k in range(200):  # 1,000 s
        t = (k * 1000 + np.arange(1000)) / RATE_HZ
        starts = np.zeros(1000, dtype=bool)
        starts[0] = k == 0
        out_t, _, _ = smoother.push(t, rng.standard_normal((3, 1000)), starts)
        given += out_t.shape[0]
        held.append(smoother._t.shape[0])
    assert max(held) <= 2 * smoother.margin + 1000
    assert given + smoother.finish()[0].shape[0] == 200_000


def test_a_fault_or_a_gap_never_reaches_its_neighbours() -> None:
    # a body at rest (0 mm), a flagged sample of 50 mm, then 10 mm; a gap, then -10 mm: a
    # filter across them would ring into both sides.
    t = np.arange(3000) / RATE_HZ
    t[2000:] += 1.0
    v = np.zeros((3, 3000))
    v[:, 1000] = 50.0
    v[:, 1001:] = 10.0
    v[:, 2000:] = -10.0
    v[:, 1000] = np.nan  # the recorder's flag on the 50 mm reading
    scans = np.arange(0.0, t[-1], 1 / 1000.0)
    got = stream(t, v, 256, SensorSmoother(DEFAULT_FILTER_HZ, 1 / RATE_HZ)).at(scans)
    first, second = scans <= t[999], (scans >= t[1001]) & (scans <= t[1999])
    third = scans >= t[2000]
    for values in (got.left_mm, got.right_mm, got.lateral_mm):
        np.testing.assert_allclose(values[first], 0.0, atol=1e-12)
        np.testing.assert_allclose(values[second], 10.0, atol=1e-12)
        np.testing.assert_allclose(values[third], -10.0, atol=1e-12)
    # the scans between the stretches stay flagged, and only they
    np.testing.assert_array_equal(got.fault, ~(first | second | third))


@pytest.mark.parametrize("rate_hz", [100.0, 200.0, 1000.0])
def test_body_motion_passes_and_noise_is_removed_and_estimated(rate_hz: float) -> None:
    rng = np.random.default_rng(7)
    t = np.arange(int(60 * rate_hz)) / rate_hz
    motion = body_motion(t)
    noise_mm = np.array([0.3, 0.2, 0.1])
    v = motion + noise_mm[:, None] * rng.standard_normal(motion.shape)
    smoother = SensorSmoother(DEFAULT_FILTER_HZ, 1 / rate_hz)
    got = SensorStream(lambda a, b: (t[a:b], v[:, a:b]), t.shape[0], 2.5 / rate_hz, 4096, smoother)
    values = got.at(t)
    error = np.stack([values.left_mm, values.right_mm, values.lateral_mm]) - motion
    # at 100 Hz 5 Hz keeps 30 % of white noise (0.09 mm of 0.3 mm)
    kept = np.sqrt(0.93 * DEFAULT_FILTER_HZ / (0.5 * rate_hz))
    inner = slice(int(rate_hz), -int(rate_hz))  # a second from the ends
    rms = np.sqrt(np.mean(error[:, inner] ** 2, axis=1))
    np.testing.assert_array_less(rms, 1.15 * kept * noise_mm)
    estimate = smoother.noise_mm
    assert estimate is not None
    np.testing.assert_allclose(estimate, noise_mm, rtol=0.05)
    assert smoother.describe().endswith(
        "low-pass 5 Hz (zero phase); noise left {:.3f}, right {:.3f}, lateral {:.3f} mm RMS".format(
            *estimate
        )
    )


def test_noise_free_body_motion_is_kept_without_lag() -> None:
    # 60 s of 0.2-2 Hz motion of up to 20 mm: no delay, 0.07 % of the amplitude at 2 Hz;
    # within a few tenths of a second of a stretch's ends, the body's curvature over the
    # 20 samples (0.1 s) of the end's line: up to 5 m/s² of acceleration here
    t = np.arange(12_000) / RATE_HZ
    motion = body_motion(t)
    got = stream(t, motion, 1000, SensorSmoother(DEFAULT_FILTER_HZ, 1 / RATE_HZ)).at(t)
    error = np.abs(np.stack([got.left_mm, got.right_mm, got.lateral_mm]) - motion)
    inner = (t > t[0] + 0.5) & (t < t[-1] - 0.5)
    assert error[:, inner].max() < 0.01
    assert error.max() < 0.5


@pytest.mark.parametrize(
    ("cutoff_hz", "interval_s", "said"),
    [
        (0.0, 1 / RATE_HZ, "not filtered (vehicle_filter_hz = 0)"),
        (5.0, None, "not filtered: fewer than two sample times"),
        (5.0, 1 / 8.0, "not filtered: sampled at 8 Hz, not above twice the 5 Hz cut-off"),
    ],
)
def test_off_or_too_slow_leaves_the_samples_as_they_are(
    cutoff_hz: float, interval_s: float | None, said: str
) -> None:
    t, v = faulty_series()
    smoother = SensorSmoother(cutoff_hz, interval_s)
    plain = stream(t, v, 500, None).at(t)
    got = stream(t, v, 500, smoother).at(t)
    np.testing.assert_array_equal(got.left_mm, plain.left_mm)
    np.testing.assert_array_equal(got.fault, plain.fault)
    assert smoother.noise_mm is None and smoother.describe() == said


@pytest.mark.parametrize("cutoff_hz", [-1.0, float("nan"), float("inf")])
def test_a_cutoff_must_be_zero_or_positive(cutoff_hz: float) -> None:
    with pytest.raises(ValueError, match="cut-off"):
        SensorSmoother(cutoff_hz, 0.005)


@pytest.mark.parametrize(
    ("section", "expected"),
    [
        ({}, 5.0),
        ({"vehicle_filter_hz": 0}, 0.0),
        ({"vehicle_filter_hz": 8.5}, 8.5),
        ({"vehicle_filter_hz": -1}, "processing.vehicle_filter_hz must be 0 (off) or a positive"),
        ({"vehicle_filter_hz": "5"}, "processing.vehicle_filter_hz must be 0 (off)"),
        ({"vehicle_filter_hz": True}, "processing.vehicle_filter_hz must be 0 (off)"),
        ({"vehicle_filter": 5}, "unknown key processing.vehicle_filter (did you mean"),
    ],
)
def test_the_processing_section_sets_the_cutoff(
    tmp_path: Path, section: dict[str, object], expected: float | str
) -> None:
    settings = Settings(
        database_url="sqlite://",
        data_dir=tmp_path,
        config_path=tmp_path / "config.toml",
        sections={"processing": section},
    )
    if isinstance(expected, float):
        assert vehicle_filter_hz(settings) == expected
    else:
        with pytest.raises(UserError, match=re.escape(expected)) as raised:
            vehicle_filter_hz(settings)
        assert str(raised.value).startswith(f"{tmp_path / 'config.toml'}: ")
