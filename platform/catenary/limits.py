"""Wear limits: operators' rules as data, and what they mean for one wire type.

A ``LimitPolicy`` is an operator's set of ``LimitRule``s, each met at a loss of cross-section
(``worn_fraction``) or at a residual thickness, for every wire type or a listed few, at one
point of the wire (``local``) or on average over an anchor section. Policies live in TOML
files (layout in the built-in presets, ``catenary_wiretypes.PRESETS_PATH``)::

    [policies.db-ril-997]
    description = "..."
    source = "..."

    [[policies.db-ril-997.rules]]
    level = "urgent"                 # plan | urgent | critical
    action = "replace the contact wire"
    scope = "local"                  # local | anchor_section_average
    worn_fraction = 0.20             # or residual_thickness_mm = 10.0
    inclusive = true                 # met at the value (default) or only beyond it
    wire_types = ["AC-120"]          # optional: default all wire types

A policy also holds **geometry rules**, beside the wear rules (a policy needs at least one rule
of either kind)::

    [[policies.db-ril-997.geometry]]
    check = "stagger"                # see GEOMETRY_CHECKS
    level = "urgent"
    action = "re-register the wire"
    max_abs_mm = 300.0               # stagger: |stagger| at most this (the pantograph's range)
    min_speed_kmh = 200.0            # optional: only where the line speed is above this
    max_speed_kmh = 400.0            # optional: only where it is at most this

``check`` is one of

- ``height``: the span's contact wire height within ``min_mm`` and/or ``max_mm``;
- ``height_gradient``: the height change between the span's two masts (the medians within
  1 m of each) over the span's length at most ``max_per_mille`` (1/1000);
- ``stagger``: the span's stagger within ``max_abs_mm`` either side of the track centre;
- ``design_stagger``, ``design_height``: the wire's median stagger (height) within 1 m of the
  span's first mast within ``tolerance_mm`` of the register's ``design_stagger_mm``
  (``design_height_mm``): a condition of the mast, shown on the span that starts there.

The line speed of a span is the register's ``line_speed_kmh`` at its first mast, else its
line's in the config (``[maintenance] line_speed_kmh = {LINE = km/h}``); a rule with a speed
band does not apply to spans without one. ``catenary.maintenance.alerts.geometry`` compares
them (running wires only); a geometry alert is resolved by a run back within its limit by
2 mm, or by a maintenance action ``adjusted`` covering it.

``thresholds(wire, policy)`` expresses every rule that applies to a wire type as residual
thickness, worn fraction and wear width together. A user's config names a policy in an
optional ``[limits]`` section: ``policy = "<name>"`` and, for their own file instead of the
presets, ``file = "<path>"`` (``policy_from_config``). Without one, alerts are evaluated with
each wire type's own standard limit (``standard_policy``: its profile's published minimum
residual thickness, else the manufacturers' 30 % rule).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from catenary.config import Settings
from catenary.errors import UserError
from catenary.wiretype import STANDARD_WORN_FRACTION, ProfileRangeError, WireType

LEVELS = ("plan", "urgent", "critical")
"""Alert levels, least to most severe: schedule work, act before the next run, end of life."""

SCOPES = ("local", "anchor_section_average")
"""Where a rule is measured: at any point, or as the mean over an anchor section."""

_RULE_KEYS = {
    "level",
    "action",
    "scope",
    "worn_fraction",
    "residual_thickness_mm",
    "inclusive",
    "wire_types",
}
_POLICY_KEYS = {"description", "source", "rules", "geometry"}

GEOMETRY_CHECKS = ("height", "height_gradient", "stagger", "design_stagger", "design_height")
"""What a geometry rule checks (the module docstring)."""

_GEOMETRY_LIMITS = {
    "height": ("min_mm", "max_mm"),
    "height_gradient": ("max_per_mille",),
    "stagger": ("max_abs_mm",),
    "design_stagger": ("tolerance_mm",),
    "design_height": ("tolerance_mm",),
}
_GEOMETRY_KEYS = {
    "check",
    "level",
    "action",
    "min_speed_kmh",
    "max_speed_kmh",
    *(key for keys in _GEOMETRY_LIMITS.values() for key in keys),
}
_CONFIG_KEYS = {"policy", "file"}


@dataclass(frozen=True)
class LimitRule:
    """One rule of a policy: met at ``worn_fraction`` or at ``residual_thickness_mm``.

    Exactly one criterion is set. ``inclusive`` says whether the rule is met when the value is
    reached (``>=`` loss, ``<=`` thickness) or only beyond it. ``wire_types`` limits the rule
    to those wire types (empty: all). ``action`` keeps the operator's own words.
    """

    level: str
    scope: str
    worn_fraction: float | None = None
    residual_thickness_mm: float | None = None
    wire_types: tuple[str, ...] = ()
    action: str = ""
    inclusive: bool = True

    def __post_init__(self) -> None:
        if self.level not in LEVELS:
            raise ValueError(f"level must be one of {', '.join(LEVELS)}, not {self.level!r}")
        if self.scope not in SCOPES:
            raise ValueError(f"scope must be one of {', '.join(SCOPES)}, not {self.scope!r}")
        if (self.worn_fraction is None) == (self.residual_thickness_mm is None):
            raise ValueError("give exactly one of worn_fraction and residual_thickness_mm")
        if self.worn_fraction is not None and not 0.0 < self.worn_fraction < 1.0:
            raise ValueError(f"worn_fraction must be between 0 and 1, not {self.worn_fraction}")
        if self.residual_thickness_mm is not None and not (
            0.0 < self.residual_thickness_mm < math.inf
        ):
            raise ValueError(
                f"residual_thickness_mm must be positive, not {self.residual_thickness_mm}"
            )

    def applies_to(self, wire_type: str) -> bool:
        """Whether the rule covers wire type ``wire_type`` (by name)."""
        return not self.wire_types or wire_type in self.wire_types

    @property
    def criterion(self) -> str:
        """The criterion as text, e.g. ``"worn fraction >= 0.20"``."""
        if self.worn_fraction is not None:
            return f"worn fraction {'>=' if self.inclusive else '>'} {self.worn_fraction:.2f}"
        comparison = "<=" if self.inclusive else "<"
        return f"residual thickness {comparison} {self.residual_thickness_mm} mm"


@dataclass(frozen=True)
class GeometryRule:
    """A geometry rule of a policy (``check`` and its limits: the module docstring) [mm,
    1/1000, km/h]; NaN where a limit is not given. It applies where the line speed lies in
    ``(min_speed_kmh, max_speed_kmh]`` (NaN: no bound, and no line speed needed)."""

    check: str
    level: str
    action: str = ""
    min_mm: float = math.nan
    max_mm: float = math.nan
    max_per_mille: float = math.nan
    max_abs_mm: float = math.nan
    tolerance_mm: float = math.nan
    min_speed_kmh: float = math.nan
    max_speed_kmh: float = math.nan

    def __post_init__(self) -> None:
        if self.check not in GEOMETRY_CHECKS:
            raise ValueError(f"check must be one of {', '.join(GEOMETRY_CHECKS)}")
        if self.level not in LEVELS:
            raise ValueError(f"level must be one of {', '.join(LEVELS)}, not {self.level!r}")
        given = [k for k in _GEOMETRY_LIMITS[self.check] if math.isfinite(getattr(self, k))]
        if not given:
            raise ValueError(f"{self.check}: give {' or '.join(_GEOMETRY_LIMITS[self.check])}")

    @property
    def speed_band(self) -> bool:
        return math.isfinite(self.min_speed_kmh) or math.isfinite(self.max_speed_kmh)

    @property
    def criterion(self) -> str:
        """The rule as text, e.g. ``"|stagger| <= 300 mm (line speed > 200 km/h)"``."""
        if self.check == "height":
            parts = []
            if math.isfinite(self.min_mm):
                parts.append(f"height >= {self.min_mm:g} mm")
            if math.isfinite(self.max_mm):
                parts.append(f"height <= {self.max_mm:g} mm")
            text = " and ".join(parts)
        elif self.check == "height_gradient":
            text = f"|height gradient| <= {self.max_per_mille:g} per mille"
        elif self.check == "stagger":
            text = f"|stagger| <= {self.max_abs_mm:g} mm"
        else:
            what = self.check.removeprefix("design_")
            text = f"{what} at the mast within {self.tolerance_mm:g} mm of design"
        band = []
        if math.isfinite(self.min_speed_kmh):
            band.append(f"> {self.min_speed_kmh:g} km/h")
        if math.isfinite(self.max_speed_kmh):
            band.append(f"<= {self.max_speed_kmh:g} km/h")
        return text + (f" (line speed {' and '.join(band)})" if band else "")


@dataclass(frozen=True)
class LimitPolicy:
    """An operator's limits: a named, sourced list of wear rules and of geometry rules."""

    name: str
    description: str
    source: str
    rules: tuple[LimitRule, ...]
    geometry: tuple[GeometryRule, ...] = ()


