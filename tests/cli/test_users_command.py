"""``catenary users`` and ``catenary tokens`` through the real CLI, on both backends, and the
audit trail of every change made on the command line."""

from __future__ import annotations

import json
from typing import Any

import pytest
from click.testing import CliRunner, Result
from sqlalchemy import Engine, select

from catenary.cli import cli
from catenary.storage.database import session_scope
from catenary.storage.models import ApiToken, AuditEntry, User
from catenary.storage.users import authenticate_password, authenticate_token, system_actor

PASSWORD = "correct horse battery"


def invoke(database_url: str, *args: str, stdin: str | None = None) -> Result:
    return CliRunner().invoke(cli, ["--db", database_url, *args], input=stdin)


def one_line_error(result: Result) -> str:
    assert result.exit_code == 1, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.output
    return lines[0]


def audit(engine: Engine) -> list[tuple[str, str, str, dict[str, Any]]]:
    with session_scope(engine, read_only=True) as session:
        entries = session.scalars(select(AuditEntry).order_by(AuditEntry.id))
        return [(e.actor, e.action, e.target, e.details) for e in entries]


@pytest.fixture
def with_ada(engine: Engine, database_url: str) -> str:
    """The database with planner ``ada`` (added through the CLI)."""
    result = invoke(
        database_url, "users", "add", "ada", "--role", "planner", "--password-stdin", stdin=PASSWORD
    )
    assert result.exit_code == 0, result.output
    assert result.output == "user ada added (planner)\n"
    return database_url


def test_a_password_from_stdin_is_hashed_and_audited(with_ada: str, engine: Engine) -> None:
    with session_scope(engine) as session:
        assert authenticate_password(session, "ada", PASSWORD) is not None
        stored = session.scalars(select(User.password_hash)).one()
    assert stored.startswith("$argon2id$") and PASSWORD not in stored
    assert audit(engine) == [(system_actor(), "user.add", "user ada", {"role": "planner"})]


def test_a_password_typed_twice_on_the_terminal(engine: Engine, database_url: str) -> None:
    typed = f"{PASSWORD}\n{PASSWORD}\n"
    result = invoke(database_url, "users", "add", "bo", "--role", "viewer", stdin=typed)
    assert result.exit_code == 0, result.output
    assert PASSWORD not in result.output  # hidden
    mistyped = f"{PASSWORD}\n{PASSWORD}x\n{PASSWORD}\n{PASSWORD}\n"
    result = invoke(database_url, "users", "set-password", "bo", stdin=mistyped)
    assert result.exit_code == 0, result.output
    assert "do not match" in result.output and PASSWORD not in result.output
    with session_scope(engine) as session:
        assert authenticate_password(session, "bo", PASSWORD) is not None


def test_list_disable_and_set_password(with_ada: str, engine: Engine) -> None:
    listed = json.loads(invoke(with_ada, "users", "list", "--format", "json").output)
    assert [(u["name"], u["role"], u["disabled"]) for u in listed] == [("ada", "planner", False)]
    assert "password_hash" not in listed[0]
    text = invoke(with_ada, "users", "list").output.splitlines()
    assert text[0].split()[:3] == ["ada", "planner", "active"] and text[-1] == "1 user(s)"

    new = "a brand new password"
    result = invoke(with_ada, "users", "set-password", "ada", "--password-stdin", stdin=new)
    assert result.output == "password of user ada set\n"
    assert invoke(with_ada, "users", "disable", "ada").output == "user ada disabled\n"
    listed = json.loads(invoke(with_ada, "users", "list", "--format", "json").output)
    assert listed[0]["disabled"] is True
    with session_scope(engine) as session:
        assert authenticate_password(session, "ada", new) is None  # disabled
        assert authenticate_password(session, "ada", PASSWORD) is None
    actions = [(action, target) for _, action, target, _ in audit(engine)]
    assert actions == [
        ("user.add", "user ada"),
        ("user.set_password", "user ada"),
        ("user.disable", "user ada"),
    ]
    assert all(new not in json.dumps(entry) for entry in audit(engine))


@pytest.mark.parametrize(
    ("args", "stdin", "message"),
    [
        (["users", "add", "ada", "--role", "viewer"], PASSWORD, "user 'ada' exists already"),
        (["users", "add", "bo", "--role", "root"], PASSWORD, "role 'root': not one of viewer"),
        (["users", "add", "bo", "--role", "viewer"], "", "the password is empty"),
        (["users", "add", "bo", "--role", "viewer"], "too short", "9 characters long"),
        (["users", "set-password", "eve"], PASSWORD, "no user 'eve'"),
        (["users", "disable", "eve"], None, "no user 'eve'"),
        (["tokens", "create", "sap", "--user", "eve"], None, "no user 'eve'"),
        (["tokens", "list", "--user", "eve"], None, "no user 'eve'"),
        (["tokens", "revoke", "7"], None, "no API token 7"),
        (["tokens", "create", "sap", "--user", "ada", "--expires-days", "-1"], None, "positive"),
    ],
)
def test_errors_are_one_line_and_change_nothing(
    with_ada: str, engine: Engine, args: list[str], stdin: str | None, message: str
) -> None:
    if args[0] == "users" and args[1] in ("add", "set-password"):
        args = [*args, "--password-stdin"]
    error = one_line_error(invoke(with_ada, *args, stdin=stdin))
    assert message in error
    with session_scope(engine, read_only=True) as session:
        assert session.scalars(select(User.name)).all() == ["ada"]
        assert session.scalars(select(ApiToken)).all() == []
    assert len(audit(engine)) == 1


