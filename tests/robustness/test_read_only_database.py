"""A SQLite database file that may not be written (the file 0444, or its folder 0555 too):
commands that write fail in one line saying so and leave nothing; those that only read work.

Root ignores permission bits, so when the tests run as root each command runs without the
capabilities that let it (``without_root_file_access``): the kernel's own permission checks
produce the fault, as for any user.
"""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import Engine
from sqlalchemy.orm import Session

from catenary.storage.database import make_engine
from catenary.storage.models import Alert, Run

from ..conftest import SmallRun
from .conftest import assert_refused, assert_succeeded, catenary
from .hardening_support import row_counts, without_root_file_access


@pytest.fixture(scope="module")
def processed(small_run: SmallRun, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder holding a database (``catenary.sqlite``) with the run processed, and its data
    directory (``data``): copied by each test."""
    folder = tmp_path_factory.mktemp("processed")
    url = f"sqlite:///{folder / 'catenary.sqlite'}"
    env = {"CATENARY_DATA_DIR": str(folder / "data")}
    assert_succeeded(catenary("--db", url, "db", "upgrade", env=env))
    assert_succeeded(catenary(*small_run.process_args(url), env=env))
    return folder


@pytest.fixture(params=["file", "file and folder"])
def read_only(
    request: pytest.FixtureRequest,
    processed: Path,
    tmp_path: Path,
    isolated_environment: Path,
    build: Any,
) -> Iterator[tuple[Path, Engine, int]]:
    """The processed database and an open alert on its run's track, made read-only: the
    file, and its folder for the second case. Yields the file, an engine and the alert's id."""
    database = tmp_path / "db" / "catenary.sqlite"
    database.parent.mkdir()
    shutil.copyfile(processed / "catenary.sqlite", database)
    shutil.copytree(processed / "data", isolated_environment)
    engine = make_engine(f"sqlite:///{database}")
    with Session(engine) as session, session.begin():
        stored = session.get(Run, 1)
        assert stored is not None
        alert = build.alert(stored.track, "key-1")
        session.add(alert)
        session.flush()
        alert_id = alert.id
    database.chmod(0o444)
    if request.param == "file and folder":
        database.parent.chmod(0o555)
    try:
        yield database, engine, alert_id
    finally:
        engine.dispose()
        database.parent.chmod(0o755)
        database.chmod(0o644)


def _as_user(database: Path, *args: str | Path) -> subprocess.CompletedProcess[str]:
    return catenary("--db", f"sqlite:///{database}", *args, preexec_fn=without_root_file_access)


def test_writers_fail_in_one_line_and_leave_nothing(
    read_only: tuple[Path, Engine, int], small_run: SmallRun, isolated_environment: Path
) -> None:
    database, engine, alert_id = read_only
    before = row_counts(engine)
    samples = sorted((isolated_environment / "samples").iterdir())
    for args in (
        ["process", small_run.run, "--rig", small_run.rig, "--masts", small_run.masts, "--replace"],
        ["alerts", "ack", str(alert_id), "--by", "me"],
    ):
        assert_refused(_as_user(database, *args), f"database {database} is read-only")
    assert row_counts(engine) == before
    assert sorted((isolated_environment / "samples").iterdir()) == samples
    with Session(engine) as session:
        alert = session.get(Alert, alert_id)
        assert alert is not None and alert.status == "open"


def test_readers_work(read_only: tuple[Path, Engine, int], tmp_path: Path) -> None:
    database = read_only[0]
    listed = _as_user(database, "alerts", "list")
    assert_succeeded(listed)
    assert "1 alert(s)" in listed.stdout
    for args in (
        ["export", "1", "--what", "spans", "-o", tmp_path / "spans.csv"],
        ["report", "run", "1", "-o", tmp_path / "run.html"],
    ):
        assert_succeeded(_as_user(database, *args))
    assert (tmp_path / "spans.csv").stat().st_size > 0
    assert (tmp_path / "run.html").stat().st_size > 0
