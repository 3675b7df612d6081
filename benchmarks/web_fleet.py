"""Benchmark: the web service's pages and API on a fleet-sized PostgreSQL database.

Builds the fleet of ``alerts_fleet.py`` (its builder functions: ``--tracks`` x ``--spans``
spans, each track inspected ``--runs`` times; by default 200,000 spans x 50 runs, about 10
million span measurements) in a schema of its own, evaluates its alerts (policy
``china-maintenance-rules``), adds a viewer with an API token, and gives the first track
(about 105 km) samples: the two latest runs' samples files (synthetic, a sample every
``--sample-m`` along each wire, written with the project's ``SampleWriter`` into a folder
store at each processing's ``samples_key``) and their envelope files (``write_envelopes``).

Then it starts ``catenary serve`` (``--workers`` processes, default 1) on a free port of
127.0.0.1 and, for each endpoint, sends 20 warm-up requests, then ``--requests`` sequential
requests from one client, then the same number in total from ``--clients`` concurrent clients
(threads, each with its own connection, an equal share each), and prints p50 and p95 of each.
The pages are read signed in through the sign-in form (a session cookie), the API with the
viewer's token. Without ``--keep`` the schema and the data folder are removed at the end;
``--reuse SCHEMA`` times a kept one again (migrated to this version first) without building
anything.

    CATENARY_TEST_DATABASE_URL=postgresql+psycopg://postgres@127.0.0.1:5432/test \\
        .venv/bin/python benchmarks/web_fleet.py [--keep]      # prints the schema it built
    .venv/bin/python benchmarks/web_fleet.py --reuse web_fleet_0123456789ab   # no build
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from urllib.parse import urlencode

import httpx2
import numpy as np
import tomli_w
from alerts_fleet import (
    FIRST_RUN,
    POLICY,
    RUN_EVERY,
    SECTION_SPANS,
    build_measurements,
    build_register,
    build_runs,
)
from sqlalchemy import Engine, create_engine, select
from sqlalchemy.engine import make_url

from catenary.config import load_settings
from catenary.maintenance.alerts import evaluate_alerts
from catenary.measurement.envelope import write_envelopes
from catenary.measurement.samples import SampleWriter
from catenary.plugins import PluginRegistry
from catenary.storage import migrate
from catenary.storage.database import make_engine, session_scope
from catenary.storage.models import Line, Mast, Processing, Run, SpanMeasurement, Track, User
from catenary.storage.store import open_store, samples_key
from catenary.storage.users import add_user, create_token

VIEWER = "bench-viewer"
PASSWORD = "benchmark password, not a secret"
LINE, TRACK = "L000", "1"
"""The track given samples: the fleet's first."""
BLOCK_M = 1000.0
"""Chainage written to the samples file at a time [m]."""
WARM_UP = 20
SPANS_WINDOW_M = 5000.0
"""The chainage range of the spans API request [m]."""
PROFILE_WINDOW_M = 500.0
"""The track view's zoomed window [m]: below ``RAW_BELOW_M``, the raw samples."""
PAGE_TARGET_MS, API_TARGET_MS = 300.0, 100.0


