"""``catenary scheduler`` as a service: the real command in a subprocess, stopped by SIGTERM and
SIGINT and started again, with a job that appends a line to a file (a reporter of a plugin
installed the way a third party's is, through a ``.dist-info`` on the path)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa
import tomli_w
from sqlalchemy import Engine

from catenary.storage import migrate

CATENARY = str(Path(sys.executable).with_name("catenary"))
INTERVAL = timedelta(seconds=2.4)

TICK_PLUGIN = """
import os
from catenary.plugins import hookimpl
from catenary.plugins.types import Reporter

def write(request, path):
    with open(path, "a") as handle:
        handle.write(f"{os.getpid()}\\n")
    return path

@hookimpl
def catenary_reporters():
    return [Reporter("tick", "appends a line to its file", write)]
"""


@pytest.fixture
def plugin_path(tmp_path: Path) -> Path:
    """A directory holding the ``tick`` plugin and its distribution's metadata."""
    root = tmp_path / "site"
    info = root / "catenary_tick-1.0.dist-info"
    info.mkdir(parents=True)
    (root / "catenary_tick.py").write_text(TICK_PLUGIN)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: catenary-tick\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[catenary.plugins]\ntick = catenary_tick\n")
    return root


class Service:
    """``catenary scheduler`` in a subprocess, its log in a file."""

    def __init__(self, args: list[str], env: dict[str, str], log: Path) -> None:
        self.log = log
        self._handle = log.open("w")
        self.process = subprocess.Popen(
            [CATENARY, *args, "scheduler"],
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=self._handle,
        )

    def text(self) -> str:
        return self.log.read_text()

    def fire_times(self) -> list[datetime]:
        return [
            datetime.fromisoformat(t) for t in re.findall(r"job 'tick' ran for (\S+)", self.text())
        ]

    def wait_for(self, condition: Callable[[], Any], timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not condition():
            assert self.process.poll() is None, self.text()
            assert time.monotonic() < deadline, self.text()
            time.sleep(0.1)

    def stop(self, signum: int) -> int:
        self.process.send_signal(signum)
        try:
            return self.process.wait(30)
        finally:
            self._handle.close()

    def kill(self) -> None:
        """Kill it if it still runs (a test failed before stopping it)."""
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait(30)
        self._handle.close()


@pytest.fixture
def start_service() -> Iterator[Callable[[list[str], dict[str, str], Path], Service]]:
    """``start_service(args, env, log)``: a ``Service``; one a failed test left running is
    killed at the end, so it holds no connection to the test's database schema."""
    started: list[Service] = []

    def start(args: list[str], env: dict[str, str], log: Path) -> Service:
        started.append(Service(args, env, log))
        return started[-1]

    yield start
    for service in started:
        service.kill()


def on_grid(moment: datetime, origin: datetime) -> bool:
    steps = (moment - origin) / INTERVAL
    return abs(steps - round(steps)) < 1e-3


@pytest.mark.slow
def test_restarts_neither_repeat_nor_lose_a_run(
    tmp_path: Path,
    database_url: str,
    engine: Engine,
    plugin_path: Path,
    start_service: Callable[[list[str], dict[str, str], Path], Service],
) -> None:
    ticks = tmp_path / "ticks.txt"
    config = tmp_path / "catenary.toml"
    job = {
        "id": "tick",
        "job": "report",
        "reporter": "tick",
        "output": str(ticks),
        "interval_minutes": INTERVAL.total_seconds() / 60,
    }
    config.write_text(tomli_w.dumps({"scheduler": {"timezone": "UTC", "jobs": [job]}}))
    env = {**os.environ, "PYTHONPATH": str(plugin_path)}
    args = ["--config", str(config), "--db", database_url]

    first = start_service(args, env, tmp_path / "first.log")
    first.wait_for(lambda: len(first.fire_times()) >= 2)
    assert first.stop(signal.SIGTERM) == 0, first.text()
    log = first.text()
    assert "SIGTERM received: stopping once the running jobs finish" in log
    assert log.rstrip().endswith("scheduler stopped")
    assert "Traceback" not in log
    before = first.fire_times()

    time.sleep(3 * INTERVAL.total_seconds())  # fire times fall due while it is down
    restarted_at = datetime.now(UTC)
    second = start_service(args, env, tmp_path / "second.log")
    second.wait_for(lambda: len(second.fire_times()) >= 2)
    assert second.stop(signal.SIGINT) == 0, second.text()
    log = second.text()
    assert "job tick: report every 0.04 min (kept)" in log
    assert "SIGINT received: stopping once the running jobs finish" in log
    assert log.rstrip().endswith("scheduler stopped")
    assert "Traceback" not in log
    after = second.fire_times()

    # the stored next fire time survived the restart: missed while down, then caught up once
    (next_at_start,) = re.findall(r"job 'tick' next runs at (\S+)", log)
    assert datetime.fromisoformat(next_at_start) == before[-1] + INTERVAL
    assert datetime.fromisoformat(next_at_start) < restarted_at
    assert after[0] >= datetime.fromisoformat(next_at_start)  # coalesced: one run for all missed
    assert after[0] < after[1] - INTERVAL / 2
    fire_times = before + after
    assert len(set(fire_times)) == len(fire_times)  # none run twice
    assert fire_times == sorted(fire_times)
    assert all(on_grid(t, before[0]) for t in fire_times)  # the schedule was not reset
    lines = ticks.read_text().splitlines()
    assert lines == [str(first.process.pid)] * len(before) + [str(second.process.pid)] * len(after)


def test_an_unmigrated_database_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "empty.sqlite").touch()
    url = f"sqlite:///{tmp_path / 'empty.sqlite'}"
    result = subprocess.run(
        [CATENARY, "--db", url, "scheduler"], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 1
    assert result.stderr.startswith("Error: database sqlite:///")
    assert "is not migrated" in result.stderr
    assert len(result.stderr.splitlines()) == 1


def test_the_migrations_make_the_job_store_table(engine: Engine) -> None:
    assert "apscheduler_jobs" in sa.inspect(engine).get_table_names()
    columns = {c["name"] for c in sa.inspect(engine).get_columns("apscheduler_jobs")}
    assert columns == {"id", "next_run_time", "job_state"}
    assert not any("apscheduler" in d for d in migrate.check_models_match(engine))
    migrate.downgrade(engine, "5e3a32fbe18d")  # the revision before the job store's
    assert "apscheduler_jobs" not in sa.inspect(engine).get_table_names()
    assert "next_attempt_at" not in {
        c["name"] for c in sa.inspect(engine).get_columns("alert_notifications")
    }
    migrate.upgrade(engine)
    assert "apscheduler_jobs" in sa.inspect(engine).get_table_names()
