"""Engines and row builders for the storage tests (``database_url``: ``tests/conftest.py``)."""

from __future__ import annotations

from collections.abc import Iterator
from datetime import UTC, datetime
from typing import Any

import pytest
from sqlalchemy import Engine
from sqlalchemy.orm import Session

from catenary.storage import migrate
from catenary.storage.database import make_engine
from catenary.storage.models import (
    Alert,
    Line,
    Mast,
    RigCalibration,
    Run,
    SpanMeasurement,
    Track,
    Vehicle,
)


@pytest.fixture
def engine(database_url: str) -> Iterator[Engine]:
    """An engine on the empty database."""
    engine = make_engine(database_url)
    yield engine
    engine.dispose()


@pytest.fixture
def migrated(engine: Engine) -> Engine:
    """The engine, its database migrated to head."""
    migrate.upgrade(engine)
    return engine


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
        run = Run(**values)
        session.add(run)
        session.flush()
        return run

    @staticmethod
    def span(run: Run | None, number: int = 0, **columns: Any) -> SpanMeasurement:
        values: dict[str, Any] = {} if run is None else {"run": run}
        values |= {
            "span": number,
            "mast_from": "M1",
            "mast_to": "M2",
            "start_chainage_m": 1000.0 + 50.0 * number,
            "end_chainage_m": 1050.0 + 50.0 * number,
            "wire": 0,
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


@pytest.fixture
def build() -> type[Build]:
    """Row builders (``build.run(session)``, ``build.span(run)``, ``build.alert(...)``)."""
    return Build
