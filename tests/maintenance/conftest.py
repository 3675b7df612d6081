"""A migrated database (``database_url``: SQLite and PostgreSQL) and a builder of lines of
masts and of runs over them with chosen span minima."""

from __future__ import annotations

import uuid
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime, timedelta
from itertools import count

import pytest
from sqlalchemy.orm import Session

from catenary.plugins import PluginRegistry
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

T0 = datetime(2020, 1, 6, 9, 0, tzinfo=UTC)
YEAR = timedelta(days=365.25)
NEW_MM = 12.9  # CTA120 new
MEAN_ABOVE_MIN_MM = 0.5  # a span's mean residual thickness above its minimum


@pytest.fixture(scope="session")
def registry() -> PluginRegistry:
    return PluginRegistry()


_sources = count()


class Fleet:
    """Lines, tracks and runs for the tests, on one session.

    ``track(...)`` adds a line and track with masts ``M00, M01, ...`` 50 m apart from chainage
    1000 m (optionally anchor sections); ``run(...)`` a run over some of its spans whose span
    minima are given per span (a span's mean is ``MEAN_ABOVE_MIN_MM`` above).
    """

    def __init__(self, session: Session) -> None:
        self.session = session
        vehicle = Vehicle(
            name=f"test-rig-{next(_sources)}",
            roof_height_mm=3900.0,
            sensor_height_mm=1100.0,
            sensor_baseline_mm=1800.0,
        )
        self.calibration = RigCalibration(
            vehicle=vehicle, name="rig", version=1, created_at=T0, content_toml="", sha256="0" * 64
        )
        session.add(self.calibration)

    def track(
        self,
        line: str = "L1",
        track: str = "1",
        masts: int = 11,
        sections: Sequence[str | None] | None = None,
        wire_type: str = "CTA120",
    ) -> Track:
        found = self.session.query(Line).filter_by(code=line).one_or_none() or Line(code=line)
        result = Track(line=found, code=track)
        result.masts = [
            Mast(
                code=f"M{k:02d}",
                chainage_m=1000.0 + 50.0 * k,
                wire_type=wire_type,
                anchor_section=None if sections is None else sections[k],
            )
            for k in range(masts)
        ]
        self.session.add(result)
        self.session.flush()
        return result

    def run(
        self,
        track: Track,
        when: datetime,
        minimum_mm: Mapping[int, float] | None = None,
        *,
        spans: Sequence[int] | None = None,
        default_mm: float = 12.5,
        direction: str = "increasing",
        overlap: Mapping[int, float] | None = None,
        mean_mm: Mapping[int, float] | None = None,
        wire_type: str = "CTA120",
    ) -> Run:
        """A run over ``spans`` (default: every span), span ``k``'s minimum ``minimum_mm[k]``
        (else ``default_mm``). ``overlap`` adds a second wire, to the right (looking towards
        increasing chainage), in the spans it names, with that minimum. A run in the decreasing
        direction over an overlap numbers the wires the other way round (as the processor
        does: in order of appearance). On a track without masts the run is cut, as one
        processed without a register, into 10 spans of 50 m from 1000 m naming no mast."""
        masts = sorted(track.masts, key=lambda m: m.chainage_m)
        at_m = [m.chainage_m for m in masts] or [1000.0 + 50.0 * k for k in range(11)]
        codes: list[str | None] = [m.code for m in masts] or [None] * len(at_m)
        chosen = list(range(len(at_m) - 1)) if spans is None else list(spans)
        minimum_mm, overlap, mean_mm = minimum_mm or {}, overlap or {}, mean_mm or {}
        source = f"{next(_sources):064x}"
        run = Run(
            uuid=run_uuid(source, self.calibration.sha256),
            rig_sha256=self.calibration.sha256,
            line=track.line,
            track=track,
            direction=direction,
            vehicle=self.calibration.vehicle,
            rig_calibration=self.calibration,
            source_file=f"/runs/{when:%Y%m%d}.h5",
            source_sha256=source,
            started_at=when,
            status="complete",
        )
        run.processing = Processing(
            run=run,
            uuid=str(uuid.uuid4()),
            processor="linescan-stereo",
            package_version="test",
            settings_sha256=settings_sha256(None),
            rig_calibration=self.calibration,
            processed_at=when,
        )
        sign = 1.0 if direction == "increasing" else -1.0
        swap = int(direction == "decreasing")  # the other way, the other wire comes first
        rows: list[SpanMeasurement] = []
        for k in chosen:
            value = minimum_mm.get(k, default_mm)
            wires = [(swap if overlap else 0, value, 0.0)]
            if k in overlap:
                wires = [(swap, value, -150.0), (1 - swap, overlap[k], 150.0)]
            for position, (wire, value, line_stagger) in enumerate(wires):
                low, high = sorted((sign * (line_stagger - 200.0), sign * (line_stagger + 200.0)))
                rows.append(
                    SpanMeasurement(
                        span=k,
                        mast_from=codes[k],
                        mast_to=codes[k + 1],
                        start_chainage_m=at_m[k],
                        end_chainage_m=at_m[k + 1],
                        wire=wire,
                        wire_position=position,
                        wire_type=wire_type,
                        min_residual_thickness_mm=value,
                        min_at_chainage_m=at_m[k] + 12.5,
                        mean_residual_thickness_mm=mean_mm.get(k, value + MEAN_ABOVE_MIN_MM),
                        height_min_mm=5280.0,
                        height_max_mm=5320.0,
                        stagger_min_mm=low,
                        stagger_max_mm=high,
                        samples=1000,
                    )
                )
        run.processing.span_measurements = rows
        self.session.add(run)
        self.session.flush()
        return run


@pytest.fixture
def fleet_of() -> type[Fleet]:
    return Fleet


def alerts_of(session: Session) -> list[Alert]:
    """Every alert, by id."""
    return list(session.query(Alert).order_by(Alert.id))
