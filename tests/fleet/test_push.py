"""``catenary push`` and ``pull``: a vehicle (SQLite, its data directory) and the central side
(PostgreSQL, an S3-compatible store) as in the depot."""

from __future__ import annotations

import re
import shutil
import textwrap
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
import tomli_w
from click.testing import CliRunner, Result
from sqlalchemy import func, select

from catenary.cli import cli
from catenary.config import load_settings
from catenary.errors import UserError
from catenary.fleet.transfer import push, run_file_key
from catenary.measurement.samples import SampleWriter
from catenary.storage.database import make_engine, session_scope
from catenary.storage.models import Alert, Mast, Processing, Run, SpanMeasurement
from catenary.storage.store import StoreError, envelope_key, open_store

POLICY = """
    [policies.every-span]
    description = "met at 1 % loss: every span measured raises an alert"
    source = "tests"

    [[policies.every-span.rules]]
    level = "critical"
    scope = "local"
    worn_fraction = 0.01
"""


def invoke(*args: object) -> Result:
    return CliRunner().invoke(cli, [str(a) for a in args])


def succeeded(result: Result) -> str:
    assert result.exit_code == 0, result.output
    return result.output


@dataclass(frozen=True)
class Depot:
    """A vehicle's database URL and data directory, and the central side's config."""

    vehicle: str
    data_dir: Path
    central: Path
    central_url: str

    def on_vehicle(self, *args: object) -> Result:
        return invoke("--db", self.vehicle, *args)

    def centrally(self, *args: object) -> Result:
        return invoke("--config", self.central, *args)

    def central_count(self, model: Any, *where: Any) -> int:
        engine = make_engine(self.central_url)
        try:
            with session_scope(engine, read_only=True) as session:
                return int(session.scalar(select(func.count()).select_from(model).where(*where)))
        finally:
            engine.dispose()


@pytest.fixture
def depot(
    database_url: str,
    s3_settings: Any,
    isolated_environment: Path,
    tmp_path: Path,
) -> Iterator[Depot]:
    """The vehicle's SQLite file in its data directory; the central side on ``database_url``
    (PostgreSQL) and a new bucket of the test S3 server, with a policy that raises an alert
    on every span."""
    policy = tmp_path / "central" / "policy.toml"
    policy.parent.mkdir()
    policy.write_text(textwrap.dedent(POLICY))
    central = tmp_path / "central" / "central.toml"
    store = tomllib.loads(s3_settings.config_path.read_text())["store"]
    central.write_text(
        tomli_w.dumps(
            {
                "database": {"url": database_url},
                "store": store,
                "limits": {"policy": "every-span", "file": "policy.toml"},
            }
        )
    )
    vehicle = f"sqlite:///{isolated_environment / 'catenary.sqlite'}"
    depot = Depot(vehicle, isolated_environment, central, database_url)
    succeeded(depot.on_vehicle("db", "upgrade"))
    succeeded(invoke("--db", database_url, "db", "upgrade"))
    yield depot


def processed(depot: Depot, run: Any, *extra: str) -> str:
    output = succeeded(
        depot.on_vehicle("process", run.run, "--rig", run.rig, "--masts", run.masts, *extra)
    )
    (stored,) = [line for line in output.splitlines() if line.startswith("stored as run")]
    return stored.split("UUID ")[1].split(")")[0]


