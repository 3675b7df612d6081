"""Leases: which process runs a service that must run once per database (``scheduler_leases``).

A lease is one row, named for its service, that its holder renews before it expires; any other
process waits until it has expired, then takes it. A holder's term is its ``holder`` (``host:pid``)
and ``acquired_at`` together, so a process that restarts with the same host name and process id
(a container's pid 1) waits like any other instead of taking a live holder's lease as its own.

Every time here is the **database's clock**, read in the transaction that decides
(PostgreSQL's ``clock_timestamp()``; SQLite's ``'now'``, the clock of the host that opens the
file): the clocks of the processes never meet. Each operation is one transaction that cannot
interleave with another's on the same row: on SQLite it begins ``IMMEDIATE`` (``session_scope``);
on PostgreSQL ``acquire`` is one ``INSERT ... ON CONFLICT DO UPDATE ... WHERE expires_at <= now``
(which locks the row it conflicts with) and ``renew`` and ``release`` are conditional
``UPDATE`` and ``DELETE`` statements.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

from sqlalchemy import Engine, delete, func, select, text, update
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from catenary.storage.database import session_scope
from catenary.storage.models import SchedulerLease

__all__ = ["Attempt", "Lease", "acquire", "database_now", "release", "renew"]


@dataclass(frozen=True)
class Lease:
    """A lease as it stands in the database."""

    name: str
    holder: str
    host: str
    pid: int
    acquired_at: datetime
    heartbeat_at: datetime
    expires_at: datetime

    @classmethod
    def of(cls, row: SchedulerLease) -> Lease:
        return cls(
            row.name,
            row.holder,
            row.host,
            row.pid,
            row.acquired_at,
            row.heartbeat_at,
            row.expires_at,
        )


@dataclass(frozen=True)
class Attempt:
    """What ``acquire`` found: the lease (``acquired``: now this process's; else another's,
    whose holder to wait for until ``lease.expires_at``)."""

    lease: Lease
    acquired: bool


def database_now(session: Session) -> datetime:
    """The database's time (UTC, aware): PostgreSQL ``clock_timestamp()``, SQLite ``'now'``."""
    if session.get_bind().dialect.name == "postgresql":
        moment: datetime = session.execute(select(func.clock_timestamp())).scalar_one()
        return moment.astimezone(UTC)
    stamp = session.execute(text("SELECT strftime('%Y-%m-%d %H:%M:%f', 'now')")).scalar_one()
    return datetime.fromisoformat(stamp).replace(tzinfo=UTC)


_INSERTS: dict[str, Callable[..., Any]] = {"postgresql": postgresql.insert, "sqlite": sqlite.insert}


def acquire(engine: Engine, name: str, *, host: str, pid: int, duration: timedelta) -> Attempt:
    """Take the lease ``name`` for ``duration`` if nobody holds it or its term has expired;
    otherwise leave it and say who holds it."""
    with session_scope(engine) as session:
        now = database_now(session)
        term = {
            "holder": f"{host}:{pid}",
            "host": host,
            "pid": pid,
            "acquired_at": now,
            "heartbeat_at": now,
            "expires_at": now + duration,
        }
        statement = _INSERTS[engine.dialect.name](SchedulerLease).values(name=name, **term)
        statement = statement.on_conflict_do_update(
            index_elements=[SchedulerLease.name],
            set_=term,
            where=SchedulerLease.expires_at <= now,
        )
        # a row comes back when it was inserted or taken over, none when the WHERE kept it
        acquired = session.execute(statement.returning(SchedulerLease.name)).first() is not None
        row = session.scalars(select(SchedulerLease).where(SchedulerLease.name == name)).one()
        return Attempt(Lease.of(row), acquired)


def _term(lease: Lease) -> tuple[Any, ...]:
    return (
        SchedulerLease.name == lease.name,
        SchedulerLease.holder == lease.holder,
        SchedulerLease.acquired_at == lease.acquired_at,
    )


def renew(engine: Engine, lease: Lease, duration: timedelta) -> Lease | None:
    """Extend ``lease`` (a term ``acquire`` gave) to ``duration`` from now; None if the term
    has expired or another process holds the lease now."""
    with session_scope(engine) as session:
        now = database_now(session)
        renewed = session.execute(
            update(SchedulerLease)
            .where(*_term(lease), SchedulerLease.expires_at > now)
            .values(heartbeat_at=now, expires_at=now + duration)
        ).rowcount  # type: ignore[attr-defined]
    if renewed != 1:
        return None
    return Lease(
        lease.name, lease.holder, lease.host, lease.pid, lease.acquired_at, now, now + duration
    )


def release(engine: Engine, lease: Lease) -> bool:
    """Give up ``lease`` at once (a waiting process may take it at its next try); False if
    its term had already ended."""
    with session_scope(engine) as session:
        deleted = session.execute(delete(SchedulerLease).where(*_term(lease))).rowcount  # type: ignore[attr-defined]
    return bool(deleted == 1)
