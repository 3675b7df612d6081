"""Wear-rate fits and reach dates on synthetic histories with known rates and noise."""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np
import pytest

from catenary.maintenance.forecast import (
    EPOCH,
    fit_histories,
    moment_of,
    reach_times,
    years_since_epoch,
)

HISTORIES = 4000
RUNS = 10  # one a year, 2015 to 2024
NOISE_MM = 0.04  # the span minimum's scatter from run to run
THRESHOLD_MM = 8.75  # CTA120 at 30 % loss


def synthetic(seed: int = 1) -> tuple[np.ndarray, ...]:
    """``HISTORIES`` wires wearing at 0.1-0.6 mm/year from 12.5-12.9 mm, yearly runs."""
    rng = np.random.default_rng(seed)
    rate = rng.uniform(0.1, 0.6, HISTORIES)
    new = rng.uniform(12.5, 12.9, HISTORIES)
    t = 15.0 + np.arange(RUNS) + rng.uniform(-0.05, 0.05, (HISTORIES, RUNS))  # years since 2000
    y = new[:, None] - rate[:, None] * (t - 15.0) + rng.normal(0.0, NOISE_MM, (HISTORIES, RUNS))
    group = np.repeat(np.arange(HISTORIES), RUNS)
    order = rng.permutation(group.shape[0])  # rows in any order
    return rate, new, group[order], t.ravel()[order], y.ravel()[order]


def test_a_noise_free_line_is_recovered_exactly() -> None:
    t = np.array([20.0, 21.5, 23.0, 24.0])
    fit = fit_histories(np.zeros(4, int), t, 12.9 - 0.3 * (t - 20.0), 1)
    assert fit.wear_rate_mm_per_year[0] == pytest.approx(0.3, abs=1e-12)
    assert fit.slope_se_mm_per_year[0] == pytest.approx(0.0, abs=1e-9)
    reach = reach_times(fit, 9.9)
    assert reach.central[0] == pytest.approx(30.0, abs=1e-9)  # 3 mm at 0.3 mm/year
    assert reach.low[0] == pytest.approx(30.0, abs=1e-6)
    assert reach.high[0] == pytest.approx(30.0, abs=1e-6)


def test_recovered_rates_lie_within_their_stated_uncertainty() -> None:
    rate, _, group, t, y = synthetic()
    fit = fit_histories(group, t, y, HISTORIES)
    error = fit.wear_rate_mm_per_year - rate
    se = fit.slope_se_mm_per_year
    # least squares' standard error: sigma / sqrt(Sxx), Sxx = 82.5 year^2 for 10 yearly runs
    assert np.median(se) == pytest.approx(NOISE_MM / np.sqrt(82.5), rel=0.1)
    assert np.std(error) == pytest.approx(np.mean(se), rel=0.05)
    # the 95 % interval of the rate (Student, 8 degrees of freedom) holds the truth 95 % of the
    # time: 4000 histories give 95 % +- 1 % (three binomial standard deviations)
    inside = np.abs(error) <= 2.306 * se
    assert 0.94 <= np.mean(inside) <= 0.96
    assert np.max(np.abs(error)) < 6 * np.max(se)


def test_reach_dates_within_tolerance_and_their_interval() -> None:
    rate, new, group, t, y = synthetic(seed=2)
    fit = fit_histories(group, t, y, HISTORIES)
    reach = reach_times(fit, THRESHOLD_MM)
    truth = 15.0 + (new - THRESHOLD_MM) / rate
    error_days = (reach.central - truth) * 365.25
    # the date's standard error (delta method): the level's and the rate's errors over the rate
    level_se = fit.residual_sd_mm / np.sqrt(fit.runs)
    spread_days = np.hypot(level_se, (truth - fit.mean_time_years) * fit.slope_se_mm_per_year)
    spread_days *= 365.25 / rate
    # errors over their standard error: Student's t with 8 degrees of freedom, median |t| 0.706
    assert np.median(np.abs(error_days / spread_days)) == pytest.approx(0.706, rel=0.07)
    # limits due within two years of the last run, the dates a planner acts on: a standard
    # error of about 15 days, half the dates within 11 days of the truth, 95 % within 40 days
    soon = truth - 24.0 < 2.0
    assert np.median(spread_days[soon]) < 20.0
    assert np.median(np.abs(error_days[soon])) < 15.0
    assert np.percentile(np.abs(error_days[soon]), 95) < 45.0
    # Fieller's 95 % interval holds the truth 95 % +- 1 % of the time (4000 histories)
    inside = (reach.low <= truth) & (truth <= reach.high)
    assert 0.94 <= np.mean(inside) <= 0.96
    assert np.all(reach.low <= reach.central) and np.all(reach.central <= reach.high)


def test_a_wire_that_may_not_wear_may_never_reach_its_limit() -> None:
    t = np.arange(5.0) + 20.0
    y = np.array([12.0, 12.05, 11.96, 12.02, 11.99])  # no wear, 0.03 mm scatter
    fit = fit_histories(np.zeros(5, int), t, y, 1)
    reach = reach_times(fit, THRESHOLD_MM)
    assert reach.high[0] == np.inf
    rising = fit_histories(np.zeros(5, int), t, 11.0 + 0.2 * (t - 20.0), 1)
    assert reach_times(rising, THRESHOLD_MM).central[0] == np.inf


def test_too_few_runs_give_no_forecast() -> None:
    fit = fit_histories(np.array([0, 0, 1]), np.array([20.0, 21.0, 20.0]), np.full(3, 12.0), 3)
    assert fit.runs.tolist() == [2, 1, 0]
    assert np.isfinite(fit.slope_mm_per_year[0]) and np.isnan(fit.slope_se_mm_per_year[0])
    assert np.isnan(fit.slope_mm_per_year[1]) and np.isnan(fit.slope_mm_per_year[2])
    assert np.all(np.isnan(reach_times(fit, THRESHOLD_MM).central))
    same_time = fit_histories(np.zeros(3, int), np.full(3, 20.0), np.array([12.0, 11.0, 12.5]), 1)
    assert np.isnan(same_time.slope_mm_per_year[0])


def test_times_in_years_since_2000() -> None:
    moment = datetime(2024, 5, 6, 7, 8, 9, tzinfo=UTC)
    years = years_since_epoch([EPOCH, moment])
    assert years[0] == 0.0 and years[1] == pytest.approx(24.34, abs=0.01)
    back = moment_of(float(years[1]))
    assert back is not None and abs((back - moment).total_seconds()) < 1e-3
    assert moment_of(np.inf) is None and moment_of(np.nan) is None
