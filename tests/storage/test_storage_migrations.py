"""The migrations, run up and down on each backend, agree with the models."""

from __future__ import annotations

import re
from typing import Any

import pytest
import sqlalchemy as sa
from alembic.operations import Operations
from alembic.runtime.migration import MigrationContext
from sqlalchemy import Engine

from catenary.errors import DatabaseNotMigrated, UserError
from catenary.storage import migrate
from catenary.storage.database import connected, require_migrated, session_scope
from catenary.storage.models import (
    EXTERNAL_TABLES,
    AlertNotification,
    ApiToken,
    AuditEntry,
    Base,
    MaintenanceAction,
    Processing,
    Run,
    SpanMeasurement,
    User,
    run_uuid,
)

MODEL_TABLES = set(Base.metadata.tables)


def tables(engine: Engine) -> set[str]:
    return set(sa.inspect(engine).get_table_names())


def test_models_have_every_table_of_the_storage_sketch() -> None:
    model_tables = set(Base.metadata.tables)
    assert model_tables == {
        "lines",
        "tracks",
        "masts",
        "vehicles",
        "rig_calibrations",
        "runs",
        "processings",
        "span_measurements",
        "alerts",
        "maintenance_actions",
        "alert_notifications",
        "scheduler_leases",
        "users",
        "api_tokens",
        "audit_entries",
        "sign_in_failures",
    }


def test_there_is_one_head_and_it_is_known() -> None:
    head = migrate.head_revision()
    assert re.fullmatch(r"[0-9a-f]{12}", head)
    assert migrate.is_known_revision(head)
    assert not migrate.is_known_revision("0123456789ab")


def test_upgrade_downgrade_upgrade(engine: Engine, build: Any) -> None:
    assert migrate.current_revision(engine) is None
    assert migrate.upgrade(engine) == migrate.head_revision()
    assert tables(engine) == MODEL_TABLES | EXTERNAL_TABLES | {"alembic_version"}
    require_migrated(engine)

    # down with rows in every table: nothing is in the way
    with session_scope(engine) as session:
        run = build.run(session)
        session.add(build.span(run))
        alert = build.alert(run.track, "k1", span_measurement=run.span_measurements[0])
        alert.notifications.append(AlertNotification(notifier="email"))
        session.add(alert)
        session.add(
            MaintenanceAction(
                track=run.track,
                kind="inspected",
                from_chainage_m=1000.0,
                to_chainage_m=1050.0,
                performed_at=build.T0,
                recorded_by="tester",
            )
        )
        user = User(name="planner", role="planner", password_hash="$argon2id$v=19$x")
        user.tokens.append(ApiToken(name="sap", token_hash="a" * 64))
        session.add(user)
        session.add(AuditEntry(actor="planner", action="alert.acknowledge", target="alert 1"))

    assert migrate.downgrade(engine, "base") is None
    assert tables(engine) <= {"alembic_version"}  # Alembic keeps its (empty) version table
    assert migrate.current_revision(engine) is None
    if engine.dialect.name == "postgresql":
        with engine.connect() as connection:
            leftovers = connection.execute(
                sa.text(
                    "SELECT relname FROM pg_class JOIN pg_namespace n ON n.oid = relnamespace "
                    "WHERE n.nspname = current_schema() AND relname <> 'alembic_version' "
                    "AND relname NOT LIKE 'alembic_version%'"
                )
            ).all()
        assert leftovers == []  # no sequence, index or type left behind

    assert migrate.upgrade(engine) == migrate.head_revision()
    assert tables(engine) == MODEL_TABLES | EXTERNAL_TABLES | {"alembic_version"}
    assert migrate.check_models_match(engine) == []


def test_models_match_migrations(migrated: Engine) -> None:
    assert migrate.check_models_match(migrated) == []


def test_check_finds_a_difference(migrated: Engine) -> None:
    with migrated.begin() as connection:
        connection.execute(sa.text("DROP INDEX ix_alerts_status"))
        connection.execute(sa.text("CREATE TABLE stray (id INTEGER PRIMARY KEY)"))
        # a table that is not ours, changed by its owner (APScheduler's job store)
        connection.execute(sa.text(f"DROP TABLE {min(EXTERNAL_TABLES)}"))
        connection.execute(sa.text(f"CREATE TABLE {min(EXTERNAL_TABLES)} (id INTEGER)"))
    differences = migrate.check_models_match(migrated)
    assert any("ix_alerts_status" in d and d.startswith("add_index") for d in differences)
    assert any("stray" in d and d.startswith("remove_table") for d in differences)
    assert not any(min(EXTERNAL_TABLES) in d for d in differences)  # not ours: left alone


