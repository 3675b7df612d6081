"""Built-in wire types: the EN 50149 and TB/T 2809 contact wire profiles, and limit presets.

The profiles are data (``profiles.toml``, read with ``importlib.resources``); so are the
operators' wear limits (``limits.toml``, at ``PRESETS_PATH``, read by
``catenary.limits.load_policies``). This plugin is registered through the ``catenary.plugins``
entry point exactly as a third party's would be.
"""

from __future__ import annotations

import tomllib
from importlib.resources import files
from pathlib import Path
from typing import Any

from catenary.limits import LimitPolicy, load_policies
from catenary.plugins import hookimpl
from catenary.wiretype import WireType

PROFILES_RESOURCE = "profiles.toml"
PRESETS_PATH = Path(__file__).with_name("limits.toml")
"""The wear-limit presets shipped with catenary (``catenary.limits.load_policies``)."""

_FIELDS = {
    "name": str,
    "standard": str,
    "height_mm": float,
    "width_mm": float,
    "area_mm2": float,
    "nominal_area_mm2": float,
    "legacy": bool,
    "source": str,
}
_OPTIONAL = {"min_residual_thickness_mm": float}


def _wire_type(raw: Any, number: int) -> WireType:
    where = f"{PROFILES_RESOURCE}: profile {number}"
    if not isinstance(raw, dict):
        raise ValueError(f"{where}: must be a table")
    where = f"{PROFILES_RESOURCE}: profile {raw.get('name', number)!r}"
    unknown = sorted(set(raw) - set(_FIELDS) - set(_OPTIONAL))
    if unknown:
        raise ValueError(f"{where}: unknown key {unknown[0]!r}")
    values: dict[str, Any] = {}
    for key, kind in (_FIELDS | _OPTIONAL).items():
        if key not in raw:
            if key in _OPTIONAL:
                continue
            raise ValueError(f"{where}: missing key {key!r}")
        value = raw[key]
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, kind):
            raise ValueError(f"{where}: {key} must be a {kind.__name__}, not {value!r}")
        values["published_min_mm" if key in _OPTIONAL else key] = value
    return WireType(**values)


def load_profiles() -> list[WireType]:
    """The wire types in ``profiles.toml``, in file order."""
    text = files(__name__).joinpath(PROFILES_RESOURCE).read_text(encoding="utf-8")
    data = tomllib.loads(text)
    return [_wire_type(raw, number) for number, raw in enumerate(data.get("profiles", []), 1)]


@hookimpl
def catenary_wire_types() -> list[WireType]:
    """The EN 50149 (AC-80 ... AC-150) and TB/T 2809 (CTA85 ... CTMH150) profiles."""
    return load_profiles()


@hookimpl
def catenary_limit_policies() -> list[LimitPolicy]:
    """The operators' wear-limit rules of ``limits.toml`` as presets."""
    return list(load_policies(PRESETS_PATH).values())