def _samples(
    chainage_m: np.ndarray, run: Run, years: float, sample_m: float, seed: int
) -> Iterator[dict[str, np.ndarray]]:
    """Synthetic sample rows of one run along the masts ``chainage_m`` ``(spans + 1,)``, block
    by block in scan order: one wire per anchor section (numbered from the start of the run's
    direction), both wires in each section's last span (the overlap); thickness wearing
    0.12 mm/year with a worn spot in every 40th span, height and stagger swinging between masts."""
    rng = np.random.default_rng(seed)
    spans = chainage_m.shape[0] - 1
    sections = (spans + SECTION_SPANS - 1) // SECTION_SPANS
    increasing = run.direction == "increasing"
    start, end = float(chainage_m[0]), float(chainage_m[-1])
    blocks = np.arange(start, end, BLOCK_M)
    if not increasing:
        blocks = blocks[::-1]
    scan = 0
    for block in blocks:
        x = np.arange(block, min(block + BLOCK_M, end), sample_m)
        if not increasing:
            x = x[::-1]
        span = np.clip(np.searchsorted(chainage_m, x, side="right") - 1, 0, spans - 1)
        section = np.minimum(span // SECTION_SPANS, sections - 1)
        overlap = (span % SECTION_SPANS == SECTION_SPANS - 1) & (section < sections - 1)
        scans = np.arange(scan, scan + x.shape[0])
        scan += x.shape[0]
        # the overlap's incoming wire: the next section's, sampled at the same scans
        row_scan = np.concatenate([scans, scans[overlap]])
        row_x = np.concatenate([x, x[overlap]])
        row_span = np.concatenate([span, span[overlap]])
        row_section = np.concatenate([section, section[overlap] + 1])
        order = np.lexsort((row_section, row_scan))
        row_scan, row_x = row_scan[order], row_x[order]
        row_span, row_section = row_span[order], row_section[order]
        n = row_x.shape[0]
        phase = (row_x - chainage_m[row_span]) / (chainage_m[row_span + 1] - chainage_m[row_span])
        worn = np.where(row_span % 40 == 7, 1.5 * np.exp(-(((phase - 0.4) / 0.05) ** 2)), 0.0)
        thickness = 12.7 - 0.12 * years - worn + rng.normal(0.0, 0.02, n)
        wire = np.where(increasing, row_section, sections - 1 - row_section)
        yield {
            "scan": row_scan,
            "position_m": np.abs(row_x - (start if increasing else end)),
            "chainage_m": row_x,
            "wire": wire.astype(np.int32),
            "height_mm": 5300.0 - 40.0 * np.sin(np.pi * phase) + rng.normal(0.0, 1.0, n),
            "stagger_mm": 200.0 * (1.0 - 2.0 * phase) * np.where(row_span % 2 == 0, 1.0, -1.0),
            "wear_width_mm": 6.0 + 0.8 * (12.8 - thickness),
            "residual_thickness_mm": thickness,
            "selection_uncertain": np.zeros(n, dtype=bool),
            "cameras": np.full(n, 3, dtype=np.int16),
            "span": row_span.astype(np.int32),
            "vehicle_fault": np.zeros(n, dtype=bool),
        }


def add_samples(engine: Engine, data_dir: Path, sample_m: float) -> None:
    """Samples and envelope files for the two latest runs of ``LINE`` track ``TRACK``, unless
    they have them already."""
    url = engine.url.render_as_string(hide_password=False)
    store = open_store(load_settings(database_url=url, environ=_environ(data_dir)))
    with session_scope(engine) as session:
        track = session.scalars(
            select(Track).join(Line).where(Line.code == LINE, Track.code == TRACK)
        ).one()
        chainage = np.array(
            session.scalars(
                select(Mast.chainage_m).where(Mast.track_id == track.id).order_by(Mast.chainage_m)
            ).all()
        )
        runs = session.scalars(
            select(Run).where(Run.track_id == track.id).order_by(Run.started_at.desc()).limit(2)
        ).all()
        for k, run in enumerate(runs):
            processing = session.get_one(Processing, run.processing_id)
            if processing.samples_key and store.exists(processing.samples_key):
                continue
            key = samples_key(LINE, TRACK, run.uuid, processing.uuid)
            years = (run.started_at - FIRST_RUN).total_seconds() / 31_557_600.0 + 1.0
            started = time.perf_counter()
            with tempfile.TemporaryDirectory() as scratch:
                path = Path(scratch) / "samples.parquet"
                with SampleWriter(path) as writer:
                    for block in _samples(chainage, run, years, sample_m, seed=k):
                        writer.write(block)
                stored = store.put_file(path, key)
            write_envelopes(store, key)
            processing.samples_key = stored.key
            processing.samples_size_bytes = stored.size_bytes
            processing.samples_sha256 = stored.sha256
            processing.length_m = float(chainage[-1] - chainage[0])
            print(
                f"run {run.id} ({run.direction}): {writer.rows:,} samples "
                f"({stored.size_bytes / 1e6:.0f} MB) and envelope levels in "
                f"{time.perf_counter() - started:.0f} s"
            )


def add_viewer(engine: Engine) -> str:
    """The viewer (added unless there) and a new API token of theirs."""
    now = datetime.now(UTC)
    with session_scope(engine) as session:
        if session.scalars(select(User.id).where(User.name == VIEWER)).first() is None:
            add_user(session, VIEWER, "viewer", PASSWORD, actor="benchmark", now=now)
        label = f"benchmark-{uuid.uuid4().hex[:8]}"
        return create_token(session, VIEWER, label, actor="benchmark", now=now)[1]


def build(engine: Engine, tracks: int, spans: int, runs: int) -> None:
    """The fleet of ``alerts_fleet.py`` and its alerts."""
    started = time.perf_counter()
    with engine.begin() as connection:
        track_ids, chainage = build_register(connection, tracks, spans)
        run_ids = build_runs(connection, track_ids, runs)
        rows = build_measurements(connection, track_ids, run_ids, chainage)
    with engine.connect() as connection:
        autocommit = connection.execution_options(isolation_level="AUTOCOMMIT")
        for table in ("masts", "runs", "span_measurements"):
            autocommit.exec_driver_sql(f"ANALYZE {table}")
    print(f"built {rows:,} span measurements in {time.perf_counter() - started:.0f} s")
    started = time.perf_counter()
    registry = PluginRegistry()
    with session_scope(engine) as session:
        result = evaluate_alerts(
            session,
            registry.limit_policies()[POLICY],
            registry.wire_types(),
            now=FIRST_RUN + runs * RUN_EVERY,
        )
    print(f"{len(result.new):,} alerts raised in {time.perf_counter() - started:.0f} s")


def _environ(data_dir: Path) -> dict[str, str]:
    return {"CATENARY_DATA_DIR": str(data_dir)}


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
        return port


@contextmanager
def serving(url: str, data_dir: Path, workers: int) -> Iterator[str]:
    """``catenary serve`` over ``url`` and the folder store in ``data_dir``; yields its base
    address once ``/health`` answers."""
    config = data_dir / "web-fleet.toml"
    config.write_text(
        tomli_w.dumps({"database": {"url": url}, "paths": {"data_dir": str(data_dir)}})
    )
    port = _free_port()
    log = (data_dir / "serve.log").open("w")
    command = [
        str(Path(sys.executable).with_name("catenary")), "--config", str(config),
        "serve", "--host", "127.0.0.1", "--port", str(port), "--workers", str(workers),
    ]  # fmt: skip
    environ = {k: v for k, v in os.environ.items() if not k.startswith("CATENARY_")}
    server = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=environ)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60.0
        while True:
            if server.poll() is not None:
                sys.exit(f"catenary serve stopped: {(data_dir / 'serve.log').read_text()[-2000:]}")
            try:
                if httpx2.get(f"{base}/health", timeout=2.0).status_code == 200:
                    break
            except httpx2.TransportError:
                pass
            if time.monotonic() > deadline:
                sys.exit(f"catenary serve did not answer on {base} within 60 s")
            time.sleep(0.2)
        yield base
    finally:
        server.terminate()
        server.wait(timeout=30)
        log.close()


