"""The database: engines, the unit of work, and the check that the schema is migrated.

A SQLite file is the default (one user, zero set-up); PostgreSQL serves a fleet. Every error a
user can cause here (a malformed URL, an unknown driver, a server that cannot be reached, a
database that is not migrated) is a one-line ``UserError`` naming the URL with any password
masked; so is a connection lost in the middle of a command (``DatabaseUnavailable``).

Bounded waits on PostgreSQL: connecting gives up after the connect timeout; TCP keepalives
(probes after :data:`KEEPALIVE_IDLE_S` idle, every :data:`KEEPALIVE_INTERVAL_S`,
:data:`KEEPALIVE_COUNT` unanswered) and ``tcp_user_timeout`` (:data:`TCP_USER_TIMEOUT_MS`)
end a connection whose server's host has gone (powered off, unplugged): its kernel no longer
answers. They cannot tell a server that is there but silent (its kernel still acknowledges):
that is what the statement timeout bounds, for interactive commands.
"""

from __future__ import annotations

import math
import os
import re
import socket
import sqlite3
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.engine import URL, Connection, ExceptionContext, make_url
from sqlalchemy.exc import ArgumentError, DBAPIError, NoSuchModuleError, OperationalError
from sqlalchemy.orm import Session

from catenary.config import DEFAULT_CONNECT_TIMEOUT_S, Settings
from catenary.errors import DatabaseNotMigrated, UserError

#: How long a SQLite connection waits for another process's lock before giving up (the
#: statement timeout, when shorter).
SQLITE_BUSY_TIMEOUT_MS = 30_000

#: PostgreSQL: a connection idle this long is probed, every interval, and dropped after this
#: many unanswered probes; data sent and not acknowledged for TCP_USER_TIMEOUT_MS drops it too.
KEEPALIVE_IDLE_S = 30
KEEPALIVE_INTERVAL_S = 10
KEEPALIVE_COUNT = 3
TCP_USER_TIMEOUT_MS = 60_000

#: PostgreSQL: how long past the statement timeout a statement's answer may take before the
#: client gives up on a silent server (the server's own timeout is then lost on the way).
STATEMENT_GRACE_S = 2.0

# SQLSTATE of a statement the server cancelled (statement_timeout)
_QUERY_CANCELED = "57014"

#: The execution option that marks a connection's transactions as reading only (SQLite then
#: begins them deferred; see ``_begin_sqlite_transaction``).
READ_ONLY = "catenary_read_only"

# SQLite's primary result codes of a file that cannot be written (the extended codes carry
# them in their low byte): SQLITE_READONLY (the file or its folder), SQLITE_IOERR and
# SQLITE_FULL (a full disk, a file size limit)
_SQLITE_READONLY = 8
_SQLITE_UNWRITABLE = {10, 13}

# For a URL that does not parse: everything from the user's ":" to the last "@" (greedy, so a
# password holding "@", "/" or "?" is masked whole).
_PASSWORD_IN_URL = re.compile(r"^((?:[^/?#@]*//)?[^/?#@:]*:(?!//)).*@")
# A query parameter holding a secret (libpq's ``password``, ``sslpassword``, ...).
_SECRET_IN_QUERY = re.compile(r"(?i)([?&][^=&#]*pass[^=&#]*=)[^&#]*")


def mask_url(url: str | URL) -> str:
    """``url`` as text, with any password (in the URL's user part or its query) replaced by
    ``***``, whether or not it parses (for messages and logs)."""
    if isinstance(url, URL):
        text = url.render_as_string(hide_password=True)
    else:
        try:
            text = make_url(url).render_as_string(hide_password=True)
        except (ArgumentError, ValueError):  # ValueError: a port that is not a number
            text = _PASSWORD_IN_URL.sub(r"\1***@", url)
    return _SECRET_IN_QUERY.sub(r"\1***", text)


def one_line(exc: BaseException) -> str:
    """A driver's error message on one line (``DBAPIError`` text spans several)."""
    orig = exc.orig if isinstance(exc, DBAPIError) else exc
    return " ".join(str(orig).split()) or type(orig).__name__


def _sqlite_file(url: URL) -> Path | None:
    """The file of a SQLite URL; None for an in-memory database or a ``file:`` URI."""
    database = url.database
    if (
        not database
        or database == ":memory:"
        or url.query.get("uri")
        or database.startswith("file:")
    ):
        return None
    return Path(database)


class DatabaseUnavailable(UserError):
    """The database stopped answering, or the connection to it was lost, during a command."""


DATABASE_ERRORS = (DBAPIError, DatabaseUnavailable)
"""What a statement raises when the database fails or goes away (a lost connection is turned
into ``DatabaseUnavailable``): what a long-running service catches to try again later."""


