"""Two ``catenary scheduler`` services on one database, on SQLite and PostgreSQL: only the holder
of the lease runs jobs, the other waits as a standby naming it and takes over after SIGKILL (the
lease expires) or SIGTERM (it is released); a holder whose lease is taken pauses its jobs.

Each scheduler is the real command in a child process with a short lease (3 s, heartbeat 0.5 s)
and a job every 0.6 s; who ran which fire time is read from the services' logs.
"""

from __future__ import annotations

import re
import signal
import socket
import threading
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
import tomli_w
from sqlalchemy import Engine, update

from catenary.maintenance.leadership import Leadership, LeaseTiming
from catenary.storage.database import make_engine, session_scope
from catenary.storage.leases import database_now
from catenary.storage.models import SchedulerLease

from .conftest import RAW_ESCAPES
from .proxy_support import proxy_for
from .two_schedulers_support import ACQUIRED, RAN, Scheduler, wait_for_holder

LEASE_S = 3.0
HEARTBEAT_S = 0.5
SLACK_S = 3.0  # a loaded machine's delay in noticing, on top of the lease's own times

pytestmark = pytest.mark.slow


@pytest.fixture
def start(tmp_path: Path, database_url: str, engine: Engine) -> Iterator[Callable[..., Scheduler]]:
    """``start(name, url=database_url)``: a scheduler on the test's (migrated) database with a
    job ``tick`` every 0.6 s; any still running at the end is killed."""
    config = tmp_path / "catenary.toml"
    job = {"id": "tick", "job": "deliver-notifications", "interval_minutes": 0.01}
    section = {"lease_seconds": LEASE_S, "heartbeat_seconds": HEARTBEAT_S, "jobs": [job]}
    config.write_text(tomli_w.dumps({"scheduler": section}))
    started: list[Scheduler] = []

    def run(name: str, url: str = database_url) -> Scheduler:
        args = ["--config", str(config), "--db", url]
        started.append(Scheduler(args, tmp_path / f"{name}.log"))
        return started[-1]

    yield run
    for scheduler in started:
        scheduler.close()


def standby_line(holder: Scheduler) -> str:
    host = re.escape(socket.gethostname())
    return (
        rf"INFO .*: standby: host {host} process {holder.pid} holds the scheduler lease "
        r"\(since \S+\) until \S+; trying again every 0.5 s$"
    )


def assert_clean(*schedulers: Scheduler) -> None:
    for scheduler in schedulers:
        text = scheduler.text()
        assert "Traceback" not in text, text
        assert not any(escape in text for escape in RAW_ESCAPES), text


def test_one_runs_the_jobs_and_a_standby_takes_over_after_sigkill_and_sigterm(
    start: Callable[..., Scheduler],
) -> None:
    started = [start(name) for name in ("first", "second", "third")]  # at once
    holder = wait_for_holder(started)
    standbys = [scheduler for scheduler in started if scheduler is not holder]
    for standby in standbys:
        standby.wait_for(standby_line(holder))
    holder.wait_for_runs(2)
    for standby in standbys:
        assert standby.fire_times() == []  # a standby runs nothing
        assert "scheduler started" not in standby.text()  # its scheduler never started

    holder.process.kill()  # SIGKILL: the lease is not released, it expires
    holder.process.wait(30)
    killed = datetime.now(UTC)
    successor = wait_for_holder(standbys)
    taken = successor.wait_for(ACQUIRED)
    assert taken - killed < timedelta(seconds=LEASE_S + HEARTBEAT_S + SLACK_S)
    (last,) = (standby for standby in standbys if standby is not successor)
    last.wait_for(standby_line(successor))  # a new holder: one line more
    successor.wait_for(RAN.pattern)

    assert successor.stop(signal.SIGTERM) == 0, successor.text()  # released as it stops
    log = successor.text()
    assert "SIGTERM received: stopping once the running jobs finish" in log
    released = successor.wait_for(r"scheduler lease released$")
    assert log.rstrip().endswith("scheduler stopped")
    taken = last.wait_for(ACQUIRED)
    assert taken - released < timedelta(seconds=HEARTBEAT_S + SLACK_S)
    last.wait_for(RAN.pattern)
    assert last.stop(signal.SIGINT) == 0, last.text()
    assert last.text().count("standby: ") == 2  # once per holder, not at every try

    # every fire time ran once, in order: the holder's, then its successor's, then the last's
    fire_times = holder.fire_times() + successor.fire_times() + last.fire_times()
    assert len(set(fire_times)) == len(fire_times)
    assert fire_times == sorted(fire_times)
    assert_clean(*started)


