"""The database: engines, the unit of work, and the check that the schema is migrated.

A SQLite file is the default (one user, zero set-up); PostgreSQL serves a fleet. Every error a
user can cause here (a malformed URL, an unknown driver, a server that cannot be reached, a
database that is not migrated) is a one-line ``UserError`` naming the URL with any password
masked.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.engine import URL, Connection, make_url
from sqlalchemy.exc import ArgumentError, DBAPIError, NoSuchModuleError, OperationalError
from sqlalchemy.orm import Session

from catenary.config import DEFAULT_CONNECT_TIMEOUT_S, Settings
from catenary.errors import DatabaseNotMigrated, UserError

#: How long a SQLite connection waits for another process's lock before giving up.
SQLITE_BUSY_TIMEOUT_MS = 30_000

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


def make_engine(url: str, *, connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S) -> Engine:
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
    is a one-line error, not a hang.

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
        options["connect_args"] = {"connect_timeout": max(2, math.ceil(connect_timeout_s))}
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

    if engine.dialect.name == "sqlite":
        if sqlite_file is not None:
            try:
                sqlite_file.parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise UserError(
                    f"cannot create the directory of database {where}: {exc.strerror}"
                ) from None
        event.listen(engine, "connect", _configure_sqlite_connection)
        event.listen(engine, "begin", _begin_sqlite_transaction)
    return engine


def _configure_sqlite_connection(dbapi_connection: Any, connection_record: Any) -> None:
    # Python's sqlite3 begins transactions itself, only before INSERT, UPDATE and DELETE, so
    # DDL and reads would run outside them; let SQLAlchemy begin every transaction instead
    # (_begin_sqlite_transaction): then a failed migration or unit of work leaves nothing.
    dbapi_connection.isolation_level = None
    cursor = dbapi_connection.cursor()
    try:
        cursor.execute("PRAGMA foreign_keys=ON")
        cursor.execute(f"PRAGMA busy_timeout={SQLITE_BUSY_TIMEOUT_MS}")
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
    database: Settings | str, *, migrated: bool = True, create: bool = False
) -> Iterator[Engine]:
    """An engine for ``database`` (the settings' database, with their connect timeout, or a
    URL), disposed of on exit; checked to be migrated unless told not to. A SQLite file that
    does not exist is refused (``require_exists``) unless ``create`` (``catenary db upgrade``).

    The usual start of a command::

        with open_database(settings) as engine, session_scope(engine) as session:
            ...
    """
    if isinstance(database, str):
        engine = make_engine(database)
    else:
        engine = make_engine(database.database_url, connect_timeout_s=database.connect_timeout_s)
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
