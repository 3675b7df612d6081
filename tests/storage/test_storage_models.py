"""The models on a migrated database: a round trip, the constraints, the unit of work."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta, timezone
from typing import Any

import pytest
import sqlalchemy as sa
from sqlalchemy import Engine
from sqlalchemy.exc import IntegrityError, StatementError

from catenary import limits
from catenary.storage.database import session_scope
from catenary.storage.models import (
    ALERT_LEVELS,
    Alert,
    AlertNotification,
    Line,
    MaintenanceAction,
    Mast,
    RigCalibration,
    Run,
    SpanMeasurement,
    Track,
    Vehicle,
    run_uuid,
)


def count(engine: Engine, model: type[Any]) -> int:
    with engine.connect() as connection:
        return int(connection.scalar(sa.select(sa.func.count()).select_from(model)) or 0)


def test_round_trip(migrated: Engine, build: Any) -> None:
    cest = timezone(timedelta(hours=2))
    with session_scope(migrated) as session:
        run = build.run(
            session,
            processed_at=datetime(2024, 5, 6, 11, 0, tzinfo=cest),
            length_m=3000.5,
            samples_key="samples/run-1.parquet",
        )
        run.status, run.scans = "complete", 120_000
        session.add_all([build.span(run, 0), build.span(run, 0, wire=1), build.span(run, 1)])
        session.flush()
        action = MaintenanceAction(
            track=run.track,
            kind="reinforced",
            from_chainage_m=1010.0,
            to_chainage_m=1015.0,
            mast_from="M1",
            mast_to="M2",
            wire=0,
            performed_at=build.T0 + timedelta(days=30),
            recorded_by="j.smith",
            note="sleeve fitted",
        )
        alert = build.alert(
            run.track,
            "threshold:db-ril-997#1:L100/1:w0:M1-M2",
            span_measurement=run.span_measurements[0],
            details={"scope": "local", "samples": [1, 2, 3]},
            status="resolved",
            resolved_at=build.T0 + timedelta(days=30),
            resolved_by_action=action,
        )
        alert.notifications.append(AlertNotification(notifier="email", attempts=2))
        session.add(alert)
        session.flush()
        ids = {"run": run.id, "alert": alert.id}

    with session_scope(migrated) as session:
        run = session.get_one(Run, ids["run"])
        assert (run.line.code, run.line.name) == ("L100", "Test line")
        assert run.track is not None
        assert run.track.code == "1"
        assert [(m.code, m.chainage_m, m.design_stagger_mm) for m in run.track.masts] == [
            ("M1", 1000.0, 200.0),
            ("M2", 1050.0, None),
        ]
        assert run.vehicle.name == "demo-rig"
        assert run.vehicle.sensor_baseline_mm == 1800.0
        assert run.rig_calibration.content_toml == 'name = "demo-rig"\n'
        assert run.rig_calibration.created_at == build.T0
        assert (run.direction, run.status, run.scans) == ("increasing", "complete", 120_000)
        processing = run.processing
        assert processing is not None
        assert (processing.length_m, processing.samples_key) == (3000.5, "samples/run-1.parquet")
        assert run.uuid == run_uuid("f" * 64, "c" * 64)
        # times come back aware, in UTC, the same instant
        assert run.started_at == build.T0
        assert run.started_at.tzinfo is UTC
        assert processing.processed_at == datetime(2024, 5, 6, 9, 0, tzinfo=UTC)
        assert processing.processed_at.tzinfo is UTC

        spans = run.span_measurements
        assert [(s.span, s.wire) for s in spans] == [(0, 0), (0, 1), (1, 0)]
        first = spans[0]
        assert first.track_id == run.track_id  # copied from the run
        assert first.min_residual_thickness_mm == 10.5
        assert first.min_at_chainage_m == 1012.25
        assert first.stagger_max_mm == 195.5
        assert first.samples == 2500

        alert = session.get_one(Alert, ids["alert"])
        assert alert.span_measurement is first
        assert alert.details == {"scope": "local", "samples": [1, 2, 3]}
        assert alert.resolved_by_action is not None
        assert alert.resolved_by_action.note == "sleeve fitted"
        assert alert.raised_at == build.T0
        assert [(n.notifier, n.status, n.attempts) for n in alert.notifications] == [
            ("email", "pending", 2)
        ]
        assert alert.notifications[0].updated_at.tzinfo is UTC

        # span measurements are found by track and chainage across runs
        found = session.scalars(
            sa.select(SpanMeasurement)
            .where(SpanMeasurement.track_id == run.track_id)
            .where(SpanMeasurement.start_chainage_m >= 1040.0)
        ).all()
        assert [(s.span, s.wire) for s in found] == [(1, 0)]


def test_same_alert_condition_is_refused(migrated: Engine, build: Any) -> None:
    with session_scope(migrated) as session:
        run = build.run(session)
        session.add(build.alert(run.track, "threshold:rule:track:w0:M1-M2"))
        track_id = run.track_id
    with pytest.raises(IntegrityError), session_scope(migrated) as session:
        track = session.get_one(Track, track_id)
        session.add(build.alert(track, "threshold:rule:track:w0:M1-M2", level="critical"))
    assert count(migrated, Alert) == 1


def test_same_run_file_and_calibration_is_stored_once(migrated: Engine, build: Any) -> None:
    """The identity is the content: the same file with the same calibration content is one
    run, whatever vehicle or calibration row it comes with."""
    with session_scope(migrated) as session:
        run = build.run(session)
        again = {
            name: getattr(run, name)
            for name in ("line_id", "track_id", "direction", "vehicle_id", "rig_sha256")
        }
        other = RigCalibration(
            vehicle=Vehicle(
                name="other",
                roof_height_mm=3900.0,
                sensor_height_mm=1100.0,
                sensor_baseline_mm=1800.0,
            ),
            name="demo",
            version=1,
            content_toml=run.rig_calibration.content_toml,
            sha256=run.rig_sha256,
        )
        session.add(other)
        session.flush()
        other_id = other.id
    for uuid in (run_uuid("f" * 64, "c" * 64), "another"):
        with pytest.raises(IntegrityError), session_scope(migrated) as session:
            session.add(
                Run(
                    **again,
                    uuid=uuid,
                    rig_calibration_id=other_id,
                    source_file="/elsewhere/copy.h5",
                    source_sha256="f" * 64,
                    started_at=datetime.now(UTC),
                )
            )
    assert count(migrated, Run) == 1


@pytest.mark.parametrize(
    ("model", "column", "value"),
    [
        (Run, "status", "done"),
        (Run, "direction", "up"),
        (Alert, "level", "warning"),
        (Alert, "kind", "guess"),
        (Alert, "status", "closed"),
        (MaintenanceAction, "kind", "painted"),
        (AlertNotification, "status", "lost"),
    ],
)
def test_enumerations_are_checked(
    migrated: Engine, build: Any, model: type[Any], column: str, value: str
) -> None:
    with session_scope(migrated) as session:
        run = build.run(session)
        alert = build.alert(run.track, "k")
        alert.notifications.append(AlertNotification(notifier="webhook"))
        session.add(alert)
        session.add(
            MaintenanceAction(
                track=run.track,
                kind="inspected",
                from_chainage_m=0.0,
                to_chainage_m=1.0,
                performed_at=build.T0,
                recorded_by="x",
            )
        )
    with pytest.raises(IntegrityError), session_scope(migrated) as session:
        row = session.scalars(sa.select(model)).one()
        setattr(row, column, value)


def test_chainages_in_order(migrated: Engine, build: Any) -> None:
    with pytest.raises(IntegrityError), session_scope(migrated) as session:
        run = build.run(session)
        session.add(build.span(run, 0, start_chainage_m=1050.0, end_chainage_m=1000.0))
    assert count(migrated, Run) == 0


def test_naive_datetime_is_refused(migrated: Engine, build: Any) -> None:
    with pytest.raises(StatementError, match="naive datetime"), session_scope(migrated) as s:
        build.run(s, started_at=datetime(2024, 5, 6, 7, 8, 9))
    assert count(migrated, Line) == 0


def test_span_measurement_track_must_be_its_runs(migrated: Engine, build: Any) -> None:
    with session_scope(migrated) as session:
        run = build.run(session)
        other = Track(line=run.line, code="2")
        session.add(other)
        session.flush()
        run_id, other_id = run.id, other.id
    with pytest.raises(IntegrityError), session_scope(migrated) as session:
        run = session.get_one(Run, run_id)
        session.add(build.span(run, 5, track_id=other_id))
    assert count(migrated, SpanMeasurement) == 0


def test_span_measurement_inserted_by_processing_id_gets_the_run_and_track(
    migrated: Engine, build: Any
) -> None:
    with session_scope(migrated) as session:
        run = build.run(session)
        run_id, track_id, processing_id = run.id, run.track_id, run.processing_id
    with session_scope(migrated) as session:
        span = build.span(None, 3, processing_id=processing_id)  # only the processing's id
        session.add(span)
        session.flush()
        assert (span.run_id, span.track_id) == (run_id, track_id)


def test_unit_of_work_rolls_back_everything_on_error(migrated: Engine, build: Any) -> None:
    with pytest.raises(RuntimeError, match="disk full"), session_scope(migrated) as session:
        run = build.run(session)  # flushed: rows are in the database's transaction
        session.add(build.span(run))
        session.flush()
        raise RuntimeError("disk full")
    for model in (Line, Track, Mast, Vehicle, RigCalibration, Run, SpanMeasurement):
        assert count(migrated, model) == 0, model.__name__

    # a failure in the database half-way is the same: the first rows are not kept either
    with pytest.raises(IntegrityError), session_scope(migrated) as session:
        run = build.run(session)
        session.add_all([build.span(run, 0), build.span(run, 0)])  # same (processing, span, wire)
    assert count(migrated, Run) == 0
    assert count(migrated, SpanMeasurement) == 0


def test_deleting_a_run_deletes_its_spans_and_keeps_the_alerts(
    migrated: Engine, build: Any
) -> None:
    with session_scope(migrated) as session:
        run = build.run(session)
        session.add(build.span(run))
        session.flush()
        alert = build.alert(run.track, "k", span_measurement=run.span_measurements[0])
        alert.resolved_by_run = run
        session.add(alert)
        run_id = run.id
    with migrated.begin() as connection:  # as the database does it, not the ORM
        connection.execute(sa.delete(Run).where(Run.id == run_id))
    assert count(migrated, SpanMeasurement) == 0
    with session_scope(migrated) as session:
        alert = session.scalars(sa.select(Alert)).one()
        assert alert.span_measurement_id is None
        assert alert.resolved_by_run_id is None
    # the register cannot be deleted from under the measurements' alerts
    with pytest.raises(IntegrityError), migrated.begin() as connection:
        connection.execute(sa.delete(Line))


def test_alert_levels_are_those_of_the_limit_policies() -> None:
    assert ALERT_LEVELS == limits.LEVELS
