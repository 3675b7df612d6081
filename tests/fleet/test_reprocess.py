"""``catenary reprocess``: stored runs processed again on a Dask ``LocalCluster`` of worker
processes, equal to serial processing; what is done is skipped; unreachable files are said;
a worker killed mid-task is replaced and nothing is stored twice."""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from datetime import date, datetime, timedelta
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner, Result
from sqlalchemy import Engine, select
from sqlalchemy.orm import Session

from catenary.cli import cli
from catenary.config import Settings, load_settings
from catenary.errors import UserError
from catenary.fleet.reprocess import ReprocessTask, Selection, reprocess_run, select_runs
from catenary.fleet.transfer import run_file_key
from catenary.measurement.process import PACKAGE_VERSION, processing_settings
from catenary.storage.database import make_engine, session_scope
from catenary.storage.models import (
    Line,
    Mast,
    Processing,
    RigCalibration,
    Run,
    SpanMeasurement,
    Track,
    Vehicle,
)
from catenary.storage.runs import settings_sha256
from catenary.storage.store import open_store

SPAN_IDENTITY = {"id", "run_id", "processing_id", "track_id"}
PROCESSING_RESULTS = (
    "length_m",
    "chainage_aligned",
    "chainage_offset_m",
    "encoder_scale",
    "alignment_matched",
    "alignment_rms_m",
    "wire_type",
    "settings_sha256",
)


def invoke(*args: object) -> Result:
    return CliRunner().invoke(cli, [str(a) for a in args])


def succeeded(result: Result) -> str:
    assert result.exit_code == 0, result.output
    return result.output


# --- selection (no cluster) ------------------------------------------------------------------


def _calibration(vehicle: Vehicle, version: int, text: str, at: datetime) -> RigCalibration:
    return RigCalibration(
        vehicle=vehicle,
        name=vehicle.name,
        version=version,
        created_at=at,
        content_toml=text,
        sha256=hashlib.sha256(text.encode()).hexdigest(),
    )


@pytest.fixture
def fleet(engine: Engine, build: Any, database_url: str) -> Settings:
    """Four runs: A (line L1 track 1, vehicle v1, day 0) and B (L1 track 2, v1, day 10), both
    processed now with v1's latest calibration; C (L2, v2, day 20) processed with v2's first
    calibration, which a second has followed since; D (L2, v2, day 30) processed by an older
    catenary."""
    settings = load_settings(database_url=database_url)
    made_with = processing_settings(settings, "linescan-stereo", "CTA120")
    with session_scope(engine) as session:
        geometry = {"roof_height_mm": 3900.0, "sensor_height_mm": 1100.0}
        v1 = Vehicle(name="v1", sensor_baseline_mm=1800.0, **geometry)
        v2 = Vehicle(name="v2", sensor_baseline_mm=1700.0, **geometry)
        r1 = _calibration(v1, 1, 'name = "v1"\n', build.T0)
        r2 = _calibration(v2, 1, 'name = "v2"\n', build.T0)
        r2_newer = _calibration(v2, 2, 'name = "v2"\n# again\n', build.T0 + timedelta(days=25))
        session.add(r2_newer)
        l1, l2 = Line(code="L1"), Line(code="L2")
        tracks = {"A": Track(line=l1, code="1"), "B": Track(line=l1, code="2")}
        tracks["C"] = tracks["D"] = Track(line=l2, code="1")
        for name, day, rig, version in (
            ("A", 0, r1, PACKAGE_VERSION),
            ("B", 10, r1, PACKAGE_VERSION),
            ("C", 20, r2, PACKAGE_VERSION),
            ("D", 30, r2_newer, "0.0.1"),
        ):
            run = build.identified_run(
                line=tracks[name].line,
                track=tracks[name],
                direction="increasing",
                vehicle=rig.vehicle,
                rig_calibration=rig,
                source_file=f"/runs/{name}.h5",
                source_sha256=name * 64,
                started_at=build.T0.replace(hour=23) + timedelta(days=day),
                status="complete",
            )
            run.processing = build.processing(
                run,
                package_version=version,
                settings=made_with,
                settings_sha256=settings_sha256(made_with),
                wire_type="CTA120",
            )
            session.add(run)
    return settings


