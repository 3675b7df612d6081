"""Wear trends of one track: each history's runs, wear rate and forecast dates, as the alerts
see them; and a run beside the track's previous one.

A track's histories (``catenary.maintenance.history``) are fitted and each local rule of a
policy is forecast on them exactly as the alert evaluation does (``rules_of``, ``Rule.limit``
on the wire type of the history's latest row, ``reach_times``), so a date printed here is the
date a forecast alert carries. Arrays ``(h,)`` are histories, ``(m,)`` the track's span rows.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy import stats
from sqlalchemy import ColumnElement
from sqlalchemy.orm import Session

from catenary.arrays import BoolArray, FloatArray, IntArray, take
from catenary.errors import UserError
from catenary.limits import LimitPolicy
from catenary.maintenance.alerts.rules import LOCAL, Rule, rules_of
from catenary.maintenance.alerts.trackdata import TrackData, history_keys, match_units
from catenary.maintenance.forecast import CONFIDENCE, MIN_RUNS, ReachTimes, WearFit, reach_times
from catenary.maintenance.history import SpanHistories, span_histories
from catenary.storage.models import SpanMeasurement
from catenary.wiretype import WireType

__all__ = [
    "LimitForecast",
    "RunComparison",
    "TrackTrends",
    "chosen_histories",
    "compare_with_previous",
    "history_rows",
    "rate_interval",
    "span_trends",
    "track_trends",
]


def rate_interval(fit: WearFit, confidence: float = CONFIDENCE) -> tuple[FloatArray, FloatArray]:
    """The wear rate's confidence interval [mm/year], ``(g,)`` each: ``rate -+ q se`` with the
    Student quantile of ``runs - 2`` degrees of freedom; NaN with fewer than ``MIN_RUNS``."""
    usable = fit.runs >= MIN_RUNS
    q = stats.t.ppf(0.5 + confidence / 2.0, np.where(usable, fit.runs, MIN_RUNS) - 2.0)
    half = np.where(usable, q * fit.slope_se_mm_per_year, np.nan)
    rate = fit.wear_rate_mm_per_year
    return rate - half, rate + half


@dataclass(frozen=True)
class LimitForecast:
    """A local rule on each history: its threshold [mm] (``(h,)``, NaN where it does not apply
    to the history's wire type) and when the fitted line reaches it (``ReachTimes``, years
    since ``catenary.maintenance.forecast.EPOCH``)."""

    rule: Rule
    threshold_mm: FloatArray
    reach: ReachTimes


@dataclass(frozen=True)
class TrackTrends:
    """A track's data, histories and forecasts.

    ``row_unit`` ``(m,)`` is each row's history, rows from before its last repair included
    (``histories.row_history`` leaves them out); ``wire_type`` ``(h,)`` indexes
    ``wire_type_names`` (-1: unknown, or no row since the last repair).
    """

    data: TrackData
    histories: SpanHistories
    row_unit: IntArray
    wire_type: IntArray
    wire_type_names: list[str]
    limits: list[LimitForecast]


def track_trends(
    session: Session,
    track_id: int,
    wire_types: Mapping[str, WireType],
    policy: LimitPolicy | None,
    rows_where: ColumnElement[bool] | None = None,
) -> TrackTrends:
    """Read track ``track_id`` (its complete runs' latest processings; ``rows_where``: only
    those span rows, ``TrackData``) and forecast the local rules of ``policy`` (none without
    one) on its histories. Raises ``UserError`` for a policy limit a wire type cannot
    reach."""
    types = [wire_types[name] for name in sorted(wire_types)]
    names = [w.name for w in types]
    data = TrackData(session, track_id, names or ["-"], rows_where)  # none: a CASE of no WHEN
    rows = data.rows
    hist = span_histories(rows, data.repairs)
    keys = history_keys(hist.mast_from, hist.mast_to, hist.start_m, hist.end_m, hist.position)
    row_keys = history_keys(
        rows.mast_from, rows.mast_to, rows.start_m, rows.end_m, hist.row_position
    )
    wire_type = take(rows.wire_type, hist.latest, -1)
    rules = [r for r in rules_of(policy, types) if r.rule.scope == LOCAL] if policy else []
    limits = []
    for rule in rules:
        threshold = rule.limit(wire_type)
        limits.append(LimitForecast(rule, threshold, reach_times(hist.fit, threshold)))
    return TrackTrends(
        data=data,
        histories=hist,
        row_unit=match_units(keys, row_keys),
        wire_type=wire_type,
        wire_type_names=names,
        limits=limits,
    )


def chosen_histories(
    trends: TrackTrends, where: str, mast: str | None, from_m: float | None, to_m: float | None
) -> IntArray:
    """The histories of the span starting at mast ``mast``, or of the spans between ``from_m``
    and ``to_m`` [m], by chainage and position; a ``UserError`` (naming the track ``where``)
    for an unknown mast or no span measured there."""
    hist, data = trends.histories, trends.data
    if mast is not None:
        index = int(data.mast_index([mast])[0])
        if index < 0:
            codes = data.mast_code
            known = f"masts {codes[0]} to {codes[-1]}" if codes else "no mast register"
            raise UserError(f"{where} has no mast {mast!r} ({known})")
        found = np.flatnonzero(hist.mast_from == index)
        if found.shape[0] == 0:
            raise UserError(f"{where}: no span measured from mast {mast!r}")
    else:
        if from_m is None or to_m is None:
            raise UserError("give a mast, or both ends of a chainage range")
        found = np.flatnonzero((hist.start_m < to_m) & (hist.end_m > from_m))
        if found.shape[0] == 0:
            raise UserError(f"{where}: no span measured between {from_m:g} and {to_m:g} m")
    return found[np.lexsort((hist.position[found], hist.start_m[found]))]


def history_rows(trends: TrackTrends, h: int) -> IntArray:
    """The span rows of history ``h`` (those before its last repair too), oldest run first."""
    rows = trends.data.rows
    found = np.flatnonzero(trends.row_unit == h)
    return found[np.lexsort((rows.run_id[found], rows.time_years[found]))]


def span_trends(
    session: Session,
    track_id: int,
    where: str,
    wire_types: Mapping[str, WireType],
    policy: LimitPolicy | None,
    *,
    mast: str | None = None,
    from_m: float | None = None,
    to_m: float | None = None,
) -> tuple[TrackTrends, IntArray]:
    """The trends of the span starting at mast ``mast`` (or of the spans between ``from_m``
    and ``to_m`` [m]) of track ``track_id``, reading only their rows, and their histories
    (``chosen_histories``); a ``UserError`` naming ``where`` when the track has no complete
    run or nothing was measured there."""
    sm = SpanMeasurement
    if mast is not None:
        rows_where = sm.mast_from == mast
    elif from_m is not None and to_m is not None:
        rows_where = (sm.start_chainage_m < to_m) & (sm.end_chainage_m > from_m)
    else:
        raise UserError("give a mast, or both ends of a chainage range")
    trends = track_trends(session, track_id, wire_types, policy, rows_where)
    if trends.data.run_id.shape[0] == 0:
        raise UserError(f"{where} has no complete run")
    return trends, chosen_histories(trends, where, mast, from_m, to_m)


@dataclass(frozen=True)
class RunComparison:
    """A run's span rows beside those of the track's previous complete run, matched by history
    (each ``(k,)``): ``now`` and ``then`` are rows of ``TrackTrends.data.rows``, ``wear_mm``
    the minimum residual thickness lost since (negative: thicker), ``wear_mm_per_year`` that
    over the ``years`` between the runs' starts; ``repaired`` where a repair lies between."""

    previous_run_id: int
    years: float
    now: IntArray
    then: IntArray
    wear_mm: FloatArray
    wear_mm_per_year: FloatArray
    repaired: BoolArray


