"""Benchmark: ``catenary push`` of a long run keeps its memory flat, and the fleet's samples
of one span read quickly across many runs.

1. **Push.** A vehicle (SQLite, a folder store) holds a synthetic processed run: its samples
   file (33 samples per metre, the rate of a 4-camera rig at 160 km/h, written in row groups
   as ``catenary process`` writes them) and its span rows, written directly (simulating
   100 km would take an hour). ``catenary push`` sends it, in a child process, to a central
   side on PostgreSQL and an S3-compatible store (``rclone serve s3`` on 127.0.0.1): its wall
   time and peak resident memory (``ru_maxrss``), for a run of ``--short-km`` and one of
   ``--km`` (memory flat: the two peaks match).
2. **Read.** ``--runs`` runs of ``--read-km`` each on one line and track are stored centrally
   the same way; ``FleetData.samples`` reads one span (50 m) of all of them, cold and then warm
   (the target: 0.5 s or less warm).

    CATENARY_TEST_DATABASE_URL=postgresql+psycopg://postgres@127.0.0.1:5432/test \\
        .venv/bin/python benchmarks/fleet_push.py            # 10 and 100 km; 50 runs of 5 km
"""

from __future__ import annotations

import argparse
import hashlib
import math
import os
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import tomli_w
from process_memory import run_command
from sqlalchemy import create_engine
from sqlalchemy.engine import make_url

from catenary.config import load_settings
from catenary.domain import TrackRegister, VehicleGeometry
from catenary.fleet.analysts import FleetData
from catenary.measurement.samples import SampleWriter
from catenary.storage import migrate
from catenary.storage.database import make_engine, session_scope
from catenary.storage.models import SpanMeasurement, run_uuid
from catenary.storage.runs import settings_sha256, store_processing
from catenary.storage.store import Store, open_store, samples_key

SAMPLES_PER_M = 33.0
SPAN_M = 50.0
BLOCK_SAMPLES = 100_000
START_M = 1000.0
LINE, TRACK = "L100", "1"
GEOMETRY = VehicleGeometry("bench-vehicle", 3900.0, 1100.0, 1800.0)
RIG_TEXT = 'name = "bench-vehicle"\n'
ACCESS_KEY, SECRET_KEY = "catenary-bench-access", "catenary-bench-secret-key"
RCLONE = Path(sys.executable).with_name("rclone")


