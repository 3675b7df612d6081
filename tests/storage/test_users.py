"""Users, API tokens and the audit trail in the database, on both backends."""

from __future__ import annotations

import hashlib
from datetime import UTC, datetime, timedelta

import pytest
from argon2 import PasswordHasher
from sqlalchemy import Engine, select

from catenary.errors import UserError
from catenary.storage.database import session_scope
from catenary.storage.models import ApiToken, AuditEntry, User
from catenary.storage.users import (
    add_user,
    authenticate_password,
    authenticate_token,
    create_token,
    disable_user,
    list_tokens,
    list_users,
    revoke_token,
    set_password,
    system_actor,
)

NOW = datetime(2026, 12, 1, 8, 0, tzinfo=UTC)
PASSWORD = "correct horse battery"
ACTOR = "system:tester@host"


@pytest.fixture
def planner(migrated: Engine) -> Engine:
    """The database with one planner, ``ada``, whose password is ``PASSWORD``."""
    with session_scope(migrated) as session:
        add_user(session, "ada", "planner", PASSWORD, actor=ACTOR, now=NOW)
    return migrated


def audit(engine: Engine) -> list[tuple[str, str, str]]:
    with session_scope(engine, read_only=True) as session:
        entries = session.scalars(select(AuditEntry).order_by(AuditEntry.id))
        return [(e.actor, e.action, e.target) for e in entries]


def test_the_password_is_kept_as_an_argon2_hash(planner: Engine) -> None:
    with session_scope(planner, read_only=True) as session:
        (user,) = list_users(session)
        assert (user.name, user.role, user.disabled) == ("ada", "planner", False)
        assert user.password_hash.startswith("$argon2id$")
        assert PASSWORD not in user.password_hash
        assert PasswordHasher().verify(user.password_hash, PASSWORD)
    assert audit(planner) == [(ACTOR, "user.add", "user ada")]


def test_sign_in_with_the_right_password_only(planner: Engine) -> None:
    with session_scope(planner) as session:
        user = authenticate_password(session, "ada", PASSWORD)
        assert user is not None and user.name == "ada"
        assert authenticate_password(session, "ada", PASSWORD + "!") is None
        assert authenticate_password(session, "ada", "") is None
        assert authenticate_password(session, "nobody", PASSWORD) is None


def test_a_new_password_replaces_the_old(planner: Engine) -> None:
    later = NOW + timedelta(hours=1)
    with session_scope(planner) as session:
        set_password(session, "ada", "another long password", actor=ACTOR, now=later)
    with session_scope(planner) as session:
        assert authenticate_password(session, "ada", PASSWORD) is None
        user = authenticate_password(session, "ada", "another long password")
        assert user is not None and user.updated_at == later
    assert audit(planner)[-1] == (ACTOR, "user.set_password", "user ada")


def test_a_disabled_user_is_refused(planner: Engine) -> None:
    with session_scope(planner) as session:
        _, token = create_token(session, "ada", "sap", actor=ACTOR, now=NOW)
        disable_user(session, "ada", actor=ACTOR, now=NOW)
    with session_scope(planner) as session:
        assert authenticate_password(session, "ada", PASSWORD) is None
        assert authenticate_token(session, token, now=NOW) is None
        with pytest.raises(UserError, match="already disabled"):
            disable_user(session, "ada", actor=ACTOR, now=NOW)
    assert audit(planner)[-1] == (ACTOR, "user.disable", "user ada")


@pytest.mark.parametrize(
    ("name", "role", "password", "message"),
    [
        ("ada", "viewer", PASSWORD, "user 'ada' exists already"),
        ("bob", "boss", PASSWORD, "role 'boss': not one of viewer, planner, admin"),
        ("bob", "viewer", "", "the password is empty (at least 12 characters)"),
        ("bob", "viewer", "eleven char", "the password is 11 characters long (at least 12"),
        ("bob\x1b[2J", "viewer", PASSWORD, "holds a control character"),
        (" bob", "viewer", PASSWORD, "without leading or trailing spaces"),
        ("b" * 201, "viewer", PASSWORD, "user name is 201 characters long (at most 200)"),
    ],
)
def test_bad_users_are_refused_in_one_line(
    planner: Engine, name: str, role: str, password: str, message: str
) -> None:
    with session_scope(planner) as session, pytest.raises(UserError) as caught:
        add_user(session, name, role, password, actor=ACTOR, now=NOW)
    assert message in str(caught.value) and "\n" not in str(caught.value)
    assert password == "" or password not in str(caught.value)
    with session_scope(planner, read_only=True) as session:
        assert [u.name for u in list_users(session)] == ["ada"]