def test_a_token_is_shown_once_and_listed_without_it(with_ada: str, engine: Engine) -> None:
    result = CliRunner().invoke(
        cli, ["--db", with_ada, "tokens", "create", "sap", "--user", "ada", "--expires-days", "30"]
    )
    assert result.exit_code == 0, result.output
    token = result.stdout.strip()
    assert token.startswith("cat_") and "\n" not in token
    (warning,) = result.stderr.splitlines()
    assert warning.startswith("token 1 'sap' of user ada (expires ")
    assert warning.endswith("it is not shown again")

    with session_scope(engine) as session:
        user = authenticate_token(session, token, now=session.get_one(ApiToken, 1).created_at)
        assert user is not None and user.name == "ada"
        assert token not in json.dumps([r[3] for r in audit(engine)])
    listed = invoke(with_ada, "tokens", "list", "--format", "json").output
    assert token not in listed and token not in invoke(with_ada, "tokens", "list").output
    (record,) = json.loads(listed)
    assert (record["id"], record["user"], record["name"], record["status"]) == (
        1,
        "ada",
        "sap",
        "active",
    )
    assert record["last_used_at"] is not None and record["expires_at"] is not None

    assert invoke(with_ada, "tokens", "revoke", "1").output == "token 1 'sap' of user ada revoked\n"
    (record,) = json.loads(
        invoke(with_ada, "tokens", "list", "--user", "ada", "--format", "json").output
    )
    assert record["status"] == "revoked" and record["revoked_at"] is not None
    assert "already revoked" in one_line_error(invoke(with_ada, "tokens", "revoke", "1"))
    assert [(action, target) for _, action, target, _ in audit(engine)][1:] == [
        ("token.create", "token 1"),
        ("token.revoke", "token 1"),
    ]


def test_alert_and_maintenance_changes_are_audited_with_the_system_user(
    engine: Engine, database_url: str, build: Any
) -> None:
    with session_scope(engine) as session:
        run = build.run(session)
        session.add(build.alert(run.track, "k1"))
        session.add(build.alert(run.track, "k2", start_chainage_m=2000.0, end_chainage_m=2050.0))
    assert invoke(database_url, "alerts", "ack", "1", "--by", "A. Planner").exit_code == 0
    result = invoke(database_url, "alerts", "resolve", "2", "--by", "B", "--note", "checked")
    assert result.exit_code == 0, result.output
    result = invoke(
        database_url, "maintenance", "record", "--line", "L100", "--track", "1",
        "--from-mast", "M1", "--to-mast", "M2", "--kind", "wire_replaced", "--by", "crew 3",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    # a refused change leaves no entry
    assert "alert 1 is resolved" in one_line_error(
        invoke(database_url, "alerts", "ack", "1", "--by", "C")
    )

    entries = audit(engine)
    assert {actor for actor, *_ in entries} == {system_actor()}
    assert [(action, target) for _, action, target, _ in entries] == [
        ("alert.acknowledge", "alert 1"),
        ("alert.resolve", "alert 2"),
        ("maintenance.record", "maintenance action 1"),
    ]
    assert entries[0][3] == {"by": "A. Planner", "status": "acknowledged"}
    assert entries[1][3] == {"by": "B", "status": "resolved", "note": "checked"}
    recorded = entries[2][3]
    assert recorded["by"] == "crew 3" and recorded["kind"] == "wire_replaced"
    assert (recorded["mast_from"], recorded["mast_to"]) == ("M1", "M2")
    assert recorded["from_chainage_m"] == pytest.approx(1000.0)
    assert recorded["to_chainage_m"] == pytest.approx(1050.0)
    assert recorded["resolved_alerts"] == [1]


def test_the_audit_trail_lists_newest_first_and_filters(with_ada: str, engine: Engine) -> None:
    url = with_ada
    assert invoke(url, "users", "disable", "ada").exit_code == 0
    listed = invoke(url, "audit", "list", "--format", "json")
    assert listed.exit_code == 0, listed.output
    records = json.loads(listed.output)
    assert [(r["action"], r["target"]) for r in records] == [
        ("user.disable", "user ada"),
        ("user.add", "user ada"),
    ]
    assert records[0]["actor"] == system_actor() and records[0]["at"].endswith("+00:00")
    assert (
        json.loads(invoke(url, "audit", "list", "--limit", "1", "--format", "json").output)[0][
            "action"
        ]
        == "user.disable"
    )
    assert (
        json.loads(invoke(url, "audit", "list", "--actor", "nobody", "--format", "json").output)
        == []
    )
    later = invoke(url, "audit", "list", "--since", "2999-01-01T00:00", "--format", "json")
    assert json.loads(later.output) == []
    text = invoke(url, "audit", "list")
    assert text.exit_code == 0 and text.output.strip().splitlines()[-1] == "2 change(s)"
    wrong = invoke(url, "audit", "list", "--since", "yesterday")
    assert one_line_error(wrong) == (
        "Error: --since 'yesterday': give an ISO 8601 time (2026-12-01T06:00)"
    )
