"""Wear-rate forecasts: a straight line through each wire's residual thickness over the runs.

For each history (a span and wire's minimum residual thickness ``y`` [mm] at each run's time
``t`` [years]) ordinary least squares gives the slope ``b`` [mm/year] (negative: the wire
wears; the wear rate is ``-b``) and its standard error ``se(b) = s / sqrt(Sxx)``,
``s**2 = SSE / (n - 2)``. The fitted line ``y(t) = ybar + b (t - tbar)`` reaches a threshold
``h`` at ``t* = tbar + (h - ybar) / b``, with Fieller's confidence interval (the level's
uncertainty ``s / sqrt(n)`` and the rate's together; ``reach_times``). A wear that is not
significant gives an unbounded end ("possibly never").

Times are Julian years (365.25 days) since ``EPOCH`` (2000-01-01 UTC): float64 keeps them to
well under a second. Everything is vectorised over histories, arrays ``(g,)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta

import numpy as np
from numpy.typing import ArrayLike
from scipy import stats

from catenary.arrays import FloatArray, IntArray

__all__ = [
    "CONFIDENCE",
    "EPOCH",
    "MIN_RUNS",
    "SECONDS_PER_YEAR",
    "ReachTimes",
    "WearFit",
    "fit_histories",
    "moment_of",
    "reach_text",
    "reach_times",
    "years_since_epoch",
]

EPOCH = datetime(2000, 1, 1, tzinfo=UTC)
SECONDS_PER_YEAR = 365.25 * 86_400.0
MIN_RUNS = 3
"""Fewest runs for a rate with a standard error (two for the line, one for the scatter)."""

CONFIDENCE = 0.95
"""Default confidence of the reach date's interval."""


def years_since_epoch(moments: Sequence[datetime]) -> FloatArray:
    """Times of timezone-aware ``moments`` in years since ``EPOCH``, ``(m,)``."""
    return np.array(
        [(m - EPOCH).total_seconds() / SECONDS_PER_YEAR for m in moments], dtype=np.float64
    )


def moment_of(years: float) -> datetime | None:
    """The UTC moment ``years`` after ``EPOCH``; None for an infinite or NaN time."""
    if not np.isfinite(years):
        return None
    return EPOCH + timedelta(seconds=float(years) * SECONDS_PER_YEAR)


@dataclass(frozen=True)
class WearFit:
    """Least-squares lines through ``g`` histories (each field ``(g,)``).

    ``slope_mm_per_year`` is NaN where a history has fewer than two distinct times,
    ``slope_se_mm_per_year`` and ``residual_sd_mm`` where it has fewer than ``MIN_RUNS`` runs.
    """

    runs: IntArray
    mean_time_years: FloatArray
    mean_thickness_mm: FloatArray
    slope_mm_per_year: FloatArray
    slope_se_mm_per_year: FloatArray
    residual_sd_mm: FloatArray

    @property
    def wear_rate_mm_per_year(self) -> FloatArray:
        """Thickness lost per year (positive when the wire wears), ``(g,)``."""
        return -self.slope_mm_per_year

    def take(self, index: IntArray) -> WearFit:
        """The fits of histories ``index``."""
        return WearFit(
            runs=self.runs[index],
            mean_time_years=self.mean_time_years[index],
            mean_thickness_mm=self.mean_thickness_mm[index],
            slope_mm_per_year=self.slope_mm_per_year[index],
            slope_se_mm_per_year=self.slope_se_mm_per_year[index],
            residual_sd_mm=self.residual_sd_mm[index],
        )


def fit_histories(
    group: ArrayLike, time_years: ArrayLike, thickness_mm: ArrayLike, groups: int
) -> WearFit:
    """Fit a line to each of ``groups`` histories.

    ``group`` ``(m,)`` gives each point's history (``0 <= group < groups``), ``time_years`` and
    ``thickness_mm`` ``(m,)`` its time and value. Sums are taken about each history's means
    (two passes), so no precision is lost to the size of the times.
    """
    g = np.asarray(group, dtype=np.int64)
    t = np.asarray(time_years, dtype=np.float64)
    y = np.asarray(thickness_mm, dtype=np.float64)
    n = np.bincount(g, minlength=groups)
    with np.errstate(invalid="ignore", divide="ignore"):
        t_mean = np.bincount(g, t, groups) / n
        y_mean = np.bincount(g, y, groups) / n
        dt = t - t_mean[g]
        dy = y - y_mean[g]
        sxx = np.bincount(g, dt * dt, groups)
        sxy = np.bincount(g, dt * dy, groups)
        syy = np.bincount(g, dy * dy, groups)
        # a history whose times all agree (to 1e-9 of their size) has no slope
        flat = sxx <= 1e-18 * np.maximum(np.bincount(g, t * t, groups), 1.0)
        slope = np.where(flat, np.nan, sxy / sxx)
        sse = np.maximum(syy - slope * sxy, 0.0)
        scatter = np.where(n >= MIN_RUNS, sse / (n - 2), np.nan)
        se = np.sqrt(scatter / sxx)
    return WearFit(
        runs=n.astype(np.int64),
        mean_time_years=t_mean,
        mean_thickness_mm=y_mean,
        slope_mm_per_year=slope,
        slope_se_mm_per_year=np.where(flat, np.nan, se),
        residual_sd_mm=np.sqrt(scatter),
    )


