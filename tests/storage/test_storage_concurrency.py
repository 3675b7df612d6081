"""Concurrent transactions: writers wait for each other, readers never wait for a writer, and
two that add the same new rows share them."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager

import numpy as np
import pytest
import sqlalchemy as sa
from click.testing import CliRunner
from sqlalchemy import Engine
from sqlalchemy.orm import Session

from catenary.cli import cli
from catenary.domain import TrackRegister, VehicleGeometry
from catenary.storage import database
from catenary.storage.database import make_engine, session_scope
from catenary.storage.models import Mast
from catenary.storage.rigs import register_rig_calibration
from catenary.storage.runs import register_track, track_masts


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


REGISTER = TrackRegister(
    line="L9",
    track="1",
    mast=("M1", "M2"),
    chainage_m=np.array([1000.0, 1050.0]),
    wire_type=("CTA120", "CTA120"),
    design_stagger_mm=np.array([200.0, np.nan]),
)
GEOMETRY = VehicleGeometry("inspection-car-9", 3900.0, 1100.0, 1800.0)


def _waits_for_a_lock(engine: Engine, pid: int | None) -> bool:
    """Whether PostgreSQL backend ``pid`` waits for a lock (SQLite: after a moment, for its
    lock: a writer waits when it begins)."""
    if pid is None:
        time.sleep(0.3)
        return True
    with engine.connect() as connection:
        query = sa.text("SELECT count(*) FROM pg_locks WHERE pid = :pid AND NOT granted")
        return bool(connection.execute(query, {"pid": pid}).scalar())


def test_two_runs_adding_the_same_new_rows_at_once_share_them(migrated: Engine) -> None:
    """Two transactions add the same new line, track, masts and vehicle, and two versions of
    one rig calibration, the second while the first is not committed: no unique key breaks,
    both end with the same rows and the second calibration is version 2."""

    def add(session: Session, rig_text: str) -> tuple[int, ...]:
        line, track = register_track(session, "L9", "1")
        track_masts(session, track, REGISTER)
        calibration = register_rig_calibration(session, GEOMETRY, "roof-rig", rig_text)
        masts = session.scalars(sa.select(Mast.id).where(Mast.track_id == track.id)).all()
        return line.id, track.id, *sorted(masts), calibration.vehicle_id, calibration.version

    postgresql = migrated.dialect.name == "postgresql"
    started = threading.Event()
    pid: list[int | None] = []

    def second() -> tuple[int, ...]:
        with session_scope(migrated) as session:
            if postgresql:
                pid.append(session.scalar(sa.text("SELECT pg_backend_pid()")))
            else:
                pid.append(None)
            started.set()
            return add(session, "a = 2\n")

    with ThreadPoolExecutor(1) as pool:
        with session_scope(migrated) as session:
            first = add(session, "a = 1\n")
            theirs = pool.submit(second)
            assert started.wait(20)
            deadline = time.monotonic() + 20
            while not _waits_for_a_lock(migrated, pid[0]):
                assert time.monotonic() < deadline, "the second transaction never waited"
                time.sleep(0.02)
        result = theirs.result(timeout=30)
    assert first[:-1] == result[:-1] and (first[-1], result[-1]) == (1, 2)
