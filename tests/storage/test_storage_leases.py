"""The lease rows (``catenary.storage.leases``) on each backend: one holder at a time, renewed
by its term only, taken over once expired, released at once, and one winner among processes
that try at the same moment."""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from datetime import timedelta

import pytest
from sqlalchemy import Engine, update

from catenary.storage import leases
from catenary.storage.database import make_engine, session_scope
from catenary.storage.models import SchedulerLease, utc_now

MINUTE = timedelta(minutes=1)


@pytest.fixture
def acquire(migrated: Engine) -> Callable[..., leases.Attempt]:
    """``acquire(pid, duration=MINUTE)``: process ``pid`` of host ``h`` tries the lease ``s``."""

    def attempt(pid: int, duration: timedelta = MINUTE) -> leases.Attempt:
        return leases.acquire(migrated, "s", host="h", pid=pid, duration=duration)

    return attempt


def expire(engine: Engine, name: str = "s") -> None:
    """The holder died long ago: its lease expired a second before now."""
    with session_scope(engine) as session:
        session.execute(
            update(SchedulerLease)
            .where(SchedulerLease.name == name)
            .values(expires_at=leases.database_now(session) - timedelta(seconds=1))
        )


def test_the_database_clock_is_utc(migrated: Engine) -> None:
    with session_scope(migrated) as session:
        now = leases.database_now(session)
    assert abs(now - utc_now()) < timedelta(seconds=5)


def test_the_first_process_holds_it_and_the_second_is_told_who(
    migrated: Engine, acquire: Callable[..., leases.Attempt]
) -> None:
    first = acquire(1)
    assert first.acquired
    lease = first.lease
    assert (lease.name, lease.holder, lease.host, lease.pid) == ("s", "h:1", "h", 1)
    assert lease.acquired_at == lease.heartbeat_at == lease.expires_at - MINUTE
    assert abs(lease.acquired_at - utc_now()) < timedelta(seconds=5)

    second = acquire(2)
    assert not second.acquired
    assert second.lease == lease  # the holder, unchanged
    # another lease name is another service's
    assert leases.acquire(migrated, "other", host="h", pid=2, duration=MINUTE).acquired


def test_a_restarted_process_with_the_same_host_and_pid_waits_for_the_term(
    acquire: Callable[..., leases.Attempt],
) -> None:
    held = acquire(1).lease
    again = acquire(1)
    assert not again.acquired
    assert again.lease == held


def test_renew_extends_the_term_of_its_holder_only(
    migrated: Engine, acquire: Callable[..., leases.Attempt]
) -> None:
    lease = acquire(1).lease
    renewed = leases.renew(migrated, lease, 2 * MINUTE)
    assert renewed is not None
    assert renewed.acquired_at == lease.acquired_at
    assert renewed.heartbeat_at >= lease.heartbeat_at
    assert renewed.expires_at == renewed.heartbeat_at + 2 * MINUTE
    assert acquire(2).lease == renewed  # as stored

    # a term that is not the stored one: another process, or an earlier term of this one
    stranger = leases.Lease(
        "s", "h:2", "h", 2, lease.acquired_at, lease.heartbeat_at, lease.expires_at
    )
    assert leases.renew(migrated, stranger, MINUTE) is None
    earlier = leases.Lease(
        "s", "h:1", "h", 1, lease.acquired_at - MINUTE, lease.heartbeat_at, lease.expires_at
    )
    assert leases.renew(migrated, earlier, MINUTE) is None
    assert not leases.release(migrated, earlier)
    assert acquire(2).lease == renewed


def test_an_expired_lease_is_taken_over_and_its_old_holder_cannot_renew_it(
    migrated: Engine, acquire: Callable[..., leases.Attempt]
) -> None:
    old = acquire(1).lease
    expire(migrated)
    assert leases.renew(migrated, old, MINUTE) is None  # expired: not renewed, even if unclaimed

    taken = acquire(2)
    assert taken.acquired
    assert (taken.lease.holder, taken.lease.pid) == ("h:2", 2)
    assert taken.lease.acquired_at > old.acquired_at
    assert leases.renew(migrated, old, MINUTE) is None
    assert not leases.release(migrated, old)
    assert acquire(1).lease == taken.lease


def test_release_lets_the_next_process_take_it_at_once(
    migrated: Engine, acquire: Callable[..., leases.Attempt]
) -> None:
    lease = acquire(1).lease
    assert leases.release(migrated, lease)
    assert not leases.release(migrated, lease)  # once
    taken = acquire(2)
    assert taken.acquired
    assert taken.lease.holder == "h:2"


def test_one_winner_among_processes_that_try_at_once(migrated: Engine, database_url: str) -> None:
    contenders = 6
    ready = threading.Barrier(contenders)

    def contend(pid: int) -> leases.Attempt:
        engine = make_engine(database_url)  # a connection of its own, as another process has
        try:
            with engine.connect():
                ready.wait(20)
            return leases.acquire(engine, "s", host="h", pid=pid, duration=MINUTE)
        finally:
            engine.dispose()

    for _ in range(2):  # a free lease, then an expired one
        with ThreadPoolExecutor(contenders) as pool:
            attempts = list(pool.map(contend, range(contenders)))
        winners = [attempt for attempt in attempts if attempt.acquired]
        assert len(winners) == 1
        assert all(attempt.lease == winners[0].lease for attempt in attempts)
        expire(migrated)
