"""Schema migrations: Alembic driven from Python, no ``alembic.ini`` needed.

The Alembic environment and the revisions ship as the package ``catenary_migrations``
(``migrations/`` in the source tree). Every function here takes an engine, runs Alembic on one
of its connections (``config.attributes["connection"]``) and turns Alembic's errors into one-line
``UserError`` messages naming the database.

On SQLite, migrations run with foreign keys off (the SQLite procedure for altering tables:
batch mode copies a table, drops the old one and renames the copy, and a ``DROP TABLE`` with
foreign keys on would cascade into the rows that refer to it); ``PRAGMA foreign_key_check``
then verifies every reference before the migration commits.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from importlib.resources import files
from typing import Any

from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.autogenerate.api import AutogenContext
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from alembic.util.exc import CommandError
from sqlalchemy import Column, Constraint, Engine, Index, Table, select
from sqlalchemy.engine import Connection
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import InstrumentedAttribute

from catenary.errors import UserError
from catenary.storage.database import connected, mask_url, one_line
from catenary.storage.models import (
    EXTERNAL_TABLES,
    Alert,
    Base,
    Line,
    MaintenanceAction,
    Mast,
    SpanMeasurement,
    Track,
    UTCDateTime,
    Vehicle,
)
from catenary.text import control_character_problem

MIGRATIONS_PACKAGE = "catenary_migrations"


def script_location() -> str:
    """The directory of the Alembic environment (``env.py``, ``versions/``)."""
    return str(files(MIGRATIONS_PACKAGE))


def alembic_config(connection: Connection | None = None) -> Config:
    """An Alembic ``Config`` for the shipped migrations, running on ``connection`` if given."""
    config = Config()
    # ConfigParser interpolates '%': escape it in a path
    config.set_main_option("script_location", script_location().replace("%", "%%"))
    if connection is not None:
        config.attributes["connection"] = connection
    return config


@functools.cache
def _scripts() -> ScriptDirectory:
    return ScriptDirectory.from_config(alembic_config())


def head_revision() -> str:
    """The revision the models of this version of catenary need."""
    head = _scripts().get_current_head()
    if head is None:  # pragma: no cover - the package always ships its initial revision
        raise RuntimeError(f"no revision in {script_location()}")
    return head


def is_known_revision(revision: str) -> bool:
    """Whether ``revision`` is one of the shipped revisions."""
    try:
        return _scripts().get_revision(revision) is not None
    except CommandError:
        return False


# --- options shared with env.py -------------------------------------------------------------


def include_name(name: str | None, type_: str, parent_names: Any) -> bool:
    """Leave out of autogenerate the tables that share the database but are not ours."""
    return not (type_ == "table" and name in EXTERNAL_TABLES)


def render_item(type_: str, obj: Any, autogen_context: AutogenContext) -> str | bool:
    """Render ``UTCDateTime`` as the plain type it stores, so revisions never import models."""
    if type_ == "type" and isinstance(obj, UTCDateTime):
        return "sa.DateTime(timezone=True)"
    return False


def context_options(dialect_name: str) -> dict[str, Any]:
    """The ``context.configure`` options of every migration and comparison."""
    return {
        "target_metadata": Base.metadata,
        "render_as_batch": dialect_name == "sqlite",
        "compare_type": True,
        "include_name": include_name,
        "render_item": render_item,
    }


# --- running migrations ---------------------------------------------------------------------


@contextmanager
def suspended_foreign_keys(connection: Connection) -> Iterator[None]:
    """On SQLite, turn foreign keys off for the block and check every reference at its end.

    Must be entered outside a transaction (SQLite ignores the pragma inside one); the block
    runs its own transaction, and ``PRAGMA foreign_key_check`` is run inside it before it
    commits. Other databases: does nothing.
    """
    if connection.dialect.name != "sqlite":
        yield
        return
    if connection.in_transaction():
        connection.commit()
    _pragma(connection, "foreign_keys=OFF")
    try:
        yield
    finally:
        if connection.in_transaction():
            connection.rollback()
        _pragma(connection, "foreign_keys=ON")


def _pragma(connection: Connection, pragma: str) -> None:
    """Run a pragma on the driver's connection, outside any transaction."""
    cursor = connection.connection.cursor()
    try:
        cursor.execute(f"PRAGMA {pragma}")
    finally:
        cursor.close()


