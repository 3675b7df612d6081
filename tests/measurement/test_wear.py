"""Stagger-angle correction (paper eq. 11-12) from the measured stagger gradient; the
along-track screen of the wear widths."""

from __future__ import annotations

import math

import numpy as np
import pytest

from catenary.measurement.wear import (
    DEFAULT_WINDOW_M,
    SCREEN_HALF_WINDOW_M,
    corrected_wear_width_mm,
    screened_wear_width_by_wire_mm,
    screened_wear_width_mm,
    stagger_angle_by_wire_rad,
    stagger_angle_rad,
)

SPACING_M = 0.0139  # 50 km/h at 1000 scans/s
START_M = 12345.0


def zigzag(amplitude_mm: float, span_m: float, length_m: float = 400.0):
    """Positions and a stagger zigzag ±amplitude between registration points ``span_m``
    apart, with the true angle ``atan(2 a / L)`` and each sample's distance to a kink."""
    position = START_M + np.arange(0.0, length_m, SPACING_M)
    phase = ((position - START_M) % (2.0 * span_m)) / span_m
    stagger = np.where(
        phase < 1.0,
        -amplitude_mm + 2.0 * amplitude_mm * phase,
        amplitude_mm - 2.0 * amplitude_mm * (phase - 1.0),
    )
    theta = math.atan(2.0 * amplitude_mm / span_m / 1000.0)
    to_kink_m = np.minimum(phase % 1.0, 1.0 - phase % 1.0) * span_m
    return position, stagger, theta, to_kink_m


@pytest.mark.parametrize(
    ("amplitude_mm", "span_m"),
    [(300.0, 50.0), (400.0, 45.0), (200.0, 65.0), (2500.0, 30.0)],  # the last: 167 mm/m
)
def test_zigzag_angle_within_1e3_relative(amplitude_mm: float, span_m: float) -> None:
    position, stagger, theta, to_kink_m = zigzag(amplitude_mm, span_m)
    estimate = stagger_angle_rad(position, stagger)
    assert np.all(np.isfinite(estimate))
    # the slope of a line, to rounding, away from the kink's own bin (window / 20)
    away = to_kink_m > DEFAULT_WINDOW_M / 20.0
    assert np.max(np.abs(estimate[away] / theta - 1.0)) < 1e-3
    # and the corrected width within 1e-3 relative everywhere, kinks included
    w = 10.0
    corrected = corrected_wear_width_mm(w, estimate)
    assert np.max(np.abs(corrected / (w * math.cos(theta)) - 1.0)) < 1e-3


def test_kinks_do_not_pull_the_angle_toward_zero() -> None:
    # a window centred on a kink averages +slope and -slope to zero; the one-sided windows
    # keep the true angle right up to the kink
    position, stagger, theta, to_kink_m = zigzag(300.0, 50.0)
    estimate = stagger_angle_rad(position, stagger)
    near = (to_kink_m < DEFAULT_WINDOW_M) & (to_kink_m > DEFAULT_WINDOW_M / 20.0)
    assert near.sum() > 100
    assert np.min(estimate[near]) > 0.999 * theta


def test_noisy_stagger_gives_the_angle_to_a_few_percent() -> None:
    rng = np.random.default_rng(3)
    position, stagger, theta, _ = zigzag(300.0, 50.0)
    noisy = stagger + rng.normal(0.0, 0.3, stagger.shape)  # 0.3 mm of stagger noise
    estimate = stagger_angle_rad(position, noisy)
    error = estimate / theta - 1.0
    assert np.sqrt(np.mean(error**2)) < 0.01
    assert np.max(np.abs(error)) < 0.05
    # which is far below what matters: cos θ to 1e-5
    assert np.max(np.abs(np.cos(estimate) / math.cos(theta) - 1.0)) < 1e-5


def test_offset_arc_in_a_curve_follows_the_changing_gradient() -> None:
    # in a curve the stagger between registrations is a parabola: slope changes linearly
    position = START_M + np.arange(0.0, 60.0, SPACING_M)
    c = position - START_M
    curvature_mm_per_m2 = 1000.0 / 600.0  # R = 600 m
    stagger = -250.0 + curvature_mm_per_m2 * c * (60.0 - c) / 2.0
    slope = curvature_mm_per_m2 * (60.0 - 2.0 * c) / 2.0
    theta = np.arctan(np.abs(slope) / 1000.0)
    estimate = stagger_angle_rad(position, stagger)
    assert np.max(np.abs(estimate - theta)) < 2e-3  # rad; one-sided at the ends
    # inside, to a fraction of the change of θ over a twentieth of the window (the largest
    # where |slope| turns through zero mid-span)
    inner = (c > DEFAULT_WINDOW_M) & (c < 60.0 - DEFAULT_WINDOW_M)
    assert np.max(np.abs(estimate[inner] - theta[inner])) < 1e-4
    assert np.median(np.abs(estimate[inner] - theta[inner])) < 1e-5