@dataclass(frozen=True)
class Threshold:
    """A rule of ``policy`` applied to ``wire_type``: the same limit in three measures.

    The rule is met when the residual thickness falls to ``residual_thickness_mm`` (the worn
    fraction rises to ``worn_fraction``, the wear face widens to ``wear_width_mm``); beyond it
    only, when ``rule.inclusive`` is false.
    """

    policy: str
    rule_number: int
    rule: LimitRule
    wire_type: str
    residual_thickness_mm: float
    worn_fraction: float
    wear_width_mm: float

    @property
    def level(self) -> str:
        return self.rule.level

    @property
    def scope(self) -> str:
        return self.rule.scope

    @property
    def action(self) -> str:
        return self.rule.action


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value)


def _table(raw: Any, where: str, known: set[str], required: tuple[str, ...]) -> dict[str, Any]:
    """``raw`` if it is a table of ``known`` keys that holds the ``required`` ones; else a
    ``UserError`` naming ``where`` and the key."""
    if not isinstance(raw, dict):
        raise UserError(f"{where}: must be a table, not {raw!r}")
    unknown = sorted(set(raw) - known)
    if unknown:
        raise UserError(f"{where}: unknown key {unknown[0]!r} (known: {', '.join(sorted(known))})")
    for key in required:
        if key not in raw:
            raise UserError(f"{where}: missing key {key!r}")
    return raw