class _Watchdog:
    """Cuts a PostgreSQL connection whose statement or commit has not been answered
    ``limit_s`` after it was sent (a silent server): its socket is shut down, so the driver's
    wait ends at once with a lost connection."""

    def __init__(self, dbapi_connection: Any, limit_s: float) -> None:
        self._connection = dbapi_connection
        self._limit_s = limit_s
        self._timer: threading.Timer | None = None
        self._lock = threading.Lock()
        self.fired = False

    def arm(self) -> None:
        with self._lock:
            if self._timer is not None:
                self._timer.cancel()
            self._timer = threading.Timer(self._limit_s, self._cut)
            self._timer.daemon = True
            self._timer.start()

    def disarm(self) -> None:
        with self._lock:
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None

    def _cut(self) -> None:
        from psycopg.pq import TransactionStatus

        with self._lock:
            if threading.current_thread() is not self._timer:
                return  # re-armed (or disarmed) as it fired
            busy = self._connection.pgconn.transaction_status == TransactionStatus.ACTIVE
            if not busy or self._connection.closed:
                return
            self.fired = True
            with socket.socket(fileno=os.dup(self._connection.fileno())) as sock:
                sock.shutdown(socket.SHUT_RDWR)


_WATCHDOG = "catenary_watchdog"


def _watch_statements(engine: Engine, limit_s: float) -> None:
    """Arm a ``_Watchdog`` of ``limit_s`` on each statement, commit and rollback of
    ``engine``'s connections."""

    def connect(dbapi_connection: Any, record: Any) -> None:
        record.info[_WATCHDOG] = _Watchdog(dbapi_connection, limit_s)

    def arm(conn: Connection, *args: Any) -> None:
        if not conn.invalidated:  # a lost connection has nothing left to watch
            conn.info[_WATCHDOG].arm()

    def disarm(conn: Connection, *args: Any) -> None:
        conn.info[_WATCHDOG].disarm()

    event.listen(engine, "connect", connect)
    for name in ("before_cursor_execute", "commit", "rollback"):
        event.listen(engine, name, arm)
    event.listen(engine, "after_cursor_execute", disarm)


def _lost_connection(
    where: str, statement_timeout_s: float | None, busy_timeout_ms: int, context: ExceptionContext
) -> BaseException | None:
    """The one-line ``DatabaseUnavailable`` for a connection lost, a statement timed out or a
    SQLite write lock not granted in time while a command ran (``handle_error``); None leaves
    any other error as it is."""
    if context.is_pre_ping or context.connection is None:
        return None  # pre-ping reconnects; connect errors are reported by ``connected``
    connection = context.connection
    watchdog = connection.info.get(_WATCHDOG) if not connection.invalidated else None
    if watchdog is not None:
        watchdog.disarm()
    orig = context.original_exception
    timed_out = getattr(orig, "sqlstate", None) == _QUERY_CANCELED
    if statement_timeout_s is not None and (timed_out or (watchdog is not None and watchdog.fired)):
        return DatabaseUnavailable(
            f"database {where} did not answer within the statement timeout "
            f"({statement_timeout_s:g} s, [database] statement_timeout_s)"
        )
    if context.is_disconnect:
        return DatabaseUnavailable(f"lost the connection to database {where}: {one_line(orig)}")
    if isinstance(orig, sqlite3.OperationalError) and "database is locked" in str(orig):
        return DatabaseUnavailable(
            f"database {where} is locked by another writer: gave up after "
            f"{busy_timeout_ms / 1000:g} s"
        )
    return None


