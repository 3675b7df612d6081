"""The mast register: CSV (FORMATS.md), one row per mast, per line and track.

Columns ``line,track,mast,chainage_m,wire_type`` and optionally ``design_stagger_mm``; extra
columns are ignored. A span runs from one mast to the next by chainage; its wire type is that
of the mast at its start. Every problem is a one-line ``FormatError`` naming the file, the
row (its line number in the file) and the field.

Optional columns: ``anchor_section``, a code naming the anchor section (tensioning length) each
mast belongs to (a span is in the section of its start mast, and a section's masts follow one
another along the track; an empty field: the mast is in no section); ``design_height_mm`` (the
contact wire's height at the mast by design), ``line_speed_kmh`` (the line speed from this mast
on), ``latitude`` and ``longitude`` (WGS 84 degrees, given together). An empty field: not given
for that mast.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from catenary.domain import CODE_LENGTH, OPTIONAL_MAST_NUMBERS, TrackRegister
from catenary.errors import FormatError, UserError
from catenary.text import identifier_problem

__all__ = ["REQUIRED_COLUMNS", "MastRegister", "read_register"]

RANGES: dict[str, tuple[float, float]] = {
    "design_height_mm": (0.0, 10_000.0),
    "line_speed_kmh": (0.0, 500.0),
    "latitude": (-90.0, 90.0),
    "longitude": (-180.0, 180.0),
}
"""The values each optional numeric column may hold (the first bound excluded for height and
speed, which are positive)."""

REQUIRED_COLUMNS = ("line", "track", "mast", "chainage_m", "wire_type")
IDENTIFIER_COLUMNS = ("line", "track", "mast", "anchor_section", "wire_type")
"""Columns holding codes: printable text, no control characters (FORMATS.md), at most
``CODE_LENGTH`` characters (the database's)."""


@dataclass(frozen=True)
class MastRegister:
    """A register file's masts by ``(line, track)``."""

    path: Path
    tracks: dict[tuple[str, str], TrackRegister]

    def track(self, line: str, track: str) -> TrackRegister:
        """The masts of one line and track; ``UserError`` when the register has none."""
        found = self.tracks.get((line, track))
        if found is None or found.masts < 2:
            known = ", ".join(f"{a}/{b}" for a, b in sorted(self.tracks)) or "none"
            raise UserError(
                f"{self.path}: no masts for line {line!r} track {track!r} "
                f"(two at least needed; the register has line/track: {known})"
            )
        return found


def _number(path: Path, row: int, field: str, text: str, *, optional: bool = False) -> float:
    if optional and text.strip() == "":
        return math.nan
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise FormatError(path, f"row {row}: {field} = {text!r} is not a finite number")
    return value


def _check_sections(
    file: Path, line: str, track: str, codes: list[str], section: tuple[str | None, ...]
) -> None:
    """An anchor section's masts follow one another along the track (by chainage)."""
    seen: set[str] = set()
    for k, code in enumerate(section):
        if code is None or (k > 0 and section[k - 1] == code):
            continue
        if code in seen:
            raise FormatError(
                file,
                f"mast {codes[k]!r} of line {line!r} track {track!r}: anchor_section {code!r} "
                f"resumes after mast {codes[k - 1]!r}, which is not in it (a section's masts "
                "follow one another)",
            )
        seen.add(code)


def read_register(path: str | Path, wire_types: Iterable[str] | None = None) -> MastRegister:
    """Read a mast register CSV.

    Parameters
    ----------
    path : str or Path
        The CSV file (UTF-8, a header row).
    wire_types : iterable of str or None
        Known wire type names; a mast naming another is refused. None: not checked.

    Raises
    ------
    FormatError
        A missing column, an empty or non-numeric field, a mast code given twice for one
        track, two masts at the same chainage, an unknown wire type, an anchor section whose
        masts do not follow one another.
    """
    file = Path(path)
    known = None if wire_types is None else set(wire_types)
    try:
        with file.open(newline="", encoding="utf-8-sig") as handle:
            reader = csv.DictReader(handle)
            columns = [c.strip() for c in reader.fieldnames or []]
            missing = [c for c in REQUIRED_COLUMNS if c not in columns]
            if missing:
                raise FormatError(
                    file,
                    f"no column {missing[0]!r} (a mast register has columns "
                    f"{','.join(REQUIRED_COLUMNS)}[,design_stagger_mm][,anchor_section])",
                )
            reader.fieldnames = columns
            sections = "anchor_section" in columns
            numbers = [c for c in OPTIONAL_MAST_NUMBERS if c in columns]
            rows: dict[tuple[str, str], list[tuple[str, float, str, float, str | None]]] = {}
            extra: dict[tuple[str, str], list[list[float]]] = {}
            for row in reader:
                number = reader.line_num
                values = {k: (v or "").strip() for k, v in row.items() if k is not None}
                for field in ("line", "track", "mast", "wire_type"):
                    if not values.get(field):
                        raise FormatError(file, f"row {number}: {field} is empty")
                for field in IDENTIFIER_COLUMNS:
                    problem = identifier_problem(field, values.get(field, ""), CODE_LENGTH)
                    if problem is not None:
                        raise FormatError(file, f"row {number}: {problem}")
                if known is not None and values["wire_type"] not in known:
                    raise FormatError(
                        file,
                        f"row {number}: wire_type = {values['wire_type']!r} is not a known "
                        f"wire type (catenary wire-types lists them)",
                    )
                chainage = _number(file, number, "chainage_m", values["chainage_m"])
                stagger = _number(
                    file,
                    number,
                    "design_stagger_mm",
                    values.get("design_stagger_mm", ""),
                    optional=True,
                )
                key = (values["line"], values["track"])
                section = values.get("anchor_section") or None
                rows.setdefault(key, []).append(
                    (values["mast"], chainage, values["wire_type"], stagger, section)
                )
                given = {c: _optional(file, number, c, values.get(c, "")) for c in numbers}
                place = [math.isnan(given.get(c, math.nan)) for c in ("latitude", "longitude")]
                if place[0] != place[1]:
                    raise FormatError(file, f"row {number}: give latitude and longitude together")
                extra.setdefault(key, []).append(list(given.values()))
    except FileNotFoundError:
        raise UserError(f"{file}: no such file") from None
    except UnicodeDecodeError as exc:
        raise FormatError(file, f"not UTF-8 text ({exc.reason})") from None
    except csv.Error as exc:
        raise FormatError(file, f"not valid CSV: {exc}") from None
    except OSError as exc:
        raise UserError(f"{file}: cannot read ({exc.strerror or exc})") from None
    if not rows:
        raise FormatError(file, "no masts")
    tracks = {}
    for (line, track), masts in rows.items():
        order = np.argsort([m[1] for m in masts], kind="stable")
        optional = np.array(extra[(line, track)], np.float64).reshape(len(masts), -1)[order]
        masts = [masts[k] for k in order]
        codes = [m[0] for m in masts]
        if len(set(codes)) != len(codes):
            twice = next(c for c in codes if codes.count(c) > 1)
            raise FormatError(file, f"mast {twice!r} of line {line!r} track {track!r} twice")
        chainages = np.array([m[1] for m in masts])
        same = np.flatnonzero(np.diff(chainages) <= 0.0)
        if same.size:
            a, b = codes[same[0]], codes[same[0] + 1]
            raise FormatError(
                file, f"masts {a!r} and {b!r} of line {line!r} track {track!r} at one chainage"
            )
        section = tuple(m[4] for m in masts)
        _check_sections(file, line, track, codes, section)
        tracks[(line, track)] = TrackRegister(
            line=line,
            track=track,
            mast=tuple(codes),
            chainage_m=chainages,
            wire_type=tuple(m[2] for m in masts),
            design_stagger_mm=np.array([m[3] for m in masts]),
            anchor_section=section if sections else None,
            **{c: optional[:, k] for k, c in enumerate(numbers)},
        )
    return MastRegister(path=file, tracks=tracks)


def _optional(file: Path, row: int, field: str, text: str) -> float:
    """An optional numeric column's value (NaN: empty), within its ``RANGES``."""
    value = _number(file, row, field, text, optional=True)
    low, high = RANGES[field]
    positive = field in ("design_height_mm", "line_speed_kmh")
    inside = (low < value if positive else low <= value) and value <= high
    if not math.isnan(value) and not inside:
        raise FormatError(file, f"row {row}: {field} = {text!r} is outside {low:g} to {high:g}")
    return value