def _parse_rule(raw: Any, where: str) -> LimitRule:
    raw = _table(raw, where, _RULE_KEYS, ("level", "scope"))
    level, scope = raw["level"], raw["scope"]
    if level not in LEVELS:
        raise UserError(f"{where}: level must be one of {', '.join(LEVELS)}, not {level!r}")
    if scope not in SCOPES:
        raise UserError(f"{where}: scope must be one of {', '.join(SCOPES)}, not {scope!r}")
    has_fraction = "worn_fraction" in raw
    has_thickness = "residual_thickness_mm" in raw
    if has_fraction == has_thickness:
        raise UserError(f"{where}: give exactly one of worn_fraction and residual_thickness_mm")
    worn_fraction = residual_thickness = None
    if has_fraction:
        worn_fraction = _number(raw["worn_fraction"])
        if worn_fraction is None or not 0.0 < worn_fraction < 1.0:
            raise UserError(
                f"{where}: worn_fraction must be a number between 0 and 1 (0.2 = 20 %), "
                f"not {raw['worn_fraction']!r}"
            )
    else:
        residual_thickness = _number(raw["residual_thickness_mm"])
        if residual_thickness is None or not 0.0 < residual_thickness < math.inf:
            raise UserError(
                f"{where}: residual_thickness_mm must be a positive number of mm, "
                f"not {raw['residual_thickness_mm']!r}"
            )
    wire_types = raw.get("wire_types", [])
    if not isinstance(wire_types, list) or not all(isinstance(x, str) for x in wire_types):
        raise UserError(f"{where}: wire_types must be a list of wire type names")
    action = raw.get("action", "")
    if not isinstance(action, str):
        raise UserError(f"{where}: action must be a string, not {action!r}")
    inclusive = raw.get("inclusive", True)
    if not isinstance(inclusive, bool):
        raise UserError(f"{where}: inclusive must be true or false, not {inclusive!r}")
    return LimitRule(
        level=level,
        scope=scope,
        worn_fraction=worn_fraction,
        residual_thickness_mm=residual_thickness,
        wire_types=tuple(wire_types),
        action=action,
        inclusive=inclusive,
    )


