"""Helpers of ``test_stranded_runs``: third-party plugins installed for a child ``catenary``
alone (a package and its ``.dist-info`` on ``PYTHONPATH``, found through its entry point), and
the default database's runs and alerts."""

from __future__ import annotations

import textwrap
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from catenary.config import load_settings
from catenary.storage import migrate
from catenary.storage.database import make_engine, session_scope
from catenary.storage.models import Alert, Run
from catenary.storage.runs import pending_runs


def install_plugin(folder: Path, name: str, source: str) -> dict[str, str]:
    """Install module ``name`` (``source``) as a plugin distribution under ``folder`` and
    return the environment that makes a child ``catenary`` load it."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{name}.py").write_text(textwrap.dedent(source))
    meta = folder / f"{name}-1.0.dist-info"
    meta.mkdir()
    (meta / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 1.0\n")
    (meta / "entry_points.txt").write_text(f"[catenary.plugins]\n{name} = {name}\n")
    return {"PYTHONPATH": str(folder)}


KILLED_AFTER_COMMIT = """
    import os
    import signal

    from catenary.plugins import hookimpl


    @hookimpl
    def catenary_run_stored(run_id, database_url):
        # the run is committed, its alerts not yet evaluated: the process dies here
        os.kill(os.getpid(), signal.SIGKILL)
"""
"""A plugin that kills ``catenary process`` between its commit and its alert evaluation."""

BROKEN_WIRE_TYPE = """
    from catenary.plugins import hookimpl
    from catenary.wiretype import WireType


    class BrokenWire(WireType):
        def worn_fraction(self, wear_width_mm):
            raise ZeroDivisionError("area table not loaded")


    @hookimpl
    def catenary_wire_types():
        return [BrokenWire("BROKEN", "none", 12.9, 12.9, 120.0, 120.0)]
"""
"""A third party's wire type whose worn fraction (what an alert reports) raises."""

EVERY_SPAN_POLICY = """
    [policies.every-span]
    description = "met at 1 % loss: every span measured raises an alert"
    source = "tests"

    [[policies.every-span.rules]]
    level = "critical"
    scope = "local"
    worn_fraction = 0.01
"""


@contextmanager
def default_database(*, read_only: bool = False) -> Iterator[Session]:
    """A session on the default database (in the test's data directory), migrated."""
    engine = make_engine(load_settings().database_url)
    try:
        migrate.upgrade(engine)
        with session_scope(engine, read_only=read_only) as session:
            yield session
    finally:
        engine.dispose()


def stored_runs() -> tuple[list[int], list[int], int]:
    """The default database's runs, those pending alert evaluation, and how many alerts."""
    with default_database() as session:
        runs = list(session.scalars(select(Run.id).order_by(Run.id)))
        alerts = session.scalar(select(func.count()).select_from(Alert)) or 0
        return runs, pending_runs(session), alerts


def alerting_config(folder: Path) -> Path:
    """A config whose policy raises an alert on every span measured; the default database
    is migrated."""
    with default_database():
        pass
    policy = folder / "policy.toml"
    policy.write_text(textwrap.dedent(EVERY_SPAN_POLICY))
    config = folder / "catenary.toml"
    config.write_text(f'[limits]\npolicy = "every-span"\nfile = "{policy}"\n')
    return config
