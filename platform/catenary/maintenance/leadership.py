"""Which ``catenary scheduler`` of a database runs the jobs: the holder of the lease
``scheduler`` (``catenary.storage.leases``); any other is a standby.

The holder renews the lease every ``heartbeat_seconds`` for ``lease_seconds`` from the renewal
(by the database's clock). A standby logs once who holds it (host, process, expiry) and tries
again every ``heartbeat_seconds``: it takes over at most ``lease_seconds + heartbeat_seconds``
after the holder died (60 s within the bounds), and at its next try after a holder that stops
released it. The holder counts its own lease as held until ``lease_seconds`` after it *began*
its last successful renewal (its monotonic clock), never later than the expiry the database
holds; past that, or once a renewal finds the term gone, it has lost the lease and must stop
starting jobs.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from dataclasses import dataclass
from datetime import timedelta

from sqlalchemy import Engine

from catenary.storage import leases
from catenary.storage.database import DATABASE_ERRORS, one_line
from catenary.storage.models import NAME_LENGTH
from catenary.text import printable

log = logging.getLogger(__name__)

LEASE_NAME = "scheduler"
DEFAULT_LEASE_SECONDS = 30.0
LEASE_SECONDS_RANGE = (1.0, 45.0)
MIN_HEARTBEAT_SECONDS = 0.1
HEARTBEATS_PER_LEASE = 3  # a lease survives two missed heartbeats


@dataclass(frozen=True)
class LeaseTiming:
    """``[scheduler]`` ``lease_seconds`` (1 to 45) and ``heartbeat_seconds`` (0.1 to a third
    of the lease; default a third)."""

    lease_s: float = DEFAULT_LEASE_SECONDS
    heartbeat_s: float = DEFAULT_LEASE_SECONDS / HEARTBEATS_PER_LEASE


class Leadership:
    """This process's claim on the lease: standby polling, heartbeat, release.

    Called from one thread; ``holds`` may be called from any.
    """

    def __init__(
        self,
        engine: Engine,
        timing: LeaseTiming,
        *,
        host: str | None = None,
        pid: int | None = None,
    ) -> None:
        self._engine = engine
        self._timing = timing
        self._duration = timedelta(seconds=timing.lease_s)
        self._pid = os.getpid() if pid is None else pid
        # the holder column is "host:pid" of at most NAME_LENGTH characters
        self._host = (socket.gethostname() if host is None else host)[: NAME_LENGTH - 12]
        self._lease: leases.Lease | None = None
        self._until = 0.0  # time.monotonic() when this process's lease may have expired
        self._other: tuple[str, object] | None = None  # the other holder's term last logged
        self._error: str | None = None  # the database error last logged

    def holds(self) -> bool:
        """Whether this process holds the lease now."""
        return self._lease is not None and time.monotonic() < self._until

    def wait_for_lease(self, stop: threading.Event) -> bool:
        """Try to take the lease now and every heartbeat until it is taken (True) or ``stop``
        is set (False)."""
        while not stop.is_set():
            if self._try_acquire():
                return True
            stop.wait(self._timing.heartbeat_s)
        return False

    def next_beat_s(self) -> float:
        """Seconds until the next renewal: a heartbeat, or less if the lease runs out first."""
        return max(0.0, min(self._timing.heartbeat_s, self._until - time.monotonic()))

    def renew(self) -> bool:
        """The heartbeat: renew the lease; False once it is lost (expired, taken by another
        process, or not renewed for its whole term because the database is out of reach)."""
        if self._lease is None:
            return False
        began = time.monotonic()
        try:
            renewed = leases.renew(self._engine, self._lease, self._duration)
        except DATABASE_ERRORS as exc:
            self._database_error(exc)
            if self.holds():
                return True
            reason = f"not renewed for {self._timing.lease_s:g} s"
        else:
            self._database_back()
            if renewed is not None:
                self._lease, self._until = renewed, began + self._timing.lease_s
                return True
            reason = "it expired or another scheduler took it"
        self._lease = None
        log.warning("scheduler lease lost (%s): jobs paused, this scheduler is a standby", reason)
        return False

    def release(self) -> None:
        """Give up the lease if this process holds it, so a standby takes over at once."""
        lease, self._lease = self._lease, None
        if lease is None:
            return
        try:
            released = leases.release(self._engine, lease)
        except DATABASE_ERRORS as exc:
            log.warning(
                "scheduler lease not released (%s): a standby takes over once it expires",
                printable(one_line(exc)),
            )
            return
        log.info("scheduler lease %s", "released" if released else "had already expired")

    def _try_acquire(self) -> bool:
        began = time.monotonic()
        try:
            attempt = leases.acquire(
                self._engine, LEASE_NAME, host=self._host, pid=self._pid, duration=self._duration
            )
        except DATABASE_ERRORS as exc:
            self._database_error(exc)
            return False
        self._database_back()
        lease = attempt.lease
        if attempt.acquired:
            self._lease, self._until = lease, began + self._timing.lease_s
            self._other = None
            log.info(
                "scheduler lease acquired by this process (%s): it runs the jobs "
                "(lease %g s, renewed every %g s)",
                printable(lease.holder),
                self._timing.lease_s,
                self._timing.heartbeat_s,
            )
            return True
        if self._other != (lease.holder, lease.acquired_at):
            self._other = (lease.holder, lease.acquired_at)
            log.info(
                "standby: host %s process %d holds the scheduler lease (since %s) until %s; "
                "trying again every %g s",
                printable(lease.host),
                lease.pid,
                lease.acquired_at.isoformat(timespec="seconds"),
                lease.expires_at.isoformat(timespec="seconds"),
                self._timing.heartbeat_s,
            )
        return False

    def _database_error(self, exc: Exception) -> None:
        text = printable(one_line(exc))
        if text != self._error:  # once per kind of failure, not at every heartbeat
            self._error = text
            log.warning("scheduler lease: database error: %s; trying again", text)

    def _database_back(self) -> None:
        if self._error is not None:
            self._error = None
            log.info("scheduler lease: the database answers again")