def _parse_geometry(raw: Any, where: str) -> GeometryRule:
    raw = _table(raw, where, _GEOMETRY_KEYS, ("check", "level"))
    check, level = raw["check"], raw["level"]
    if check not in GEOMETRY_CHECKS:
        raise UserError(
            f"{where}: check must be one of {', '.join(GEOMETRY_CHECKS)}, not {check!r}"
        )
    if level not in LEVELS:
        raise UserError(f"{where}: level must be one of {', '.join(LEVELS)}, not {level!r}")
    allowed = set(_GEOMETRY_LIMITS[check])
    values: dict[str, float] = {}
    for key in sorted(set(raw) & (_GEOMETRY_KEYS - {"check", "level", "action"})):
        if key not in allowed and key not in ("min_speed_kmh", "max_speed_kmh"):
            raise UserError(
                f"{where}: {key} is not a limit of check {check!r} "
                f"(its limits: {', '.join(_GEOMETRY_LIMITS[check])})"
            )
        value = _number(raw[key])
        if value is None or not math.isfinite(value) or (value <= 0 and key != "min_speed_kmh"):
            raise UserError(f"{where}: {key} must be a positive number, not {raw[key]!r}")
        if value < 0:
            raise UserError(f"{where}: {key} must be 0 or more, not {raw[key]!r}")
        values[key] = value
    if not allowed & set(values):
        raise UserError(f"{where}: check {check!r} needs {' or '.join(sorted(allowed))}")
    if values.get("min_mm", -math.inf) >= values.get("max_mm", math.inf):
        raise UserError(f"{where}: min_mm must be below max_mm")
    if values.get("min_speed_kmh", -math.inf) >= values.get("max_speed_kmh", math.inf):
        raise UserError(f"{where}: min_speed_kmh must be below max_speed_kmh")
    action = raw.get("action", "")
    if not isinstance(action, str):
        raise UserError(f"{where}: action must be a string, not {action!r}")
    return GeometryRule(check=check, level=level, action=action, **values)


def _parse_policy(name: str, raw: Any, origin: str) -> LimitPolicy:
    where = f"{origin}: policy {name!r}"
    if not isinstance(raw, dict):
        raise UserError(f"{where}: must be a table")
    unknown = sorted(set(raw) - _POLICY_KEYS)
    if unknown:
        raise UserError(
            f"{where}: unknown key {unknown[0]!r} (known: {', '.join(sorted(_POLICY_KEYS))})"
        )
    texts: dict[str, str] = {}
    for key in ("description", "source"):
        value = raw.get(key, "")
        if not isinstance(value, str):
            raise UserError(f"{where}: {key} must be a string, not {value!r}")
        texts[key] = value
    rules, geometry = raw.get("rules", []), raw.get("geometry", [])
    for key, value in (("rules", rules), ("geometry", geometry)):
        if not isinstance(value, list):
            raise UserError(f"{where}: {key} must be [[policies.{name}.{key}]] tables")
    if not rules and not geometry:
        raise UserError(
            f"{where}: needs at least one [[policies.{name}.rules]] or "
            f"[[policies.{name}.geometry]] table"
        )
    return LimitPolicy(
        name=name,
        description=texts["description"],
        source=texts["source"],
        rules=tuple(
            _parse_rule(rule, f"{where} rule {number}") for number, rule in enumerate(rules, 1)
        ),
        geometry=tuple(
            _parse_geometry(rule, f"{where} geometry rule {number}")
            for number, rule in enumerate(geometry, 1)
        ),
    )


