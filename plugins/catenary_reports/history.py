"""``catenary history``: a span's (or a stretch's spans') measurements over runs, each wire
position's wear rate and the forecast date of each limit, as the alerts see them
(``catenary.maintenance.trends``); ``-o FILE.png|.svg`` plots the minimum residual thickness
over time with the fitted lines, their confidence bands and the limits.

Only complete runs count, each by its latest processing. Staggers are shown looking towards
increasing chainage (the run's direction undone), so runs either way compare.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import click
import numpy as np
from matplotlib import rc_context
from scipy import stats
from sqlalchemy import select
from sqlalchemy.orm import Session

from catenary.arrays import FloatArray, IntArray
from catenary.errors import UserError
from catenary.limits import choose_policy
from catenary.maintenance.forecast import (
    CONFIDENCE,
    MIN_RUNS,
    moment_of,
    reach_text,
)
from catenary.maintenance.trends import TrackTrends, history_rows, rate_interval, span_trends
from catenary.plugins import CommandContext
from catenary.storage.database import session_scope
from catenary.storage.models import SpanMeasurement
from catenary.text import printable
from catenary_reports.plots import LimitLine, TrendSeries, trend_figure, wire_colour
from catenary_reports.request import check_output
from catenary_reports.trend_report import track_of

__all__ = ["show_history"]

Geometry = tuple[float, float, float, float]
"""A span measurement's height and stagger ranges [mm]: lowest, highest height, stagger."""

FORECAST_YEARS = 10.0
"""How far past the last run a fitted line is drawn at most [years]."""


def _geometry(session: Session, ids: IntArray) -> dict[int, Geometry]:
    """Height and stagger ranges [mm] of span measurements ``ids``, by id."""
    sm = SpanMeasurement
    found = session.execute(
        select(
            sm.id, sm.height_min_mm, sm.height_max_mm, sm.stagger_min_mm, sm.stagger_max_mm
        ).where(sm.id.in_(ids.tolist()))
    ).all()
    return {int(r[0]): (r[1], r[2], r[3], r[4]) for r in found}


def _stretch(trends: TrackTrends, h: int) -> str:
    hist, data = trends.histories, trends.data
    chainage = f"{hist.start_m[h]:.1f} to {hist.end_m[h]:.1f} m"
    if hist.mast_from[h] >= 0:
        codes = data.mast_code
        return f"masts {codes[hist.mast_from[h]]} to {codes[hist.mast_to[h]]} ({chainage})"
    return f"chainage {chainage} (no mast register)"


def _lines(trends: TrackTrends, h: int, geometry: Mapping[int, Geometry]) -> list[str]:
    """The printed block of history ``h``."""
    data, hist, rows = trends.data, trends.histories, trends.data.rows
    kind = trends.wire_type[h]
    wire_type = trends.wire_type_names[kind] if kind >= 0 else "wire type not registered"
    out = [f"{_stretch(trends, h)}, wire position {hist.position[h]}, {wire_type}"]
    out.append("  run   started            direction    min mm  mean mm  height mm      stagger mm")
    for row in history_rows(trends, h).tolist():
        run_id = int(rows.run_id[row])
        started = data.run_started[int(np.searchsorted(data.run_id, run_id))]
        low_h, high_h, low_s, high_s = geometry[int(rows.measurement_id[row])]
        sign = rows.direction[row]
        left, right = sorted((sign * low_s, sign * high_s))
        before = "" if trends.histories.row_history[row] >= 0 else "  (before the last repair)"
        out.append(
            f"  {run_id:<5d} {started:%Y-%m-%d %H:%M}   "
            f"{'increasing' if sign > 0 else 'decreasing':<11s}"
            f"{rows.min_thickness_mm[row]:8.2f} {rows.mean_thickness_mm[row]:8.2f}  "
            f"{low_h:5.0f} to {high_h:<5.0f}  {left:5.0f} to {right:<5.0f}{before}".rstrip()
        )
    fit = hist.fit
    runs = int(fit.runs[h])
    if runs < MIN_RUNS or not np.isfinite(fit.slope_mm_per_year[h]):
        out.append(f"  wear rate: needs {MIN_RUNS} runs since the last repair, has {runs}")
        return out
    low, high = (float(x[h]) for x in rate_interval(fit))
    out.append(
        f"  wear rate {fit.wear_rate_mm_per_year[h]:.3f} mm/year "
        f"({CONFIDENCE:.0%}: {low:.3f} to {high:.3f}) over {runs} runs"
    )
    for limit in trends.limits:
        threshold = float(limit.threshold_mm[h])
        if not np.isfinite(threshold):
            continue
        reach = limit.reach
        out.append(
            f"  {limit.rule.rule.level:<8s} {threshold:6.2f} mm ({limit.rule.name}): "
            f"{reach_text(float(reach.central[h]))} "
            f"({reach_text(float(reach.low[h]))} to {reach_text(float(reach.high[h]))})"
        )
    return out


