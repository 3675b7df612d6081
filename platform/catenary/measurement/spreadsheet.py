"""Text cells of CSV written for people, made safe to open in a spreadsheet (FORMATS.md,
"Exports"): a cell starting with ``=``, ``+``, ``-``, ``@``, tab or carriage return would be
evaluated as a formula, so it gets a leading single quote (OWASP's rule for CSV injection).
Only text columns are touched: a number (a negative stagger) stays a number."""

from __future__ import annotations

import pyarrow as pa
import pyarrow.compute as pc

__all__ = ["neutralise_formulas"]

_FORMULA_START = r"^([=+\-@\t\r])"


def neutralise_formulas(table: pa.Table) -> pa.Table:
    """``table`` with every text cell that a spreadsheet would evaluate prefixed by ``'``."""
    for index, field in enumerate(table.schema):
        if pa.types.is_string(field.type) or pa.types.is_large_string(field.type):
            safe = pc.replace_substring_regex(
                table.column(index), pattern=_FORMULA_START, replacement=r"'\1"
            )
            table = table.set_column(index, field, safe)
    return table
