"""SIGINT, SIGTERM and SIGKILL at several points of ``catenary process``: the database holds
nothing of the run or all of it (its span rows matching its samples file), Ctrl-C and SIGTERM
end in one line (130, 143), and the next ``process`` of the same file leaves no scratch file
and stores the run or says it is stored. A ``process`` with worker processes killed by SIGKILL
leaves none of them behind."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext, suppress
from dataclasses import dataclass
from pathlib import Path

import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from catenary.storage import migrate
from catenary.storage.database import make_engine

from ..conftest import SmallRun
from .conftest import assert_succeeded, catenary, start_catenary


@pytest.fixture
def database(tmp_path: Path) -> Path:
    """A migrated SQLite file of this test's own."""
    path = tmp_path / "catenary.sqlite"
    engine = make_engine(f"sqlite:///{path}")
    migrate.upgrade(engine)
    engine.dispose()
    return path


@contextmanager
def write_lock(database: Path) -> Iterator[None]:
    """Hold the SQLite write lock: ``process`` waits for it at its storing transaction."""
    connection = sqlite3.connect(database, isolation_level=None)
    connection.execute("BEGIN IMMEDIATE")
    try:
        yield
    finally:
        connection.rollback()
        connection.close()


def wait_for(condition: str, samples: Path, process: subprocess.Popen[str]) -> None:
    """Wait until ``process`` is measuring (``pass1``: its first pass's scratch file exists),
    finishing (``pass2``: its samples scratch file exists) or storing (``store``: its first
    pass's file is gone, the samples file written)."""
    deadline = time.monotonic() + 60.0

    def reached() -> bool:
        pass1, pass2 = list(samples.glob(".pass1-*")), list(samples.glob(".samples-*"))
        return {"pass1": bool(pass1), "pass2": bool(pass2), "store": bool(pass2) and not pass1}[
            condition
        ]

    while not reached():
        assert process.poll() is None, f"process ended before {condition}: {process.stderr}"
        assert time.monotonic() < deadline, f"no {condition} after 60 s"
        time.sleep(0.02)
    if condition == "store":
        time.sleep(0.5)  # from the last file written to the storing transaction


def stored(database: Path, data_dir: Path) -> int | None:
    """The id of the run stored, after checking that all of it is (its span rows match its
    samples file); None if nothing of it is."""
    with sqlite3.connect(database) as connection:
        runs = connection.execute(
            "SELECT runs.id, samples_key FROM runs JOIN processings p ON p.id = processing_id"
        ).fetchall()
        spans, samples = connection.execute(
            "SELECT count(*), coalesce(sum(samples), 0) FROM span_measurements"
        ).fetchone()
    if not runs:
        assert spans == 0
        return None
    ((run_id, samples_path),) = runs
    table = pq.read_table(data_dir / samples_path)
    pairs = set(zip(table["span"].to_pylist(), table["wire"].to_pylist(), strict=True))
    assert spans == len(pairs - {(None, w) for _, w in pairs}) > 0
    assert samples == pc.sum(pc.is_valid(table["span"])).as_py()
    return int(run_id)


CASES = [
    ("SIGINT", "pass1"),
    ("SIGINT", "store"),
    ("SIGTERM", "pass2"),
    ("SIGTERM", "store"),
    ("SIGKILL", "pass1"),
    ("SIGKILL", "store"),
]


@pytest.mark.parametrize(("name", "when"), CASES, ids=[f"{n}-{w}" for n, w in CASES])
def test_a_signal_during_process(
    small_run: SmallRun, database: Path, isolated_environment: Path, name: str, when: str
) -> None:
    url = f"sqlite:///{database}"
    samples = isolated_environment / "samples"
    with write_lock(database) if when == "store" else nullcontext():
        process = start_catenary(*small_run.process_args(url))
        try:
            wait_for(when, samples, process)
            process.send_signal(getattr(signal, name))
        except BaseException:
            process.kill()
            raise
    out, err = process.communicate(timeout=60)
    run_id = stored(database, isolated_environment)
    if name == "SIGKILL":
        assert process.returncode == -signal.SIGKILL
    else:
        assert process.returncode == (130 if name == "SIGINT" else 143), out + err
        assert "Traceback" not in err, err
        expected = (
            f"interrupted: {small_run.run} not stored (nothing of it kept)"
            if run_id is None
            else f"interrupted: stored as run {run_id}, its alerts not evaluated "
            f"(catenary alerts evaluate --run {run_id})"
        )
        assert err.strip().splitlines() == [expected], err
        assert not list(samples.glob(".*")), list(samples.iterdir())  # cleaned up at once
    if when == "store" and name != "SIGKILL":
        assert run_id is not None  # held until the transaction ended, then delivered

    again = catenary(*small_run.process_args(url))
    assert_succeeded(again)
    if run_id is None:
        assert "stored as run" in again.stdout
    else:
        assert f"is already stored with this rig calibration as run {run_id}" in again.stdout
    assert stored(database, isolated_environment) is not None
    assert not list(samples.rglob(".*"))  # no hidden file left anywhere
    (kept,) = samples.rglob("*.parquet")  # the stored processing's, at its key
    assert kept.relative_to(samples).parts[:2] == ("line=demo-line", "track=1")


@dataclass(frozen=True)
class Member:
    """A live process of a process group: its parent's pid and its command line."""

    parent: int
    command: str


def group_members(group: int) -> dict[int, Member]:
    """The live processes (not zombies) of the process group ``group``, by pid (``/proc``)."""
    found = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            state, parent, pgrp = stat.read_text().rpartition(")")[2].split()[:3]
            if int(pgrp) == group and state != "Z":
                command = (stat.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode()
                found[int(stat.parent.name)] = Member(int(parent), command)
        except OSError:  # ended meanwhile
            continue
    return found


@pytest.mark.slow  # the real CLI on a simulated run
def test_sigkill_leaves_no_worker_behind(
    small_run: SmallRun, database: Path, isolated_environment: Path
) -> None:
    """``process --workers 2`` killed by SIGKILL while its workers stage blocks: within a few
    seconds its output pipes reach end-of-file and none of its processes (workers, fork
    server, resource tracker) remains."""
    url = f"sqlite:///{database}"
    process = start_catenary(*small_run.process_args(url), "--workers", "2", new_session=True)
    try:
        deadline = time.monotonic() + 60.0
        while True:
            members = group_members(process.pid)
            server = {p for p, m in members.items() if "multiprocessing.forkserver" in m.command}
            if sum(m.parent in server for m in members.values()) == 2:  # its two workers
                break
            assert process.poll() is None, f"process ended before its workers were seen: {members}"
            assert time.monotonic() < deadline, f"no two workers after 60 s: {members}"
            time.sleep(0.01)
        process.kill()
        killed = time.monotonic()
        assert any("resource_tracker" in m.command for m in members.values()), members
        process.communicate(timeout=60)  # both pipes at end-of-file, the process reaped
        assert process.returncode == -signal.SIGKILL
        assert time.monotonic() - killed < 5.0, f"pipes held {time.monotonic() - killed:.1f} s"
        while (left := group_members(process.pid)) and time.monotonic() - killed < 5.0:
            time.sleep(0.05)
        assert not left, left
    finally:
        with suppress(ProcessLookupError):  # whatever of it a failure left
            os.killpg(process.pid, signal.SIGKILL)
        process.wait()