def signed_in(base: str) -> httpx2.Client:
    """A client signed in as the viewer through the sign-in form."""
    client = httpx2.Client(base_url=base, timeout=60.0)
    page = client.get("/sign-in")
    token = re.search(r'name="csrf_token" value="([^"]+)"', page.text)
    if token is None:
        sys.exit("the sign-in page has no CSRF token")
    answer = client.post(
        "/sign-in", data={"name": VIEWER, "password": PASSWORD, "csrf_token": token.group(1)}
    )
    if answer.status_code != 303:
        sys.exit(f"sign-in answered {answer.status_code}: {answer.text[:200]}")
    return client


@dataclass(frozen=True)
class Endpoint:
    label: str
    path: str
    page: bool
    """Read signed in (a page), else with the API token."""
    target_ms: float | None


def endpoints(engine: Engine) -> list[Endpoint]:
    """The requests timed, on ``LINE`` track ``TRACK``: its worst span of the latest run."""
    with session_scope(engine, read_only=True) as session:
        track = session.scalars(
            select(Track).join(Line).where(Line.code == LINE, Track.code == TRACK)
        ).one()
        first, last = (
            session.execute(
                select(Mast.chainage_m)
                .where(Mast.track_id == track.id)
                .order_by(Mast.chainage_m)
                .limit(1)
            ).scalar_one(),
            session.scalars(
                select(Mast.chainage_m)
                .where(Mast.track_id == track.id)
                .order_by(Mast.chainage_m.desc())
                .limit(1)
            ).one(),
        )
        latest = session.scalars(
            select(Run.id).where(Run.track_id == track.id).order_by(Run.started_at.desc())
        ).first()
        worst = session.scalars(
            select(SpanMeasurement)
            .where(SpanMeasurement.run_id == latest)
            .order_by(SpanMeasurement.min_residual_thickness_mm)
            .limit(1)
        ).one()
        mast, at = worst.mast_from, worst.start_chainage_m
    where = {"line": LINE, "track": TRACK}
    middle = round(0.5 * (first + last), 1)

    def url(path: str, **query: object) -> str:
        return f"{path}?{urlencode({**where, **query})}"

    return [
        Endpoint("health", "/health", False, None),
        Endpoint("runs API (the track's)", url("/api/v1/runs"), False, None),
        Endpoint("overview /", "/", True, PAGE_TARGET_MS),
        Endpoint("track view page", url("/track"), True, PAGE_TARGET_MS),
        Endpoint(
            f"track profile {(last - first) / 1000:.0f} km",
            url("/api/v1/tracks/profile", from_m=first, to_m=last),
            False,
            PAGE_TARGET_MS,
        ),
        Endpoint(
            f"track profile {PROFILE_WINDOW_M:.0f} m",
            url("/api/v1/tracks/profile", from_m=middle, to_m=middle + PROFILE_WINDOW_M),
            False,
            PAGE_TARGET_MS,
        ),
        Endpoint(f"span page (mast {mast})", url("/span", mast=mast), True, PAGE_TARGET_MS),
        Endpoint(
            f"spans API {SPANS_WINDOW_M / 1000:.0f} km worst",
            url("/api/v1/spans", from_m=at, to_m=at + SPANS_WINDOW_M, order="worst"),
            False,
            API_TARGET_MS,
        ),
        Endpoint("span history API", url("/api/v1/spans/history", mast=mast), False, API_TARGET_MS),
    ]


