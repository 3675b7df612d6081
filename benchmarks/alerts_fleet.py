"""Benchmark: the alert evaluation (thresholds and forecasts) on a fleet-sized PostgreSQL database.

Builds, in a schema of its own (dropped at the end), a fleet of ``--tracks`` tracks of
``--spans`` spans each (default 100 x 2,000 = 200,000 spans), every track inspected
``--runs`` times (default 50, every 7-8 weeks over 7 years, the direction alternating): about
10 million span measurement rows, written with binary COPY. Every 25 spans form an anchor
section whose last span is an overlap (two contact wires). Each span and wire wears at its own
rate (log-normal around 0.12 mm/year, 2 % hot spots at 0.5-1.0 mm/year) from its own new
thickness, with 0.03 mm of noise on the span minimum.

Then it times the full evaluation (``catenary.maintenance.alerts.evaluate_alerts`` over every span,
policy ``china-maintenance-rules``: the anchor-section average rule and two local rules, with
forecasts over a 365-day horizon), once on the fresh database (raising every alert) and once
again (nothing new: every alert found and left as it is), and the evaluation of one run.

    CATENARY_TEST_DATABASE_URL=postgresql+psycopg://postgres@127.0.0.1:5432/test \\
        .venv/bin/python benchmarks/alerts_fleet.py [--tracks 100 --spans 2000 --runs 50]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import uuid
from collections import Counter
from datetime import UTC, datetime, timedelta

import numpy as np
from sqlalchemy import bindparam, create_engine, func, insert, select, update
from sqlalchemy.engine import Connection, make_url

from catenary.maintenance.alerts import evaluate_alerts
from catenary.plugins import PluginRegistry
from catenary.storage import migrate
from catenary.storage.database import make_engine, session_scope
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

SECTION_SPANS = 25
"""Spans per anchor section; the last one of each is an overlap."""

FIRST_RUN = datetime(2018, 1, 8, 9, 0, tzinfo=UTC)
RUN_EVERY = timedelta(days=52)
POLICY = "china-maintenance-rules"
WIRE_TYPE = "CTA120"
RIG_SHA256 = "0" * 64

_SPAN_COLUMNS = (
    ("run_id", "i4"),
    ("processing_id", "i4"),
    ("track_id", "i4"),
    ("span", "i4"),
    ("mast_from", "S4"),
    ("mast_to", "S4"),
    ("start_chainage_m", "f8"),
    ("end_chainage_m", "f8"),
    ("wire", "i4"),
    ("wire_position", "i4"),
    ("wire_type", "S6"),
    ("min_residual_thickness_mm", "f8"),
    ("min_at_chainage_m", "f8"),
    ("mean_residual_thickness_mm", "f8"),
    ("height_min_mm", "f8"),
    ("height_max_mm", "f8"),
    ("stagger_min_mm", "f8"),
    ("stagger_max_mm", "f8"),
    ("samples", "i4"),
)


def _copy_dtype() -> np.dtype:
    """One row of PostgreSQL's binary COPY: field count, then (length, big-endian value)."""
    fields: list[tuple[str, str]] = [("count", ">i2")]
    for name, kind in _SPAN_COLUMNS:
        fields.append((f"{name}_len", ">i4"))
        fields.append((name, kind if kind.startswith("S") else ">" + kind))
    return np.dtype(fields)


def _code(numbers: np.ndarray) -> np.ndarray:
    """Mast codes ``0000``..``9999`` as 4-byte strings."""
    return np.char.zfill(numbers.astype("U4"), 4).astype("S4")


