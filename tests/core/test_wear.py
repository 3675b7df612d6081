"""Stagger-angle correction (paper eq. 11-12) from the measured stagger gradient."""

from __future__ import annotations

import math

import numpy as np
import pytest

from catenary.wear import (
    DEFAULT_WINDOW_M,
    corrected_wear_width_mm,
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