@pytest.mark.slow
@pytest.mark.parametrize("database_url", ["postgresql"], indirect=True)
def test_runs_processed_offline_are_pushed_whole_and_read_centrally(
    depot: Depot, small_run: Any, second_small_run: Any, tmp_path: Path
) -> None:
    first, second = processed(depot, small_run), processed(depot, second_small_run)
    vehicle_export = tmp_path / "vehicle-samples.parquet"
    succeeded(depot.on_vehicle("export", first, "--what", "samples", "-o", vehicle_export))

    crops = sorted(p.name for p in (depot.data_dir / "evidence").rglob("*.png"))
    assert crops  # a crop per span and wire, each run
    vehicle_store = open_store(load_settings(database_url=depot.vehicle))
    copied, built = vehicle_store.keys("envelopes")
    envelopes = {k.split("/run=")[1]: pq.read_table(depot.data_dir / k) for k in (copied, built)}
    vehicle_store.delete(built)  # as of a processing stored before envelope files
    output = succeeded(depot.on_vehicle("push", "--to", depot.central))
    # each processing's samples and envelope files, and the crops
    assert f"pushed 2 new run(s), 2 processing(s), {4 + len(crops)} object(s)" in output
    assert f"run {first}: processing " in output and f"run {second}: processing " in output
    assert "alerts     " in output and "central" in output
    # the vehicle's data directory goes: the central side has all it needs
    shutil.rmtree(depot.data_dir)

    assert depot.central_count(Run) == 2
    assert depot.central_count(Alert) > 0
    central_store = open_store(load_settings(config_path=depot.central, environ={}))
    assert sorted(k.rsplit("/", 1)[1] for k in central_store.keys("evidence")) == crops
    # the envelope files beside the central samples: the vehicle's copied, the missing built
    engine = make_engine(depot.central_url)
    try:
        with session_scope(engine, read_only=True) as session:
            central_samples = [p.samples_key for p in session.scalars(select(Processing))]
    finally:
        engine.dispose()
    for key in central_samples:
        assert key is not None
        with central_store.open_input(envelope_key(key)) as source:
            assert pq.read_table(source).equals(envelopes[key.split("/run=")[1]])
    report = tmp_path / "run.html"
    succeeded(depot.centrally("report", "run", first[:8], "-o", report))
    assert first in report.read_text()
    assert 'id="evidence"' in report.read_text() and "data:image/png;base64," in report.read_text()
    # an alert raised centrally shows the wire where it is
    engine = make_engine(depot.central_url)
    try:
        with session_scope(engine, read_only=True) as session:
            alert_id = session.scalars(select(Alert.id).order_by(Alert.id)).first()
    finally:
        engine.dispose()
    crop = tmp_path / "crop.png"
    said = succeeded(depot.centrally("alerts", "evidence", alert_id, "-o", crop))
    assert said.startswith(f"alert {alert_id}: crop of ")
    assert crop.read_bytes().startswith(b"\x89PNG")
    wrong = depot.centrally("alerts", "evidence", 999999, "-o", crop)
    assert wrong.exit_code != 0 and "no alert 999999 in the database" in wrong.output
    # (the two small runs are of different scenes: a run against itself)
    comparison = succeeded(depot.centrally("compare", first, first))
    assert comparison.startswith("run 1 against run 1\npoints compared")
    central_export = tmp_path / "central-samples.parquet"
    succeeded(depot.centrally("export", first, "--what", "samples", "-o", central_export))
    read, expected = pq.read_table(central_export), pq.read_table(vehicle_export)
    assert read.schema == expected.schema and read.num_rows == expected.num_rows > 0
    for name in expected.column_names:  # NaN where the vehicle had NaN
        np.testing.assert_array_equal(read[name].to_numpy(), expected[name].to_numpy())
    spans = tmp_path / "spans.csv"
    succeeded(depot.centrally("export", second, "--what", "spans", "-o", spans))
    assert len(spans.read_text().splitlines()) > 1

    # twice: nothing moves, nothing doubles
    depot.data_dir.mkdir()
    succeeded(depot.on_vehicle("db", "upgrade"))
    again = succeeded(depot.on_vehicle("push", "--to", depot.central))
    assert "pushed 0 new run(s), 0 processing(s), 0 object(s)" in again
    assert depot.central_count(Run) == 2 and depot.central_count(Processing) == 2


