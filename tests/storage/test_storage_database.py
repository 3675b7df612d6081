"""Engines: URLs, SQLite set-up, and the one-line errors a user can cause."""

from __future__ import annotations

import sqlite3
import time
from pathlib import Path

import pytest
import sqlalchemy as sa

from catenary.config import Settings
from catenary.errors import DatabaseNotMigrated, UserError
from catenary.storage import migrate
from catenary.storage.database import (
    SQLITE_BUSY_TIMEOUT_MS,
    DatabaseUnavailable,
    make_engine,
    mask_url,
    open_database,
    require_migrated,
    session_scope,
)

UNREACHABLE = "postgresql+psycopg://fleet:s3cret@127.0.0.1:1/catenary"


@pytest.mark.parametrize(
    ("url", "masked"),
    [
        (UNREACHABLE, "postgresql+psycopg://fleet:***@127.0.0.1:1/catenary"),
        ("sqlite:////data/catenary.sqlite", "sqlite:////data/catenary.sqlite"),
        ("bad//user:s3cret@host", "bad//user:***@host"),
        ("fleet:s3cret@host/db", "fleet:***@host/db"),
        ("postgresql+psycopg://u:s3c@ret@h:x/d", "postgresql+psycopg://u:***@h:x/d"),
        (
            "postgresql+psycopg://fleet@h/d?sslmode=require&password=s3cret&sslpassword=s3cret",
            "postgresql+psycopg://fleet@h/d?password=***&sslmode=require&sslpassword=***",
        ),
        (
            "postgresql+psycopg://fleet@h:x/d?PASSWORD=s3cret",
            "postgresql+psycopg://fleet@h:x/d?PASSWORD=***",
        ),
    ],
)
def test_mask_url(url: str, masked: str) -> None:
    assert mask_url(url) == masked


@pytest.mark.parametrize(
    ("url", "message"),
    [
        ("nonsense", "malformed database URL 'nonsense'"),
        ("nonsense://x", "unknown database driver 'nonsense' in nonsense://x"),
        ("postgresql+nodriver://u:s3cret@h/d", "unknown database driver 'postgresql+nodriver'"),
        ("mysql+mysqldb://u:s3cret@h/d", "mysql+mysqldb://u:***@h/d is not installed"),
        (
            "postgresql+psycopg://u:s3cret@h:5432x/d",
            "malformed database URL 'postgresql+psycopg://u:***@h:5432x/d': "
            "the port is not a number",
        ),
        (
            "postgresql+psycopg://u@h:x/d?password=s3cret",
            "malformed database URL 'postgresql+psycopg://u@h:x/d?password=***'",
        ),
        (
            "mysql+mysqldb://u@h/d?password=s3cret",
            "mysql+mysqldb://u@h/d?password=*** is not installed",
        ),
    ],
)
def test_bad_url_is_one_line_with_password_masked(url: str, message: str) -> None:
    with pytest.raises(UserError) as raised:
        make_engine(url)
    assert message in str(raised.value)
    assert "\n" not in str(raised.value)
    assert "s3cret" not in str(raised.value)


@pytest.mark.parametrize(
    "url", [UNREACHABLE, "postgresql+psycopg://fleet@127.0.0.1:1/catenary?password=s3cret"]
)
def test_unreachable_server_is_one_line_with_password_masked(url: str) -> None:
    engine = make_engine(url)
    try:
        with pytest.raises(UserError) as raised:
            require_migrated(engine)
    finally:
        engine.dispose()
    message = str(raised.value)
    assert message.startswith(f"cannot connect to database {mask_url(url)}: ")
    assert "\n" not in message
    assert "s3cret" not in message


def test_sqlite_creates_the_directory_and_enforces_foreign_keys(tmp_path: Path) -> None:
    path = tmp_path / "a" / "b" / "catenary.sqlite"
    engine = make_engine(f"sqlite:///{path}")
    try:
        assert path.parent.is_dir()
        with engine.connect() as connection:
            assert connection.exec_driver_sql("PRAGMA foreign_keys").scalar() == 1
            assert (connection.exec_driver_sql("PRAGMA busy_timeout").scalar() or 0) >= 10_000
    finally:
        engine.dispose()
    assert path.is_file()


def test_sqlite_expands_the_home_directory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HOME", str(tmp_path))
    engine = make_engine("sqlite:///~/catenary/catenary.sqlite")
    try:
        assert engine.url.database == str(tmp_path / "catenary" / "catenary.sqlite")
        assert (tmp_path / "catenary").is_dir()
    finally:
        engine.dispose()


