"""Rows added unless another transaction added them first: ``INSERT ... ON CONFLICT DO
NOTHING`` (SQLite and PostgreSQL), so that two processes adding the same new line, track,
mast, vehicle or rig calibration at once both go on with the one row.

On PostgreSQL the second insert waits for the first's transaction and, once it is committed,
does nothing; the next statement (read committed) sees the row. On SQLite writers take the
lock when they begin, so they never meet here; the same statement serves both.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, TypeVar

from sqlalchemy import select
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.engine import Row
from sqlalchemy.orm import Session

from catenary.storage.models import Base

__all__ = ["get_or_add", "insert_new"]

Model = TypeVar("Model", bound=Base)


def insert_new(
    session: Session,
    model: type[Base],
    rows: Sequence[Mapping[str, Any]],
    unique: Sequence[str],
    returning: Sequence[str] = ("id",),
) -> Sequence[Row[Any]]:
    """Insert ``rows`` of ``model``, leaving out each whose ``unique`` columns (one of the
    table's unique constraints) are taken; returns the ``returning`` columns of those inserted.
    """
    if not rows:
        return []
    dialect = postgresql if session.get_bind().dialect.name == "postgresql" else sqlite
    columns = model.__table__.c
    statement = (
        dialect.insert(model)
        .on_conflict_do_nothing(index_elements=list(unique))
        .returning(*(columns[name] for name in returning))
    )
    return session.execute(statement, list(rows)).all()


def get_or_add(
    session: Session,
    model: type[Model],
    keys: Mapping[str, Any],
    values: Mapping[str, Any] | None = None,
) -> Model:
    """The row of ``model`` whose ``keys`` (the columns of one of its unique constraints)
    have these values, added with ``values`` too if there is none."""
    query = select(model).filter_by(**keys)
    found = session.scalars(query).one_or_none()
    if found is None:
        insert_new(session, model, [{**keys, **(values or {})}], list(keys))
        found = session.scalars(query).one()
    return found
