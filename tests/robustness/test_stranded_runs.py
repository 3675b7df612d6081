"""No run is stranded: a run stored whose alert evaluation was killed, or failed, is evaluated
by the next ``alerts evaluate --all`` and by ``process`` of the same file; a track whose
evaluation fails is named and the others are still evaluated."""

from __future__ import annotations

import re
import signal
import subprocess
import time
from pathlib import Path

import pytest
import sqlalchemy as sa

from ..conftest import SmallRun
from .conftest import assert_refused, assert_succeeded, catenary, start_catenary
from .stranded_support import (
    BROKEN_WIRE_TYPE,
    KILLED_AFTER_COMMIT,
    alerting_config,
    default_database,
    install_plugin,
    stored_runs,
)

pytestmark = pytest.mark.slow  # the real CLI on simulated runs


def _process(
    run: SmallRun, config: Path, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    return catenary(
        "--config", config, "process", run.run, "--rig", run.rig, "--masts", run.masts, env=env
    )


def _killed_after_its_commit(run: SmallRun, tmp_path: Path) -> Path:
    """Process the first run with a plugin that kills the process right after its commit;
    return the config (a policy that raises an alert on every span)."""
    config = alerting_config(tmp_path)
    killer = install_plugin(tmp_path / "killer", "killer", KILLED_AFTER_COMMIT)
    killed = _process(run, config, env=killer)
    assert killed.returncode == -signal.SIGKILL, killed.stdout + killed.stderr
    assert stored_runs() == ([1], [1], 0)  # stored, pending
    return config


def _new_alerts(output: str) -> int:
    found = re.search(r"(\d+) new", output)
    assert found is not None, output
    return int(found.group(1))


def test_a_run_killed_before_its_alerts_is_evaluated_by_the_next_evaluate_all(
    small_run: SmallRun, tmp_path: Path
) -> None:
    config = _killed_after_its_commit(small_run, tmp_path)
    evaluated = catenary("--config", config, "alerts", "evaluate", "--all")
    assert_succeeded(evaluated)
    assert "1 run(s) evaluated for the first time" in evaluated.stdout
    assert _new_alerts(evaluated.stdout) > 0
    assert stored_runs() == ([1], [], _new_alerts(evaluated.stdout))


def test_a_run_killed_before_its_alerts_is_evaluated_by_processing_it_again(
    small_run: SmallRun, tmp_path: Path
) -> None:
    config = _killed_after_its_commit(small_run, tmp_path)
    again = _process(small_run, config)
    assert_succeeded(again)
    first, alerts = again.stdout.splitlines()[:2]
    assert re.search(
        r"is already stored with this rig calibration as run 1 \(UUID [0-9a-f-]{36}\); its "
        "alerts were not evaluated yet: evaluated now$",
        first,
    )
    assert alerts.startswith("alerts     ") and _new_alerts(alerts) > 0
    assert stored_runs() == ([1], [], _new_alerts(alerts))


def test_one_broken_track_does_not_stop_the_others(
    small_run: SmallRun, second_small_run: SmallRun, tmp_path: Path
) -> None:
    config = alerting_config(tmp_path)
    plugin = install_plugin(tmp_path / "plugin", "broken_wires", BROKEN_WIRE_TYPE)
    # a run of the broken wire type: stored, its alerts fail, named in one line
    broken = catenary(
        "--config", config, "process", small_run.run, "--rig", small_run.rig,
        "--line", "L1", "--track", "1", "--wire-type", "BROKEN", env=plugin,
    )  # fmt: skip
    assert_refused(
        broken, "run 1 is stored", "line L1 track 1", "ZeroDivisionError: area table not loaded"
    )
    assert "stored as run 1" in broken.stdout
    # another track's run, killed right after its commit: pending
    killer = install_plugin(tmp_path / "killer", "killer", KILLED_AFTER_COMMIT)
    other = _process(second_small_run, config, env=killer)
    assert other.returncode == -signal.SIGKILL, other.stdout + other.stderr
    assert stored_runs() == ([1, 2], [1, 2], 0)
    # every track: the broken one named, the other evaluated and committed
    evaluated = catenary("--config", config, "alerts", "evaluate", "--all", env=plugin)
    assert_refused(
        evaluated, "line L1 track 1", "ZeroDivisionError: area table not loaded", "pending"
    )
    assert "1 run(s) evaluated for the first time" in evaluated.stdout
    assert stored_runs() == ([1, 2], [1], _new_alerts(evaluated.stdout))


def test_a_process_killed_before_its_commit_leaves_no_samples_file_for_the_next_one(
    small_run: SmallRun, tmp_path: Path, isolated_environment: Path
) -> None:
    """``kill -9`` once the samples file is in the store but before the commit (SQLite's
    commit waits for a reader to finish): no row, and the next ``process`` removes the object
    the killed one put in the store, and stores the run with one samples file."""
    config = alerting_config(tmp_path)
    samples = isolated_environment / "samples"
    with default_database(read_only=True) as reading:
        reading.execute(sa.text("SELECT count(*) FROM runs"))  # a reader: the commit waits
        killed = start_catenary(
            "--config", config, "process", small_run.run, "--rig", small_run.rig,
            "--masts", small_run.masts, stderr=subprocess.STDOUT,
        )  # fmt: skip
        try:
            deadline = time.monotonic() + 60.0
            while not _visible(samples):
                assert killed.poll() is None, killed.communicate()[0]
                assert time.monotonic() < deadline, "the process never named its samples file"
                time.sleep(0.02)
        finally:
            killed.kill()
            killed.communicate()
    assert stored_runs() == ([], [], 0)
    again = _process(small_run, config)
    assert_succeeded(again)
    assert stored_runs()[0] == [1]
    (line,) = [line for line in again.stdout.splitlines() if line.startswith("samples")]
    assert [p.name for p in _visible(samples)] == [Path(line.split(" in ")[1].split()[0]).name]


def _visible(folder: Path) -> list[Path]:
    """The samples files in the local store's folder (not the hidden ones being written)."""
    return [p for p in folder.rglob("*.parquet") if not p.name.startswith(".")]
