"""What the field-length, read-only, disk-full and hostile-name cases share: a short simulated
run with its rig calibration and mast register (made once per worker), counts of what a
database holds, and the command run under a file size limit or without root's file access."""

from __future__ import annotations

import ctypes
import os
import resource
import signal
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest
from click.testing import CliRunner
from sqlalchemy import Engine, func, select

from catenary.cli import cli
from catenary.storage.models import Base
from catenary_linescan.simulator import DEMO_RIG_PATH, load_rig, record_run
from catenary_linescan.simulator.captures import write_captures


@dataclass(frozen=True)
class SmallRun:
    """A recorded run file, its mast register and a rig calibration for it."""

    run: Path
    masts: Path
    rig: Path


def small_run(tmp_path_factory: pytest.TempPathFactory) -> SmallRun:
    """A 60 m simulated run (about 1,400 scans), made once per worker; treat it as read-only."""
    folder = tmp_path_factory.getbasetemp() / "hardening-small-run"
    found = SmallRun(folder / "run.h5", folder / "run.masts.csv", folder / "rig.toml")
    if found.rig.exists():
        return found
    folder.mkdir(exist_ok=True)
    record_run(found.run, {"length_m": 60.0, "speed_kmh": 160.0, "seed": 3})
    captures, _ = write_captures(folder / "captures.h5", load_rig(DEMO_RIG_PATH), seed=2)
    result = CliRunner().invoke(
        cli, ["calibrate", str(captures), "--vehicle", str(DEMO_RIG_PATH), "-o", str(found.rig)]
    )
    assert result.exit_code == 0, result.output
    return found


def row_counts(engine: Engine) -> dict[str, int]:
    """The rows of every table of the models, by table name."""
    with engine.connect() as connection:
        return {
            name: int(connection.scalar(select(func.count()).select_from(table)) or 0)
            for name, table in Base.metadata.tables.items()
        }


def catenary_limited(
    preexec: Callable[[], None], *args: str | os.PathLike[str], timeout: float = 120.0
) -> subprocess.CompletedProcess[str]:
    """``catenary ARGS`` in a child process, as ``conftest.catenary`` runs it, with ``preexec``
    called in the child before it starts (``file_size_limit``, ``without_root_file_access``)."""
    return subprocess.run(
        [sys.executable, "-m", "catenary.cli", *map(str, args)],
        env=dict(os.environ),
        capture_output=True,
        text=True,
        timeout=timeout,
        preexec_fn=preexec,
    )


def file_size_limit(limit_bytes: int) -> Callable[[], None]:
    """A child may write no file past ``limit_bytes`` (``RLIMIT_FSIZE``, with SIGXFSZ ignored so
    that a write past it fails with EFBIG, as on a full disk)."""

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    return limit


_PR_CAPBSET_DROP = 24
# CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH, CAP_FOWNER: what lets root ignore a file's permissions
_FILE_ACCESS_CAPABILITIES = (1, 2, 3)


def without_root_file_access() -> None:
    """In a child: when running as root, drop the capabilities that let root write what its
    permissions forbid (from the bounding set, so that the command it starts has none of them);
    the child then meets a file's permission bits as its owner does. Nothing to do for others.
    """
    if os.geteuid() != 0:
        return
    libc = ctypes.CDLL(None, use_errno=True)
    for capability in _FILE_ACCESS_CAPABILITIES:
        if libc.prctl(_PR_CAPBSET_DROP, capability, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), f"prctl(PR_CAPBSET_DROP, {capability})")
