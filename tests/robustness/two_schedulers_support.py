"""Helpers of ``test_two_schedulers.py``: ``catenary scheduler`` in a child process, read through
its log, and a TCP proxy on 127.0.0.1 that a test cuts to take a database away from one process
(the shared PostgreSQL server itself is never touched)."""

from __future__ import annotations

import contextlib
import os
import re
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import TypeVar

ACQUIRED = "scheduler lease acquired by this process"
RAN = re.compile(r"job 'tick' ran for (\S+)")
LOG_TIME = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) ")

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


class Proxy:
    """A TCP proxy from a port of 127.0.0.1 to ``upstream``. ``cut()`` closes every connection
    through it and closes new ones at once (the database is gone for whoever uses the proxy);
    ``restore()`` lets new ones through again."""

    def __init__(self, upstream: tuple[str, int]) -> None:
        self._upstream = upstream
        self._listener = socket.create_server(("127.0.0.1", 0))
        self.port = int(self._listener.getsockname()[1])
        self._cut = threading.Event()
        self._lock = threading.Lock()
        self._open: set[socket.socket] = set()
        threading.Thread(target=self._accept, name="proxy", daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self._listener.accept()
            except OSError:  # closed
                return
            if self._cut.is_set():
                client.close()
                continue
            try:
                server = socket.create_connection(self._upstream, timeout=10)
            except OSError:
                client.close()
                continue
            server.settimeout(None)
            with self._lock:
                self._open |= {client, server}
            for source, sink in ((client, server), (server, client)):
                threading.Thread(target=_pump, args=(source, sink), daemon=True).start()

    def cut(self) -> None:
        self._cut.set()
        with self._lock:
            sockets, self._open = self._open, set()
        for sock in sockets:
            _close(sock)

    def restore(self) -> None:
        self._cut.clear()

    def close(self) -> None:
        self.cut()
        _close(self._listener)  # shutdown wakes the accepting thread


def _pump(source: socket.socket, sink: socket.socket) -> None:
    try:
        while data := source.recv(65536):
            sink.sendall(data)
    except OSError:
        pass
    _close(source)
    _close(sink)


def _close(sock: socket.socket) -> None:
    with contextlib.suppress(OSError):
        sock.shutdown(socket.SHUT_RDWR)
    sock.close()