def make_engine(
    url: str,
    *,
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S,
    statement_timeout_s: float | None = None,
) -> Engine:
    """An engine for ``url``.

    SQLite: ``~`` in the path is expanded, the file's directory is created, foreign keys are
    enforced (``PRAGMA foreign_keys=ON``, off by default in SQLite), a connection waits up to
    ``SQLITE_BUSY_TIMEOUT_MS`` for another process's lock, and every transaction, DDL
    included, is a real SQLite transaction (SQLAlchemy's recipe for pysqlite): one that may
    write begins ``IMMEDIATE`` (it takes the write lock at once, waiting for it), one marked
    read-only (``session_scope(engine, read_only=True)``, ``connected(engine,
    read_only=True)``) begins deferred. Other
    backends: connections are checked before use (``pool_pre_ping``), so a long-running service
    survives a server restart; PostgreSQL: connecting gives up after ``connect_timeout_s``
    (whole seconds, at least 2: libpq's minimum), so a server that accepts and never answers
    is a one-line error, not a hang, and TCP keepalives end a connection to a host that has
    gone (module docstring).

    ``statement_timeout_s`` (None: none) bounds each statement: PostgreSQL cancels it
    (``statement_timeout``), and a server that does not answer at all is given up
    ``STATEMENT_GRACE_S`` later; SQLite waits at most that long for another writer's lock.
    A connection lost during a statement, or a statement timed out, raises the one-line
    ``DatabaseUnavailable``.

    Raises ``UserError`` for a malformed URL, an unknown or missing driver, or a SQLite directory
    that cannot be created.
    """
    try:
        parsed = make_url(url)
    except ArgumentError:
        raise UserError(
            f"malformed database URL {mask_url(url)!r}: expected e.g. "
            "sqlite:////path/catenary.sqlite or postgresql+psycopg://user@host/database"
        ) from None
    except ValueError:
        raise UserError(
            f"malformed database URL {mask_url(url)!r}: the port is not a number"
        ) from None
    options: dict[str, Any] = {}
    sqlite_file = None
    if parsed.get_backend_name() == "sqlite":
        sqlite_file = _sqlite_file(parsed)
        if sqlite_file is not None:
            sqlite_file = sqlite_file.expanduser()
            parsed = parsed.set(database=str(sqlite_file))
    else:
        options["pool_pre_ping"] = True
    if parsed.get_backend_name() == "postgresql":
        connect_args: dict[str, Any] = {
            "connect_timeout": max(2, math.ceil(connect_timeout_s)),
            "keepalives": 1,
            "keepalives_idle": KEEPALIVE_IDLE_S,
            "keepalives_interval": KEEPALIVE_INTERVAL_S,
            "keepalives_count": KEEPALIVE_COUNT,
            "tcp_user_timeout": TCP_USER_TIMEOUT_MS,
        }
        if statement_timeout_s is not None:
            milliseconds = max(1, math.ceil(statement_timeout_s * 1000))
            given = parsed.query.get("options", ())  # the URL's own (e.g. a search_path) kept
            connect_args["options"] = " ".join(
                [
                    *([given] if isinstance(given, str) else given),
                    f"-c statement_timeout={milliseconds}",
                ]
            )
        options["connect_args"] = connect_args
    where = mask_url(parsed)
    try:
        engine = create_engine(parsed, **options)
    except NoSuchModuleError:
        raise UserError(
            f"unknown database driver {parsed.drivername!r} in {where} "
            "(known: sqlite, postgresql+psycopg)"
        ) from None
    except ImportError as exc:
        raise UserError(
            f"the driver of database {where} is not installed (module {exc.name})"
        ) from None
    except (ArgumentError, TypeError) as exc:
        raise UserError(f"invalid database URL {where}: {one_line(exc)}") from None

    busy_ms = SQLITE_BUSY_TIMEOUT_MS
    if statement_timeout_s is not None:
        busy_ms = min(busy_ms, max(1, math.ceil(statement_timeout_s * 1000)))
    event.listen(
        engine, "handle_error", partial(_lost_connection, where, statement_timeout_s, busy_ms)
    )
    if engine.dialect.name == "sqlite":
        if sqlite_file is not None:
            try:
                sqlite_file.parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise UserError(
                    f"cannot create the directory of database {where}: {exc.strerror}"
                ) from None
        event.listen(engine, "connect", partial(_configure_sqlite_connection, busy_ms))
        event.listen(engine, "begin", _begin_sqlite_transaction)
    elif engine.dialect.name == "postgresql" and statement_timeout_s is not None:
        _watch_statements(engine, statement_timeout_s + STATEMENT_GRACE_S)
    return engine


def _configure_sqlite_connection(
    busy_timeout_ms: int, dbapi_connection: Any, connection_record: Any
) -> None:
    # Python's sqlite3 begins transactions itself, only before INSERT, UPDATE and DELETE, so
    # DDL and reads would run outside them; let SQLAlchemy begin every transaction instead
    # (_begin_sqlite_transaction): then a failed migration or unit of work leaves nothing.
    dbapi_connection.isolation_level = None
    cursor = dbapi_connection.cursor()
    try:
        cursor.execute("PRAGMA foreign_keys=ON")
        cursor.execute(f"PRAGMA busy_timeout={busy_timeout_ms}")
    finally:
        cursor.close()


def _begin_sqlite_transaction(connection: Connection) -> None:
    # A deferred BEGIN that later writes cannot wait for the lock: SQLite returns "database is
    # locked" at once, whatever busy_timeout says (waiting could deadlock two readers upgrading
    # together). A transaction that may write therefore takes the write lock when it begins,
    # waiting up to busy_timeout; a read-only one stays deferred and never blocks a writer.
    if connection.get_execution_options().get(READ_ONLY):
        connection.exec_driver_sql("BEGIN")
    else:
        connection.exec_driver_sql("BEGIN IMMEDIATE")


