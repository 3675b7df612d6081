"""Engines for the storage tests (``database_url`` and the row builders ``build``:
``tests/conftest.py``)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from sqlalchemy import Engine

from catenary.storage import migrate
from catenary.storage.database import make_engine


@pytest.fixture
def engine(database_url: str) -> Iterator[Engine]:
    """An engine on the empty database."""
    engine = make_engine(database_url)
    yield engine
    engine.dispose()


@pytest.fixture
def migrated(engine: Engine) -> Engine:
    """The engine, its database migrated to head."""
    migrate.upgrade(engine)
    return engine