def test_check_constraints_match_the_models(migrated: Engine) -> None:
    """Autogenerate does not compare CHECK constraints: compare them here."""
    inspector = sa.inspect(migrated)
    for table in Base.metadata.sorted_tables:
        expected = {
            c.name: str(c.sqltext) for c in table.constraints if isinstance(c, sa.CheckConstraint)
        }
        found = {c["name"]: c["sqltext"] for c in inspector.get_check_constraints(table.name)}
        assert set(found) == set(expected), table.name
        if migrated.dialect.name == "sqlite":  # SQLite keeps the text as written
            assert found == expected, table.name


def test_foreign_key_actions_match_the_models(migrated: Engine) -> None:
    inspector = sa.inspect(migrated)
    for table in Base.metadata.sorted_tables:
        expected = {
            fk.name: (fk.ondelete or "NO ACTION", fk.onupdate or "NO ACTION")
            for fk in table.foreign_key_constraints
        }
        found = {
            fk["name"]: (
                fk["options"].get("ondelete", "NO ACTION").upper(),
                fk["options"].get("onupdate", "NO ACTION").upper(),
            )
            for fk in inspector.get_foreign_keys(table.name)
        }
        assert found == expected, table.name


def test_require_migrated_on_an_empty_database(engine: Engine) -> None:
    with pytest.raises(DatabaseNotMigrated) as raised:
        require_migrated(engine)
    message = str(raised.value)
    assert "\n" not in message
    assert "is not migrated (revision: none, " in message
    assert f"needed: {migrate.head_revision()}" in message
    assert "run 'catenary db upgrade'" in message
    assert engine.url.render_as_string(hide_password=True) in message


def test_require_migrated_at_an_unknown_revision(migrated: Engine) -> None:
    with migrated.begin() as connection:
        connection.execute(sa.text("UPDATE alembic_version SET version_num = 'feedfacecafe'"))
    with pytest.raises(DatabaseNotMigrated, match=r"revision feedfacecafe, unknown") as raised:
        require_migrated(migrated)
    assert "\n" not in str(raised.value)
    # and upgrading cannot find it either: one line, no Alembic traceback
    with pytest.raises(UserError, match="feedfacecafe"):
        migrate.upgrade(migrated)


def test_upgrade_to_an_unknown_revision_is_one_line(engine: Engine) -> None:
    with pytest.raises(UserError, match="nosuchrev") as raised:
        migrate.upgrade(engine, "nosuchrev")
    assert "\n" not in str(raised.value)
    assert migrate.current_revision(engine) is None


def test_sqlite_foreign_keys_are_on_after_migrating(migrated: Engine) -> None:
    if migrated.dialect.name != "sqlite":
        pytest.skip("SQLite only")
    with migrated.connect() as connection:
        assert connection.exec_driver_sql("PRAGMA foreign_keys").scalar() == 1


def test_sqlite_batch_migration_keeps_the_rows_that_refer_to_a_rebuilt_table(
    migrated: Engine, build: Any
) -> None:
    """Batch mode rebuilds `runs`; with foreign keys on, dropping the old table would cascade
    into span_measurements. Migrations run with them suspended, then checked."""
    if migrated.dialect.name != "sqlite":
        pytest.skip("SQLite only")
    with session_scope(migrated) as session:
        run = build.run(session)
        session.add_all([build.span(run, 0), build.span(run, 1)])
    with (
        connected(migrated) as connection,
        migrate.suspended_foreign_keys(connection),
        connection.begin(),
    ):
        operations = Operations(MigrationContext.configure(connection))
        with operations.batch_alter_table("runs", recreate="always") as batch:
            batch.add_column(sa.Column("note", sa.Text()))
        migrate.check_foreign_keys(connection)
    with session_scope(migrated) as session:
        assert session.scalar(sa.select(sa.func.count()).select_from(SpanMeasurement)) == 2
        assert session.scalar(sa.select(sa.func.count()).select_from(Run)) == 1
    with migrated.connect() as connection:
        assert connection.exec_driver_sql("PRAGMA foreign_keys").scalar() == 1


