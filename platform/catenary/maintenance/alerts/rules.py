"""The alert rules: a policy's limits per wire type, and the planning horizon."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from catenary.arrays import BoolArray, FloatArray, IntArray, take
from catenary.config import Settings
from catenary.errors import UserError
from catenary.limits import GeometryRule, LimitPolicy, LimitRule, thresholds
from catenary.storage.models import NAME_LENGTH
from catenary.wiretype import WireType

__all__ = [
    "DEFAULT_HORIZON_DAYS",
    "LOCAL",
    "SECTION",
    "Rule",
    "check_policy",
    "geometry_rules_of",
    "horizon_days",
    "line_speeds",
    "rules_of",
]


DEFAULT_HORIZON_DAYS = 365.0
"""Planning horizon of the forecasts without ``[maintenance] horizon_days``."""

LOCAL, SECTION = "local", "anchor_section_average"
"""The rules' scopes: one span's minimum, an anchor section's average."""

_MAINTENANCE_KEYS = {"horizon_days", "line_speed_kmh"}
_MAX_SPEED_KMH = 1000.0


def _maintenance(settings: Settings) -> tuple[Mapping[str, Any], str]:
    """The config's ``[maintenance]`` section (empty without one) and its name for errors."""
    section = settings.sections.get("maintenance", {})
    where = f"{settings.config_path or 'config'}: [maintenance]"
    if not isinstance(section, Mapping):
        raise UserError(f"{where} must be a table")
    unknown = sorted(set(section) - _MAINTENANCE_KEYS)
    if unknown:
        known = ", ".join(sorted(_MAINTENANCE_KEYS))
        raise UserError(f"{where}: unknown key {unknown[0]!r} (known: {known})")
    return section, where


def line_speeds(settings: Settings) -> dict[str, float]:
    """Each line's speed [km/h] by line code: ``[maintenance] line_speed_kmh = {L100 = 160}``
    (empty without one); the geometry rules use it where the register gives no
    ``line_speed_kmh``."""
    section, where = _maintenance(settings)
    table = section.get("line_speed_kmh", {})
    if not isinstance(table, Mapping):
        raise UserError(f"{where}: line_speed_kmh must be a table of line code = km/h")
    speeds: dict[str, float] = {}
    for line, value in table.items():
        if isinstance(value, bool) or not isinstance(value, int | float):
            value = math.nan
        if not 0 < value <= _MAX_SPEED_KMH:
            raise UserError(
                f"{where}: line_speed_kmh.{line} must be a speed from 0 to "
                f"{_MAX_SPEED_KMH:g} km/h, not {table[line]!r}"
            )
        speeds[str(line)] = float(value)
    return speeds


def horizon_days(settings: Settings) -> float:
    """The planning horizon [days]: ``[maintenance] horizon_days``, default 365."""
    section, where = _maintenance(settings)
    value = section.get("horizon_days", DEFAULT_HORIZON_DAYS)
    if isinstance(value, bool) or not isinstance(value, int | float) or not 1 <= value <= 36525:
        raise UserError(
            f"{where}: horizon_days must be a number of days from 1 to 36525, not {value!r}"
        )
    return float(value)


# --- the rules ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Rule:
    """A policy rule with its threshold per wire type (index into the evaluation's wire type
    names; NaN where the rule does not apply)."""

    number: int
    rule: LimitRule
    name: str  # "policy#number", Alert.rule
    thickness_mm: FloatArray  # (w,)
    worn_fraction: FloatArray  # (w,)

    def limit(self, wire_type: IntArray) -> FloatArray:
        """The threshold [mm] for each wire type index (-1 and -2: NaN)."""
        return take(self.thickness_mm, np.maximum(wire_type, -1), np.nan)

    def met(self, value_mm: FloatArray, limit_mm: FloatArray) -> BoolArray:
        return np.asarray(value_mm <= limit_mm if self.rule.inclusive else value_mm < limit_mm)


def rules_of(policy: LimitPolicy, wire_types: Sequence[WireType]) -> list[Rule]:
    if len(policy.name) + 8 > NAME_LENGTH:
        raise UserError(
            f"policy name {policy.name[:40]!r}...: at most {NAME_LENGTH - 8} characters"
        )
    count = len(wire_types)
    thickness = {n: np.full(count, np.nan) for n in range(1, len(policy.rules) + 1)}
    fraction = {n: np.full(count, np.nan) for n in range(1, len(policy.rules) + 1)}
    for index, wire in enumerate(wire_types):
        for t in thresholds(wire, policy):
            thickness[t.rule_number][index] = t.residual_thickness_mm
            fraction[t.rule_number][index] = t.worn_fraction
    return [
        Rule(n, rule, f"{policy.name}#{n}", thickness[n], fraction[n])
        for n, rule in enumerate(policy.rules, 1)
    ]


def geometry_rules_of(policy: LimitPolicy) -> list[tuple[str, GeometryRule]]:
    """The policy's geometry rules by their ``Alert.rule`` name, ``"policy#g<number>"``."""
    return [(f"{policy.name}#g{n}", rule) for n, rule in enumerate(policy.geometry, 1)]


def check_policy(policy: LimitPolicy, wire_types: Mapping[str, WireType]) -> None:
    """Raise ``UserError`` unless every rule of ``policy`` can be evaluated on every wire type
    (before anything is written: ``evaluate_alerts`` would refuse it)."""
    rules_of(policy, [wire_types[name] for name in sorted(wire_types)])
