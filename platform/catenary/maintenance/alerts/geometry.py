"""Geometry rules on a track's span rows: what each rule compares and whether it is met.

A rule is checked on each history's latest row (``catenary.maintenance.alerts.trackdata``),
for the **running wires** only: those within ``RUNNING_LIFT_MM`` of the lowest wire at the
span's first mast (the design checks), and at its last mast too where the wire was measured
there (the others: at an overlap the wire leaving running rises towards its anchor within the
span, and its stagger lies further out). The register gives one design value per mast: where
two wires run at a mast (an overlap's middle mast), the design checks take the wire nearest
it. A row whose values or register entries the rule needs are missing is not evaluated (its
alerts are left as they are). Staggers are compared in the register's frame: positive to the right
looking towards increasing chainage (a run the other way has its sign undone).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from catenary.arrays import BoolArray, FloatArray, IntArray, take
from catenary.limits import GeometryRule

__all__ = [
    "GEOMETRY_MARGIN_MM",
    "RUNNING_LIFT_MM",
    "Checked",
    "GeometryRows",
    "MastGeometry",
    "check",
    "running",
]

GEOMETRY_MARGIN_MM = 2.0
"""A geometry alert is resolved by a run only when the wire is back within its limit by this
much [mm] (the measurement's height and stagger accuracy, DESIGN.md's 2 mm)."""


RUNNING_LIFT_MM = 20.0
"""A wire higher than the lowest at a mast by more than this [mm] is out of running there."""


def _groups(*keys: IntArray) -> IntArray:
    """A group number for each row of equal ``keys`` (each ``(m,)``)."""
    if keys[0].shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    _, group = np.unique(np.column_stack(keys), axis=0, return_inverse=True)
    return group.reshape(-1).astype(np.int64)


@dataclass(frozen=True)
class GeometryRows:
    """Geometry of a track's span rows ``(m,)`` [mm], as measured (NaN: not measured): the
    ranges over the span, and the medians within 1 m of its first (``start``) and last mast."""

    height_min_mm: FloatArray
    height_max_mm: FloatArray
    stagger_min_mm: FloatArray
    stagger_max_mm: FloatArray
    height_start_mm: FloatArray
    height_end_mm: FloatArray
    stagger_start_mm: FloatArray


@dataclass(frozen=True)
class MastGeometry:
    """A track's masts' register entries ``(n,)`` (NaN: not given) [mm, km/h]."""

    design_stagger_mm: FloatArray
    design_height_mm: FloatArray
    line_speed_kmh: FloatArray


@dataclass(frozen=True)
class Checked:
    """A rule on units ``(k,)``: the value compared and its limit (NaN: not evaluated), how far
    beyond the limit the wire is [mm of height or stagger; negative: within], and for the
    design checks the measured and design values [mm]."""

    value: FloatArray
    limit: FloatArray
    excess_mm: FloatArray
    measured_mm: FloatArray
    design_mm: FloatArray
    line_speed_kmh: FloatArray

    def met(self) -> BoolArray:
        return np.isfinite(self.limit) & (self.excess_mm > 0.0)

    def clear(self) -> BoolArray:
        return np.isfinite(self.limit) & (self.excess_mm < -GEOMETRY_MARGIN_MM)


def running(
    run_id: IntArray, mast: IntArray, span: IntArray, height_at_mast_mm: FloatArray
) -> BoolArray:
    """Whether each row ``(m,)`` is a running wire at one of its span's masts (``mast``, -1:
    none, and the wire's median height there): within ``RUNNING_LIFT_MM`` of the lowest wire
    there among the rows of its run and span (all of them when none has a height there)."""
    group = _groups(run_id, np.where(mast >= 0, mast, -1 - span))
    lowest = np.full(int(group.max()) + 1 if group.size else 0, np.inf)
    finite = np.isfinite(height_at_mast_mm)
    np.minimum.at(lowest, group[finite], height_at_mast_mm[finite])
    none_known = ~np.isfinite(lowest[group])
    near = height_at_mast_mm <= lowest[group] + RUNNING_LIFT_MM
    out: BoolArray = none_known | (finite & near)
    return out


def _nearest(group: IntArray, deviation: FloatArray) -> BoolArray:
    """Whether each row has the least finite ``deviation`` of its group (one per group)."""
    finite = np.flatnonzero(np.isfinite(deviation))
    order = finite[np.lexsort((deviation[finite], group[finite]))]
    first = order[np.r_[True, np.diff(group[order]) != 0]] if order.size else order
    out = np.zeros(deviation.shape, dtype=bool)
    out[first] = True
    return out


def _band(rule: GeometryRule, speed_kmh: FloatArray) -> BoolArray:
    if not rule.speed_band:
        return np.ones(speed_kmh.shape, dtype=bool)
    low = rule.min_speed_kmh if math.isfinite(rule.min_speed_kmh) else -np.inf
    high = rule.max_speed_kmh if math.isfinite(rule.max_speed_kmh) else np.inf
    return np.asarray(np.isfinite(speed_kmh) & (speed_kmh > low) & (speed_kmh <= high))


def check(
    rule: GeometryRule,
    geometry: GeometryRows,
    masts: MastGeometry,
    row: IntArray,
    run_id: IntArray,
    mast_from: IntArray,
    length_m: FloatArray,
    direction: FloatArray,
    running_start: BoolArray,
    running_end: BoolArray,
) -> Checked:
    """``rule`` on units ``(k,)`` whose latest rows are ``row`` (into ``geometry`` and
    ``running_start``, ``running_end``: ``running`` at the rows' first and last masts);
    ``run_id``, ``mast_from`` (-1: none), ``length_m`` and ``direction``
    (+1, -1) are the units' run, first mast, span length [m] and run direction."""
    g = geometry
    nan = np.full(row.shape, np.nan)
    speed = take(masts.line_speed_kmh, mast_from, np.nan)
    design_check = rule.check in ("design_stagger", "design_height")
    applies = _band(rule, speed) & running_start[row] & (design_check | running_end[row])
    measured = design = nan
    if rule.check == "height":
        low, high = g.height_min_mm[row], g.height_max_mm[row]
        below = (rule.min_mm - low) if math.isfinite(rule.min_mm) else np.full_like(low, -np.inf)
        above = (high - rule.max_mm) if math.isfinite(rule.max_mm) else np.full_like(high, -np.inf)
        upper = above >= below
        value = np.where(upper, high, low)
        limit = np.where(upper, rule.max_mm, rule.min_mm)
        excess = np.maximum(below, above)
    elif rule.check == "height_gradient":
        rise_mm = np.abs(g.height_end_mm[row] - g.height_start_mm[row])
        allowed_mm = rule.max_per_mille * length_m
        value = rise_mm / length_m
        limit = np.full(row.shape, rule.max_per_mille)
        excess = rise_mm - allowed_mm
    elif rule.check == "stagger":
        value = np.maximum(np.abs(g.stagger_min_mm[row]), np.abs(g.stagger_max_mm[row]))
        limit = np.full(row.shape, rule.max_abs_mm)
        excess = value - rule.max_abs_mm
    else:
        if rule.check == "design_stagger":
            measured = g.stagger_start_mm[row] * direction
            design = take(masts.design_stagger_mm, mast_from, np.nan)
        else:
            measured = g.height_start_mm[row]
            design = take(masts.design_height_mm, mast_from, np.nan)
        value = np.abs(measured - design)
        value = np.where(applies, value, np.nan)
        applies &= _nearest(_groups(run_id, mast_from), value)
        limit = np.full(row.shape, rule.tolerance_mm)
        excess = value - rule.tolerance_mm
    evaluated = applies & np.isfinite(value) & np.isfinite(excess)
    return Checked(
        value=np.where(evaluated, value, np.nan),
        limit=np.where(evaluated, limit, np.nan),
        excess_mm=np.where(evaluated, excess, np.nan),
        measured_mm=measured,
        design_mm=design,
        line_speed_kmh=speed,
    )