@dataclass(frozen=True)
class ReachTimes:
    """When each fitted line reaches its threshold, in years since ``EPOCH`` (each ``(g,)``).

    ``central`` is the fitted line's crossing; ``low`` to ``high`` its confidence interval.
    ``+inf``: never (the line does not fall; as a ``high``: possibly never, the wear not being
    significant); ``-inf``: the mean level is already below the threshold and does not fall
    (as a ``low``: possibly reached already); NaN: no forecast (fewer than ``MIN_RUNS`` runs).
    """

    central: FloatArray
    low: FloatArray
    high: FloatArray


def reach_times(
    fit: WearFit, threshold_mm: ArrayLike, confidence: float = CONFIDENCE
) -> ReachTimes:
    """When each history's line reaches ``threshold_mm`` [mm] (a scalar or ``(g,)``).

    The interval is Fieller's: the times ``t`` at which the line's value, known to
    ``s sqrt(1/n + (t - tbar)**2 / Sxx)``, is consistent with the threshold at ``confidence``
    (Student quantile ``q``, ``n - 2`` degrees of freedom); with ``u = t - tbar`` and
    ``d = h - ybar``: ``(b**2 - q**2 se**2) u**2 - 2 b d u + d**2 - q**2 s**2 / n <= 0``.
    It holds the level's uncertainty and the rate's; when the wear is not significant
    (``|b| <= q se``) the set is unbounded and the side towards the future is given.
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie between 0 and 1, not {confidence}")
    threshold = np.broadcast_to(np.asarray(threshold_mm, dtype=np.float64), fit.runs.shape)
    usable = (fit.runs >= MIN_RUNS) & np.isfinite(fit.slope_mm_per_year)
    n = np.where(usable, fit.runs, MIN_RUNS).astype(np.float64)
    q = stats.t.ppf(0.5 + confidence / 2.0, n - 2.0)
    slope = np.where(usable, fit.slope_mm_per_year, -1.0)
    se = np.where(usable, fit.slope_se_mm_per_year, 0.0)
    level_var = np.where(usable, fit.residual_sd_mm, 0.0) ** 2 / n
    gap = threshold - fit.mean_thickness_mm  # d: negative while the level is above it
    a = slope**2 - (q * se) ** 2
    b = slope * gap
    c = gap**2 - q**2 * level_var
    root = np.sqrt(np.maximum(b * b - a * c, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        one, two = (b - root) / a, (b + root) / a
        central = fit.mean_time_years + gap / slope
    lower, upper = np.minimum(one, two), np.maximum(one, two)
    after = np.where(gap < 0.0, np.inf, -np.inf)  # a line that does not fall
    falling = slope < 0.0
    bounded = a > 0.0
    everything = b * b - a * c <= 0.0
    # not significant: the set is (-inf, lower] and [upper, inf); the future's side is given
    low = np.where(
        bounded,
        np.where(falling, lower, after),
        np.where(everything | (gap >= 0.0), -np.inf, upper),
    )
    high = np.where(
        bounded,
        np.where(falling, upper, after),
        np.where(everything | (gap < 0.0), np.inf, lower),
    )
    t_mean = fit.mean_time_years
    nan = np.full(fit.runs.shape, np.nan)
    finite_low = np.where(np.isfinite(low), t_mean + low, low)
    finite_high = np.where(np.isfinite(high), t_mean + high, high)
    return ReachTimes(
        central=np.where(usable, np.where(falling, central, after), nan),
        low=np.where(usable, finite_low, nan),
        high=np.where(usable, finite_high, nan),
    )


def reach_text(years: float) -> str:
    """A reach time (``catenary.maintenance.forecast.ReachTimes``) as a date, ``never``
    (+inf), ``reached`` (-inf) or ``-`` (NaN: no forecast)."""
    if math.isnan(years):
        return "-"
    if math.isinf(years):
        return "never" if years > 0 else "reached"
    moment = moment_of(years)
    assert moment is not None
    return moment.date().isoformat()