def _chosen(engine: Engine, settings: Settings, rig: tuple[str, str] | None = None,
            **selection: Any) -> list[str]:  # fmt: skip
    with session_scope(engine, read_only=True) as session:
        return [
            run.source_file[6]
            for run, _, _ in select_runs(session, Selection(**selection), settings, rig)
        ]


def test_selection_by_reference_line_track_dates_vehicle(
    engine: Engine, fleet: Settings, build: Any
) -> None:
    day0 = build.T0.date()
    assert _chosen(engine, fleet) == ["A", "B", "C", "D"]
    with session_scope(engine, read_only=True) as session:
        uuids = {r.source_file[6]: r.uuid for r in session.scalars(select(Run))}
    assert _chosen(engine, fleet, references=("1", uuids["C"][:8])) == ["A", "C"]
    assert _chosen(engine, fleet, line="L1") == ["A", "B"]
    assert _chosen(engine, fleet, line="L1", track="2") == ["B"]
    # whole UTC days, both ends included (each run starts at 23:00 on its day)
    assert _chosen(engine, fleet, since=day0 + timedelta(days=10)) == ["B", "C", "D"]
    assert _chosen(engine, fleet, until=day0 + timedelta(days=20)) == ["A", "B", "C"]
    assert _chosen(engine, fleet, since=day0 + timedelta(days=11), until=date(2100, 1, 1)) == [
        "C",
        "D",
    ]
    assert _chosen(engine, fleet, vehicle="v2") == ["C", "D"]
    with pytest.raises(UserError, match="no vehicle 'v3'"):
        _chosen(engine, fleet, vehicle="v3")
    with pytest.raises(UserError, match="no run 99"):
        _chosen(engine, fleet, references=("99",))


def test_stale_runs_are_those_reprocessing_would_change(engine: Engine, fleet: Settings) -> None:
    # C: its vehicle has a newer calibration; D: an older catenary made it
    assert _chosen(engine, fleet, stale=True) == ["C", "D"]
    with session_scope(engine, read_only=True) as session:
        by_vehicle = {
            run.source_file[6]: calibration_name
            for run, calibration_name, _ in select_runs(session, Selection(), fleet, None)
        }
    assert by_vehicle == {"A": "v1", "B": "v1", "C": "v2", "D": "v2"}
    # a rig given: every run processed with another is stale
    assert _chosen(engine, fleet, ("new", 'name = "v1"\n# new\n'), stale=True) == [
        "A",
        "B",
        "C",
        "D",
    ]
    # other settings than the runs were made with
    other = Settings(**{**fleet.__dict__, "sections": {"processing": {"vehicle_filter_hz": 2.0}}})
    assert _chosen(engine, other, stale=True) == ["A", "B", "C", "D"]


# --- on a LocalCluster -----------------------------------------------------------------------


def _latest(session: Session, source_sha256: str) -> tuple[Run, Processing]:
    run = session.scalars(select(Run).where(Run.source_sha256 == source_sha256)).one()
    assert run.processing is not None
    return run, run.processing


def _spans(processing: Processing) -> list[dict[str, Any]]:
    return [
        {
            c.key: getattr(s, c.key)
            for c in SpanMeasurement.__table__.c
            if c.key not in SPAN_IDENTITY
        }
        for s in processing.span_measurements
    ]


def _add_run(session: Session, build: Any, source_file: Path, source_sha256: str) -> Run:
    """A run of run 1's line, track and vehicle whose file is ``source_file``."""
    template = session.get_one(Run, 1)
    run = build.identified_run(
        line=template.line,
        track=template.track,
        direction=template.direction,
        vehicle=template.vehicle,
        rig_calibration=template.rig_calibration,
        source_file=str(source_file),
        source_sha256=source_sha256,
        started_at=template.started_at,
        status="complete",
    )
    run.processing = build.processing(run)
    session.add(run)
    session.flush()
    return run