def test_a_holder_whose_lease_is_taken_pauses_its_jobs_until_it_holds_it_again(
    start: Callable[..., Scheduler], engine: Engine
) -> None:
    holder = start("holder")
    holder.wait_for(RAN.pattern)

    def rewrite(expires_in: timedelta) -> None:
        """Another scheduler, on another host, holds the lease until ``expires_in``."""
        with session_scope(engine) as session:
            now = database_now(session)
            session.execute(
                update(SchedulerLease).values(
                    holder="elsewhere:7",
                    host="elsewhere",
                    pid=7,
                    acquired_at=now,
                    heartbeat_at=now,
                    expires_at=now + expires_in,
                )
            )

    rewrite(timedelta(hours=1))
    lost = holder.wait_for(
        r"WARNING .*: scheduler lease lost \(it expired or another scheduler took it\): "
        r"jobs paused, this scheduler is a standby$"
    )
    holder.wait_for(r"standby: host elsewhere process 7 holds the scheduler lease")
    time.sleep(3 * 0.6)  # three fire times fall due while it waits
    assert all(fire_time < lost for fire_time in holder.fire_times())

    rewrite(-timedelta(seconds=1))  # that one died: its lease has expired
    holder.wait_for(r"scheduler resumed: 1 job\(s\)")
    holder.wait_until(lambda: True if max(holder.fire_times()) > lost else None)
    assert holder.stop(signal.SIGTERM) == 0, holder.text()
    assert holder.text().count(ACQUIRED) == 2
    assert_clean(holder)


@pytest.mark.parametrize("database_url", ["postgresql"], indirect=True)
def test_a_holder_cut_off_from_its_database_pauses_and_the_standby_takes_over(
    start: Callable[..., Scheduler], database_url: str
) -> None:
    with proxy_for(database_url) as proxy:
        cut_off = start("cut-off", proxy.url(database_url))
        cut_off.wait_for(ACQUIRED)
        standby = start("standby")
        standby.wait_for(standby_line(cut_off))
        cut_off.wait_for(RAN.pattern)

        proxy.cut()  # the holder's database is gone; the standby's is not
        cut = datetime.now(UTC)
        lost = cut_off.wait_for(
            rf"WARNING .*: scheduler lease lost \(not renewed for {LEASE_S:g} s\): jobs paused"
        )
        assert lost - cut < timedelta(seconds=LEASE_S + SLACK_S)
        assert cut_off.wait_for(r"WARNING .*: scheduler lease: database error: ") < lost
        standby.wait_for(ACQUIRED)
        standby.wait_for(RAN.pattern)
        # never both: the cut-off one stopped before its lease expired for the database
        assert max(cut_off.fire_times()) < min(standby.fire_times())

        proxy.restore()
        cut_off.wait_for(r"scheduler lease: the database answers again")
        cut_off.wait_for(standby_line(standby))
        assert cut_off.stop(signal.SIGTERM) == 0, cut_off.text()
        assert standby.stop(signal.SIGTERM) == 0, standby.text()
    fire_times = cut_off.fire_times() + standby.fire_times()
    assert len(set(fire_times)) == len(fire_times)
    assert_clean(standby)


@pytest.mark.parametrize("database_url", ["postgresql"], indirect=True)
def test_a_heartbeat_cut_off_mid_statement_keeps_the_lease_for_its_term(
    database_url: str, engine: Engine
) -> None:
    """A connection lost during the renewal (``DatabaseUnavailable``, not a bare driver
    error) is a database error like any other: the holder keeps its lease until its term ends,
    then pauses, instead of dying."""
    with proxy_for(database_url) as proxy:
        through = make_engine(proxy.url(database_url))
        try:
            leadership = Leadership(through, LeaseTiming(lease_s=3.0, heartbeat_s=1.0))
            assert leadership.wait_for_lease(threading.Event())
            proxy.cut_on(b"UPDATE scheduler_leases")
            assert leadership.renew()  # within its term: still the holder
            time.sleep(3.0)
            assert not leadership.renew()  # not renewed for a whole term: lost
        finally:
            through.dispose()
