"""Wear trends: ``catenary history``, the trend report and a run beside the previous one, on
runs with chosen span minima (both backends)."""

from __future__ import annotations

import csv
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from click.testing import CliRunner, Result
from sqlalchemy import Engine

from catenary.cli import cli
from catenary.maintenance.alerts import evaluate_alerts
from catenary.maintenance.forecast import moment_of
from catenary.maintenance.trends import compare_with_previous, track_trends
from catenary.plugins import PluginRegistry
from catenary.storage.database import session_scope
from catenary.storage.models import Alert

from .conftest import T0, YEAR, Fleet

RATE_MM_PER_YEAR = 0.4
START_MM = 12.0
NOISE_MM = (0.0, 0.02, -0.01, 0.01, -0.02)
URGENT_MM = 8.751693900842861  # china-maintenance-rules, local, CTA120
SLOW_MM_PER_YEAR = 0.1


def invoke(database_url: str, *args: object, config: Path | None = None) -> Result:
    options = ["--config", str(config)] if config else []
    arguments = [*options, "--db", database_url, *(str(a) for a in args)]
    return CliRunner().invoke(cli, arguments, catch_exceptions=False)


def one_line_error(result: Result) -> str:
    assert result.exit_code == 1, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.output
    return lines[0]


@pytest.fixture
def config(tmp_path: Path) -> Path:
    path = tmp_path / "config.toml"
    path.write_text(
        '[limits]\npolicy = "china-maintenance-rules"\n\n[maintenance]\nhorizon_days = 3650\n'
    )
    return path


@pytest.fixture
def worn(engine: Engine, database_url: str) -> str:
    """L1 track 1: five runs half a year apart; span 3 (M03 to M04) wears 0.4 mm/year from
    12.0 mm (with a little scatter), span 5 0.1 mm/year, the others not at all. L1 track 2:
    no run."""
    with session_scope(engine) as session:
        fleet = Fleet(session)
        track = fleet.track()
        fleet.track(track="2")
        for k, noise in enumerate(NOISE_MM):
            years = 0.5 * k
            fleet.run(
                track,
                T0 + k * YEAR / 2,
                {
                    3: START_MM - RATE_MM_PER_YEAR * years + noise,
                    5: START_MM - SLOW_MM_PER_YEAR * years,
                },
                default_mm=12.5,
            )
    return database_url


def expected_reach(threshold_mm: float, rate: float) -> datetime:
    return T0 + (START_MM - threshold_mm) / rate * YEAR


def test_trends_forecast_the_date_the_alerts_carry(
    worn: str, engine: Engine, registry: PluginRegistry
) -> None:
    policy = registry.limit_policies()["china-maintenance-rules"]
    wire_types = registry.wire_types()
    with session_scope(engine) as session:
        trends = track_trends(session, 1, wire_types, policy)
        evaluate_alerts(session, policy, wire_types, now=T0 + 2 * YEAR, horizon_days=36525)
        alerts = session.query(Alert).filter_by(kind="forecast").all()
    hist = trends.histories
    span3 = int(
        next(h for h in range(hist.histories) if trends.data.mast_code[hist.mast_from[h]] == "M03")
    )
    assert hist.fit.wear_rate_mm_per_year[span3] == pytest.approx(RATE_MM_PER_YEAR, abs=0.02)
    assert [f.rule.rule.level for f in trends.limits] == ["urgent", "critical"]  # local only
    urgent = trends.limits[0]
    assert urgent.threshold_mm[span3] == pytest.approx(URGENT_MM, abs=1e-9)
    central = moment_of(float(urgent.reach.central[span3]))
    assert central is not None
    assert abs(central - expected_reach(URGENT_MM, RATE_MM_PER_YEAR)) < timedelta(days=90)
    assert urgent.reach.low[span3] < urgent.reach.central[span3] < urgent.reach.high[span3]
    # the alert on span 3 carries the same date
    (alert,) = [a for a in alerts if a.mast_from == "M03" and a.rule.endswith("#2")]
    assert alert.details["reach_at"][:10] == central.date().isoformat()