def test_runs_become_their_first_processing_and_back(engine: Engine) -> None:
    """Revision 6638ba43c1b6: a run stored before it gets its identity (the UUID
    ``run_uuid`` gives) and a first processing holding what it measured; the downgrade puts
    the latest processing back on the run and drops the others."""
    migrate.upgrade(engine, "8b51c0d2e7a3")
    statements = [
        "INSERT INTO lines (id, code) VALUES (1, 'L1')",
        "INSERT INTO tracks (id, line_id, code) VALUES (1, 1, '1')",
        "INSERT INTO vehicles (id, name, roof_height_mm, sensor_height_mm, sensor_baseline_mm) "
        "VALUES (1, 'v', 3900, 1100, 1800)",
        "INSERT INTO rig_calibrations (id, vehicle_id, name, version, created_at, content_toml, "
        f"sha256) VALUES (1, 1, 'rig', 1, '2024-05-06 07:00:00+00:00', '', '{'c' * 64}')",
        "INSERT INTO runs (id, line_id, track_id, direction, vehicle_id, rig_calibration_id, "
        "source_file, source_sha256, wire_type, started_at, processed_at, scans, length_m, "
        "status, samples_path, chainage_aligned, alignment_matched) VALUES (7, 1, 1, "
        f"'increasing', 1, 1, '/runs/a.h5', '{'f' * 64}', 'CTA120', "
        "'2024-05-06 07:00:00+00:00', '2024-05-06 08:00:00+00:00', 100, 250.5, 'complete', "
        "'samples/run-7-abc.parquet', true, 4)",
        *(
            "INSERT INTO span_measurements (run_id, track_id, span, wire, wire_type, "
            "start_chainage_m, end_chainage_m, min_residual_thickness_mm, min_at_chainage_m, "
            "mean_residual_thickness_mm, height_min_mm, height_max_mm, stagger_min_mm, "
            f"stagger_max_mm, samples) VALUES (7, 1, {k}, 0, 'CTA120', {k * 50}, {k * 50 + 50}, "
            "11, 1, 12, 5300, 5310, -200, 200, 10)"
            for k in range(3)
        ),
    ]
    with engine.begin() as connection:
        for statement in statements:
            connection.execute(sa.text(statement))
    migrate.upgrade(engine)
    with session_scope(engine) as session:
        run = session.get_one(Run, 7)
        processing = run.processing
        assert processing is not None
        assert run.uuid == run_uuid("f" * 64, "c" * 64)
        assert run.rig_sha256 == "c" * 64
        assert (processing.processor, processing.package_version) == ("unrecorded",) * 2
        assert processing.samples_key == "samples/run-7-abc.parquet"
        assert (processing.wire_type, processing.length_m) == ("CTA120", 250.5)
        assert (processing.chainage_aligned, processing.alignment_matched) == (True, 4)
        assert processing.processed_at.hour == 8
        assert [s.span for s in run.span_measurements] == [0, 1, 2]
        # a second processing of one span: the latest
        second = Processing(
            run=run,
            uuid="second",
            processor="linescan-stereo",
            package_version="0.1.0",
            settings_sha256="0" * 64,
            rig_calibration=run.rig_calibration,
            processed_at=processing.processed_at,
            length_m=99.0,
            samples_key="samples/second.parquet",
        )
        second.span_measurements = [
            SpanMeasurement(**{**_span_columns(run.span_measurements[0]), "span": 5})
        ]
        session.add(second)
        session.flush()
        run.processing = second
    with session_scope(engine) as session:
        assert [s.span for s in session.get_one(Run, 7).span_measurements] == [5]
    migrate.downgrade(engine, "8b51c0d2e7a3")
    with engine.connect() as connection:
        assert connection.execute(
            sa.text("SELECT length_m, samples_path FROM runs WHERE id = 7")
        ).one() == (99.0, "samples/second.parquet")
        spans = connection.execute(sa.text("SELECT span FROM span_measurements")).scalars()
        assert list(spans) == [5]


def _span_columns(span: SpanMeasurement) -> dict[str, Any]:
    """A span measurement's columns but its keys and owners."""
    leave = {"id", "run_id", "processing_id", "track_id"}
    return {c.key: getattr(span, c.key) for c in SpanMeasurement.__table__.c if c.key not in leave}


def test_stored_span_rows_get_their_wire_position(migrated: Engine, build: Any) -> None:
    """Revision 0302f8277c49 ranks a span's wires left to right looking toward increasing
    chainage, whichever way the run went."""
    with session_scope(migrated) as session:
        run = build.run(session, direction="decreasing")
        # decreasing chainage: the run's stagger +150 is the line's -150, the left wire
        session.add_all(
            [
                build.span(run, 0, wire=0, stagger_min_mm=100.0, stagger_max_mm=200.0),
                build.span(run, 0, wire=1, stagger_min_mm=-200.0, stagger_max_mm=-100.0),
                build.span(run, 1, wire=1, stagger_min_mm=-200.0, stagger_max_mm=200.0),
            ]
        )
    with migrated.begin() as connection:
        connection.execute(sa.text("UPDATE span_measurements SET wire_position = 9"))
    migrate.downgrade(migrated, "5f3e39e9d5e9")
    migrate.upgrade(migrated)
    with migrated.connect() as connection:
        found = connection.execute(
            sa.text("SELECT span, wire, wire_position FROM span_measurements ORDER BY span, wire")
        ).all()
    assert [tuple(row) for row in found] == [(0, 0, 0), (0, 1, 1), (1, 1, 0)]