def test_sqlite_directory_that_cannot_be_made(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("not a directory")
    with pytest.raises(UserError, match="cannot create the directory of database sqlite:///"):
        make_engine(f"sqlite:///{tmp_path / 'file' / 'catenary.sqlite'}")


def test_sqlite_file_that_is_not_a_database(tmp_path: Path) -> None:
    path = tmp_path / "catenary.sqlite"
    path.write_bytes(b"this is not a database, just some text " * 100)
    engine = make_engine(f"sqlite:///{path}")
    try:
        with pytest.raises(UserError, match=f"database sqlite:///{path}") as raised:
            require_migrated(engine)
        assert "\n" not in str(raised.value)
    finally:
        engine.dispose()


def test_sqlite_in_memory() -> None:
    engine = make_engine("sqlite://")
    try:
        with engine.connect() as connection:
            assert connection.exec_driver_sql("PRAGMA foreign_keys").scalar() == 1
    finally:
        engine.dispose()


def test_sqlite_ddl_is_transactional(tmp_path: Path) -> None:
    """Python's sqlite3 runs DDL outside transactions unless told otherwise."""
    engine = make_engine(f"sqlite:///{tmp_path / 'x.sqlite'}")
    try:
        with pytest.raises(RuntimeError), engine.begin() as connection:
            connection.exec_driver_sql("CREATE TABLE t (id INTEGER)")
            raise RuntimeError
        assert sa.inspect(engine).get_table_names() == []
    finally:
        engine.dispose()


def test_open_database_checks_the_migration(database_url: str) -> None:
    with pytest.raises(DatabaseNotMigrated), open_database(database_url):
        pass
    with open_database(database_url, migrated=False, create=True) as engine:
        migrate.upgrade(engine)
    with open_database(database_url) as engine:
        assert migrate.current_revision(engine) == migrate.head_revision()


def test_a_sqlite_file_that_does_not_exist_is_refused_not_created(tmp_path: Path) -> None:
    file = tmp_path / "none.sqlite"
    for migrated in (True, False):
        with (
            pytest.raises(
                DatabaseNotMigrated, match=r"none\.sqlite does not exist: run 'catenary db upgrade'"
            ),
            open_database(f"sqlite:///{file}", migrated=migrated),
        ):
            pass
    assert not file.exists()


@pytest.mark.parametrize("batch", [False, True])
def test_the_statement_timeout_bounds_interactive_commands_only(
    database_url: str, tmp_path: Path, batch: bool
) -> None:
    settings = Settings(database_url=database_url, data_dir=tmp_path, statement_timeout_s=1.5)
    with (
        open_database(settings, migrated=False, create=True, batch=batch) as engine,
        engine.connect() as connection,
    ):
        if engine.dialect.name == "postgresql":
            timeout = connection.exec_driver_sql("SHOW statement_timeout").scalar()
            assert timeout == ("0" if batch else "1500ms")
            # the URL's own options (the test's schema) are kept
            assert "catenary_test_" in str(connection.exec_driver_sql("SHOW search_path").scalar())
            # a host that has gone is found within a minute (measured: 61 s idle, 60.6 s with a
            # statement sent, loopback cut in a private network namespace)
            parameters = connection.connection.dbapi_connection.info.get_parameters()
            assert {k: parameters[k] for k in ("keepalives_idle", "tcp_user_timeout")} == {
                "keepalives_idle": "30",
                "tcp_user_timeout": "60000",
            }
        else:  # SQLite: the wait for another writer's lock
            timeout = connection.exec_driver_sql("PRAGMA busy_timeout").scalar()
            assert timeout == (SQLITE_BUSY_TIMEOUT_MS if batch else 1500)


def test_a_sqlite_write_lock_not_granted_in_time_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "c.sqlite"
    engine = make_engine(f"sqlite:///{path}", statement_timeout_s=0.2)
    holder = sqlite3.connect(path, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")
    try:
        start = time.monotonic()
        with pytest.raises(DatabaseUnavailable) as caught, session_scope(engine) as session:
            session.execute(sa.text("SELECT 1"))
        assert time.monotonic() - start < 5
    finally:
        holder.rollback()
        holder.close()
        engine.dispose()
    assert str(caught.value) == (
        f"database sqlite:///{path} is locked by another writer: gave up after 0.2 s"
    )