def _timed(client: httpx2.Client, path: str, count: int) -> list[float]:
    """``count`` requests of ``path`` in a row: each one's time [ms]; exits on an error."""
    times = []
    for _ in range(count):
        started = time.perf_counter()
        answer = client.get(path)
        answer.read()
        times.append(1000.0 * (time.perf_counter() - started))
        if answer.status_code != 200:
            sys.exit(f"GET {path}: {answer.status_code} {answer.text[:300]}")
    return times


def _concurrent(
    make: Callable[[], httpx2.Client], path: str, clients: int, total: int
) -> list[float]:
    """``total`` requests of ``path`` shared among ``clients`` threads, each its own client."""
    shares = [total // clients + (k < total % clients) for k in range(clients)]
    made = [make() for _ in shares]
    times: list[list[float]] = [[] for _ in shares]
    threads = [
        threading.Thread(target=lambda k=k: times[k].extend(_timed(made[k], path, shares[k])))
        for k in range(clients)
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    for client in made:
        client.close()
    return [t for part in times for t in part]


def measure(base: str, token: str, chosen: list[Endpoint], requests: int, clients: int) -> None:
    """Each endpoint's p50 and p95 [ms], one client then ``clients`` at once, as a table."""

    def make(page: bool) -> httpx2.Client:
        if page:
            return signed_in(base)
        return httpx2.Client(
            base_url=base, timeout=60.0, headers={"Authorization": f"Bearer {token}"}
        )

    head = f"| endpoint | target p95 ms | 1 client p50 / p95 ms | {clients} clients p50 / p95 ms |"
    print(head + "\n|---|---:|---:|---:|")
    for endpoint in chosen:
        client = make(endpoint.page)
        _timed(client, endpoint.path, WARM_UP)
        single = np.percentile(_timed(client, endpoint.path, requests), [50, 95])
        client.close()
        together = np.percentile(
            _concurrent(lambda e=endpoint: make(e.page), endpoint.path, clients, requests), [50, 95]
        )
        target = "" if endpoint.target_ms is None else f"{endpoint.target_ms:.0f}"
        ok = "" if endpoint.target_ms is None or single[1] < endpoint.target_ms else " (over)"
        print(
            f"| {endpoint.label} | {target} | {single[0]:.0f} / {single[1]:.0f}{ok} "
            f"| {together[0]:.0f} / {together[1]:.0f} |",
            flush=True,
        )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--db", default=os.environ.get("CATENARY_TEST_DATABASE_URL"))
    parser.add_argument("--tracks", type=int, default=100)
    parser.add_argument("--spans", type=int, default=2000)
    parser.add_argument("--runs", type=int, default=50)
    parser.add_argument("--sample-m", type=float, default=0.05, help="Sample spacing [m].")
    parser.add_argument("--requests", type=int, default=200, help="Per endpoint and phase.")
    parser.add_argument("--clients", type=int, default=4)
    parser.add_argument("--workers", type=int, default=1, help="catenary serve --workers.")
    parser.add_argument("--keep", action="store_true", help="Keep the schema and data folder.")
    parser.add_argument("--reuse", metavar="SCHEMA", help="A schema kept before: no build.")
    parser.add_argument("--only", help="Time only the endpoints whose label holds this.")
    args = parser.parse_args(argv)
    if not args.db or make_url(args.db).get_backend_name() != "postgresql":
        sys.exit("give a PostgreSQL URL: --db URL or $CATENARY_TEST_DATABASE_URL")
    schema = args.reuse or f"web_fleet_{uuid.uuid4().hex[:12]}"
    if not re.fullmatch(r"[a-z_][a-z0-9_]*", schema):
        sys.exit(f"--reuse {schema!r}: not a schema name")
    data_dir = Path(tempfile.gettempdir()) / f"catenary-{schema}"
    admin = create_engine(args.db)
    with admin.begin() as connection:
        exists = connection.exec_driver_sql(
            "SELECT 1 FROM information_schema.schemata WHERE schema_name = %(s)s", {"s": schema}
        ).first()
        if args.reuse and exists is None:
            sys.exit(f"--reuse {schema}: no such schema")
        if not args.reuse:
            connection.exec_driver_sql(f'CREATE SCHEMA "{schema}"')
    url = make_url(args.db).update_query_dict({"options": f"-csearch_path={schema}"})
    url_text = url.render_as_string(hide_password=False)
    engine = make_engine(url_text)
    try:
        migrate.upgrade(engine)  # a kept schema gets this version's migrations
        if not args.reuse:
            build(engine, args.tracks, args.spans, args.runs)
        data_dir.mkdir(exist_ok=True)
        add_samples(engine, data_dir, args.sample_m)
        token = add_viewer(engine)
        chosen = [e for e in endpoints(engine) if args.only is None or args.only in e.label]
        print(
            f"schema {schema}; {args.requests} requests per endpoint from 1 client, then "
            f"{args.requests} shared by {args.clients} concurrent clients, after {WARM_UP} "
            "warm-up requests"
        )
        with serving(url_text, data_dir, args.workers) as base:
            measure(base, token, chosen, args.requests, args.clients)
    finally:
        engine.dispose()
        if not (args.keep or args.reuse):
            with admin.begin() as connection:
                connection.exec_driver_sql(f'DROP SCHEMA "{schema}" CASCADE')
            shutil.rmtree(data_dir, ignore_errors=True)
        admin.dispose()


if __name__ == "__main__":
    main()