def check_foreign_keys(connection: Connection) -> None:
    """On SQLite, raise ``UserError`` if a row refers to a row that does not exist."""
    if connection.dialect.name != "sqlite":
        return
    broken = connection.exec_driver_sql("PRAGMA foreign_key_check").all()
    if broken:
        table, rowid, parent, _ = broken[0]
        raise UserError(
            f"database {mask_url(connection.engine.url)}: the migration leaves {len(broken)} "
            f"broken reference(s), e.g. {table} row {rowid} to {parent}; nothing was changed"
        )


def _migrate(engine: Engine, run: Callable[[Config], None]) -> str | None:
    where = mask_url(engine.url)
    with connected(engine) as connection, suspended_foreign_keys(connection):
        try:
            with connection.begin():
                run(alembic_config(connection))
                check_foreign_keys(connection)
        except CommandError as exc:
            raise UserError(f"database {where}: {one_line(exc)}") from None
    return current_revision(engine)


def upgrade(engine: Engine, revision: str = "head") -> str | None:
    """Migrate the database up to ``revision``; return the revision it is now at."""
    return _migrate(engine, lambda config: command.upgrade(config, revision))


def downgrade(engine: Engine, revision: str) -> str | None:
    """Migrate the database down to ``revision`` (``"base"``: empty); return where it is now."""
    return _migrate(engine, lambda config: command.downgrade(config, revision))


def current_revision(engine: Engine) -> str | None:
    """The database's revision; None when it has never been migrated."""
    where = mask_url(engine.url)
    with connected(engine, read_only=True) as connection:
        try:
            return MigrationContext.configure(connection).get_current_revision()
        except CommandError as exc:
            raise UserError(f"database {where}: {one_line(exc)}") from None
        except DBAPIError as exc:
            raise UserError(f"cannot read database {where}: {one_line(exc)}") from None


# --- models against migrations --------------------------------------------------------------


def check_models_match(engine: Engine) -> list[str]:
    """Differences between the models and the database's schema, one line each; empty if none.

    Run on a database migrated to head, this checks that the migrations build what the models
    describe (what ``alembic check`` does).
    """
    with connected(engine) as connection:
        context = MigrationContext.configure(
            connection, opts=context_options(connection.dialect.name)
        )
        return [_describe(diff) for diff in compare_metadata(context, Base.metadata)]


#: Columns holding identifiers and names given at input: printable text (FORMATS.md).
IDENTIFIER_COLUMNS: tuple[InstrumentedAttribute[Any], ...] = (
    Line.code,
    Track.code,
    Mast.code,
    Mast.anchor_section,
    Vehicle.name,
    SpanMeasurement.mast_from,
    SpanMeasurement.mast_to,
    MaintenanceAction.mast_from,
    MaintenanceAction.mast_to,
    MaintenanceAction.recorded_by,
    Alert.mast_from,
    Alert.mast_to,
    Alert.acknowledged_by,
)


def identifiers_with_control_characters(engine: Engine) -> list[str]:
    """The stored identifiers holding control characters (rows stored before they were refused
    at input), one line each naming the table, the column and the value (escaped)."""
    found: list[str] = []
    with connected(engine) as connection:
        for column in IDENTIFIER_COLUMNS:
            values = connection.scalars(select(column).where(column.is_not(None)).distinct())
            where = f"{column.class_.__tablename__}.{column.key}"
            problems = (control_character_problem(where, value) for value in sorted(values))
            found.extend(problem for problem in problems if problem is not None)
    return found


def _describe(diff: Any) -> str:
    if isinstance(diff, list):
        return "; ".join(_describe(item) for item in diff)
    operation, *arguments = diff
    parts = [_describe_part(argument) for argument in arguments]
    return " ".join([operation, *(part for part in parts if part)])


def _describe_part(item: Any) -> str:
    if isinstance(item, Table):
        return f"table {item.name}"
    if isinstance(item, Column):
        table = item.table.name if isinstance(item.table, Table) else "?"
        return f"column {table}.{item.name}"
    if isinstance(item, Index | Constraint):
        return f"{type(item).__name__} {item.name}"
    if item is None or isinstance(item, dict):
        return ""
    return repr(item)
