"""CSV written for people (FORMATS.md, "Exports"): what ``for_people`` does to a table
before it is written.

- Numbers are rounded to what they mean: a column in millimetres or metres (its name's unit
  suffix, ``height_mm``, ``chainage_m``, or a ``unit`` in its field's metadata for a column
  whose name has none) to 0.001 (:data:`DECIMALS`); other numbers are left as computed.
- A text cell starting with ``=``, ``+``, ``-``, ``@``, tab or carriage return would be
  evaluated as a formula, so it gets a leading single quote (OWASP's rule for CSV injection).
  Only text columns are touched: a number (a negative stagger) stays a number.
- Control characters in text (a name stored before they were refused) are escaped as
  ``catenary.text.printable`` escapes them (``\\x1b``, ``\\n``), so the file carries no
  terminal escape sequence.
"""

from __future__ import annotations

import pyarrow as pa
import pyarrow.compute as pc

from catenary.text import CONTROL_PATTERN, printable

__all__ = ["DECIMALS", "column_decimals", "for_people"]

DECIMALS = {"mm": 3, "m": 3}
"""Decimals of a number in CSV written for people, by its unit (0.001 mm, 0.001 m)."""

_FORMULA_START = r"^([=+\-@\t\r])"


def column_decimals(field: pa.Field) -> int | None:
    """The decimals ``field``'s numbers are written with; None: as computed (not a float, or
    a unit without a rule)."""
    if not pa.types.is_floating(field.type):
        return None
    unit = (field.metadata or {}).get(b"unit", b"").decode() or field.name.rpartition("_")[2]
    return DECIMALS.get(unit)


def _safe_text(column: pa.ChunkedArray) -> pa.ChunkedArray:
    column = pc.replace_substring_regex(column, pattern=_FORMULA_START, replacement=r"'\1")
    if not pc.any(pc.match_substring_regex(column, CONTROL_PATTERN)).as_py():
        return column
    return pa.chunked_array(
        [[None if v is None else printable(v) for v in column.to_pylist()]], column.type
    )


def for_people(table: pa.Table) -> pa.Table:
    """``table`` as CSV written for people shows it (module docstring)."""
    for index, field in enumerate(table.schema):
        column = table.column(index)
        decimals = column_decimals(field)
        if decimals is not None:
            rounded = pc.add(pc.round(column, ndigits=decimals), 0.0)  # + 0.0: no "-0"
            table = table.set_column(index, field, rounded)
        elif pa.types.is_string(field.type) or pa.types.is_large_string(field.type):
            table = table.set_column(index, field, _safe_text(column))
    return table