def test_a_run_beside_the_previous_one_worst_first(
    worn: str, engine: Engine, registry: PluginRegistry
) -> None:
    with session_scope(engine, read_only=True) as session:
        trends = track_trends(session, 1, registry.wire_types(), None)
    last = int(trends.data.run_id.max())
    comparison = compare_with_previous(trends, last)
    assert comparison is not None
    assert comparison.previous_run_id == last - 1
    assert comparison.years == pytest.approx(0.5, abs=1e-6)
    rows = trends.data.rows
    # span 3: 0.2 mm lost in half a year plus the scatter (0.01 then -0.02)
    assert rows.span[comparison.now[0]] == 3 and rows.span[comparison.then[0]] == 3
    assert comparison.wear_mm[0] == pytest.approx(0.2 + 0.03, abs=1e-9)
    assert comparison.wear_mm_per_year[0] == pytest.approx(0.46, abs=1e-6)
    assert rows.span[comparison.now[1]] == 5
    assert comparison.wear_mm_per_year[1] == pytest.approx(SLOW_MM_PER_YEAR, abs=1e-6)
    assert list(comparison.wear_mm) == sorted(comparison.wear_mm, reverse=True)
    assert comparison.now.shape[0] == 10 and not comparison.repaired.any()
    assert compare_with_previous(trends, int(trends.data.run_id.min())) is None


def test_history_prints_each_run_the_rate_and_the_forecast_dates(worn: str, config: Path) -> None:
    result = invoke(worn, "history", "--line", "L1", "--track", "1", "--mast", "M03", config=config)
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0] == "line L1 track 1: 5 run(s), policy china-maintenance-rules, 95% intervals"
    assert lines[1].startswith("masts M03 to M04 (1150.0 to 1200.0 m), wire position 0, CTA120")
    runs = lines[3:8]
    assert [float(r.split()[4]) for r in runs] == pytest.approx(
        [START_MM - 0.2 * k + n for k, n in enumerate(NOISE_MM)], abs=0.005
    )
    assert [float(r.split()[5]) for r in runs] == pytest.approx(
        [START_MM - 0.2 * k + n + 0.5 for k, n in enumerate(NOISE_MM)], abs=0.005
    )
    assert "5280 to 5320" in runs[0] and "-200 to 200" in runs[0]
    rate = lines[8].split()
    assert rate[:2] == ["wear", "rate"] and float(rate[2]) == pytest.approx(0.4, abs=0.02)
    low, high = float(rate[5]), float(rate[7].rstrip(")"))
    assert low < float(rate[2]) < high
    urgent = lines[9].split()
    assert urgent[:3] == ["urgent", "8.75", "mm"]
    when = datetime.fromisoformat(urgent[4]).replace(tzinfo=UTC)
    assert abs(when - expected_reach(URGENT_MM, RATE_MM_PER_YEAR)) < timedelta(days=90)
    assert lines[10].split()[:2] == ["critical", "7.77"]
    assert len(lines) == 11


def test_history_of_a_stretch_and_without_a_policy(worn: str) -> None:
    result = invoke(
        worn, "history", "--line", "L1", "--track", "1", "--from-m", "1160", "--to-m", "1260"
    )
    assert result.exit_code == 0, result.output
    heads = [line for line in result.output.splitlines() if line.startswith("masts ")]
    assert [h.split(" (")[0] for h in heads] == [
        "masts M03 to M04",
        "masts M04 to M05",
        "masts M05 to M06",
    ]
    assert "no wear-limit policy" in result.output.splitlines()[0]
    assert "urgent" not in result.output


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ("--line", "L9", "--track", "1", "--mast", "M03"),
            "no line 'L9' in the database (known: L1)",
        ),
        (
            ("--line", "L1", "--track", "7", "--mast", "M03"),
            "line 'L1' has no track '7' (known: 1, 2)",
        ),
        (
            ("--line", "L1", "--track", "1", "--mast", "X1"),
            "line L1 track 1 has no mast 'X1' (masts M00 to M10)",
        ),
        (("--line", "L1", "--track", "2", "--mast", "M03"), "line L1 track 2 has no complete run"),
        (("--line", "L1", "--track", "1"), "give --mast CODE, or --from-m M and --to-m M"),
        (
            ("--line", "L1", "--track", "1", "--from-m", "5"),
            "give --mast CODE, or --from-m M and --to-m M",
        ),
        (
            ("--line", "L1", "--track", "1", "--from-m", "5000", "--to-m", "6000"),
            "line L1 track 1: no span measured between 5000 and 6000 m",
        ),
        (
            ("--line", "L1", "--track", "1", "--mast", "M03", "-o", "plot.jpg"),
            "plot.jpg: the output's suffix must be .png or .svg",
        ),
    ],
)
def test_history_errors_are_one_line(worn: str, args: tuple[str, ...], message: str) -> None:
    assert one_line_error(invoke(worn, "history", *args)) == f"Error: {message}"


