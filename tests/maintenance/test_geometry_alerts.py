"""Geometry rules: the policy syntax, what each check compares, and their alerts on a simulated
run processed through the real CLI, on both backends."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result
from sqlalchemy import Engine, select

from catenary.cli import cli
from catenary.errors import UserError
from catenary.limits import GeometryRule, parse_policies
from catenary.maintenance.actions import record_maintenance
from catenary.maintenance.alerts.geometry import (
    GEOMETRY_MARGIN_MM,
    GeometryRows,
    MastGeometry,
    check,
    running,
)
from catenary.storage.database import session_scope
from catenary.storage.models import Alert, SpanMeasurement, Track

from ..conftest import SmallRun

OFFSET_MM = 150.0
TOLERANCE_MM = 100.0
MEDIAN_INSIDE_MM = 15.0
"""How far a wire's median stagger within 1 m of a mast may lie from its design value on the
simulator's line: the stagger is a V at the registration point, so the median lies inside its
extreme by about half the stagger gradient (about 12 mm/m, so 6 mm), plus the 2 mm accuracy."""

POLICY = f"""
[policies.geo]
description = "design stagger within {TOLERANCE_MM} mm; running wires within 400 mm"

[[policies.geo.geometry]]
check = "design_stagger"
level = "urgent"
action = "re-register the wire"
tolerance_mm = {TOLERANCE_MM}

[[policies.geo.geometry]]
check = "stagger"
level = "urgent"
max_abs_mm = 400.0
"""


@pytest.fixture(scope="module")
def long_run(small_run: SmallRun, tmp_path_factory: pytest.TempPathFactory) -> SmallRun:
    """A 200 m run without an overlap (one wire at each mast) with ``small_run``'s rig."""
    from catenary_linescan.simulator import record_run

    folder = tmp_path_factory.mktemp("geometry")
    run = folder / "long.h5"
    record_run(run, {"length_m": 200.0, "speed_kmh": 160.0, "seed": 5, "overlap": False})
    return SmallRun(run, run.with_suffix(".masts.csv"), small_run.rig)


def invoke(database_url: str, config: Path, *args: str) -> Result:
    result = CliRunner().invoke(
        cli, ["--config", str(config), "--db", database_url, *args], catch_exceptions=False
    )
    assert result.exit_code == 0, result.output
    return result


def process(run: SmallRun, masts: Path, database_url: str, config: Path, *extra: str) -> Result:
    return invoke(
        database_url, config, "process", str(run.run), "--rig", str(run.rig), "--masts",
        str(masts), *extra,
    )  # fmt: skip


def register_with_offset(run: SmallRun, mast: str, offset_mm: float, path: Path) -> Path:
    """``run``'s register with ``mast``'s design stagger moved by ``offset_mm``."""
    with run.masts.open(newline="") as file:
        rows = list(csv.DictReader(file))
    for row in rows:
        if row["mast"] == mast:
            row["design_stagger_mm"] = f"{float(row['design_stagger_mm']) + offset_mm:.1f}"
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return path


@pytest.fixture
def config(tmp_path: Path) -> Path:
    (tmp_path / "geo.toml").write_text(POLICY)
    path = tmp_path / "config.toml"
    path.write_text('[limits]\nfile = "geo.toml"\n')
    return path


def measured_masts(engine: Engine) -> list[str]:
    with session_scope(engine) as session:
        return list(
            session.scalars(
                select(SpanMeasurement.mast_from)
                .where(SpanMeasurement.stagger_at_start_mm.is_not(None))
                .order_by(SpanMeasurement.start_chainage_m)
            )
        )


def test_the_wire_at_each_mast_lies_at_its_design_stagger(
    long_run: SmallRun, engine: Engine, database_url: str, config: Path
) -> None:
    result = process(long_run, long_run.masts, database_url, config)
    assert "alerts     0 new, 0 updated, 0 resolved (policy geo)" in result.output
    with long_run.masts.open(newline="") as file:
        design = {row["mast"]: float(row["design_stagger_mm"]) for row in csv.DictReader(file)}
    with session_scope(engine) as session:
        spans = list(session.scalars(select(SpanMeasurement)))
    at_masts = [s for s in spans if s.stagger_at_start_mm is not None]
    assert len(at_masts) >= 3
    for span in at_masts:
        assert span.mast_from is not None
        assert span.stagger_at_start_mm == pytest.approx(
            design[span.mast_from], abs=MEDIAN_INSIDE_MM
        )
        assert span.height_at_start_mm is not None
        assert span.height_min_mm - 1.0 <= span.height_at_start_mm <= span.height_max_mm + 1.0