def _stored_register(engine: Engine, path: Path) -> Path:
    """The database's masts written as a mast register CSV (every number as stored)."""
    rows = ["line,track,mast,chainage_m,wire_type,design_stagger_mm"]
    with session_scope(engine, read_only=True) as session:
        for mast in session.scalars(select(Mast).order_by(Mast.chainage_m)):
            stagger = "" if mast.design_stagger_mm is None else repr(mast.design_stagger_mm)
            rows.append(
                f"{mast.track.line.code},{mast.track.code},{mast.code},{mast.chainage_m!r},"
                f"{mast.wire_type},{stagger}"
            )
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.mark.slow
def test_reprocess_on_a_local_cluster_equals_serial_processing(
    database_url: str,
    small_run: Any,
    second_small_run: Any,
    build: Any,
    isolated_environment: Path,
    tmp_path: Path,
) -> None:
    serial_url = f"sqlite:///{tmp_path / 'serial.sqlite'}"
    recalibrated = tmp_path / "recalibrated.toml"
    recalibrated.write_text(small_run.rig.read_text() + "\n# recalibrated\n")
    for url in (database_url, serial_url):
        succeeded(invoke("--db", url, "db", "upgrade"))
    for run in (small_run, second_small_run):
        succeeded(invoke(*run.process_args(database_url)))
    engine = make_engine(database_url)
    # serially, with the recalibrated rig and the register as stored now (the two runs' mast
    # registers differ: the second's chainages replaced the first's)
    stored_masts = _stored_register(engine, tmp_path / "stored-masts.csv")
    for run in (small_run, second_small_run):
        succeeded(invoke("process", run.run, "--rig", recalibrated, "--masts", stored_masts,
                         "--db", serial_url))  # fmt: skip
    with session_scope(engine) as session:
        gone = _add_run(session, build, tmp_path / "gone.h5", "0" * 64)
        changed = _add_run(session, build, small_run.run, "1" * 64)  # another file there now
        gone_id, changed_id = gone.id, changed.id

    first = invoke("--db", database_url, "reprocess", "--rig", recalibrated, "--workers", 2)
    assert first.exit_code == 1, first.output
    lines = first.output.splitlines()
    assert lines[0] == "reprocessing 4 run(s) on a local cluster"
    outcome = {int(line.split()[1]): line for line in lines[1:5]}
    assert ": stored as processing " in outcome[1] and ": stored as processing " in outcome[2]
    assert outcome[gone_id].endswith(
        f"skipped: {tmp_path / 'gone.h5'} is not readable here and the store has no "
        f"{isolated_environment}/runs/{gone.uuid}.h5 (catenary push --run-files sends it)"
    )
    assert (
        f"failed: {small_run.run}: its content is not that of run {changed.uuid}"
        in (outcome[changed_id])
    )
    assert "4 run(s) in" in lines[5] and lines[5].endswith(": 2 stored, 1 skipped, 1 failed")
    assert "Error: 1 run(s) failed (above)" in first.output

    serial = make_engine(serial_url)
    store = open_store(load_settings(database_url=database_url))
    with session_scope(engine, read_only=True) as session, Session(serial) as other:
        for made in (small_run, second_small_run):
            sha = hashlib.sha256(made.run.read_bytes()).hexdigest()
            run, latest = _latest(session, sha)
            _, expected = _latest(other, sha)
            # a new processing of the same run (its identity, file path and first kept)
            assert len(run.processings) == 2 and run.processings[0] is not latest
            assert run.source_file == str(made.run.resolve())
            assert run.rig_sha256 != latest.rig_calibration.sha256
            assert latest.rig_calibration.content_toml == recalibrated.read_text()
            assert run.alerts_evaluated_at is None
            # exactly what serial processing made
            for column in PROCESSING_RESULTS:
                assert getattr(latest, column) == getattr(expected, column), column
            assert _spans(latest) == _spans(expected) and len(_spans(latest)) > 0
            assert latest.samples_key is not None and expected.samples_key is not None
            ours = pq.read_table(store.local_path(latest.samples_key))
            theirs = pq.read_table(store.local_path(expected.samples_key))
            assert ours.num_rows > 1000 and ours.schema == theirs.schema
            assert ours.to_pandas().equals(theirs.to_pandas())  # NaN where NaN, else equal
        processings = session.scalars(select(Processing.id)).all()
    serial.dispose()

    again = invoke("--db", database_url, "reprocess", "1", "2", "--rig", recalibrated,
                   "--workers", 2)  # fmt: skip
    output = succeeded(again)
    assert output.count(": skipped: already processed so (processing ") == 2, output
    assert output.splitlines()[-1].endswith(": 0 stored, 2 skipped, 0 failed")

    # without --rig: the vehicle's latest calibration, now the recalibrated one; the runs
    # processed with it are not stale, the two added ones (an older catenary's) are
    stale = invoke("--db", database_url, "reprocess", "--stale", "--workers", 1)
    assert stale.exit_code == 1, stale.output
    assert stale.output.splitlines()[0] == "reprocessing 2 run(s) on a local cluster"
    with session_scope(engine, read_only=True) as session:
        assert session.scalars(select(Processing.id)).all() == processings
    engine.dispose()