def write_samples(path: Path, length_m: float, seed: int) -> int:
    """A samples file of a run over ``length_m`` from ``START_M``; returns its rows."""
    rng = np.random.default_rng(seed)
    rows = int(length_m * SAMPLES_PER_M)
    with SampleWriter(path) as writer:
        for first in range(0, rows, BLOCK_SAMPLES):
            scan = np.arange(first, min(first + BLOCK_SAMPLES, rows), dtype=np.int64)
            position = scan / SAMPLES_PER_M
            k = scan.shape[0]
            writer.write(
                {
                    "scan": scan,
                    "position_m": position,
                    "chainage_m": START_M + position,
                    "wire": np.zeros(k, np.int32),
                    "height_mm": 5300.0 + rng.normal(0.0, 5.0, k),
                    "stagger_mm": 200.0 * np.sin(position / SPAN_M * np.pi),
                    "wear_width_mm": 6.0 + rng.normal(0.0, 0.3, k),
                    "residual_thickness_mm": 11.5 + rng.normal(0.0, 0.05, k),
                    "selection_uncertain": np.zeros(k, bool),
                    "cameras": np.full(k, 4, np.int16),
                    "span": (position // SPAN_M).astype(np.int32),
                    "vehicle_fault": np.zeros(k, bool),
                }
            )
    return rows


def store_run(database_url: str, store: Store, length_m: float, seed: int) -> str:
    """A synthetic processed run stored in ``database_url`` and ``store`` (its samples file
    and span rows), as ``catenary process`` stores one; returns its UUID."""
    spans = math.ceil(length_m / SPAN_M)
    masts = np.arange(spans + 1) * SPAN_M + START_M
    register = TrackRegister(
        LINE, TRACK, tuple(f"M{k:05d}" for k in range(spans + 1)), masts,
        ("CTA120",) * (spans + 1), np.full(spans + 1, np.nan),
    )  # fmt: skip
    source = hashlib.sha256(f"bench-{seed}".encode()).hexdigest()
    rig_sha256 = hashlib.sha256(RIG_TEXT.encode()).hexdigest()
    made = str(uuid.uuid4())
    with tempfile.TemporaryDirectory() as scratch:
        local = Path(scratch) / "samples.parquet"
        write_samples(local, length_m, seed)
        key = samples_key(LINE, TRACK, run_uuid(source, rig_sha256), made)
        placed = store.put_file(local, key)
    rows = [span_row(register, k) for k in range(spans)]
    started = datetime(2026, 1, 1, tzinfo=UTC) + timedelta(days=seed)
    engine = make_engine(database_url)
    try:
        with session_scope(engine) as session:
            run, _ = store_processing(
                session, line=LINE, track=TRACK, register=register, geometry=GEOMETRY,
                rig_name="bench", rig_text=RIG_TEXT, replacing=None, span_rows=rows,
                run_values=dict(
                    direction="increasing", source_file=f"/runs/bench-{seed}.h5",
                    source_sha256=source, started_at=started, scans=int(length_m * SAMPLES_PER_M),
                    status="complete", error=None, alerts_evaluated_at=None,
                ),
                processing_values=dict(
                    uuid=made, processor="linescan-stereo", package_version="bench",
                    settings={}, settings_sha256=settings_sha256({}), processed_at=started,
                    wire_type=None, length_m=length_m, samples_key=placed.key,
                    samples_size_bytes=placed.size_bytes, samples_sha256=placed.sha256,
                ),
            )  # fmt: skip
            return run.uuid
    finally:
        engine.dispose()


def span_row(register: TrackRegister, k: int) -> SpanMeasurement:
    """Span ``k``'s row (from mast ``k`` to the next), its figures plausible."""
    start, end = register.chainage_m[k], register.chainage_m[k + 1]
    return SpanMeasurement(
        span=k,
        mast_from=register.mast[k],
        mast_to=register.mast[k + 1],
        start_chainage_m=start,
        end_chainage_m=end,
        wire=0,
        wire_position=0,
        wire_type="CTA120",
        min_residual_thickness_mm=11.3,
        min_at_chainage_m=start + 10.0,
        mean_residual_thickness_mm=11.5,
        height_min_mm=5290.0,
        height_max_mm=5310.0,
        stagger_min_mm=-200.0,
        stagger_max_mm=200.0,
        samples=int((end - start) * SAMPLES_PER_M),
    )


@contextmanager
def s3_server(folder: Path) -> Iterator[str]:
    """``rclone serve s3`` on a free port of 127.0.0.1 serving ``folder``; its endpoint."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    folder.mkdir(parents=True, exist_ok=True)
    (folder.parent / "rclone.conf").touch()
    server = subprocess.Popen(
        [str(RCLONE), "serve", "s3", "--config", str(folder.parent / "rclone.conf"),
         "--addr", f"127.0.0.1:{port}", "--auth-key", f"{ACCESS_KEY},{SECRET_KEY}", str(folder)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        for _ in range(400):
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1.0).close()
                break
            except OSError:
                time.sleep(0.05)
        yield f"http://127.0.0.1:{port}"
    finally:
        server.terminate()
        server.wait()


@contextmanager
def postgres_schema(base: str) -> Iterator[str]:
    """A new schema of the PostgreSQL database ``base``, migrated, dropped at the end."""
    schema = f"fleet_push_{uuid.uuid4().hex[:12]}"
    admin = create_engine(base)
    with admin.begin() as connection:
        connection.exec_driver_sql(f'CREATE SCHEMA "{schema}"')
    url = make_url(base).update_query_dict({"options": f"-csearch_path={schema}"})
    text = url.render_as_string(hide_password=False)
    engine = make_engine(text)
    migrate.upgrade(engine)
    engine.dispose()
    try:
        yield text
    finally:
        with admin.begin() as connection:
            connection.exec_driver_sql(f'DROP SCHEMA "{schema}" CASCADE')
        admin.dispose()


def central_config(folder: Path, database_url: str, endpoint: str) -> Path:
    path = folder / "central.toml"
    path.write_text(
        tomli_w.dumps(
            {
                "database": {"url": database_url},
                "store": {
                    "url": f"s3://bench-{uuid.uuid4().hex[:8]}/fleet",
                    "endpoint": endpoint,
                    "access_key_env": "BENCH_S3_ACCESS_KEY",
                    "secret_key_env": "BENCH_S3_SECRET_KEY",
                },
            }
        )
    )
    return path


def push_case(folder: Path, base: str, endpoint: str, length_m: float, env: dict[str, str]) -> None:
    """Store one run of ``length_m`` on a new vehicle and push it to a new central side."""
    vehicle_data = folder / f"vehicle-{length_m:.0f}"
    vehicle = f"sqlite:///{vehicle_data / 'catenary.sqlite'}"
    vehicle_data.mkdir()
    engine = make_engine(vehicle)
    migrate.upgrade(engine)
    engine.dispose()
    folder_store = open_store(load_settings(environ={"CATENARY_DATA_DIR": str(vehicle_data)}))
    store_run(vehicle, folder_store, length_m, seed=int(length_m))
    size = sum(p.stat().st_size for p in vehicle_data.rglob("*.parquet"))
    with postgres_schema(base) as central_url:
        config = central_config(folder, central_url, endpoint)
        peak, seconds, output = run_command(
            ["--db", vehicle, "push", "--to", str(config)],
            {**env, "CATENARY_DATA_DIR": str(vehicle_data)},
        )
    rows = int(length_m * SAMPLES_PER_M)
    print(
        f"push {length_m / 1000:6.1f} km: {rows:>10,} samples, {size / 1e6:7.1f} MB, "
        f"{seconds:6.1f} s ({size / 1e6 / seconds:5.1f} MB/s), peak RSS {peak:6.0f} MiB"
    )
    print("   " + next(line for line in output.splitlines() if line.startswith("pushed")))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--db", default=os.environ.get("CATENARY_TEST_DATABASE_URL"))
    parser.add_argument("--km", type=float, default=100.0)
    parser.add_argument("--short-km", type=float, default=10.0)
    parser.add_argument("--runs", type=int, default=50)
    parser.add_argument("--read-km", type=float, default=5.0)
    args = parser.parse_args(argv)
    if not args.db or make_url(args.db).get_backend_name() != "postgresql":
        sys.exit("give a PostgreSQL URL: --db URL or $CATENARY_TEST_DATABASE_URL")
    env = {**os.environ, "BENCH_S3_ACCESS_KEY": ACCESS_KEY, "BENCH_S3_SECRET_KEY": SECRET_KEY}
    os.environ.update(env)
    with tempfile.TemporaryDirectory() as tmp, s3_server(Path(tmp) / "s3" / "buckets") as endpoint:
        folder = Path(tmp)
        for km in (args.short_km, args.km):
            push_case(folder, args.db, endpoint, km * 1000.0, env)
        read_case(folder, args.db, endpoint, args.runs, args.read_km * 1000.0)
    return 0


def read_case(folder: Path, base: str, endpoint: str, runs: int, length_m: float) -> None:
    """``runs`` runs of ``length_m`` stored centrally; one span of all of them read."""
    with postgres_schema(base) as central_url:
        config = central_config(folder, central_url, endpoint)
        store = open_store(load_settings(config_path=config, environ={}))
        started = time.perf_counter()
        for seed in range(runs):
            store_run(central_url, store, length_m, seed=1000 + seed)
        print(f"stored {runs} runs of {length_m / 1000:.1f} km centrally in "
              f"{time.perf_counter() - started:.0f} s")  # fmt: skip
        middle = START_M + SPAN_M * (length_m // SPAN_M // 2)
        with FleetData.open(config) as fleet:
            for label in ("cold", "warm", "warm"):
                started = time.perf_counter()
                samples = fleet.samples(LINE, TRACK, middle, middle + SPAN_M)
                seconds = time.perf_counter() - started
                print(
                    f"one span of {samples['run'].nunique()} runs ({len(samples):,} samples, "
                    f"{label}): {seconds:.2f} s"
                )


if __name__ == "__main__":
    sys.exit(main())