def _series(trends: TrackTrends, chosen: IntArray) -> list[TrendSeries]:
    """Each history's points and fitted line with its band (Student quantile as the rate's)."""
    data, hist, rows = trends.data, trends.histories, trends.data.rows
    fit = hist.fit
    out = []
    for number, h in enumerate(chosen.tolist()):
        found = history_rows(trends, h)
        runs = np.searchsorted(data.run_id, rows.run_id[found])
        times = [data.run_started[int(r)] for r in runs]
        kept = hist.row_history[found] >= 0
        fit_years: FloatArray = np.zeros(0)
        line = low = high = np.zeros(0)
        if fit.runs[h] >= MIN_RUNS and np.isfinite(fit.slope_mm_per_year[h]):
            first, last = rows.time_years[found[kept]].min(), rows.time_years[found[kept]].max()
            end = last
            for limit in trends.limits:
                reach = float(limit.reach.central[h])
                if np.isfinite(reach) and reach > last:
                    end = max(end, min(reach, last + FORECAST_YEARS))
            fit_years = np.linspace(first, end, 60)
            n = float(fit.runs[h])
            q = stats.t.ppf(0.5 + CONFIDENCE / 2.0, n - 2.0)
            offset = fit_years - fit.mean_time_years[h]
            line = fit.mean_thickness_mm[h] + fit.slope_mm_per_year[h] * offset
            half = q * np.sqrt(
                fit.residual_sd_mm[h] ** 2 / n + (fit.slope_se_mm_per_year[h] * offset) ** 2
            )
            low, high = line - half, line + half
        stretch = _stretch(trends, h).split(" (")[0]
        out.append(
            TrendSeries(
                label=f"{stretch}, position {hist.position[h]}",
                colour=wire_colour(number),
                times=times,
                values_mm=rows.min_thickness_mm[found],
                since_repair=kept.tolist(),
                fit_times=[m for y in fit_years if (m := moment_of(float(y))) is not None],
                fit_mm=line,
                band_low_mm=low,
                band_high_mm=high,
            )
        )
    return out


def _limit_lines(trends: TrackTrends, chosen: IntArray) -> list[LimitLine]:
    seen: dict[tuple[str, float], LimitLine] = {}
    for limit in trends.limits:
        for value in np.unique(limit.threshold_mm[chosen]).tolist():
            if np.isfinite(value):
                label = f"{limit.rule.rule.level} {value:.2f} mm"
                seen.setdefault(
                    (limit.rule.name, value), LimitLine(value, limit.rule.rule.level, label)
                )
    return list(seen.values())


def _plot(
    output: Path, suffix: str, series: Sequence[TrendSeries], lines: list[LimitLine], title: str
) -> None:
    """Write the figure to ``output`` through a partial file (nothing half-written)."""
    fig = trend_figure(series, lines, title)
    partial = output.with_name(f".{output.name}.partial")
    try:
        with rc_context({"svg.hashsalt": "history"}):
            fig.savefig(
                partial, format=suffix[1:], metadata={"Date": None} if suffix == ".svg" else None
            )
        os.replace(partial, output)
    except OSError as exc:
        partial.unlink(missing_ok=True)
        raise UserError(f"{output}: cannot write the plot: {exc.strerror or exc}") from None


def show_history(
    context: CommandContext,
    line: str,
    track: str,
    mast: str | None,
    from_m: float | None,
    to_m: float | None,
    policy_name: str | None,
    output: Path | None,
) -> None:
    """Print the history of a span (``mast``) or of the spans between ``from_m`` and ``to_m``
    [m] of a track, and plot it to ``output`` (.png or .svg) when given: ``catenary
    history``."""
    stretch = (from_m, to_m)
    if (mast is None) == (stretch == (None, None)) or (mast is None and None in stretch):
        raise UserError("give --mast CODE, or --from-m M and --to-m M")
    if from_m is not None and to_m is not None and not from_m < to_m:
        raise UserError(f"--from-m {from_m:g} must be less than --to-m {to_m:g}")
    suffix = check_output(output, (".png", ".svg")) if output is not None else ""
    registry = context.registry
    policy = choose_policy(context.settings, registry.limit_policies(), policy_name)
    where = f"line {line} track {track}"
    with context.database() as engine, session_scope(engine, read_only=True) as session:
        track_id = track_of(session, line, track)
        trends, chosen = span_trends(
            session,
            track_id,
            where,
            registry.wire_types(),
            policy,
            mast=mast,
            from_m=from_m,
            to_m=to_m,
        )
        ids = trends.data.rows.measurement_id[np.isin(trends.row_unit, chosen)]
        geometry = _geometry(session, ids)
    rules = (
        f"policy {policy.name}, {CONFIDENCE:.0%} intervals"
        if policy
        else "no wear-limit policy ([limits] policy in the config, or --policy NAME): no forecast"
    )
    runs = len(set(trends.data.rows.run_id[np.isin(trends.row_unit, chosen)].tolist()))
    click.echo(printable(f"{where}: {runs} run(s), {rules}"))
    for h in chosen.tolist():
        for text in _lines(trends, h, geometry):
            click.echo(printable(text))
    if output is not None:
        title = f"{where}: minimum residual thickness over the runs"
        _plot(output, suffix, _series(trends, chosen), _limit_lines(trends, chosen), title)
        click.echo(f"plot written to {output}")