@pytest.mark.slow
def test_a_worker_killed_mid_task_is_replaced_and_nothing_is_stored_twice(
    small_run: Any, second_small_run: Any, isolated_environment: Path, tmp_path: Path
) -> None:
    url = f"sqlite:///{tmp_path / 'catenary.sqlite'}"
    succeeded(invoke("--db", url, "db", "upgrade"))
    for run in (small_run, second_small_run):
        succeeded(invoke(*run.process_args(url)))
    recalibrated = tmp_path / "recalibrated.toml"
    recalibrated.write_text(small_run.rig.read_text() + "\n# recalibrated\n")
    samples = isolated_environment / "samples"
    command = [sys.executable, "-m", "catenary.cli", "--db", url, "reprocess", "--rig",
               str(recalibrated), "--workers", "2"]  # fmt: skip
    with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT) as reprocess:
        deadline = time.monotonic() + 120.0
        killed = None
        while killed is None and time.monotonic() < deadline and reprocess.poll() is None:
            # a worker measuring a run writes .pass1-HOST-PID-TOKEN.parquet: kill that PID
            for path in samples.glob(".pass1-*.parquet"):
                killed = int(path.name.split("-")[-2])
                os.kill(killed, signal.SIGKILL)
                break
            time.sleep(0.02)
        output, _ = reprocess.communicate(timeout=300)
    text = output.decode()
    assert killed is not None, text
    assert reprocess.returncode == 0, text
    assert text.count(": stored as processing ") == 2, text
    engine = make_engine(url)
    with session_scope(engine, read_only=True) as session:
        for run in session.scalars(select(Run)):
            assert len(run.processings) == 2  # the first and one new: never two new
    engine.dispose()
    assert not list(samples.glob(".*")), "the killed worker's scratch files were tidied"


def test_an_unreachable_scheduler_is_one_line(
    engine: Engine, fleet: Settings, database_url: str
) -> None:
    result = invoke("--db", database_url, "reprocess", "--scheduler", "tcp://127.0.0.1:9")
    assert result.exit_code == 1
    assert result.output.startswith("reprocessing 4 run(s) on tcp://127.0.0.1:9\nError: cannot "
                                    "reach the Dask scheduler tcp://127.0.0.1:9: ")  # fmt: skip
    assert len(result.output.splitlines()) == 2


def test_until_before_since_is_refused(database_url: str) -> None:
    result = invoke("--db", database_url, "reprocess", "--since", "2024-05-02", "--until",
                    "2024-05-01")  # fmt: skip
    assert result.exit_code == 1
    assert result.output == "Error: --until 2024-05-01 is before --since 2024-05-02\n"


