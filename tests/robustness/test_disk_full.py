"""A full disk, made by a file size limit (``RLIMIT_FSIZE``) on the command's process: the
recording keeps every complete block in a file that ``process`` takes, and ``process`` fails in
one line leaving nothing half-written."""

from __future__ import annotations

import re
from pathlib import Path

from sqlalchemy import Engine

from catenary.measurement.runfile import open_run
from catenary.storage.database import make_engine

from ..conftest import SmallRun
from .conftest import assert_refused, assert_succeeded, catenary
from .hardening_support import file_size_limit, row_counts

BLOCK_SCANS = 128
RECORD_LIMIT_BYTES = 24 << 20  # the simulated run needs about 40 MiB


def test_a_recording_that_fills_the_disk_keeps_its_complete_blocks(
    small_run: SmallRun, engine: Engine, database_url: str, tmp_path: Path
) -> None:
    out = tmp_path / "full.h5"
    result = catenary(
        "record", out, "--source", "simulator", "--source-option", "length_m=120",
        "--block-scans", str(BLOCK_SCANS), preexec_fn=file_size_limit(RECORD_LIMIT_BYTES),
    )  # fmt: skip
    line = assert_refused(result, f"disk full writing {out} after ")
    found = re.search(r"after (\d+) scans: kept (\d+) complete scans$", line)
    assert found is not None, line
    kept = int(found[1])
    assert int(found[2]) == kept and kept > 0 and kept % BLOCK_SCANS == 0
    with open_run(out) as recorded:
        assert recorded.complete and recorded.header.scans == kept
    processed = catenary(
        "--db", database_url, "process", out, "--rig", small_run.rig, "--wire-type", "CTA120"
    )
    assert_succeeded(processed)
    assert "stored as run " in processed.stdout
    assert row_counts(engine)["runs"] == 1


def test_process_that_cannot_write_its_samples_leaves_nothing(
    small_run: SmallRun, engine: Engine, database_url: str, isolated_environment: Path
) -> None:
    process = small_run.process_args(database_url)
    result = catenary(*process, preexec_fn=file_size_limit(40_000))
    assert_refused(result, str(isolated_environment / "samples"), "cannot write samples")
    assert not any(row_counts(engine).values())
    assert not list((isolated_environment / "samples").iterdir())  # no scratch file left
    assert_succeeded(catenary(*process))


def test_process_that_cannot_grow_its_sqlite_database_leaves_nothing(
    small_run: SmallRun, tmp_path: Path, isolated_environment: Path
) -> None:
    database = tmp_path / "catenary.sqlite"
    url = f"sqlite:///{database}"
    assert_succeeded(catenary("--db", url, "db", "upgrade"))
    engine = make_engine(url)
    before = row_counts(engine)
    process = small_run.process_args(url)
    result = catenary(*process, preexec_fn=file_size_limit(database.stat().st_size))
    assert_refused(result, f"database {database} cannot be written", "disk full")
    assert row_counts(engine) == before
    engine.dispose()
    assert not list((isolated_environment / "samples").iterdir())
    assert_succeeded(catenary(*process))


def test_an_export_that_fills_the_disk_leaves_no_partial_file(
    small_run: SmallRun, tmp_path: Path
) -> None:
    url = f"sqlite:///{tmp_path / 'catenary.sqlite'}"
    assert_succeeded(catenary("--db", url, "db", "upgrade"))
    assert_succeeded(catenary(*small_run.process_args(url)))
    out = tmp_path / "exports" / "samples.csv"
    out.parent.mkdir()
    export = ["--db", url, "export", "1", "--what", "samples", "-o", out]
    limited = catenary(*export, preexec_fn=file_size_limit(20_000))
    assert_refused(limited, str(out), "cannot write")
    assert not list(out.parent.iterdir())
    assert_succeeded(catenary(*export))
