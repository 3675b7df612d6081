"""Concurrent transactions: writers wait for each other, readers never wait for a writer."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import pytest
import sqlalchemy as sa
from click.testing import CliRunner
from sqlalchemy import Engine

from catenary.cli import cli
from catenary.storage import database
from catenary.storage.database import make_engine, session_scope


@pytest.fixture
def counter(engine: Engine) -> Engine:
    with engine.begin() as connection:
        connection.exec_driver_sql("CREATE TABLE counter (n INTEGER NOT NULL)")
        connection.exec_driver_sql("INSERT INTO counter VALUES (0)")
    return engine


@contextmanager
def _writer_holding_the_lock(database_url: str, statement: str) -> Iterator[None]:
    """A transaction in another thread that has run ``statement`` and holds its write lock
    (uncommitted) until the block ends."""
    holding = threading.Event()
    release = threading.Event()

    def hold() -> None:
        engine = make_engine(database_url)
        try:
            with session_scope(engine) as session:
                session.execute(sa.text(statement))
                holding.set()
                release.wait(20)
        finally:
            engine.dispose()

    with ThreadPoolExecutor(1) as pool:
        writer = pool.submit(hold)
        try:
            assert holding.wait(20)
            yield
        finally:
            release.set()
            writer.result(timeout=30)


def _in_threads(count: int, work: Callable[[], object]) -> list[object]:
    with ThreadPoolExecutor(count) as pool:
        futures = [pool.submit(work) for _ in range(count)]
        return [future.result(timeout=30) for future in futures]


def test_writers_that_read_first_wait_for_each_other(counter: Engine, database_url: str) -> None:
    # each reads, holds its transaction 0.5 s, then writes: with a deferred BEGIN on SQLite
    # the second writer failed at once with "database is locked"
    def write() -> int:
        engine = make_engine(database_url)
        try:
            with session_scope(engine) as session:
                seen = session.execute(sa.text("SELECT n FROM counter")).scalar_one()
                time.sleep(0.5)
                session.execute(sa.text("UPDATE counter SET n = n + 1"))
                return int(seen)
        finally:
            engine.dispose()

    _in_threads(2, write)
    with session_scope(counter, read_only=True) as session:
        assert session.execute(sa.text("SELECT n FROM counter")).scalar_one() == 2


def test_a_reader_does_not_wait_for_a_writer(
    counter: Engine, database_url: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(database, "SQLITE_BUSY_TIMEOUT_MS", 2_000)
    with _writer_holding_the_lock(database_url, "UPDATE counter SET n = 7"):
        reader = make_engine(database_url)
        try:
            started = time.monotonic()
            with session_scope(reader, read_only=True) as session:
                seen = session.execute(sa.text("SELECT n FROM counter")).scalar_one()
            assert seen == 0  # the writer's change is not committed yet
            assert time.monotonic() - started < 1.5
        finally:
            reader.dispose()


def test_sqlite_writers_begin_immediate_and_readers_deferred(tmp_path: object) -> None:
    engine = make_engine(f"sqlite:///{tmp_path}/x.sqlite")
    statements: list[str] = []
    sa.event.listen(
        engine, "before_cursor_execute", lambda c, cur, stmt, *rest: statements.append(stmt)
    )
    try:
        with session_scope(engine) as session:
            session.execute(sa.text("SELECT 1"))
        with session_scope(engine, read_only=True) as session:
            session.execute(sa.text("SELECT 1"))
    finally:
        engine.dispose()
    begins = [s for s in statements if s.startswith("BEGIN")]
    assert begins == ["BEGIN IMMEDIATE", "BEGIN"]


@pytest.mark.parametrize("command", [["alerts", "list"], ["notify", "status"]])
def test_read_only_commands_do_not_wait_for_a_writer(
    migrated: Engine, database_url: str, monkeypatch: pytest.MonkeyPatch, command: list[str]
) -> None:
    # a command that waited for the writer would fail with "database is locked" after 0.5 s
    monkeypatch.setattr(database, "SQLITE_BUSY_TIMEOUT_MS", 500)
    with _writer_holding_the_lock(database_url, "DELETE FROM alerts"):
        result = CliRunner().invoke(cli, ["--db", database_url, *command])
        assert result.exit_code == 0, result.output