def build_register(connection: Connection, tracks: int, spans: int) -> tuple[list[int], np.ndarray]:
    """Lines, tracks and masts; returns the track ids and the masts' chainages ``(spans + 1,)``."""
    rng = np.random.default_rng(1)
    chainage = np.concatenate([[0.0], np.cumsum(rng.uniform(40.0, 65.0, spans))]) + 10_000.0
    sections = np.minimum(np.arange(spans + 1) // SECTION_SPANS, (spans - 1) // SECTION_SPANS)
    track_ids = []
    for k in range(tracks):  # two tracks a line
        line_id = (
            connection.execute(
                select(Line.id).where(Line.code == f"L{k // 2:03d}")
            ).scalar_one_or_none()
            or connection.execute(
                insert(Line).values(code=f"L{k // 2:03d}").returning(Line.id)
            ).scalar_one()
        )
        track_ids.append(
            connection.execute(
                insert(Track).values(line_id=line_id, code=str(k % 2 + 1)).returning(Track.id)
            ).scalar_one()
        )
    codes = [c.decode() for c in _code(np.arange(spans + 1))]
    rows = [
        {
            "track_id": track_id,
            "code": codes[i],
            "chainage_m": float(chainage[i]),
            "wire_type": WIRE_TYPE,
            "anchor_section": f"S{sections[i]:03d}",
        }
        for track_id in track_ids
        for i in range(spans + 1)
    ]
    connection.execute(insert(Mast), rows)
    return track_ids, chainage


def build_runs(connection: Connection, track_ids: list[int], runs: int) -> np.ndarray:
    """``runs`` runs per track; returns their ids ``(tracks, runs)`` and sets their times."""
    vehicle = connection.execute(
        insert(Vehicle)
        .values(
            name="fleet", roof_height_mm=3900.0, sensor_height_mm=1100.0, sensor_baseline_mm=1800.0
        )
        .returning(Vehicle.id)
    ).scalar_one()
    calibration = connection.execute(
        insert(RigCalibration)
        .values(
            vehicle_id=vehicle,
            name="fleet",
            version=1,
            created_at=FIRST_RUN,
            content_toml="",
            sha256=RIG_SHA256,
        )
        .returning(RigCalibration.id)
    ).scalar_one()
    line_of = dict(connection.execute(select(Track.id, Track.line_id)).all())
    rng = np.random.default_rng(2)
    rows = []
    for k, track_id in enumerate(track_ids):
        for j in range(runs):
            started = FIRST_RUN + j * RUN_EVERY + timedelta(hours=float(rng.uniform(0, 24 * 10)))
            source = f"{k * runs + j:064x}"
            rows.append(
                {
                    "uuid": run_uuid(source, RIG_SHA256),
                    "line_id": line_of[track_id],
                    "track_id": track_id,
                    "direction": "increasing" if j % 2 == 0 else "decreasing",
                    "vehicle_id": vehicle,
                    "rig_calibration_id": calibration,
                    "source_file": f"/fleet/{k}/{j}.h5",
                    "source_sha256": source,
                    "rig_sha256": RIG_SHA256,
                    "started_at": started,
                    "scans": 0,
                    "status": "complete",
                }
            )
    connection.execute(insert(Run), rows)
    found = connection.execute(
        select(Run.track_id, Run.id, Run.started_at).order_by(Run.track_id, Run.started_at)
    ).all()
    made = connection.execute(
        insert(Processing).returning(
            Processing.id, Processing.run_id, sort_by_parameter_order=True
        ),
        [
            {
                "uuid": str(uuid.uuid4()),
                "run_id": r.id,
                "processor": "linescan-stereo",
                "package_version": "benchmark",
                "settings_sha256": settings_sha256(None),
                "rig_calibration_id": calibration,
                "processed_at": r.started_at,
                "length_m": 0.0,
            }
            for r in found
        ],
    ).all()
    connection.execute(
        update(Run).where(Run.id == bindparam("run")).values(processing_id=bindparam("made")),
        [{"run": run_id, "made": processing_id} for processing_id, run_id in made],
    )
    return np.array([r.id for r in found], dtype=np.int64).reshape(len(track_ids), runs)


def _track_rows(
    track_id: int,
    run_ids: np.ndarray,
    processing_ids: np.ndarray,
    started_years: np.ndarray,
    chainage: np.ndarray,
    seed: int,
) -> np.ndarray:
    """The span measurement rows of one track, every run (and its processing), as binary
    COPY rows."""
    rng = np.random.default_rng(seed)
    spans = chainage.shape[0] - 1
    sections = (spans + SECTION_SPANS - 1) // SECTION_SPANS
    overlap = np.arange(SECTION_SPANS - 1, spans - 1, SECTION_SPANS)
    # the wires of one run: every span's own, plus the incoming wire in each overlap span
    span = np.concatenate([np.arange(spans), overlap])
    incoming = np.concatenate([np.zeros(spans, bool), np.ones(overlap.shape[0], bool)])
    order = np.lexsort((incoming, span))
    span, incoming = span[order], incoming[order]
    section = np.minimum(span // SECTION_SPANS + incoming, sections - 1)
    k = span.shape[0]
    new_mm = rng.uniform(12.55, 12.9, k)
    rate = rng.lognormal(np.log(0.12), 0.5, k)
    hot = rng.random(k) < 0.02
    rate[hot] = rng.uniform(0.5, 1.0, hot.sum())
    line_stagger = np.where(incoming, 150.0, np.where(np.isin(span, overlap), -150.0, 0.0))
    runs = run_ids.shape[0]
    rows = np.zeros(runs * k, dtype=_copy_dtype())
    rows["count"] = len(_SPAN_COLUMNS)
    for name, kind in _SPAN_COLUMNS:
        rows[f"{name}_len"] = np.dtype(kind).itemsize
    age = started_years[:, None] - started_years[0] + 1.0  # (runs, 1): years since new
    thickness = new_mm - rate * age + rng.normal(0.0, 0.03, (runs, k))
    thickness = np.maximum(thickness, 7.0)
    decreasing = (np.arange(runs) % 2 == 1)[:, None]
    rows["run_id"] = np.repeat(run_ids, k)
    rows["processing_id"] = np.repeat(processing_ids, k)
    rows["track_id"] = track_id
    rows["span"] = np.tile(span, runs)
    rows["mast_from"] = np.tile(_code(span), runs)
    rows["mast_to"] = np.tile(_code(span + 1), runs)
    rows["start_chainage_m"] = np.tile(chainage[span], runs)
    rows["end_chainage_m"] = np.tile(chainage[span + 1], runs)
    # wires numbered in order of appearance: from the start of the run's direction
    rows["wire"] = np.where(decreasing, sections - 1 - section, section).ravel()
    rows["wire_position"] = np.tile(incoming.astype(np.int32), runs)  # left to right
    rows["wire_type"] = WIRE_TYPE.encode()
    rows["min_residual_thickness_mm"] = thickness.ravel()
    rows["min_at_chainage_m"] = np.tile(0.5 * (chainage[span] + chainage[span + 1]), runs)
    rows["mean_residual_thickness_mm"] = (thickness + 0.5).ravel()
    rows["height_min_mm"] = 5280.0
    rows["height_max_mm"] = 5320.0
    sign = np.where(decreasing, -1.0, 1.0)  # the track frame: right of the direction of travel
    rows["stagger_min_mm"] = (sign * (line_stagger - 200.0 * sign)).ravel()
    rows["stagger_max_mm"] = (sign * (line_stagger + 200.0 * sign)).ravel()
    rows["samples"] = 4000
    return rows


def build_measurements(
    connection: Connection,
    track_ids: list[int],
    run_ids: np.ndarray,
    chainage: np.ndarray,
) -> int:
    """Every span measurement, through one binary COPY; returns the rows written."""
    started = dict(connection.execute(select(Run.id, Run.started_at)).all())
    processing = dict(connection.execute(select(Run.id, Run.processing_id)).all())
    epoch = datetime(2000, 1, 1, tzinfo=UTC)
    raw = connection.connection.driver_connection
    assert raw is not None
    columns = ", ".join(name for name, _ in _SPAN_COLUMNS)
    written = 0
    statement = f"COPY span_measurements ({columns}) FROM STDIN (FORMAT BINARY)"
    with raw.cursor() as cursor, cursor.copy(statement) as copy:
        copy.write(b"PGCOPY\n\xff\r\n\x00" + bytes(8))  # signature, flags, no extension
        for k, track_id in enumerate(track_ids):
            years = np.array(
                [(started[int(r)] - epoch).total_seconds() / 31_557_600.0 for r in run_ids[k]]
            )
            made = np.array([processing[int(r)] for r in run_ids[k]], dtype=np.int64)
            rows = _track_rows(track_id, run_ids[k], made, years, chainage, seed=100 + k)
            copy.write(rows.tobytes())
            written += rows.shape[0]
        copy.write(b"\xff\xff")  # end of data
    return written


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--db", default=os.environ.get("CATENARY_TEST_DATABASE_URL"))
    parser.add_argument("--tracks", type=int, default=100)
    parser.add_argument("--spans", type=int, default=2000)
    parser.add_argument("--runs", type=int, default=50)
    parser.add_argument("--keep", action="store_true", help="Keep the schema (prints its name).")
    args = parser.parse_args(argv)
    if not args.db or make_url(args.db).get_backend_name() != "postgresql":
        sys.exit("give a PostgreSQL URL: --db URL or $CATENARY_TEST_DATABASE_URL")
    schema = f"alerts_fleet_{uuid.uuid4().hex[:12]}"
    admin = create_engine(args.db)
    with admin.begin() as connection:
        connection.exec_driver_sql(f'CREATE SCHEMA "{schema}"')
    url = make_url(args.db).update_query_dict({"options": f"-csearch_path={schema}"})
    engine = make_engine(url.render_as_string(hide_password=False))
    try:
        migrate.upgrade(engine)
        started = time.perf_counter()
        with engine.begin() as connection:
            track_ids, chainage = build_register(connection, args.tracks, args.spans)
            run_ids = build_runs(connection, track_ids, args.runs)
            rows = build_measurements(connection, track_ids, run_ids, chainage)
        with engine.connect() as connection:
            autocommit = connection.execution_options(isolation_level="AUTOCOMMIT")
            for table in ("masts", "runs", "span_measurements"):
                autocommit.exec_driver_sql(f"ANALYZE {table}")
        print(
            f"built {args.tracks * args.spans:,} spans x {args.runs} runs = {rows:,} span "
            f"measurements in {time.perf_counter() - started:.0f} s (schema {schema})"
        )
        registry = PluginRegistry()
        policy = registry.limit_policies()[POLICY]
        now = FIRST_RUN + args.runs * RUN_EVERY
        for label in ("first evaluation", "again"):
            started = time.perf_counter()
            with session_scope(engine) as session:
                result = evaluate_alerts(session, policy, registry.wire_types(), now=now)
            seconds = time.perf_counter() - started
            print(
                f"{label}: {seconds:.1f} s for {result.spans:,} span-wires and "
                f"{result.sections:,} anchor sections: {len(result.new)} new, "
                f"{result.updated} updated, {result.resolved} resolved"
            )
        with session_scope(engine) as session:
            kinds = Counter(
                (row.kind, row.level)
                for row in session.execute(select(Alert.kind, Alert.level)).all()
            )
            total = session.scalar(select(func.count()).select_from(SpanMeasurement))
        print(f"alerts: {dict(sorted(kinds.items()))} over {total:,} rows")
        run_id = int(run_ids[args.tracks // 2, -1])
        started = time.perf_counter()
        with session_scope(engine) as session:
            result = evaluate_alerts(
                session, policy, registry.wire_types(), run_ids=[run_id], now=now
            )
        print(
            f"one run ({result.spans:,} span-wires, {result.sections} anchor sections): "
            f"{time.perf_counter() - started:.2f} s"
        )
    finally:
        engine.dispose()
        if not args.keep:
            with admin.begin() as connection:
                connection.exec_driver_sql(f'DROP SCHEMA "{schema}" CASCADE')
        admin.dispose()


if __name__ == "__main__":
    main()