def test_a_token_is_kept_as_its_sha256_and_marks_its_use(planner: Engine) -> None:
    with session_scope(planner) as session:
        row, token = create_token(session, "ada", "sap", actor=ACTOR, now=NOW)
        token_id = row.id
    assert token.startswith("cat_") and len(token) > 40
    later = NOW + timedelta(days=3)
    with session_scope(planner) as session:
        stored = session.get_one(ApiToken, token_id)
        assert stored.token_hash == hashlib.sha256(token.encode()).hexdigest()
        assert stored.last_used_at is None
        user = authenticate_token(session, token, now=later)
        assert user is not None and user.name == "ada"
    with session_scope(planner, read_only=True) as session:
        assert session.get_one(ApiToken, token_id).last_used_at == later
        assert session.scalars(select(ApiToken.token_hash)).all() == [stored.token_hash]
    assert audit(planner)[-1] == (ACTOR, "token.create", f"token {token_id}")


def test_unknown_expired_and_revoked_tokens_are_refused(planner: Engine) -> None:
    with session_scope(planner) as session:
        brief, brief_token = create_token(
            session, "ada", "brief", actor=ACTOR, now=NOW, expires_days=1
        )
        revoked, revoked_token = create_token(session, "ada", "old", actor=ACTOR, now=NOW)
        revoke_token(session, revoked.id, actor=ACTOR, now=NOW)
        brief_id = brief.id
    with session_scope(planner) as session:
        assert authenticate_token(session, brief_token, now=NOW + timedelta(hours=23)) is not None
        assert authenticate_token(session, brief_token, now=NOW + timedelta(days=1)) is None
        assert authenticate_token(session, revoked_token, now=NOW) is None
        assert authenticate_token(session, "cat_" + "x" * 43, now=NOW) is None
        assert authenticate_token(session, "", now=NOW) is None
        with pytest.raises(UserError, match="already revoked"):
            revoke_token(session, revoked.id, actor=ACTOR, now=NOW)
        with pytest.raises(UserError, match="no API token 99"):
            revoke_token(session, 99, actor=ACTOR, now=NOW)
        assert session.get_one(ApiToken, brief_id).last_used_at == NOW + timedelta(hours=23)
    assert audit(planner)[-1] == (ACTOR, "token.revoke", f"token {revoked.id}")


def test_tokens_are_listed_by_user_and_names_are_unique_per_user(planner: Engine) -> None:
    with session_scope(planner) as session:
        add_user(session, "bob", "viewer", PASSWORD, actor=ACTOR, now=NOW)
        create_token(session, "ada", "sap", actor=ACTOR, now=NOW)
        create_token(session, "bob", "sap", actor=ACTOR, now=NOW)
        with pytest.raises(UserError, match="user 'ada' has a token 'sap' already"):
            create_token(session, "ada", "sap", actor=ACTOR, now=NOW)
        with pytest.raises(UserError, match="positive number of days"):
            create_token(session, "ada", "other", actor=ACTOR, now=NOW, expires_days=0)
        with pytest.raises(UserError, match="no user 'eve'"):
            create_token(session, "eve", "sap", actor=ACTOR, now=NOW)
    with session_scope(planner, read_only=True) as session:
        assert [(t.user.name, t.name) for t in list_tokens(session)] == [
            ("ada", "sap"),
            ("bob", "sap"),
        ]
        assert [t.user.name for t in list_tokens(session, "bob")] == ["bob"]


def test_deleting_a_user_deletes_their_tokens(planner: Engine) -> None:
    with session_scope(planner) as session:
        create_token(session, "ada", "sap", actor=ACTOR, now=NOW)
    with planner.begin() as connection:
        connection.execute(User.__table__.delete())
    with session_scope(planner, read_only=True) as session:
        assert session.scalars(select(ApiToken)).all() == []


def test_the_system_actor_names_the_os_user_and_host() -> None:
    actor = system_actor()
    assert actor.startswith("system:") and "@" in actor