def test_unordered_samples_gaps_and_nan() -> None:
    position, stagger, theta, _ = zigzag(300.0, 50.0, length_m=120.0)
    rng = np.random.default_rng(5)
    keep = rng.random(position.shape) > 0.3  # 30 % of scans without the wire
    keep &= ~((position > START_M + 20.0) & (position < START_M + 20.6))  # a 0.6 m gap
    position, stagger = position[keep], stagger[keep]
    stagger[::50] = np.nan
    order = rng.permutation(position.shape[0])
    estimate = stagger_angle_rad(position[order], stagger[order])
    assert np.all(np.isnan(estimate[np.isnan(stagger[order])]))
    finite = np.isfinite(estimate)
    assert finite.sum() == np.isfinite(stagger).sum()
    # straight stretches only (the gap's neighbourhood and kinks aside)
    assert np.median(np.abs(estimate[finite] / theta - 1.0)) < 1e-5


def test_too_few_samples_give_nan() -> None:
    assert np.all(np.isnan(stagger_angle_rad([1.0, 2.0, 3.0], [0.0, 1.0, 2.0])))
    # a window needs its samples spread along it, not all at one position
    assert np.all(np.isnan(stagger_angle_rad(np.full(20, 5.0), np.arange(20.0))))
    assert stagger_angle_rad(np.zeros(0), np.zeros(0)).shape == (0,)


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="window_m"):
        stagger_angle_rad([0.0, 1.0], [0.0, 1.0], window_m=0.0)
    with pytest.raises(ValueError, match="shape"):
        stagger_angle_rad([0.0, 1.0], [0.0, 1.0, 2.0])


def test_each_wire_gets_its_own_angle() -> None:
    position, stagger_a, theta_a, _ = zigzag(300.0, 50.0, length_m=100.0)
    _, stagger_b, theta_b, _ = zigzag(200.0, 50.0, length_m=100.0)
    wire = np.concatenate([np.zeros(position.shape[0], int), np.ones(position.shape[0], int)])
    positions = np.concatenate([position, position])
    staggers = np.concatenate([stagger_a, stagger_b + 200.0])
    order = np.argsort(positions, kind="stable")  # interleaved, as rows of a table come
    theta = stagger_angle_by_wire_rad(wire[order], positions[order], staggers[order])
    back = np.empty_like(theta)
    back[order] = theta
    n = position.shape[0]
    assert np.median(back[:n]) == pytest.approx(theta_a, rel=1e-6)
    assert np.median(back[n:]) == pytest.approx(theta_b, rel=1e-6)


def test_correction_is_w_cos_theta() -> None:
    # the paper's example: S1 = 300, S2 = -300 mm, L = 50 m: sin θ = 0.012
    theta = math.asin(0.012)
    assert corrected_wear_width_mm(10.0, theta) == pytest.approx(10.0 * 0.999928, abs=1e-6)
    np.testing.assert_allclose(
        corrected_wear_width_mm(np.array([[8.0], [12.0]]), np.array([0.0, 0.2])),
        [[8.0, 8.0 * math.cos(0.2)], [12.0, 12.0 * math.cos(0.2)]],
    )
    assert np.isnan(corrected_wear_width_mm(np.nan, 0.1))
    assert np.isnan(corrected_wear_width_mm(5.0, np.nan))


def worn_wire(length_m: float = 60.0, noise_mm: float = 0.012, seed: int = 3):
    """Positions and wear widths of one wire: a base, undulation over metres, a hot spot of
    a metre and a half, and the measurement's noise (the benchmark's 0.012 mm RMS)."""
    rng = np.random.default_rng(seed)
    position = START_M + np.arange(0.0, length_m, SPACING_M)
    x = position - START_M
    width = (
        9.0 + 0.3 * np.sin(2.0 * math.pi * x / 7.0) + 1.5 * np.exp(-0.5 * ((x - 30.0) / 0.6) ** 2)
    )
    return position, width + rng.normal(0.0, noise_mm, x.shape)


