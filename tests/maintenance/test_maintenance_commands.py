"""``catenary alerts`` and ``catenary maintenance`` through the real CLI, on both backends."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner, Result
from sqlalchemy import Engine, func, select

from catenary.cli import cli
from catenary.storage.database import session_scope
from catenary.storage.models import Alert, Line, MaintenanceAction

from .conftest import T0, Fleet


def invoke(database_url: str, *args: str, config: Path | None = None) -> Result:
    options = ["--config", str(config)] if config else []
    return CliRunner().invoke(cli, [*options, "--db", database_url, *args], catch_exceptions=False)


def one_line_error(result: Result) -> str:
    assert result.exit_code == 1, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.output
    return lines[0]


@pytest.fixture
def worn(engine: Engine, database_url: str) -> str:
    """Two lines: L1 with spans worn to the urgent and critical limits, L2 to the urgent."""
    with session_scope(engine) as session:
        fleet = Fleet(session)
        one, two = fleet.track(line="L1"), fleet.track(line="L2")
        fleet.run(one, T0, {6: 8.6, 2: 7.5})  # 8.75 mm urgent, 7.77 mm critical
        fleet.run(two, T0, {1: 8.6})
    return database_url


@pytest.fixture
def config(tmp_path: Path) -> Path:
    path = tmp_path / "config.toml"
    path.write_text(
        '[limits]\npolicy = "china-maintenance-rules"\n\n[maintenance]\nhorizon_days = 180\n'
    )
    return path


def test_evaluate_then_list_as_a_planner_reads_it(worn: str, config: Path) -> None:
    before = invoke(worn, "alerts", "list").output.splitlines()
    assert before == [
        "0 alert(s)",
        "2 run(s) not yet evaluated for alerts (runs 1, 2): catenary alerts evaluate --all",
    ]
    assert invoke(worn, "alerts", "list", "--line", "L2").output.splitlines()[-1] == (
        "1 run(s) on line L2 not yet evaluated for alerts (run 2): catenary alerts evaluate --all"
    )
    result = invoke(worn, "alerts", "evaluate", "--all", config=config)
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0].startswith("alerts     policy china-maintenance-rules, every span: 20 span-")
    assert "horizon 180 days" in lines[0]
    assert lines[1].strip() == "4 new (1 critical, 3 urgent), 0 updated, 0 resolved"
    assert lines[2].strip() == "2 run(s) evaluated for the first time"
    assert lines[3].startswith("note       rule china-maintenance-rules#1")  # no sections
    listed = invoke(worn, "alerts", "list")
    assert listed.exit_code == 0, listed.output
    rows = listed.output.splitlines()
    assert rows[-1] == "4 alert(s)"
    # critical first, then urgent by line, track and chainage
    assert [r.split()[1] for r in rows[:-1]] == ["critical", "urgent", "urgent", "urgent"]
    assert [r.split()[4] for r in rows[:-1]] == ["L1/1", "L1/1", "L1/1", "L2/1"]
    assert "masts M02 to M03" in rows[0] and "masts M02 to M03" in rows[1]
    assert "masts M06 to M07" in rows[2] and "minimum 8.60 mm, limit 8.75 mm" in rows[2]
    assert len(invoke(worn, "alerts", "list", "--line", "L2").output.splitlines()) == 2
    critical = invoke(worn, "alerts", "list", "--level", "critical", "--status", "all")
    assert critical.output.splitlines()[-1] == "1 alert(s)"
    again = invoke(worn, "alerts", "evaluate", "--run", "latest", config=config)
    assert "0 new, 0 updated, 0 resolved" in again.output


def test_without_a_policy_each_wire_types_standard_limit_is_evaluated(worn: str) -> None:
    # the fleet's CTA120 has no published minimum: the manufacturers' 30 % rule, 8.75 mm
    result = invoke(worn, "alerts", "evaluate", "--all")
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[0].startswith("alerts     policy standard-limits, every span")
    assert lines[1].strip() == "3 new (3 critical), 0 updated, 0 resolved"
    rows = invoke(worn, "alerts", "list").output.splitlines()
    assert rows[-1] == "3 alert(s)"
    assert all("limit 8.75 mm" in row for row in rows[:-1])


def test_ack_and_resolve(worn: str, engine: Engine) -> None:
    assert (
        invoke(worn, "alerts", "evaluate", "--all", "--policy", "manufacturer-30pct").exit_code == 0
    )
    result = invoke(worn, "alerts", "ack", "1", "--by", "A. Planner")
    assert result.output.strip() == "alert 1 acknowledged by A. Planner"
    assert "already acknowledged (by A. Planner" in one_line_error(
        invoke(worn, "alerts", "ack", "1", "--by", "B")
    )
    result = invoke(worn, "alerts", "resolve", "1", "--by", "A. Planner", "--note", "re-measured")
    assert result.exit_code == 0, result.output
    with session_scope(engine) as session:
        alert = session.get(Alert, 1)
        assert alert is not None and alert.status == "resolved"
        assert alert.acknowledged_by == "A. Planner"
        assert alert.details["note"] == "re-measured"
    assert "alert 1 is resolved" in one_line_error(invoke(worn, "alerts", "ack", "1", "--by", "B"))
    assert "no alert 99 in the database" in one_line_error(
        invoke(worn, "alerts", "resolve", "99", "--by", "B")
    )
    assert "give a name" in one_line_error(invoke(worn, "alerts", "ack", "2", "--by", " "))


def test_record_maintenance_resolves_what_it_covers(worn: str, engine: Engine) -> None:
    invoke(worn, "alerts", "evaluate", "--all", "--policy", "manufacturer-30pct")
    result = invoke(
        worn, "maintenance", "record", "--line", "L1", "--track", "1", "--from-mast", "M04",
        "--to-mast", "M01", "--kind", "wire_replaced", "--by", "crew 7", "--at", "2021-03-01T08:00",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert result.output.strip() == (
        "recorded wire_replaced on line L1 track 1, masts M01 to M04 (1050.0 to 1200.0 m), all "
        "wires, by crew 7 at 2021-03-01T08:00:00+00:00 (action 1): resolved alert(s) 1"
    )
    with session_scope(engine) as session:
        action = session.get(MaintenanceAction, 1)
        assert action is not None and action.performed_at.isoformat() == "2021-03-01T08:00:00+00:00"
        statuses = dict(session.execute(select(Alert.mast_from, Alert.status)).all())
    assert statuses == {"M02": "resolved", "M06": "open", "M01": "open"}  # L2's is M01
    by_chainage = invoke(
        worn, "maintenance", "record", "--line", "L2", "--track", "1", "--from-m", "1060",
        "--to-m", "1070", "--kind", "inspected", "--by", "inspector",
    )  # fmt: skip
    assert by_chainage.output.strip().endswith("no alert resolved")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--from-mast", "M01", "--to-mast", "M99"], "no mast 'M99' on line 'L1' track '1'"),
        (
            ["--from-mast", "M01", "--to-mast", "M02", "--kind", "painted"],
            "unknown maintenance kind",
        ),
        (["--from-m", "1000", "--to-m", "1100", "--at", "yesterday"], "not an ISO 8601 time"),
        (["--from-m", "1000", "--to-m", "1100", "--at", "2999-01-01"], "in the future"),
        (["--from-m", "1000", "--to-m", "1100", "--wire", "-1"], "wire must be 0 or more"),
        (["--from-m", "1000", "--to-m", "1100", "--track", "9"], "no track '9' on line 'L1'"),
        (["--from-m", "-inf", "--to-m", "inf"], "--from-m -inf: not a finite chainage"),
        (["--from-m", "1000", "--to-m", "inf"], "--to-m inf: not a finite chainage"),
        (["--from-m", "nan", "--to-m", "1100"], "--from-m nan: not a finite chainage"),
    ],
)
def test_bad_maintenance_records_are_one_line_and_write_nothing(
    worn: str, engine: Engine, args: list[str], message: str
) -> None:
    options = {"--line": "L1", "--track": "1", "--kind": "wire_replaced", "--by": "crew"}
    options.update(zip(args[::2], args[1::2], strict=True))
    options_list = [x for pair in options.items() for x in pair]
    assert message in one_line_error(invoke(worn, "maintenance", "record", *options_list))
    with session_scope(engine) as session:
        assert session.scalar(select(func.count()).select_from(MaintenanceAction)) == 0


def test_usage_and_configuration_errors(worn: str, tmp_path: Path) -> None:
    assert invoke(worn, "alerts", "evaluate").exit_code == 2  # --run ID or --all
    assert invoke(worn, "maintenance", "record", "--line", "L1", "--track", "1", "--kind",
                  "inspected", "--by", "x").exit_code == 2  # fmt: skip
    assert "unknown policy 'nope'" in one_line_error(
        invoke(worn, "alerts", "evaluate", "--all", "--policy", "nope")
    )
    assert "no run 42 in the database" in one_line_error(
        invoke(worn, "alerts", "evaluate", "--run", "42", "--policy", "manufacturer-30pct")
    )
    bad = tmp_path / "bad.toml"
    bad.write_text('[limits]\npolicy = "db-ril-997"\n[maintenance]\nhorizon_days = -3\n')
    assert "[maintenance]: horizon_days must be a number of days" in one_line_error(
        invoke(worn, "alerts", "evaluate", "--all", config=bad)
    )
    bad.write_text("[maintenance]\nhorizon = 3\n")
    assert "unknown key 'horizon'" in one_line_error(
        invoke(worn, "alerts", "evaluate", "--all", "--policy", "db-ril-997", config=bad)
    )


RECORD = ["maintenance", "record", "--line", "L1", "--kind", "inspection"]


@pytest.mark.parametrize(
    ("options", "option"),
    [
        (["alerts", "list", "--line", "L1\x1b[31m"], "--line"),
        (["alerts", "ack", "1", "--by", "A. Planner\r\nBcc: x"], "--by"),
        (["alerts", "resolve", "1", "--by", "A\x9b"], "--by"),
        ([*RECORD, "--track", "1\x7f", "--by", "A"], "--track"),
        ([*RECORD, "--track", "1", "--by", "\x1b]0;pwned\x07"], "--by"),
    ],
)
def test_identifier_options_with_control_characters_are_refused(
    worn: str, engine: Engine, options: list[str], option: str
) -> None:
    error = one_line_error(invoke(worn, *options))
    assert error.startswith(f"Error: {option} = ")
    assert error.endswith("holds a control character (identifiers are printable text)")
    with session_scope(engine) as session:
        assert session.scalar(select(func.count()).select_from(MaintenanceAction)) == 0


def test_stored_names_are_escaped_on_the_terminal(worn: str, engine: Engine) -> None:
    """A name stored before control characters were refused reaches the terminal escaped."""
    with session_scope(engine) as session:
        session.scalars(select(Line).where(Line.code == "L1")).one().code = "L1\x1b]0;pwned\x07"
    invoke(worn, "alerts", "evaluate", "--all", "--policy", "manufacturer-30pct")
    listed = invoke(worn, "alerts", "list").output
    assert "\x1b" not in listed and "\x07" not in listed
    assert "L1\\x1b]0;pwned\\x07/1" in listed