@pytest.mark.slow
@pytest.mark.parametrize("database_url", ["postgresql"], indirect=True)
def test_a_push_cut_off_resumes_where_it_stopped(
    depot: Depot, small_run: Any, second_small_run: Any, s3_server: Any
) -> None:
    """The S3 server stops after the first processing is committed: the second is not
    visible centrally at all; once the server is back, the push finishes it."""
    processed(depot, small_run)
    processed(depot, second_small_run)
    vehicle = load_settings(database_url=depot.vehicle)
    central = load_settings(config_path=depot.central, environ={})
    committed: list[int] = []

    def cut(size: int) -> None:
        committed.append(size)
        s3_server.stop()

    with pytest.raises(StoreError, match=r"127\.0\.0\.1"):
        push(vehicle, central, progress=cut)
    assert len(committed) == 1
    assert depot.central_count(Processing) == 1 and depot.central_count(Run) == 1
    s3_server.start()
    result = push(vehicle, central)
    assert (result.runs, result.processings, result.already) == (1, 1, 0)
    assert depot.central_count(Processing) == 2
    # every processing's object is in place, as the database says
    store = open_store(central)
    engine = make_engine(depot.central_url)
    try:
        with session_scope(engine, read_only=True) as session:
            for made in session.scalars(select(Processing)):
                assert made.samples_key and made.samples_size_bytes and made.samples_sha256
                store.check(made.samples_key, made.samples_size_bytes, made.samples_sha256)
    finally:
        engine.dispose()


@pytest.mark.slow
@pytest.mark.parametrize("database_url", ["postgresql"], indirect=True)
def test_a_run_processed_again_is_pushed_as_a_new_processing_with_its_run_file(
    depot: Depot, small_run: Any
) -> None:
    run = processed(depot, small_run)
    succeeded(depot.on_vehicle("push", "--to", depot.central))
    latest = processed(depot, small_run, "--replace")
    assert latest == run  # the same run: its UUID
    output = succeeded(depot.on_vehicle("push", "--to", depot.central, "--run-files"))
    assert re.search(r"pushed 0 new run\(s\), 1 processing\(s\), \d+ object\(s\)", output)
    assert depot.central_count(Run) == 1 and depot.central_count(Processing) == 2
    engine = make_engine(depot.central_url)
    try:
        with session_scope(engine, read_only=True) as session:
            (stored,) = session.scalars(select(Run))
            assert stored.processing is not None
            latest, _ = sorted(stored.processings, key=lambda p: p.processed_at)[::-1]
            assert stored.processing.id == latest.id
            visible = {s.processing_id for s in stored.span_measurements}
            assert visible == {latest.id}
            assert stored.source_key == run_file_key(run)
    finally:
        engine.dispose()
    central = load_settings(config_path=depot.central, environ={})
    assert open_store(central).digest(run_file_key(run)).size_bytes == small_run.run.stat().st_size


class Cut(Exception):
    """A put of a run file cut short."""