@pytest.fixture
def dask_cluster(s3_settings: Settings, tmp_path: Path) -> Iterator[str]:
    """A Dask cluster as on real machines: ``dask scheduler`` and one ``dask worker`` (one
    process, one thread) on 127.0.0.1, started in this test's environment (the store's keys
    set); gives the scheduler's address."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    dask = Path(sys.executable).with_name("dask")
    address = f"tcp://127.0.0.1:{port}"
    log = (tmp_path / "dask.log").open("wb")
    commands = [
        [dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
        [dask, "worker", address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard",
         "--host", "127.0.0.1"],
    ]  # fmt: skip
    started = [subprocess.Popen(c, stdout=log, stderr=subprocess.STDOUT) for c in commands]
    try:
        yield address
    finally:
        for process in reversed(started):
            process.terminate()
            process.wait(timeout=30)
        log.close()


@pytest.mark.slow
def test_a_run_file_only_in_the_store_is_copied_to_the_worker_first(
    small_run: Any, s3_settings: Settings, dask_cluster: str, tmp_path: Path
) -> None:
    """On an existing cluster (--scheduler)."""
    assert s3_settings.config_path is not None
    url = f"sqlite:///{tmp_path / 'catenary.sqlite'}"
    recorded = tmp_path / "vehicle" / "run.h5"
    recorded.parent.mkdir()
    shutil.copyfile(small_run.run, recorded)
    side = ("--config", s3_settings.config_path, "--db", url)
    succeeded(invoke(*side, "db", "upgrade"))
    succeeded(
        invoke(*side, "process", recorded, "--rig", small_run.rig, "--masts", small_run.masts)
    )
    engine = make_engine(url)
    with session_scope(engine, read_only=True) as session:
        run_uuid = session.get_one(Run, 1).uuid
    engine.dispose()
    # what push --run-files does: the file under runs/RUN.h5; then it is gone from the vehicle
    store = open_store(s3_settings)
    sent = store.put_file(recorded, run_file_key(run_uuid))
    recorded.unlink()
    recalibrated = tmp_path / "recalibrated.toml"
    recalibrated.write_text(small_run.rig.read_text() + "\n# recalibrated\n")

    result = invoke(*side, "reprocess", "--rig", recalibrated, "--scheduler", dask_cluster)
    output = succeeded(result)
    assert output.startswith(f"reprocessing 1 run(s) on {dask_cluster}\n"), output
    copied = re.search(r"stored as processing \S+ in \S+ s, its file copied from the store "
                       r"\((\S+) MB at (\d+) MB/s\)", output)  # fmt: skip
    assert copied is not None, output
    assert float(copied.group(1)) == pytest.approx(sent.size_bytes / 1e6, abs=0.05)
    assert int(copied.group(2)) > 0
    assert not list(Path(tempfile.gettempdir()).glob("catenary-reprocess-*/run.h5"))  # removed


@pytest.mark.slow
def test_the_same_run_reprocessed_twice_at_once_is_stored_once(
    database_url: str, small_run: Any, tmp_path: Path
) -> None:
    """Two tasks of one run at once (a task Dask ran again while the first still ran): the
    storing transaction checks, the run locked, that no alike processing came meanwhile."""
    succeeded(invoke("--db", database_url, "db", "upgrade"))
    succeeded(invoke(*small_run.process_args(database_url)))
    text = small_run.rig.read_text() + "\n# recalibrated\n"
    engine = make_engine(database_url)
    with session_scope(engine, read_only=True) as session:
        run = session.get_one(Run, 1)
        task = ReprocessTask(None, database_url, run.id, run.uuid, "recalibrated", text)
    with ThreadPoolExecutor(2) as pool:
        outcomes = sorted(pool.map(reprocess_run, [task, task]), key=lambda o: o.status)
    assert [o.status for o in outcomes] == ["skipped", "stored"], outcomes
    assert outcomes[0].reason == "processed so meanwhile (by another task)"
    with session_scope(engine, read_only=True) as session:
        run = session.get_one(Run, 1)
        assert len(run.processings) == 2
        assert run.processing is not None and run.processing.uuid == outcomes[1].processing_uuid
    engine.dispose()
