"""Names stored before control characters were refused (or written into the database by
another tool) come out safe in every output: CSV neutralised, rounded and without control
characters, HTML escaped, the terminal without raw escape sequences."""

from __future__ import annotations

import csv
import json
import re
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import Engine, update
from sqlalchemy.orm import Session

from catenary.storage.database import make_engine
from catenary.storage.models import Alert, Line, Mast, SpanMeasurement, Track, Vehicle

from ..conftest import Build, SmallRun, read_sheet
from .conftest import assert_succeeded, catenary

HOSTILE_MASTS = (
    "M\x1b]0;owned\x07",  # OSC: retitles a terminal
    '=HYPERLINK("http://x/?"&A1)',
    "<script>alert(1)</script>",
    "M1\r\nM2",
    "\x9b31mred",  # an 8-bit CSI
    "+cmd|' /C calc'!A0",
    "@SUM(1)",
    "-2+3",
    "\x1b[2J\x1b[H",  # clears the screen
)
"""Mast codes of at most 32 characters, each hostile to a terminal, a spreadsheet or a page;
the run's spans end at the first three."""
HOSTILE_LINE = "<b>L</b>\x1b[5m"
HOSTILE_TRACK = "=1+1"
CONTROL = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f]")
"""A control character that no output may carry raw (tab and newline are a file's own)."""
ROUNDED = re.compile(r"-?\d+(\.\d{1,3})?")