def test_a_design_stagger_off_by_150_mm_raises_that_masts_alert_and_no_other(
    long_run: SmallRun, engine: Engine, database_url: str, config: Path, tmp_path: Path
) -> None:
    process(long_run, long_run.masts, database_url, config)
    masts = measured_masts(engine)
    wrong = masts[len(masts) // 2]
    off = register_with_offset(long_run, wrong, OFFSET_MM, tmp_path / "off.csv")
    result = process(long_run, off, database_url, config, "--replace")
    assert "alerts     1 new (1 urgent), 0 updated, 0 resolved (policy geo)" in result.output
    with session_scope(engine) as session:
        (alert,) = session.scalars(select(Alert))
        assert (alert.kind, alert.rule, alert.mast_from, alert.status) == (
            "geometry",
            "geo#g1",
            wrong,
            "open",
        )
        assert alert.value == pytest.approx(OFFSET_MM, abs=MEDIAN_INSIDE_MM)
        assert alert.threshold == TOLERANCE_MM
        assert alert.details["check"] == "design_stagger"
        assert alert.span_measurement is not None
        assert alert.span_measurement.mast_from == wrong  # shown on the span that starts there
    listed = invoke(database_url, config, "alerts", "list").output.splitlines()
    assert listed[-1] == "1 alert(s)"
    assert f"design_stagger {alert.value:.1f} mm, limit 100.0 mm (at the mast" in listed[0]

    # the register set right and the run processed again: back within tolerance, resolved
    result = process(long_run, long_run.masts, database_url, config, "--replace")
    assert "alerts     0 new, 0 updated, 1 resolved (policy geo)" in result.output
    with session_scope(engine) as session:
        (alert,) = session.scalars(select(Alert))
        assert alert.status == "resolved"
        assert alert.details["resolution"] == f"back within the limit by {GEOMETRY_MARGIN_MM} mm"


def test_an_adjustment_resolves_the_geometry_alerts_it_covers(
    long_run: SmallRun, engine: Engine, database_url: str, config: Path, tmp_path: Path
) -> None:
    process(long_run, long_run.masts, database_url, config)
    masts = measured_masts(engine)
    off = register_with_offset(long_run, masts[0], -OFFSET_MM, tmp_path / "off.csv")
    off = register_with_offset(
        SmallRun(long_run.run, off, long_run.rig), masts[-1], OFFSET_MM, tmp_path / "off2.csv"
    )
    process(long_run, off, database_url, config, "--replace")
    with session_scope(engine) as session:
        alerts = {a.mast_from: a for a in session.scalars(select(Alert))}
        assert set(alerts) == {masts[0], masts[-1]}
        first = alerts[masts[0]]
        track = session.get(Track, first.track_id)
        assert track is not None
        recorded = record_maintenance(
            session,
            track,
            "adjusted",
            first.start_chainage_m,
            first.end_chainage_m,
            first.raised_at,
            "fitter",
            now=first.raised_at,
            actor="test",
        )
        assert recorded.resolved == (first.id,)
        assert alerts[masts[-1]].status == "open"
        recorded = record_maintenance(
            session,
            track,
            "inspected",
            -1e6,
            1e6,
            first.raised_at,
            "fitter",
            now=first.raised_at,
            actor="test",
        )
        assert recorded.resolved == ()


# --- what each check compares -------------------------------------------------------------


def rows(**values: list[float]) -> GeometryRows:
    names = GeometryRows.__dataclass_fields__
    count = len(next(iter(values.values())))
    return GeometryRows(
        **{name: np.array(values.get(name, [np.nan] * count), dtype=np.float64) for name in names}
    )


def test_the_height_gradient_is_the_rise_between_the_masts_over_the_span() -> None:
    # spans of 50 m whose height rises 200, 151, 148.5 and 147 mm from mast to mast
    rise = [200.0, 151.0, 148.5, 147.0]
    geometry = rows(height_start_mm=[5500.0] * 4, height_end_mm=[5500.0 + r for r in rise])
    masts = MastGeometry(
        design_stagger_mm=np.full(4, np.nan),
        design_height_mm=np.full(4, np.nan),
        line_speed_kmh=np.array([160.0, 160.0, 160.0, 250.0]),
    )
    rule = GeometryRule(check="height_gradient", level="urgent", max_per_mille=3.0)
    index = np.arange(4)
    checked = check(
        rule, geometry, masts, index, index, index, np.full(4, 50.0), np.ones(4),
        np.ones(4, dtype=bool), np.ones(4, dtype=bool),
    )  # fmt: skip
    # 3 per mille over 50 m allows 150 mm
    np.testing.assert_allclose(checked.value, np.array(rise) / 50.0, atol=1e-9)
    np.testing.assert_allclose(checked.excess_mm, np.array(rise) - 150.0, atol=1e-9)
    assert checked.met().tolist() == [True, True, False, False]
    assert checked.clear().tolist() == [False, False, False, True]  # 2 mm margin
    # the same limit only up to 200 km/h: the span at 250 km/h is not evaluated
    banded = GeometryRule(
        check="height_gradient", level="urgent", max_per_mille=3.0, max_speed_kmh=200.0
    )
    checked = check(
        banded, geometry, masts, index, index, index, np.full(4, 50.0), np.ones(4),
        np.ones(4, dtype=bool), np.ones(4, dtype=bool),
    )  # fmt: skip
    assert np.isnan(checked.limit[3]) and not checked.met()[3] and not checked.clear()[3]
    assert checked.met()[:2].all()


def test_height_and_stagger_ranges() -> None:
    geometry = rows(
        height_min_mm=[4990.0, 5100.0, 5100.0],
        height_max_mm=[5200.0, 6510.0, 5300.0],
        stagger_min_mm=[-405.0, 100.0, -300.0],
        stagger_max_mm=[100.0, 250.0, 300.0],
    )
    masts = MastGeometry(np.full(3, np.nan), np.full(3, np.nan), np.full(3, np.nan))
    index = np.arange(3)
    ones = np.ones(3, dtype=bool)
    args = (index, index, index, np.full(3, 50.0), np.ones(3), ones, ones)
    height = GeometryRule(check="height", level="urgent", min_mm=5000.0, max_mm=6500.0)
    checked = check(height, geometry, masts, *args)
    assert checked.met().tolist() == [True, True, False]
    np.testing.assert_allclose(checked.value[:2], [4990.0, 6510.0])
    np.testing.assert_allclose(checked.limit[:2], [5000.0, 6500.0])
    stagger = GeometryRule(check="stagger", level="urgent", max_abs_mm=400.0)
    checked = check(stagger, geometry, masts, *args)
    assert checked.met().tolist() == [True, False, False]
    np.testing.assert_allclose(checked.value, [405.0, 250.0, 300.0])
    # a wire out of running at the span's last mast (it leaves running within it): not checked
    checked = check(stagger, geometry, masts, *args[:-1], np.array([False, True, True]))
    assert np.isnan(checked.limit[0]) and not checked.met().any()


def test_a_wire_lifted_out_of_running_at_a_mast_is_not_checked_there() -> None:
    # one run, mast 0: wires at 5500 mm and 5850 mm (out of running); mast 1: two running
    # wires 10 mm apart in height (an overlap's middle mast), mast 2: no height at the mast
    out = running(
        np.zeros(5, dtype=np.int64),
        np.array([0, 0, 1, 1, 2]),
        np.array([0, 0, 1, 1, 2]),
        np.array([5500.0, 5850.0, 5500.0, 5510.0, math.nan]),
    )
    assert out.tolist() == [True, False, True, True, True]


def test_the_design_check_takes_the_wire_nearest_design_where_two_run() -> None:
    geometry = rows(stagger_start_mm=[-100.0, 100.0], height_start_mm=[5500.0, 5500.0])
    masts = MastGeometry(np.array([120.0]), np.array([np.nan]), np.array([np.nan]))
    rule = GeometryRule(check="design_stagger", level="plan", tolerance_mm=50.0)
    zero = np.zeros(2, dtype=np.int64)
    checked = check(
        rule, geometry, masts, np.arange(2), zero, zero, np.full(2, 50.0), np.ones(2),
        np.ones(2, dtype=bool), np.zeros(2, dtype=bool),
    )  # fmt: skip
    assert np.isnan(checked.value[0]) and checked.value[1] == pytest.approx(20.0)
    assert not checked.met().any()
    # a run the other way round: its staggers' sign is undone
    checked = check(
        rule, geometry, masts, np.arange(2), zero, zero, np.full(2, 50.0), -np.ones(2),
        np.ones(2, dtype=bool), np.zeros(2, dtype=bool),
    )  # fmt: skip
    assert checked.value[0] == pytest.approx(20.0)


# --- the syntax -------------------------------------------------------------------------------


def test_geometry_rules_parse_beside_the_wear_rules() -> None:
    policies = parse_policies(POLICY + '\n[[policies.geo.rules]]\nlevel = "urgent"\n'
                              'scope = "local"\nworn_fraction = 0.3\n')  # fmt: skip
    policy = policies["geo"]
    assert [r.check for r in policy.geometry] == ["design_stagger", "stagger"]
    assert policy.geometry[0].tolerance_mm == TOLERANCE_MM
    assert len(policy.rules) == 1
    assert policy.geometry[1].criterion == "|stagger| <= 400 mm"


@pytest.mark.parametrize(
    ("rule", "message"),
    [
        ('check = "sag"\nlevel = "plan"\nmax_mm = 1.0', "check must be one of height,"),
        ('check = "stagger"\nlevel = "plan"', "check 'stagger' needs max_abs_mm"),
        ('check = "stagger"\nlevel = "plan"\nmax_mm = 400.0', "max_mm is not a limit of check"),
        ('check = "height"\nlevel = "plan"\nmin_mm = 6000.0\nmax_mm = 5000.0', "min_mm must be"),
        ('check = "stagger"\nlevel = "plan"\nmax_abs_mm = -1.0', "max_abs_mm must be a positive"),
    ],
)
def test_a_bad_geometry_rule_is_one_line_naming_it(rule: str, message: str) -> None:
    with pytest.raises(UserError) as error:
        parse_policies(f"[policies.p]\n[[policies.p.geometry]]\n{rule}\n", origin="my.toml")
    text = str(error.value)
    assert "\n" not in text
    assert text.startswith("my.toml: policy 'p' geometry rule 1: ")
    assert message in text


# --- line speeds from the configuration -----------------------------------------------------

HIGH_SPEED_POLICY = """
[policies.fast]
[[policies.fast.geometry]]
check = "stagger"
level = "urgent"
max_abs_mm = 300.0
min_speed_kmh = 200.0
"""


def test_a_lines_speed_in_the_config_chooses_the_speed_banded_rules(
    long_run: SmallRun, engine: Engine, database_url: str, tmp_path: Path
) -> None:
    (tmp_path / "fast.toml").write_text(HIGH_SPEED_POLICY)
    config = tmp_path / "config.toml"
    limits = '[limits]\nfile = "fast.toml"\n'
    config.write_text(limits)  # no line speed at all: the banded rule is not evaluated
    assert "0 new" in process(long_run, long_run.masts, database_url, config).output
    config.write_text(limits + "[maintenance]\nline_speed_kmh = {demo-line = 160}\n")
    replaced = process(long_run, long_run.masts, database_url, config, "--replace")
    assert "0 new" in replaced.output
    config.write_text(limits + "[maintenance]\nline_speed_kmh = {demo-line = 250}\n")
    process(long_run, long_run.masts, database_url, config, "--replace")
    with session_scope(engine) as session:
        alerts = list(session.scalars(select(Alert)))
        latest = max(session.scalars(select(SpanMeasurement.processing_id)))
        spans = session.scalars(
            select(SpanMeasurement).where(SpanMeasurement.processing_id == latest)
        )
        # one wire a span (no overlap): every span's wire runs
        beyond = {
            s.mast_from for s in spans if max(abs(s.stagger_min_mm), abs(s.stagger_max_mm)) > 300.0
        }
    assert beyond  # the simulated line staggers up to about ±400 mm
    assert {a.mast_from for a in alerts} == beyond
    assert all(a.details["line_speed_kmh"] == 250.0 for a in alerts)


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ("line_speed_kmh = 160", "line_speed_kmh must be a table"),
        ("line_speed_kmh = {L1 = -5}", "line_speed_kmh.L1 must be a speed from 0 to 1000 km/h"),
        ("line_speed_kmh = {L1 = 'fast'}", "not 'fast'"),
    ],
)
def test_a_bad_line_speed_table_is_one_line(table: str, message: str, tmp_path: Path) -> None:
    config = tmp_path / "config.toml"
    config.write_text(f"[maintenance]\n{table}\n")
    result = CliRunner().invoke(
        cli, ["--config", str(config), "--db", "sqlite://", "alerts", "evaluate", "--all"]
    )
    assert result.exit_code == 1
    (line,) = result.output.strip().splitlines()
    assert line.startswith(f"Error: {config}: [maintenance]: ") and message in line


def test_the_design_height_at_a_mast() -> None:
    # masts designed at 5500 mm; the wires hang at 5530, 5470 and 5497 mm there
    geometry = rows(height_start_mm=[5530.0, 5470.0, 5497.0])
    masts = MastGeometry(np.full(3, np.nan), np.full(3, 5500.0), np.full(3, np.nan))
    rule = GeometryRule(check="design_height", level="plan", tolerance_mm=25.0)
    index = np.arange(3)
    ones = np.ones(3, dtype=bool)
    checked = check(rule, geometry, masts, index, index, index, np.full(3, 50.0), np.ones(3),
                    ones, ones)  # fmt: skip
    np.testing.assert_allclose(checked.value, [30.0, 30.0, 3.0])
    assert checked.met().tolist() == [True, True, False]
    assert checked.clear().tolist() == [False, False, True]  # 22 mm within, beyond the margin