@pytest.mark.slow
@pytest.mark.parametrize("database_url", ["postgresql"], indirect=True)
def test_run_files_pushed_in_parts_resume_where_a_push_was_cut(
    depot: Depot, small_run: Any
) -> None:
    """The central store takes run files in 5 MiB parts; a push of the run file cut after two
    parts leaves them in place, and the next push sends only the others."""
    config = tomllib.loads(depot.central.read_text())
    config["store"]["part_size_mb"] = 5
    depot.central.write_text(tomli_w.dumps(config))
    run = processed(depot, small_run)
    succeeded(depot.on_vehicle("push", "--to", depot.central))
    central = open_store(load_settings(config_path=depot.central, environ={}))
    parts = -(-small_run.run.stat().st_size // (5 << 20))
    assert parts > 2

    def cut(part: Any) -> None:
        if part.number == 2:
            raise Cut

    with pytest.raises(Cut):  # what a push cut after two parts of the run file leaves
        central.put_parts(small_run.run, run_file_key(run), on_part=cut)
    output = succeeded(depot.on_vehicle("push", "--to", depot.central, "--run-files"))
    assert f"run files: {parts - 2} part(s) sent, 2 found in place" in output
    sent = central.digest(run_file_key(run))
    assert sent.size_bytes == small_run.run.stat().st_size
    engine = make_engine(depot.central_url)
    try:
        with session_scope(engine, read_only=True) as session:
            (stored,) = session.scalars(select(Run))
            assert stored.source_key == run_file_key(run) and stored.source_sha256 == sent.sha256
    finally:
        engine.dispose()


@pytest.mark.parametrize("database_url", ["postgresql"], indirect=True)
def test_a_run_cut_at_other_masts_than_the_central_registers_is_refused(
    depot: Depot, build: Any
) -> None:
    """The central register places M2 elsewhere: the push names the mast and moves nothing."""
    vehicle = load_settings(database_url=depot.vehicle)
    engine = make_engine(depot.vehicle)
    try:
        with session_scope(engine) as session:
            run = build.run(session, samples_key="samples/x.parquet", status="complete")
            session.add(build.span(run))
    finally:
        engine.dispose()
    central_engine = make_engine(depot.central_url)
    try:
        with session_scope(central_engine) as session:
            moved = build.run(session, source_sha256="0" * 64)
            for mast in moved.track.masts:
                if mast.code == "M2":
                    mast.chainage_m = 1052.5
    finally:
        central_engine.dispose()
    store = open_store(vehicle)
    (depot.data_dir / "samples").mkdir(parents=True, exist_ok=True)
    source = depot.data_dir / "x.parquet"
    SampleWriter(source).close()  # no rows: its envelope file is built empty
    store.put_file(source, "samples/x.parquet")
    central = load_settings(config_path=depot.central, environ={})
    with pytest.raises(UserError, match=r"mast M2 is at 1050.0 m here, 1052.5 m centrally"):
        push(vehicle, central)
    assert depot.central_count(Processing) == 1  # the central side's own run only
    assert depot.central_count(SpanMeasurement) == 0


@pytest.mark.parametrize("database_url", ["postgresql"], indirect=True)
def test_pull_copies_the_central_register_and_policy(depot: Depot, build: Any) -> None:
    central_engine = make_engine(depot.central_url)
    try:
        with session_scope(central_engine) as session:
            run = build.run(session)
            for mast in run.track.masts:
                mast.anchor_section = "A1"
                mast.design_height_mm, mast.line_speed_kmh = 5300.0, 160.0
            run.track.masts[0].wire_type = "XW-95"  # installed nowhere
            run.track.masts[1].latitude, run.track.masts[1].longitude = 48.1372, 11.5756
    finally:
        central_engine.dispose()
    result = depot.on_vehicle("pull", "--from", depot.central)
    assert result.exit_code == 0, result.output
    assert "pulled 1 track(s): 2 mast(s) added or changed, 0 removed" in result.output
    assert "wire types not installed here: XW-95" in result.output
    assert (depot.data_dir / "policies" / "policy.toml").is_file()
    engine = make_engine(depot.vehicle)
    try:
        with session_scope(engine, read_only=True) as session:
            masts = session.scalars(select(Mast).order_by(Mast.chainage_m)).all()
            assert [(m.code, m.chainage_m, m.wire_type, m.design_stagger_mm, m.anchor_section)
                    for m in masts] == [("M1", 1000.0, "XW-95", 200.0, "A1"),
                                        ("M2", 1050.0, "CTA120", None, "A1")]  # fmt: skip
            assert [(m.design_height_mm, m.line_speed_kmh, m.latitude, m.longitude)
                    for m in masts] == [(5300.0, 160.0, None, None),
                                        (5300.0, 160.0, 48.1372, 11.5756)]  # fmt: skip
    finally:
        engine.dispose()


@pytest.mark.parametrize(
    ("config", "missing"),
    [
        ('[store]\nurl = "s3://fleet/x"\n', "[database] url is missing"),
        ('[database]\nurl = "sqlite:///c.sqlite"\n', "[store] url is missing"),
    ],
)
def test_a_central_config_without_its_database_or_store_is_refused(
    tmp_path: Path, config: str, missing: str
) -> None:
    central = tmp_path / "central.toml"
    central.write_text(config)
    for command in ("push --to", "pull --from"):
        result = invoke(*command.split(), central)
        assert result.exit_code != 0
        (line,) = [x for x in result.output.splitlines() if x.startswith("Error:")]
        assert line.startswith(f"Error: {central}: {missing}")
