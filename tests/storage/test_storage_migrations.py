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
    Base,
    MaintenanceAction,
    Run,
    SpanMeasurement,
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
        "span_measurements",
        "alerts",
        "maintenance_actions",
        "alert_notifications",
        "scheduler_leases",
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