@pytest.fixture(scope="module")
def hostile(small_run: SmallRun, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with a database (``catenary.sqlite``) holding the small run processed, its
    names replaced by hostile ones and an open alert on each span, and its data directory
    (``data``)."""
    folder = tmp_path_factory.mktemp("hostile")
    url = f"sqlite:///{folder / 'catenary.sqlite'}"
    env = {"CATENARY_DATA_DIR": str(folder / "data")}
    assert_succeeded(catenary("--db", url, "db", "upgrade", env=env))
    assert_succeeded(catenary(*small_run.process_args(url), env=env))
    engine = make_engine(url)
    with Session(engine) as session, session.begin():
        _rename(session)
        for number, span in enumerate(session.query(SpanMeasurement).all()):
            session.add(_alert(span, number))
    engine.dispose()
    return folder


def _rename(session: Session) -> None:
    spans = session.query(SpanMeasurement).all()
    ends = {code for span in spans for code in (span.mast_from, span.mast_to)}
    masts = sorted(
        session.query(Mast).all(), key=lambda mast: (mast.code not in ends, mast.chainage_m)
    )
    assert len(ends) >= 3
    for mast, name in zip(masts, HOSTILE_MASTS, strict=False):
        for model in (SpanMeasurement, Alert):
            for column in (model.mast_from, model.mast_to):
                session.execute(update(model).where(column == mast.code).values({column: name}))
        mast.code = name
    session.execute(update(Line).values(code=HOSTILE_LINE, name="\x1b]8;;http://x\x07"))
    session.execute(update(Track).values(code=HOSTILE_TRACK))
    session.execute(update(Vehicle).values(name="car\x1b[8m"))


def _alert(span: SpanMeasurement, number: int) -> Alert:
    return Build.alert_on(
        span,
        rule="<i>policy</i>\r\n\x1b[1m#1",
        level="urgent",
        kind="threshold",
        threshold=span.min_residual_thickness_mm + 0.5,
        condition_key=f"hostile-{number}",
        details={"action": "=cmd|'/C calc'!A0 \x1b[2J<img src=x onerror=alert(1)>"},
    )


@pytest.fixture
def database(hostile: Path, tmp_path: Path, isolated_environment: Path) -> Iterator[str]:
    """This test's copy of the hostile database (its data in this test's data directory)."""
    shutil.copyfile(hostile / "catenary.sqlite", tmp_path / "catenary.sqlite")
    shutil.copytree(hostile / "data", isolated_environment)
    yield f"sqlite:///{tmp_path / 'catenary.sqlite'}"


def _csv_rows(path: Path) -> list[dict[str, Any]]:
    text = path.read_text(encoding="utf-8")
    assert not CONTROL.search(text.replace("\r\n", "\n")), repr(CONTROL.findall(text))
    with path.open(newline="", encoding="utf-8") as handle:
        return list(csv.DictReader(handle))


def _check_csv(path: Path) -> None:
    rows = _csv_rows(path)
    assert rows, path
    for row in rows:
        for column, cell in row.items():
            if cell[:1] in ("=", "+", "-", "@"):
                float(cell)  # a number, never a formula
            if column.endswith(("_mm", "_m")) and cell:
                assert ROUNDED.fullmatch(cell), (path.name, column, cell)


CSV_OUTPUTS = {
    "export spans": ("export", "1", "--what", "spans"),
    "report run": ("report", "run", "1"),
    "report maintenance": ("report", "maintenance"),
    "linear-events": ("report", "linear-events", "--run", "1"),
}


@pytest.mark.parametrize("name", sorted(CSV_OUTPUTS))
def test_csv_outputs_are_safe(name: str, database: str, tmp_path: Path) -> None:
    out = tmp_path / "out.csv"
    assert_succeeded(catenary("--db", database, *CSV_OUTPUTS[name], "-o", out))
    _check_csv(out)
    text = out.read_text(encoding="utf-8")
    assert "'=HYPERLINK" in text and "\\x1b" in text  # the names are there, made safe


@pytest.mark.parametrize("name", sorted(CSV_OUTPUTS))
def test_xlsx_outputs_keep_hostile_names_as_text(name: str, database: str, tmp_path: Path) -> None:
    out = tmp_path / "out.xlsx"
    assert_succeeded(catenary("--db", database, *CSV_OUTPUTS[name], "-o", out))
    header, *rows = read_sheet(out)  # no formula cell anywhere
    assert rows, name
    cells = [cell for row in rows for cell in row]
    assert '=HYPERLINK("http://x/?"&A1)' in cells  # as typed text, never evaluated
    assert not any(isinstance(c, str) and CONTROL.search(c) for c in cells)
    for row in rows:
        for column, cell in zip(header, row, strict=False):
            if column.endswith(("_mm", "_m")) and isinstance(cell, float):
                assert cell == round(cell, 3), (name, column, cell)


@pytest.mark.parametrize("name", sorted(CSV_OUTPUTS))
def test_csv_to_standard_output_is_the_csv_file(name: str, database: str, tmp_path: Path) -> None:
    out = tmp_path / "out.csv"
    assert_succeeded(catenary("--db", database, *CSV_OUTPUTS[name], "-o", out))
    printed = catenary("--db", database, *CSV_OUTPUTS[name], "-o", "-")
    assert_succeeded(printed)
    assert printed.stdout == out.read_text(encoding="utf-8")
    assert "written to standard output" in printed.stderr


def test_csv_to_a_reader_that_stops_early_ends_in_one_line(database: str) -> None:
    command = [sys.executable, "-m", "catenary.cli", "--db", database, "export", "1"]
    with subprocess.Popen(
        [*command, "--what", "samples", "-o", "-"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    ) as reader:
        assert reader.stdout is not None and reader.stderr is not None
        assert reader.stdout.readline().startswith('"scan","position_m","chainage_m",')
        reader.stdout.close()  # as `| head -1` does
        error = reader.stderr.read()
        assert reader.wait(timeout=120) == 1
    assert error.startswith("Error: standard output closed by its reader: "), error
    assert len(error.strip().splitlines()) == 1 and "Traceback" not in error


@pytest.mark.parametrize("report", ["run", "maintenance"])
def test_html_reports_escape_every_name(report: str, database: str, tmp_path: Path) -> None:
    out = tmp_path / "out.html"
    args = ["report", report, *(["1"] if report == "run" else []), "-o", out]
    assert_succeeded(catenary("--db", database, *args))
    page = out.read_text(encoding="utf-8")
    assert not CONTROL.search(page), repr(CONTROL.findall(page)[:5])
    for raw in ("<script>alert", "<b>L</b>", "<i>policy</i>", "<img src=x"):
        assert raw not in page, raw
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in page


def test_alerts_list_carries_no_control_character(database: str) -> None:
    result = catenary("--db", database, "alerts", "list", "--status", "all")
    assert_succeeded(result)
    assert not CONTROL.search(result.stdout + result.stderr), repr(result.stdout[:400])
    assert "\\x1b]0;owned\\x07" in result.stdout and "<b>L</b>\\x1b[5m" in result.stdout


@pytest.mark.parametrize(
    "command", [("alerts", "list", "--status", "all"), ("runs", "list")], ids=" ".join
)
def test_json_listings_carry_the_names_escaped(database: str, command: tuple[str, ...]) -> None:
    result = catenary("--db", database, *command, "--format", "json")
    assert_succeeded(result)
    assert not CONTROL.search(result.stdout), repr(result.stdout[:400])
    records = json.loads(result.stdout)
    assert records and all(r["line"] == HOSTILE_LINE for r in records)  # as stored
    if command[0] == "alerts":
        assert {r["mast_from"] for r in records} & set(HOSTILE_MASTS)


def test_the_database_engine_sees_the_hostile_names(database: str) -> None:
    """The fixture did store them (the tests above are not vacuous)."""
    engine: Engine = make_engine(database)
    with Session(engine) as session:
        codes = {mast.code for mast in session.query(Mast)}
    engine.dispose()
    assert set(HOSTILE_MASTS) <= codes
