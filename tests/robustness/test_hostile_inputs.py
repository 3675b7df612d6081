"""Hostile rig calibrations, vehicle geometries and mast registers (FORMATS.md): each is read or
refused with a one-line ``UserError`` naming the file, never another exception.

A valid document is mutated (a key removed, or its value replaced by any TOML value: wrong
types, NaN, infinities, huge numbers, nested tables and arrays); registers are rows of hostile
text (separators, quotes, control characters, numbers that are not finite) under any header.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import tomli_w
from hypothesis import given
from hypothesis import strategies as st

from catenary.errors import UserError
from catenary.measurement.masts import read_register
from catenary.measurement.vehicle import load_vehicle_geometry
from catenary_linescan.rig import read_rig

from .conftest import assert_names_file, examples

VEHICLE: dict[str, Any] = {
    "name": "tiny",
    "roof_height_mm": 3900.0,
    "sensor_height_mm": 1100.0,
    "sensor_baseline_mm": 1800.0,
}
RIG: dict[str, Any] = {
    "format": "catenary-rig",
    "format_version": 1,
    **VEHICLE,
    "cameras": [
        {"name": "a", "pixels": 64, "matrix": [[0.01, -0.005, 32.0], [0.0, 0.0002, 1.0]]},
        {
            "name": "b",
            "pixels": 64,
            "matrix": [[0.01, 0.005, 32.0], [0.0, 0.0002, 1.0]],
            "k1": 0.0,
            "resolution": {
                "x_mm": [-500.0, 500.0],
                "z_mm": [1000.0, 2000.0],
                "mm_per_px": [[0.5, 0.6], [0.5, 0.6]],
            },
        },
    ],
}
REGISTER_COLUMNS = (
    "line", "track", "mast", "chainage_m", "wire_type", "design_stagger_mm", "anchor_section",
)  # fmt: skip

TEXT = st.text(st.characters(exclude_categories=("Cs",)), max_size=8)
SCALARS = st.one_of(
    st.booleans(),
    st.integers(-(2**63), 2**63 - 1),
    st.floats(),
    st.sampled_from((math.nan, math.inf, -math.inf, 0.0, -1.0, 1e308)),
    TEXT,
)
TOML_VALUES = st.recursive(
    SCALARS,
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(TEXT, inner, max_size=3),
    max_leaves=6,
)
FIELDS = st.one_of(
    TEXT,
    st.sampled_from(("", "nan", "inf", "-1e400", "1e308", "CTA120", "M1", "L1", "=1+1", "\x1b[2J")),
    st.floats().map(repr),
)


def _places(document: Any, path: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every key path of a parsed TOML document (tables and arrays)."""
    items = document.items() if isinstance(document, dict) else enumerate(document)
    places = []
    for key, value in items:
        places.append((*path, key))
        if isinstance(value, dict | list):
            places += _places(value, (*path, key))
    return places


@st.composite
def mutated(draw: st.DrawFn, valid: dict[str, Any]) -> dict[str, Any]:
    """``valid`` (a copy) with one to three keys removed or given another value."""
    document = tomli_w_roundtrip(valid)
    for _ in range(draw(st.integers(1, 3))):
        places = _places(document)
        if not places:
            break
        *parents, key = draw(st.sampled_from(places))
        container = document
        for parent in parents:
            container = container[parent]
        if isinstance(container, dict) and draw(st.booleans()):
            del container[key]
        else:
            container[key] = draw(TOML_VALUES)
    return document


def tomli_w_roundtrip(document: dict[str, Any]) -> dict[str, Any]:
    """A deep copy of a TOML document."""
    import tomllib

    return tomllib.loads(tomli_w.dumps(document))


def read_or_refuse(read: Callable[[Path], object], path: Path) -> None:
    """``read(path)`` accepts the file, or refuses it in one line naming it."""
    try:
        read(path)
    except UserError as exc:
        assert_names_file(exc, path)


HOSTILE = examples(60)
DOCUMENTS: dict[str, tuple[dict[str, Any], Callable[[Path], object]]] = {
    "rig": (RIG, read_rig),
    "vehicle": (VEHICLE, load_vehicle_geometry),
}
"""A valid document of each kind, and what reads it."""


def test_the_valid_documents_are_read(examples_folder: Path) -> None:
    (examples_folder / "rig.toml").write_text(tomli_w.dumps(RIG))
    (examples_folder / "vehicle.toml").write_text(tomli_w.dumps(VEHICLE))
    assert sorted(read_rig(examples_folder / "rig.toml").cameras) == ["a", "b"]
    assert load_vehicle_geometry(examples_folder / "vehicle.toml").roof_height_mm == 3900.0


@pytest.mark.parametrize("kind", sorted(DOCUMENTS))
@HOSTILE
@given(data=st.data())
def test_a_hostile_document_is_read_or_refused_in_one_line(
    examples_folder: Path, kind: str, data: st.DataObject
) -> None:
    valid, read = DOCUMENTS[kind]
    path = examples_folder / f"{kind}.toml"
    path.write_text(tomli_w.dumps(data.draw(mutated(valid), label=kind)))
    read_or_refuse(read, path)


@HOSTILE
@given(
    header=st.lists(st.sampled_from((*REGISTER_COLUMNS, "", "extra")), max_size=9).flatmap(
        lambda h: st.sampled_from((list(REGISTER_COLUMNS), h))
    ),
    rows=st.lists(st.lists(FIELDS, max_size=9), max_size=6),
    encoding=st.sampled_from(("utf-8", "utf-8-sig", "latin-1", "utf-16")),
)
def test_a_hostile_mast_register_is_read_or_refused_in_one_line(
    examples_folder: Path, header: list[str], rows: list[list[str]], encoding: str
) -> None:
    text = io.StringIO()
    csv.writer(text).writerows([header, *rows])
    path = examples_folder / "masts.csv"
    path.write_bytes(text.getvalue().encode(encoding, errors="replace"))
    read_or_refuse(lambda p: read_register(p, wire_types=["CTA120"]), path)
