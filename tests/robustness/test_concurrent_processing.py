"""Two different runs of one new line and track processed at once: both are stored, sharing
the new line, track, masts, vehicle and rig calibration (on PostgreSQL the second's insert
of them used to break a unique key: a traceback, and its run lost)."""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable
from pathlib import Path

import pytest
import sqlalchemy as sa
from sqlalchemy import Engine
from sqlalchemy.engine import make_url

from catenary.storage.database import session_scope
from catenary.storage.models import Run

from ..conftest import SmallRun
from .conftest import assert_succeeded, finished, start_catenary

pytestmark = pytest.mark.slow  # the real CLI on simulated runs


def _wait_for(condition: Callable[[], bool], what: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting until {what}"
        time.sleep(0.05)


def test_two_runs_of_a_new_track_processed_at_once_are_both_stored(
    small_run: SmallRun,
    second_small_run: SmallRun,
    engine: Engine,
    database_url: str,
    isolated_environment: Path,
) -> None:
    postgresql = engine.dialect.name == "postgresql"
    name = f"catenary-test-{uuid.uuid4().hex[:12]}"  # finds the processes' connections
    url = database_url
    if postgresql:
        url = make_url(url).update_query_dict({"application_name": name})
        url = url.render_as_string(hide_password=False)
    samples = isolated_environment / "samples"

    def both_wait() -> bool:
        """Both stores wait: on PostgreSQL one for the lock on runs, holding its new rows,
        the other for those rows; on SQLite both for the write lock, measured."""
        if not postgresql:
            return len(list(samples.glob(".samples-*"))) == 2 and not list(samples.glob(".pass1-*"))
        with engine.connect() as connection:
            waiting = connection.execute(
                sa.text(
                    "SELECT count(*) FROM pg_locks JOIN pg_stat_activity USING (pid) "
                    "WHERE NOT granted AND application_name = :name"
                ),
                {"name": name},
            ).scalar()
        return waiting == 2

    with session_scope(engine) as holding:
        # runs are written by nobody else until both processes wait in their stores
        holding.execute(sa.text("LOCK TABLE runs IN EXCLUSIVE MODE" if postgresql else "SELECT 1"))
        processes = [
            start_catenary(
                "process", run, "--rig", small_run.rig, "--masts", small_run.masts, "--db", url
            )
            for run in (small_run.run, second_small_run.run)
        ]
        try:
            _wait_for(
                lambda: both_wait() or any(p.poll() is not None for p in processes), "both wait"
            )
        except BaseException:
            for process in processes:
                process.kill()
            raise
    for process in processes:
        assert_succeeded(finished(process, timeout=60))
    with session_scope(engine, read_only=True) as session:
        tracks = session.execute(sa.select(Run.track_id, Run.rig_calibration_id)).all()
    assert len(tracks) == 2 and len(set(tracks)) == 1  # one track, one calibration
    stored = [p for p in samples.rglob("*.parquet") if not p.name.startswith(".")]
    assert len(stored) == 2
