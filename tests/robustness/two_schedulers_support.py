"""Helpers of ``test_two_schedulers.py``: ``catenary scheduler`` in a child process, read through
its log."""

from __future__ import annotations

import re
import subprocess
import time
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import TypeVar

from .conftest import start_catenary

ACQUIRED = "scheduler lease acquired by this process"
RAN = re.compile(r"job 'tick' ran for (\S+)")
LOG_TIME = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) ")

T = TypeVar("T")


class Scheduler:
    """``catenary scheduler`` in a child process; its log (UTC times) in a file."""

    def __init__(self, args: list[str], log: Path) -> None:
        self.log = log
        self._handle = log.open("w")
        self.process = start_catenary(
            *args, "scheduler", env={"TZ": "UTC"}, stdout=subprocess.DEVNULL, stderr=self._handle
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


def wait_for_holder(candidates: list[Scheduler], timeout_s: float = 30.0) -> Scheduler:
    """The one of ``candidates`` that logged it acquired the lease, once one has; only one may
    have."""
    deadline = time.monotonic() + timeout_s
    while not (holders := [one for one in candidates if ACQUIRED in one.text()]):
        for one in candidates:
            assert one.process.poll() is None, one.text()
        assert time.monotonic() < deadline, "no scheduler acquired the lease"
        time.sleep(0.05)
    assert len(holders) == 1, [holder.text() for holder in holders]
    return holders[0]
