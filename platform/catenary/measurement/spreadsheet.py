"""Tables written for people (FORMATS.md, "Exports"): what ``for_people`` does to a table
before it is written as CSV or ``.xlsx``, and the ``.xlsx`` writer (``XlsxTableWriter``).

- Numbers are rounded to what they mean: a column in millimetres or metres (its name's unit
  suffix, ``height_mm``, ``chainage_m``, or a ``unit`` in its field's metadata for a column
  whose name has none) to 0.001, a share (unit ``fraction``) to 0.000001 (:data:`DECIMALS`);
  every floating-point column of the project's CSV outputs has one of these units.
- A text cell starting with ``=``, ``+``, ``-``, ``@``, tab or carriage return would be
  evaluated as a formula, so it gets a leading single quote (OWASP's rule for CSV injection).
  Only text columns are touched: a number (a negative stagger) stays a number. In ``.xlsx``
  a text cell is typed text, never evaluated, so it is written as it is (``formulas=False``).
- Control characters in text (a name stored before they were refused) are escaped as
  ``catenary.text.printable`` escapes them (``\\x1b``, ``\\n``), so the file carries no
  terminal escape sequence.
"""

from __future__ import annotations

import math
from pathlib import Path
from types import TracebackType
from typing import Any

import pyarrow as pa
import pyarrow.compute as pc
import xlsxwriter

from catenary.text import CONTROL_PATTERN, printable

__all__ = ["DECIMALS", "SHEET_ROWS", "XlsxTableWriter", "column_decimals", "for_people"]

SHEET_ROWS = 1_048_576
"""The rows a spreadsheet's sheet holds, the header's included (Excel, LibreOffice)."""

DECIMALS = {"mm": 3, "m": 3, "fraction": 6}
"""Decimals of a number in CSV written for people, by its unit (0.001 mm, 0.001 m, a share
to 0.0001 %)."""

_FORMULA_START = r"^([=+\-@\t\r])"


def column_decimals(field: pa.Field) -> int | None:
    """The decimals ``field``'s numbers are written with; None: as computed (not a float, or
    a unit without a rule)."""
    if not pa.types.is_floating(field.type):
        return None
    unit = (field.metadata or {}).get(b"unit", b"").decode() or field.name.rpartition("_")[2]
    return DECIMALS.get(unit)


def _safe_text(column: pa.ChunkedArray, formulas: bool) -> pa.ChunkedArray:
    if formulas:
        column = pc.replace_substring_regex(column, pattern=_FORMULA_START, replacement=r"'\1")
    if not pc.any(pc.match_substring_regex(column, CONTROL_PATTERN)).as_py():
        return column
    return pa.chunked_array(
        [[None if v is None else printable(v) for v in column.to_pylist()]], column.type
    )


def for_people(table: pa.Table, *, formulas: bool = True) -> pa.Table:
    """``table`` as a file written for people shows it (module docstring); ``formulas``: text
    that a spreadsheet would evaluate gets its leading quote (CSV; not ``.xlsx``)."""
    for index, field in enumerate(table.schema):
        column = table.column(index)
        decimals = column_decimals(field)
        if decimals is not None:
            rounded = pc.add(pc.round(column, ndigits=decimals), 0.0)  # + 0.0: no "-0"
            table = table.set_column(index, field, rounded)
        elif pa.types.is_string(field.type) or pa.types.is_large_string(field.type):
            table = table.set_column(index, field, _safe_text(column, formulas))
    return table


class XlsxTableWriter:
    """Tables written as one sheet of an ``.xlsx`` workbook at ``path``, a header row then
    the rows (``for_people``, text as typed text), in XlsxWriter's constant-memory mode.

    Text is never turned into a formula, a link or a number; NaN is written as an empty
    cell. The caller keeps to ``SHEET_ROWS`` (XlsxWriter would drop the rows beyond it).
    """

    def __init__(self, path: Path, schema: pa.Schema) -> None:
        self._book = xlsxwriter.Workbook(
            str(path),
            {
                "constant_memory": True,
                "strings_to_formulas": False,
                "strings_to_urls": False,
                "strings_to_numbers": False,
            },
        )
        self._sheet = self._book.add_worksheet()
        self._sheet.write_row(0, 0, schema.names)
        self._rows = 0

    def write_table(self, table: pa.Table) -> None:
        """Write ``table``'s rows below those written."""
        columns = [c.to_pylist() for c in for_people(table, formulas=False).columns]
        write = self._sheet.write
        for offset, values in enumerate(zip(*columns, strict=True)):
            row = 1 + self._rows + offset
            for column, value in enumerate(values):
                if value is not None and not (isinstance(value, float) and math.isnan(value)):
                    write(row, column, _cell(value))
        self._rows += table.num_rows

    def __enter__(self) -> XlsxTableWriter:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self._book.close()


def _cell(value: Any) -> Any:
    """A value as XlsxWriter writes it: numbers, booleans and text as they are, infinities
    and anything else as text."""
    if isinstance(value, bool | int | str) or (isinstance(value, float) and math.isfinite(value)):
        return value
    return str(value)
