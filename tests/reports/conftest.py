"""Fixtures of the report tests: two runs over one section, processed by the real pipeline.

The runs are simulated (an overlap, encoder and start errors), the rig calibrated from
simulated captures and both runs processed by ``catenary process`` into a template SQLite
database once per session. Each test gets a copy of the template's rows in the backend's
fresh database (``database_url``: SQLite and PostgreSQL), the samples files shared read-only
through ``CATENARY_DATA_DIR``, and adds alerts and maintenance actions of its own.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner, Result
from sqlalchemy import create_engine, insert, select, update
from sqlalchemy.orm import Session

from catenary.cli import cli
from catenary.storage import migrate
from catenary.storage.database import make_engine
from catenary.storage.models import Base, MaintenanceAction, Run, SpanMeasurement
from catenary_linescan.simulator import DEMO_RIG_PATH, load_rig, record_run
from catenary_linescan.simulator.captures import write_captures

SETTINGS = {"length_m": 250.0, "overlap": True, "speed_kmh": 160.0, "scene_seed": 5}

POLICY = """
[policies.test-limits]
description = "limits met by the simulated wear"
source = "tests"

[[policies.test-limits.rules]]
level = "plan"
action = "plan renewal"
scope = "local"
residual_thickness_mm = 11.7

[[policies.test-limits.rules]]
level = "urgent"
action = "reinforce"
scope = "local"
residual_thickness_mm = 11.0

[[policies.test-limits.rules]]
level = "critical"
action = "cut out and splice"
scope = "local"
residual_thickness_mm = 10.6
"""
"""Limits of the simulated wear (10.47-12.9 mm): each level is met by some span."""


def invoke(*args: object) -> Result:
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


@dataclass(frozen=True)
class Stored:
    """The template: its database URL, data directory and a config with the test policy."""

    url: str
    data_dir: Path
    config: Path


@pytest.fixture(scope="session")
def stored(tmp_path_factory: pytest.TempPathFactory) -> Stored:
    folder = tmp_path_factory.mktemp("reports")
    data_dir = folder / "data"
    url = f"sqlite:///{data_dir / 'template.sqlite'}"
    (folder / "policy.toml").write_text(POLICY)
    config = folder / "config.toml"
    config.write_text('[limits]\nfile = "policy.toml"\n')
    with pytest.MonkeyPatch.context() as env:
        env.setenv("CATENARY_DATA_DIR", str(data_dir))
        env.setenv("XDG_CONFIG_HOME", str(folder / "xdg-config"))
        for name in ("CATENARY_DATABASE_URL", "CATENARY_CONFIG"):
            env.delenv(name, raising=False)
        runs = []
        for name, seed, errors in (
            ("a", 5, {"encoder_scale_error": 0.004, "start_chainage_error_m": -2.5}),
            ("b", 6, {"encoder_scale_error": -0.0025, "start_chainage_error_m": 1.8}),
        ):
            run = folder / f"{name}.h5"
            record_run(run, {**SETTINGS, **errors, "seed": seed})
            runs.append(run)
        captures, _ = write_captures(folder / "captures.h5", load_rig(DEMO_RIG_PATH), seed=2)
        rig = folder / "rig.toml"
        result = invoke("calibrate", captures, "--vehicle", DEMO_RIG_PATH, "-o", rig)
        assert result.exit_code == 0, result.output
        assert invoke("--db", url, "db", "upgrade").exit_code == 0
        for run in runs:
            masts = run.with_suffix(".masts.csv")
            result = invoke("--db", url, "process", run, "--rig", rig, "--masts", masts)
            assert result.exit_code == 0, result.output
    return Stored(url, data_dir, config)


@pytest.fixture
def database(stored: Stored, database_url: str, monkeypatch: pytest.MonkeyPatch) -> str:
    """A fresh database on the backend holding the template's rows (runs 1 and 2)."""
    engine = make_engine(database_url)
    migrate.upgrade(engine)
    source = create_engine(stored.url)
    with source.connect() as rows, engine.begin() as target:
        latest = {}  # runs refer to their processings, which refer to them: set last
        for table in Base.metadata.sorted_tables:
            found = [dict(row) for row in rows.execute(select(table)).mappings()]
            if table.name == "runs":
                latest = {row["id"]: row.pop("processing_id") for row in found}
            if found:
                target.execute(insert(table), found)
        for run_id, processing_id in latest.items():
            target.execute(update(Run).where(Run.id == run_id).values(processing_id=processing_id))
    source.dispose()
    engine.dispose()
    monkeypatch.setenv("CATENARY_DATA_DIR", str(stored.data_dir))
    return database_url


@pytest.fixture
def config(stored: Stored) -> Path:
    """A config file choosing the test policy (``POLICY``)."""
    return stored.config


@pytest.fixture
def alerts(database: str, build: Any) -> str:
    """``database`` with open, acknowledged and resolved alerts on run 2's spans, and a splice.

    Alert 1: critical threshold, masts 12/02 to 12/03 wire 0 (the overlap, minimum at mast
    12/03); 2: urgent threshold, acknowledged, 12/03 to 12/04 wire 0 (the splice there); 3 and
    4: plan forecasts due 2027-03-01 (12/01 to 12/02) and 2026-09-15 (12/03 to 12/04 wire 1);
    5: resolved (not reported).
    """
    with Session(create_engine(database)) as session:
        spans = {
            (s.mast_from, s.wire): s
            for s in session.scalars(select(SpanMeasurement).where(SpanMeasurement.run_id == 2))
        }

        def forecast(reach_at: str) -> dict[str, object]:  # catenary.maintenance.alerts' details
            return {
                "wear_rate_mm_per_year": 0.12,
                "runs": 4,
                "reach_at": reach_at,
                "reach_earliest": "2026-01-10T00:00:00+00:00",
                "reach_latest": "2028-02-20T00:00:00+00:00",
            }

        def alert(key: tuple[str, int], level: str, kind: str, **extra: object) -> None:
            session.add(
                build.alert_on(
                    spans[key],
                    rule=f"test-limits {level}",
                    level=level,
                    kind=kind,
                    threshold=extra.pop("threshold", 11.0),
                    raised_at=datetime(2025, 3, 1, 8, tzinfo=UTC),
                    condition_key=f"{key}-{level}-{kind}",
                    **extra,
                )
            )
            session.flush()

        alert(("12/02", 0), "critical", "threshold", threshold=10.6)
        alert(("12/03", 0), "urgent", "threshold", status="acknowledged", acknowledged_by="J. Ng")
        alert(("12/01", 0), "plan", "forecast", details=forecast("2027-03-01T06:00:00+00:00"))
        alert(("12/03", 1), "plan", "forecast", details=forecast("2026-09-15"), threshold=11.7)
        alert(("12/04", 1), "plan", "threshold", status="resolved", threshold=11.7)
        session.add(
            MaintenanceAction(
                track_id=spans[("12/03", 0)].track_id,
                kind="spliced",
                from_chainage_m=12140.0,
                to_chainage_m=12140.4,
                wire=0,
                performed_at=datetime(2024, 5, 2, tzinfo=UTC),
                recorded_by="crew 4",
            )
        )
        session.commit()
    return database
