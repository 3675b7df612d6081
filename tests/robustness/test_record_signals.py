"""Signals during ``catenary record``: every complete block is kept, whatever stops it.

Ctrl-C and SIGTERM finish the block being written, close the file with its completion marker
and say in one line how many scans were kept (exit 130 and 143). SIGKILL cannot be caught:
the file keeps the blocks flushed before it and reads as interrupted (no marker).
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from catenary.measurement.runfile import RunFileWarning, open_run

BLOCK_SCANS = 256


def read_back(path: Path) -> tuple[int, int, bool]:
    """The scans the file declares, the scans read back block by block, and its marker."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RunFileWarning)  # SIGKILL's file: "may be interrupted"
        with open_run(path) as run:
            read = sum(block.scans for block in run.blocks(100))
            times = np.concatenate([block.time_s for block in run.blocks(1000)])
            assert np.all(np.diff(times) > 0.0) and np.all(np.isfinite(times))
            return run.header.scans, read, run.complete


@pytest.mark.parametrize(
    ("signum", "exit_code"),
    [(signal.SIGINT, 130), (signal.SIGTERM, 143), (signal.SIGKILL, -signal.SIGKILL)],
    ids=["SIGINT", "SIGTERM", "SIGKILL"],
)
def test_a_signal_during_record_keeps_every_complete_block(
    tmp_path: Path, small_rig_file: Path, signum: int, exit_code: int
) -> None:
    out = tmp_path / "run.h5"
    recording = subprocess.Popen(
        [
            sys.executable, "-m", "catenary.cli", "record", str(out),
            "--source", "simulator", "--source-option", f"rig={small_rig_file}",
            "--source-option", "length_m=5000", "--block-scans", str(BLOCK_SCANS),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
    )  # fmt: skip
    deadline = time.monotonic() + 60.0
    while not out.exists() and time.monotonic() < deadline and recording.poll() is None:
        time.sleep(0.05)
    time.sleep(1.5)  # a few blocks in, one of them likely being written
    recording.send_signal(signum)
    _, stderr = recording.communicate(timeout=60)
    assert recording.returncode == exit_code, stderr
    assert "Traceback" not in stderr
    declared, read, complete = read_back(out)
    assert declared == read > 0 and read % BLOCK_SCANS == 0
    if signum == signal.SIGKILL:
        assert not complete
        return
    assert complete
    how = "terminated" if signum == signal.SIGTERM else "interrupted"
    lines = stderr.strip().splitlines()
    assert lines[-1] == f"{how}: kept {read} scans in {out} (complete up to the last block)"