@pytest.mark.parametrize("suffix", [".png", ".svg"])
def test_history_plots_to_png_and_svg(worn: str, config: Path, tmp_path: Path, suffix: str) -> None:
    out = tmp_path / f"history{suffix}"
    args = ("history", "--line", "L1", "--track", "1", "--mast", "M03", "-o", out)
    result = invoke(worn, *args, config=config)
    assert result.exit_code == 0, result.output
    assert result.output.splitlines()[-1] == f"plot written to {out}"
    data = out.read_bytes()
    assert len(data) > 5000
    if suffix == ".png":
        assert data.startswith(b"\x89PNG\r\n\x1a\n")
    else:
        text = data.decode()
        assert text.startswith("<?xml") and "<svg" in text and text.rstrip().endswith("</svg>")
        assert "urgent 8.75 mm" in text or "urgent" in text
    assert not list(tmp_path.glob(".*.partial"))


def test_trend_report_lists_the_worst_rates_and_what_is_due(
    worn: str, config: Path, tmp_path: Path
) -> None:
    out = tmp_path / "trends.csv"
    result = invoke(
        worn, "report", "trends", "--line", "L1", "--set", "top=2", "-o", out, config=config
    )
    assert result.exit_code == 0, result.output
    with out.open(newline="") as f:
        rows = list(csv.DictReader(f))
    # top 2 by rate: span 3 then span 5; span 3 (urgent in about 8.1 years) is due in 10 years
    assert [(r["mast_from"], r["rank"]) for r in rows] == [("M03", "1"), ("M05", "2")]
    assert float(rows[0]["wear_rate_mm_per_year"]) == pytest.approx(0.4, abs=0.02)
    assert float(rows[1]["wear_rate_mm_per_year"]) == pytest.approx(SLOW_MM_PER_YEAR, abs=1e-6)
    low, high = (
        float(rows[0]["wear_rate_low_mm_per_year"]),
        float(rows[0]["wear_rate_high_mm_per_year"]),
    )
    assert low < 0.4 < high
    assert rows[0]["wire_position"] == "0" and rows[0]["runs"] == "5"
    assert rows[0]["limit_level"] == "urgent"
    reach = datetime.fromisoformat(rows[0]["reach_date"]).replace(tzinfo=UTC)
    assert abs(reach - expected_reach(URGENT_MM, RATE_MM_PER_YEAR)) < timedelta(days=90)
    assert rows[1]["limit_level"] == ""  # span 5: decades away
    html = tmp_path / "trends.html"
    assert invoke(worn, "report", "trends", "-o", html, config=config).exit_code == 0
    text = html.read_text()
    assert 'id="rates"' in text and "china-maintenance-rules" in text
    due = text.split('id="due"')[1].split("</table>")[0]
    # span 3's urgent (about 2028) and critical (about 2030) limits, each within ten years of
    # today; span 5 reaches its urgent limit in about 2052
    assert due.count("<tr") == 3
    assert due.index("urgent") < due.index("critical")
    assert "M03 to M04" in due and "M05" not in due
    bad = invoke(worn, "report", "trends", "--line", "L9", "-o", html, config=config)
    assert one_line_error(bad) == "Error: no line 'L9' in the database (known: L1)"
    assert one_line_error(
        invoke(worn, "report", "trends", "--set", "top=0", "-o", html, config=config)
    ).startswith("Error: reporter 'trends': option top = '0' is outside 1 to 10000")
    listed = invoke(worn, "report", "--list")
    assert "trends  (plugin reports)" in listed.output
