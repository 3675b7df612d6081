"""The same run processed twice at once: one stores it, the other finds it already stored."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import func, select

from catenary.config import Settings
from catenary.measurement.process import ProcessRequest, ProcessResult, process_run
from catenary.plugins.manager import PluginRegistry
from catenary.storage import migrate
from catenary.storage.database import make_engine, session_scope
from catenary.storage.models import Run

from ..conftest import SmallRun


@pytest.fixture
def settings(make_settings: Callable[[dict[str, Any]], Settings]) -> Settings:
    settings = make_settings({})
    engine = make_engine(settings.database_url)
    migrate.upgrade(engine)
    engine.dispose()
    return settings


def _runs(settings: Settings) -> int:
    engine = make_engine(settings.database_url)
    try:
        with session_scope(engine, read_only=True) as session:
            return int(session.scalar(select(func.count()).select_from(Run)) or 0)
    finally:
        engine.dispose()


def _samples(settings: Settings) -> list[Path]:
    return sorted((settings.data_dir / "samples").glob("*")) + sorted(
        (settings.data_dir / "samples").glob(".*")
    )


def test_both_checked_before_either_stored(small_run: SmallRun, settings: Settings) -> None:
    # both pass the first check (nothing stored yet) before either measures: the one that
    # stores second must find the run in its own transaction, not break a unique key
    both_started = threading.Barrier(2, timeout=30)
    request = ProcessRequest(small_run.run, small_run.rig, register_path=small_run.masts)

    def process() -> ProcessResult:
        registry = PluginRegistry(disabled=settings.disabled_plugins)
        return process_run(request, settings, registry, on_start=lambda h: both_started.wait())

    with ThreadPoolExecutor(2) as pool:
        futures = [pool.submit(process) for _ in range(2)]
        results = [future.result(timeout=120) for future in futures]
    assert sorted(r.already_stored for r in results) == [False, True]
    assert results[0].run_id == results[1].run_id
    assert _runs(settings) == 1
    assert len(_samples(settings)) == 1  # the loser's samples file is gone


def test_two_commands_at_once(small_run: SmallRun, settings: Settings) -> None:
    command = [
        str(Path(sys.executable).parent / "catenary"),
        *small_run.process_args(settings.database_url),
    ]
    processes = [
        subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=os.environ
        )
        for _ in range(3)
    ]
    outputs = [p.communicate(timeout=120) for p in processes]
    for process, (out, err) in zip(processes, outputs, strict=True):
        assert process.returncode == 0, out + err
        assert "Traceback" not in err, err
    assert sum("already stored" in out for out, _ in outputs) == 2, outputs
    assert _runs(settings) == 1
    assert len(_samples(settings)) == 1
