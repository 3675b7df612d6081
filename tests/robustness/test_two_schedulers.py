"""Two ``catenary scheduler`` services on one database, on SQLite and PostgreSQL: only the holder
of the lease runs jobs, the other waits as a standby naming it and takes over after SIGKILL (the
lease expires) or SIGTERM (it is released); a holder whose lease is taken pauses its jobs.

Each scheduler is the real command in a child process with a short lease (3 s, heartbeat 0.5 s)
and a job every 0.6 s; who ran which fire time is read from the services' logs.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import TypeVar

import pytest
import tomli_w
from sqlalchemy import Engine, update

from catenary.storage.database import session_scope
from catenary.storage.leases import database_now
from catenary.storage.models import SchedulerLease

from .conftest import RAW_ESCAPES

LEASE_S = 3.0
HEARTBEAT_S = 0.5
SLACK_S = 3.0  # a loaded machine's delay in noticing, on top of the lease's own times
RAN = re.compile(r"job 'tick' ran for (\S+)")
LOG_TIME = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) ", re.MULTILINE)

pytestmark = pytest.mark.slow
T = TypeVar("T")


class Scheduler:
    """``catenary scheduler`` in a child process; its log (UTC times) in a file."""

    def __init__(self, args: list[str], log: Path) -> None:
        self.log = log
        self._handle = log.open("w")
        self.process = subprocess.Popen(
            [sys.executable, "-m", "catenary.cli", *args, "scheduler"],
            env={**os.environ, "TZ": "UTC"},
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=self._handle,
        )
        self.pid = self.process.pid

    def text(self) -> str:
        return self.log.read_text()

    def fire_times(self) -> list[datetime]:
        return [datetime.fromisoformat(t) for t in RAN.findall(self.text())]

    def wait_until(self, found: Callable[[], T | None], timeout_s: float = 30.0) -> T:
        """What ``found()`` returns, once it is not None (the service still running)."""
        deadline = time.monotonic() + timeout_s
        while (value := found()) is None:
            assert self.process.poll() is None, self.text()
            assert time.monotonic() < deadline, f"timed out; the log:\n{self.text()}"
            time.sleep(0.05)
        return value

    def wait_for(self, pattern: str) -> datetime:
        """The log time of the first line matching ``pattern``, once there is one."""

        def first() -> datetime | None:
            lines = (line for line in self.text().splitlines() if re.search(pattern, line))
            return next(map(logged_at, lines), None)

        return self.wait_until(first)

    def wait_for_runs(self, count: int) -> list[datetime]:
        """Its fire times, once it has run ``count`` at least."""
        return self.wait_until(lambda: times if len(times := self.fire_times()) >= count else None)

    def stop(self, signum: int) -> int:
        self.process.send_signal(signum)
        return self.process.wait(30)

    def close(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait(30)
        self._handle.close()


def logged_at(line: str) -> datetime:
    match = LOG_TIME.match(line)
    assert match is not None, line
    return datetime.strptime(match.group(1), "%Y-%m-%d %H:%M:%S,%f").replace(tzinfo=UTC)


@pytest.fixture
def start(
    tmp_path: Path, database_url: str, engine: Engine
) -> Iterator[Callable[[str], Scheduler]]:
    """``start(name)``: a scheduler on the test's (migrated) database with a job ``tick`` every
    0.6 s; any still running at the end is killed."""
    config = tmp_path / "catenary.toml"
    job = {"id": "tick", "job": "deliver-notifications", "interval_minutes": 0.01}
    section = {"lease_seconds": LEASE_S, "heartbeat_seconds": HEARTBEAT_S, "jobs": [job]}
    config.write_text(tomli_w.dumps({"scheduler": section}))
    started: list[Scheduler] = []

    def run(name: str) -> Scheduler:
        args = ["--config", str(config), "--db", database_url]
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
    start: Callable[[str], Scheduler],
) -> None:
    first = start("first")
    first.wait_for(r"scheduler lease acquired by this process")
    first.wait_for(RAN.pattern)
    second = start("second")
    second.wait_for(standby_line(first))
    first.wait_for_runs(len(first.fire_times()) + 3)  # the holder goes on
    assert second.fire_times() == []  # the standby runs nothing
    assert "scheduler started" not in second.text()  # its scheduler never started

    first.process.kill()  # SIGKILL: the lease is not released, it expires
    first.process.wait(30)
    killed = datetime.now(UTC)
    taken = second.wait_for(r"scheduler lease acquired by this process")
    assert taken - killed < timedelta(seconds=LEASE_S + HEARTBEAT_S + SLACK_S)
    second.wait_for(RAN.pattern)

    third = start("third")
    third.wait_for(standby_line(second))
    assert second.stop(signal.SIGTERM) == 0, second.text()  # released as it stops
    log = second.text()
    assert "SIGTERM received: stopping once the running jobs finish" in log
    released = second.wait_for(r"scheduler lease released$")
    assert log.rstrip().endswith("scheduler stopped")
    taken = third.wait_for(r"scheduler lease acquired by this process")
    assert taken - released < timedelta(seconds=HEARTBEAT_S + SLACK_S)
    third.wait_for(RAN.pattern)
    assert third.stop(signal.SIGINT) == 0, third.text()

    # every fire time ran once, in order: the first's, then the second's, then the third's
    fire_times = first.fire_times() + second.fire_times() + third.fire_times()
    assert len(set(fire_times)) == len(fire_times)
    assert fire_times == sorted(fire_times)
    assert_clean(first, second, third)


def test_a_holder_whose_lease_is_taken_pauses_its_jobs_until_it_holds_it_again(
    start: Callable[[str], Scheduler], engine: Engine
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
    time.sleep(5 * 0.6)  # five fire times fall due while it waits
    assert all(fire_time < lost for fire_time in holder.fire_times())

    rewrite(-timedelta(seconds=1))  # that one died: its lease has expired
    holder.wait_for(r"scheduler resumed: 1 job\(s\)")
    holder.wait_until(lambda: True if max(holder.fire_times()) > lost else None)
    assert holder.stop(signal.SIGTERM) == 0, holder.text()
    assert holder.text().count("scheduler lease acquired by this process") == 2
    assert_clean(holder)