def test_a_few_scans_off_their_neighbours_are_screened_out() -> None:
    position, width = worn_wire()
    # a dropper clamp: three scans whose face reads 0.1 mm narrower (the cameras' pull)
    clamp = np.flatnonzero(
        (position >= START_M + 20.0) & (position < START_M + 20.0 + 3 * SPACING_M)
    )
    width[clamp] -= 0.1
    screened = screened_wear_width_mm(position, width)
    assert clamp.shape == (3,)
    assert np.all(np.isnan(screened[clamp]))
    kept = np.ones(width.shape, dtype=bool)
    kept[clamp] = False
    # the wire's own changes (undulation, the hot spot's flanks) are kept, and its noise
    # but for the odd sample four deviations out
    out = np.isnan(screened[kept])
    assert np.count_nonzero(out) <= 1e-3 * out.shape[0]
    np.testing.assert_array_equal(screened[kept][~out], width[kept][~out])


def test_a_step_in_the_wear_and_a_short_stretch_of_new_wear_are_kept() -> None:
    position, width = worn_wire(seed=4)
    x = position - START_M
    width += np.where(x > 40.0, 0.5, 0.0)  # a splice: the wear steps
    # new wear over a little more than the window: longer than any fitting
    width += np.where((x > 10.0) & (x < 10.0 + 3.0 * SCREEN_HALF_WINDOW_M), 0.3, 0.0)
    screened = screened_wear_width_mm(position, width)
    changes = (np.abs(x - 40.0) < 0.5) | ((x > 9.5) & (x < 10.8))
    assert np.all(np.isfinite(screened[changes]))
    assert np.count_nonzero(np.isnan(screened)) <= 1e-3 * x.shape[0]


def test_the_screen_follows_the_noise_of_the_widths() -> None:
    # noisier widths (0.05 mm RMS): a 0.08 mm excursion is within their noise and stays,
    # a 0.4 mm one does not
    position, width = worn_wire(noise_mm=0.05, seed=6)
    at = np.flatnonzero(position >= START_M + 20.0)[:2]
    small, large = width.copy(), width.copy()
    small[at] -= 0.08
    large[at] -= 0.4
    assert np.all(np.isfinite(screened_wear_width_mm(position, small)[at]))
    assert np.all(np.isnan(screened_wear_width_mm(position, large)[at]))


def test_the_screen_takes_any_order_keeps_nan_and_needs_a_few_samples() -> None:
    position, width = worn_wire(length_m=10.0)
    width[100] += 0.2
    width[::40] = np.nan
    expected = screened_wear_width_mm(position, width)
    assert np.isnan(expected[100])
    order = np.random.default_rng(8).permutation(position.shape[0])
    np.testing.assert_array_equal(
        screened_wear_width_mm(position[order], width[order]), expected[order]
    )
    assert np.array_equal(np.isnan(expected), np.isnan(width) | (np.arange(width.shape[0]) == 100))
    # scans further apart than a window can hold five of (over 50 mm): nothing to compare
    sparse = np.full(200, 9.0)
    sparse[100] = 9.5
    np.testing.assert_array_equal(screened_wear_width_mm(np.arange(200) * 0.07, sparse), sparse)
    few = np.array([9.0, 9.0, 9.5, 9.0])
    np.testing.assert_array_equal(screened_wear_width_mm([0.0, 0.01, 0.02, 0.03], few), few)
    # at a standstill every scan is at one place: the window holds its nearest samples
    still = np.full(5000, 9.0)
    still[2500] = 9.3
    assert np.flatnonzero(np.isnan(screened_wear_width_mm(np.zeros(5000), still))).tolist() == [
        2500
    ]
    with pytest.raises(ValueError, match="shape"):
        screened_wear_width_mm([0.0, 1.0], [1.0])


def test_each_wire_is_screened_against_its_own_widths() -> None:
    position, width_a = worn_wire(length_m=20.0)
    _, width_b = worn_wire(length_m=20.0, seed=9)
    width_b += 2.0  # another wire, more worn: mixed, every row would look off
    width_a[200] -= 0.1
    wire = np.repeat([0, 1], position.shape[0])
    positions = np.concatenate([position, position])
    widths = np.concatenate([width_a, width_b])
    order = np.argsort(positions, kind="stable")  # interleaved, as rows of a table come
    screened = np.empty_like(widths)
    screened[order] = screened_wear_width_by_wire_mm(wire[order], positions[order], widths[order])
    assert np.flatnonzero(np.isnan(screened)).tolist() == [200]
