"""Fixtures for every test: each test runs with its own data directory and no user config.

``database_url`` gives an empty database on each backend: a SQLite file, and PostgreSQL when
CI gives one. Each PostgreSQL test gets a schema of its own (``search_path`` set in the URL),
dropped with everything in it, ``alembic_version`` included, when the test ends: tests never
see each other's tables, nor leave any for other suites.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import create_engine
from sqlalchemy.engine import make_url


@pytest.fixture(autouse=True)
def isolated_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Point catenary at a per-test data dir and hide the user's config and database."""
    data_dir = tmp_path / "catenary-data"
    monkeypatch.setenv("CATENARY_DATA_DIR", str(data_dir))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg-config"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg-data"))
    monkeypatch.delenv("CATENARY_DATABASE_URL", raising=False)
    monkeypatch.delenv("CATENARY_CONFIG", raising=False)
    monkeypatch.delenv("CATENARY_DISABLE_PLUGIN_AUTOLOAD", raising=False)
    return data_dir


POSTGRES_ENV = "CATENARY_TEST_DATABASE_URL"


@pytest.fixture(
    params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)],
)
def database_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """The URL of an empty database, on each backend."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'data' / 'catenary.sqlite'}"
        return
    base = os.environ.get(POSTGRES_ENV)
    if not base:
        pytest.skip(f"{POSTGRES_ENV} is not set")
    schema = f"catenary_test_{uuid.uuid4().hex[:16]}"
    admin = create_engine(base)
    try:
        with admin.begin() as connection:
            connection.exec_driver_sql(f'CREATE SCHEMA "{schema}"')
        url = make_url(base).update_query_dict({"options": f"-csearch_path={schema}"})
        yield url.render_as_string(hide_password=False)
    finally:
        with admin.begin() as connection:
            # a connection a test left in a transaction fails the test instead of hanging it
            connection.exec_driver_sql("SET LOCAL lock_timeout = '20s'")
            connection.exec_driver_sql(f'DROP SCHEMA IF EXISTS "{schema}" CASCADE')
        admin.dispose()