def compare_with_previous(trends: TrackTrends, run_id: int) -> RunComparison | None:
    """Run ``run_id`` beside the latest complete run of its track that started before it,
    worst wear first; None when the run is not among the track's complete runs or has no
    earlier one."""
    data, rows = trends.data, trends.data.rows
    at = np.flatnonzero(data.run_id == run_id)
    if at.shape[0] == 0:
        return None
    moment = data.run_years[at[0]]
    earlier = np.flatnonzero(data.run_years < moment)
    if earlier.shape[0] == 0:
        return None
    previous = earlier[np.lexsort((data.run_id[earlier], data.run_years[earlier]))[-1]]
    previous_id, years = int(data.run_id[previous]), float(moment - data.run_years[previous])
    now = np.flatnonzero((rows.run_id == run_id) & (trends.row_unit >= 0))
    then_rows = np.flatnonzero(rows.run_id == previous_id)
    unit_then = trends.row_unit[then_rows].astype(np.float64)[:, None]
    match = match_units(unit_then, trends.row_unit[now].astype(np.float64)[:, None])
    found = match >= 0
    now, then = now[found], then_rows[match[found]]
    wear = rows.min_thickness_mm[then] - rows.min_thickness_mm[now]
    repaired_years = trends.histories.repaired_years[trends.row_unit[now]]
    repaired = repaired_years > rows.time_years[then]
    order = np.argsort(-wear, kind="stable")
    return RunComparison(
        previous_run_id=previous_id,
        years=years,
        now=now[order],
        then=then[order],
        wear_mm=wear[order],
        wear_mm_per_year=wear[order] / years,
        repaired=repaired[order],
    )