def reading(engine: Engine) -> Engine:
    """``engine`` whose transactions only read: deferred on SQLite, unchanged elsewhere."""
    return engine.execution_options(**{READ_ONLY: True})


@contextmanager
def connected(engine: Engine, *, read_only: bool = False) -> Iterator[Connection]:
    """A connection of ``engine``; a failure to connect is a one-line ``UserError``.

    Its transactions may write unless ``read_only`` (see ``make_engine``).
    """
    try:
        connection = (reading(engine) if read_only else engine).connect()
    except DBAPIError as exc:
        raise UserError(
            f"cannot connect to database {mask_url(engine.url)}: {one_line(exc)}"
        ) from None
    with connection:
        yield connection


@contextmanager
def open_database(
    database: Settings | str,
    *,
    migrated: bool = True,
    create: bool = False,
    batch: bool = False,
) -> Iterator[Engine]:
    """An engine for ``database`` (the settings' database, with their connect and statement
    timeouts, or a URL), disposed of on exit; checked to be migrated unless told not to. A
    SQLite file that does not exist is refused (``require_exists``) unless ``create``
    (``catenary db upgrade``).

    ``batch``: the caller is a batch command or a scheduled job (``process``, ``alerts
    evaluate --all``, the scheduler), whose statements may take as long as they need: the
    statement timeout of interactive commands does not apply.

    The usual start of a command::

        with open_database(settings) as engine, session_scope(engine) as session:
            ...
    """
    if isinstance(database, str):
        engine = make_engine(database)
    else:
        engine = make_engine(
            database.database_url,
            connect_timeout_s=database.connect_timeout_s,
            statement_timeout_s=None if batch else database.statement_timeout_s,
        )
    try:
        if not create:
            require_exists(engine)
        if migrated:
            require_migrated(engine)
        yield engine
    finally:
        engine.dispose()


@contextmanager
def session_scope(engine: Engine, *, read_only: bool = False) -> Iterator[Session]:
    """One unit of work: a session committed if the block succeeds, rolled back on any error.

    Nothing of a failed block is written. Objects stay readable after the block
    (``expire_on_commit=False``), detached from the closed session. On SQLite the unit of work
    takes the write lock when it begins (waiting for another writer to finish), unless
    ``read_only``: then it begins deferred, never waits for a writer, and must not write.
    """
    session = Session(reading(engine) if read_only else engine, expire_on_commit=False)
    try:
        yield session
        session.commit()
    except BaseException as exc:
        session.rollback()
        problem = _unwritable(engine, exc)
        if problem is not None:
            raise problem from None
        raise
    finally:
        session.close()


def require_exists(engine: Engine) -> None:
    """Raise ``DatabaseNotMigrated`` for a SQLite file that does not exist: connecting would
    create it empty."""
    file = _sqlite_file(engine.url) if engine.dialect.name == "sqlite" else None
    if file is not None and not file.exists():
        raise DatabaseNotMigrated(
            f"database {mask_url(engine.url)} does not exist: run 'catenary db upgrade' to "
            "create it"
        )


def _unwritable(engine: Engine, exc: BaseException) -> UserError | None:
    """The one-line error for a SQLite file that cannot be written (read-only, its disk full),
    else None."""
    code = (
        getattr(exc.orig, "sqlite_errorcode", None) if isinstance(exc, OperationalError) else None
    )
    if code is None:
        return None
    where = f"database {engine.url.database}"
    if code & 0xFF == _SQLITE_READONLY:
        return UserError(
            f"{where} is read-only: {one_line(exc)} (writing needs write permission on the file "
            "and its folder; commands that only read work)"
        )
    if code & 0xFF in _SQLITE_UNWRITABLE:
        return UserError(f"{where} cannot be written: {one_line(exc)} (is its disk full?)")
    return None


def require_migrated(engine: Engine) -> None:
    """Raise ``DatabaseNotMigrated`` unless the database is at the head revision.

    The message is one line naming the database, its revision and the one needed, and what to
    run. A database that cannot be reached is a ``UserError``.
    """
    # migrate imports this module (for ``connected``); import it here to keep that one-way
    from catenary.storage import migrate

    current = migrate.current_revision(engine)
    head = migrate.head_revision()
    if current == head:
        return
    where = mask_url(engine.url)
    if current is None or migrate.is_known_revision(current):
        raise DatabaseNotMigrated(
            f"database {where} is not migrated (revision: {current or 'none'}, needed: {head}): "
            "run 'catenary db upgrade'"
        )
    raise DatabaseNotMigrated(
        f"database {where} is at revision {current}, unknown to this version of catenary "
        f"(needed: {head}): it was migrated by a newer catenary; upgrade catenary to use it"
    )