def parse_policies(text: str, origin: str = "<policy text>") -> dict[str, LimitPolicy]:
    """Policies from TOML ``text``, by name; ``origin`` names the text in error messages.

    Raises ``UserError`` (one line naming ``origin``, the policy, the rule and the key) on
    invalid TOML or a bad value.
    """
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"{origin}: invalid TOML: {exc}") from None
    unknown = sorted(set(data) - {"policies"})
    if unknown:
        raise UserError(f"{origin}: unknown key {unknown[0]!r} (policies go in [policies.NAME])")
    policies = data.get("policies")
    if not isinstance(policies, dict) or not policies:
        raise UserError(f"{origin}: no policies (expected [policies.NAME] tables)")
    return {name: _parse_policy(name, raw, origin) for name, raw in policies.items()}


def load_policies(path: Path | str) -> dict[str, LimitPolicy]:
    """Policies from the TOML file at ``path``, by name (errors name the file)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UserError(f"{path}: policy file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: cannot read policy file: {exc}") from None
    return parse_policies(text, origin=str(path))


def select_policy(
    policies: Mapping[str, LimitPolicy], name: str, origin: str = "policies"
) -> LimitPolicy:
    """The policy called ``name``; an unknown name is a ``UserError`` listing the known ones."""
    try:
        return policies[name]
    except KeyError:
        known = ", ".join(sorted(policies)) or "none"
        raise UserError(f"{origin}: unknown policy {name!r} (known: {known})") from None


def policy_from_config(
    section: Mapping[str, Any] | None,
    *,
    presets: Mapping[str, LimitPolicy],
    config_path: Path | None = None,
) -> LimitPolicy | None:
    """The policy a config's ``[limits]`` section names, or None without one.

    ``policy`` names a policy; ``file`` (relative to the config file's folder) is the user's
    own policy file, else ``presets`` (the policies plugins register) are used. With ``file``
    holding a single policy, ``policy`` may be left out.
    """
    if section is None:
        return None
    where = f"{config_path or 'config'}: [limits]"
    if not isinstance(section, Mapping):
        raise UserError(f"{where} must be a table")
    unknown = sorted(set(section) - _CONFIG_KEYS)
    if unknown:
        raise UserError(
            f"{where}: unknown key {unknown[0]!r} (known: {', '.join(sorted(_CONFIG_KEYS))})"
        )
    name = section.get("policy")
    if name is not None and not isinstance(name, str):
        raise UserError(f"{where}: policy must be a policy name, not {name!r}")
    file = section.get("file")
    if file is not None and not isinstance(file, str):
        raise UserError(f"{where}: file must be a path, not {file!r}")
    policies: Mapping[str, LimitPolicy] = presets
    origin = "wear-limit presets"
    if file is not None:
        path = Path(file).expanduser()
        if not path.is_absolute() and config_path is not None:
            path = config_path.parent / path
        policies, origin = load_policies(path), str(path)
    if name is None:
        if file is None or len(policies) != 1:
            raise UserError(
                f'{where}: name a policy (policy = "..."; known: {", ".join(sorted(policies))})'
            )
        (name,) = policies
    return select_policy(policies, name, origin=origin)


STANDARD_POLICY = "standard-limits"
"""The name of the policy evaluated without one configured (``standard_policy``)."""


def standard_policy(wire_types: Mapping[str, WireType]) -> LimitPolicy:
    """Each wire type's own standard limit (``WireType.standard_limit``): a critical local
    rule at its published minimum residual thickness, or at the manufacturers' 30 % loss of
    cross-section for the wire types with none published."""
    published = sorted(n for n, w in wire_types.items() if w.published_min_mm is not None)
    others = tuple(sorted(n for n in wire_types if n not in published))
    rules = [
        LimitRule(
            level="critical",
            scope="local",
            residual_thickness_mm=wire_types[name].published_min_mm,
            wire_types=(name,),
            action="the profile's published minimum residual thickness reached",
        )
        for name in published
    ]
    if others:
        rules.append(
            LimitRule(
                level="critical",
                scope="local",
                worn_fraction=STANDARD_WORN_FRACTION,
                wire_types=others,
                action="the manufacturers' allowable wear reached (30 % loss of cross-section)",
            )
        )
    return LimitPolicy(
        name=STANDARD_POLICY,
        description=(
            "each wire type's standard limit: its profile's published minimum residual "
            "thickness, else the manufacturers' 30 % loss of cross-section"
        ),
        source="the wire types' profiles; reference/wire-profiles.md, 'Wear limits in use'",
        rules=tuple(rules),
    )


def choose_policy(
    settings: Settings,
    presets: Mapping[str, LimitPolicy],
    name: str | None = None,
    policy_file: Path | None = None,
    *,
    wire_types: Mapping[str, WireType] | None = None,
) -> LimitPolicy | None:
    """The policy a command is told to use, or None without one.

    ``name`` (``--policy``) picks one of ``policy_file``'s policies (``--policy-file``; a file
    of a single policy needs no name), else of the ``presets``; with neither, the config's
    ``[limits]`` section (``policy_from_config``) decides, and without one, given
    ``wire_types``, their standard limits (``standard_policy``).
    """
    if policy_file is not None:
        policies = load_policies(policy_file)
        if name is None:
            if len(policies) != 1:
                known = ", ".join(sorted(policies))
                raise UserError(
                    f"{policy_file}: holds several policies, choose one with --policy ({known})"
                )
            (name,) = policies
        return select_policy(policies, name, origin=str(policy_file))
    if name is not None:
        return select_policy(presets, name, origin="wear-limit presets")
    configured = policy_from_config(
        settings.sections.get("limits"), presets=presets, config_path=settings.config_path
    )
    if configured is None and wire_types:
        return standard_policy(wire_types)
    return configured


def thresholds(wire: WireType, policy: LimitPolicy) -> list[Threshold]:
    """Every rule of ``policy`` that applies to ``wire``, in rule order, in three measures.

    A worn-fraction rule is turned into a wear width by the inverse of ``worn_fraction``
    (``WireType.wear_width_for_worn_fraction``) and then a thickness; a thickness rule into a
    width by the inverse of eq. 1 and then a worn fraction. A limit the profile cannot reach
    is a ``UserError`` naming the policy, rule and wire type.
    """
    found: list[Threshold] = []
    for number, rule in enumerate(policy.rules, 1):
        if not rule.applies_to(wire.name):
            continue
        try:
            if rule.worn_fraction is not None:
                width = float(wire.wear_width_for_worn_fraction(rule.worn_fraction))
                thickness = float(wire.residual_thickness_mm(width))
                fraction = rule.worn_fraction
            else:
                assert rule.residual_thickness_mm is not None
                thickness = rule.residual_thickness_mm
                width = float(wire.wear_width_mm(thickness))
                fraction = float(wire.worn_fraction(width))
        except ProfileRangeError as exc:
            raise UserError(
                f"policy {policy.name!r} rule {number} ({rule.criterion}): {exc}"
            ) from None
        found.append(
            Threshold(
                policy=policy.name,
                rule_number=number,
                rule=rule,
                wire_type=wire.name,
                residual_thickness_mm=thickness,
                worn_fraction=fraction,
                wear_width_mm=width,
            )
        )
    return found


__all__ = [
    "GEOMETRY_CHECKS",
    "LEVELS",
    "SCOPES",
    "STANDARD_POLICY",
    "GeometryRule",
    "LimitPolicy",
    "LimitRule",
    "Threshold",
    "choose_policy",
    "load_policies",
    "parse_policies",
    "policy_from_config",
    "select_policy",
    "standard_policy",
    "thresholds",
]
