"""initial schema

The register (lines, tracks, masts), vehicles and their rig calibrations, runs and their span
measurements, maintenance actions, alerts and their notifications.

Revision ID: 79a969434a84
Revises:
Create Date: 2026-11-23 15:08:01.105036+00:00

Written for SQLite (batch mode) and PostgreSQL alike; the downgrade undoes all of the upgrade.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql


# revision identifiers, used by Alembic.
revision: str = "79a969434a84"
down_revision: str | Sequence[str] | None = None
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "lines",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("code", sa.String(length=32), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=True),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_lines")),
        sa.UniqueConstraint("code", name=op.f("uq_lines_code")),
    )
    op.create_table(
        "vehicles",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("roof_height_mm", sa.Float(), nullable=False),
        sa.Column("sensor_height_mm", sa.Float(), nullable=False),
        sa.Column("sensor_baseline_mm", sa.Float(), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_vehicles")),
        sa.UniqueConstraint("name", name=op.f("uq_vehicles_name")),
    )
    op.create_table(
        "rig_calibrations",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("vehicle_id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=200), nullable=False),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("content_toml", sa.Text(), nullable=False),
        sa.Column("sha256", sa.String(length=64), nullable=False),
        sa.CheckConstraint("version >= 1", name=op.f("ck_rig_calibrations_version_positive")),
        sa.ForeignKeyConstraint(
            ["vehicle_id"],
            ["vehicles.id"],
            name=op.f("fk_rig_calibrations_vehicle_id_vehicles"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_rig_calibrations")),
        sa.UniqueConstraint(
            "vehicle_id",
            "name",
            "version",
            name=op.f("uq_rig_calibrations_vehicle_id_name_version"),
        ),
    )
    op.create_table(
        "tracks",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("line_id", sa.Integer(), nullable=False),
        sa.Column("code", sa.String(length=32), nullable=False),
        sa.ForeignKeyConstraint(
            ["line_id"], ["lines.id"], name=op.f("fk_tracks_line_id_lines"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_tracks")),
        sa.UniqueConstraint("line_id", "code", name=op.f("uq_tracks_line_id_code")),
    )
    op.create_table(
        "maintenance_actions",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("track_id", sa.Integer(), nullable=False),
        sa.Column("kind", sa.String(length=32), nullable=False),
        sa.Column("from_chainage_m", sa.Float(), nullable=False),
        sa.Column("to_chainage_m", sa.Float(), nullable=False),
        sa.Column("mast_from", sa.String(length=32), nullable=True),
        sa.Column("mast_to", sa.String(length=32), nullable=True),
        sa.Column("wire", sa.Integer(), nullable=True),
        sa.Column("performed_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("recorded_by", sa.String(length=200), nullable=False),
        sa.Column("note", sa.Text(), nullable=True),
        sa.CheckConstraint(
            "kind IN ('wire_replaced', 'reinforced', 'spliced', 'inspected', 'adjusted')",
            name=op.f("ck_maintenance_actions_kind"),
        ),
        sa.CheckConstraint(
            "to_chainage_m >= from_chainage_m", name=op.f("ck_maintenance_actions_chainage_order")
        ),
        sa.CheckConstraint("wire >= 0", name=op.f("ck_maintenance_actions_wire_not_negative")),
        sa.ForeignKeyConstraint(
            ["track_id"],
            ["tracks.id"],
            name=op.f("fk_maintenance_actions_track_id_tracks"),
            ondelete="RESTRICT",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_maintenance_actions")),
    )
    op.create_index(
        op.f("ix_maintenance_actions_track_id_from_chainage_m"),
        "maintenance_actions",
        ["track_id", "from_chainage_m"],
        unique=False,
    )
    op.create_table(
        "masts",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("track_id", sa.Integer(), nullable=False),
        sa.Column("code", sa.String(length=32), nullable=False),
        sa.Column("chainage_m", sa.Float(), nullable=False),
        sa.Column("wire_type", sa.String(length=32), nullable=False),
        sa.Column("design_stagger_mm", sa.Float(), nullable=True),
        sa.ForeignKeyConstraint(
            ["track_id"], ["tracks.id"], name=op.f("fk_masts_track_id_tracks"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_masts")),
        sa.UniqueConstraint("track_id", "code", name=op.f("uq_masts_track_id_code")),
    )
    op.create_index(
        op.f("ix_masts_track_id_chainage_m"), "masts", ["track_id", "chainage_m"], unique=False
    )
    op.create_table(
        "runs",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("line_id", sa.Integer(), nullable=False),
        sa.Column("track_id", sa.Integer(), nullable=True),
        sa.Column("direction", sa.String(length=16), nullable=False),
        sa.Column("vehicle_id", sa.Integer(), nullable=False),
        sa.Column("rig_calibration_id", sa.Integer(), nullable=False),
        sa.Column("source_file", sa.String(length=1024), nullable=False),
        sa.Column("source_sha256", sa.String(length=64), nullable=False),
        sa.Column("wire_type", sa.String(length=32), nullable=True),
        sa.Column("started_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("processed_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("scans", sa.Integer(), nullable=False),
        sa.Column("length_m", sa.Float(), nullable=False),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("samples_path", sa.String(length=1024), nullable=True),
        sa.Column("error", sa.Text(), nullable=True),
        sa.CheckConstraint(
            "direction IN ('increasing', 'decreasing')", name=op.f("ck_runs_direction")
        ),
        sa.CheckConstraint(
            "status IN ('processing', 'complete', 'failed')", name=op.f("ck_runs_status")
        ),
        sa.CheckConstraint("scans >= 0", name=op.f("ck_runs_scans_not_negative")),
        sa.ForeignKeyConstraint(
            ["line_id"], ["lines.id"], name=op.f("fk_runs_line_id_lines"), ondelete="RESTRICT"
        ),
        sa.ForeignKeyConstraint(
            ["rig_calibration_id"],
            ["rig_calibrations.id"],
            name=op.f("fk_runs_rig_calibration_id_rig_calibrations"),
            ondelete="RESTRICT",
        ),
        sa.ForeignKeyConstraint(
            ["track_id"], ["tracks.id"], name=op.f("fk_runs_track_id_tracks"), ondelete="RESTRICT"
        ),
        sa.ForeignKeyConstraint(
            ["vehicle_id"],
            ["vehicles.id"],
            name=op.f("fk_runs_vehicle_id_vehicles"),
            ondelete="RESTRICT",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_runs")),
        sa.UniqueConstraint("id", "track_id", name=op.f("uq_runs_id_track_id")),
        sa.UniqueConstraint(
            "source_sha256",
            "rig_calibration_id",
            name=op.f("uq_runs_source_sha256_rig_calibration_id"),
        ),
    )
    op.create_index(
        op.f("ix_runs_line_id_track_id_started_at"),
        "runs",
        ["line_id", "track_id", "started_at"],
        unique=False,
    )
    op.create_table(
        "span_measurements",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("track_id", sa.Integer(), nullable=True),
        sa.Column("span", sa.Integer(), nullable=False),
        sa.Column("mast_from", sa.String(length=32), nullable=True),
        sa.Column("mast_to", sa.String(length=32), nullable=True),
        sa.Column("start_chainage_m", sa.Float(), nullable=False),
        sa.Column("end_chainage_m", sa.Float(), nullable=False),
        sa.Column("wire", sa.Integer(), nullable=False),
        sa.Column("wire_type", sa.String(length=32), nullable=False),
        sa.Column("min_residual_thickness_mm", sa.Float(), nullable=False),
        sa.Column("min_at_chainage_m", sa.Float(), nullable=False),
        sa.Column("mean_residual_thickness_mm", sa.Float(), nullable=False),
        sa.Column("height_min_mm", sa.Float(), nullable=False),
        sa.Column("height_max_mm", sa.Float(), nullable=False),
        sa.Column("stagger_min_mm", sa.Float(), nullable=False),
        sa.Column("stagger_max_mm", sa.Float(), nullable=False),
        sa.Column("samples", sa.Integer(), nullable=False),
        sa.CheckConstraint(
            "end_chainage_m >= start_chainage_m", name=op.f("ck_span_measurements_chainage_order")
        ),
        sa.CheckConstraint("samples >= 0", name=op.f("ck_span_measurements_samples_not_negative")),
        sa.CheckConstraint("wire >= 0", name=op.f("ck_span_measurements_wire_not_negative")),
        sa.ForeignKeyConstraint(
            ["run_id", "track_id"],
            ["runs.id", "runs.track_id"],
            name=op.f("fk_span_measurements_run_id_track_id_runs"),
            onupdate="CASCADE",
            ondelete="CASCADE",
        ),
        sa.ForeignKeyConstraint(
            ["run_id"],
            ["runs.id"],
            name=op.f("fk_span_measurements_run_id_runs"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_span_measurements")),
        sa.UniqueConstraint(
            "run_id", "span", "wire", name=op.f("uq_span_measurements_run_id_span_wire")
        ),
    )
    op.create_index(
        op.f("ix_span_measurements_track_id_start_chainage_m"),
        "span_measurements",
        ["track_id", "start_chainage_m"],
        unique=False,
    )
    op.create_table(
        "alerts",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("track_id", sa.Integer(), nullable=False),
        sa.Column("wire", sa.Integer(), nullable=False),
        sa.Column("mast_from", sa.String(length=32), nullable=True),
        sa.Column("mast_to", sa.String(length=32), nullable=True),
        sa.Column("start_chainage_m", sa.Float(), nullable=False),
        sa.Column("end_chainage_m", sa.Float(), nullable=False),
        sa.Column("span_measurement_id", sa.Integer(), nullable=True),
        sa.Column("rule", sa.String(length=200), nullable=False),
        sa.Column("level", sa.String(length=16), nullable=False),
        sa.Column("kind", sa.String(length=16), nullable=False),
        sa.Column("value", sa.Float(), nullable=False),
        sa.Column("threshold", sa.Float(), nullable=False),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("raised_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("acknowledged_by", sa.String(length=200), nullable=True),
        sa.Column("acknowledged_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("resolved_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("resolved_by_run_id", sa.Integer(), nullable=True),
        sa.Column("resolved_by_action_id", sa.Integer(), nullable=True),
        sa.Column("condition_key", sa.String(length=255), nullable=False),
        sa.Column(
            "details",
            sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), "postgresql"),
            nullable=True,
        ),
        sa.CheckConstraint("kind IN ('threshold', 'forecast')", name=op.f("ck_alerts_kind")),
        sa.CheckConstraint("level IN ('plan', 'urgent', 'critical')", name=op.f("ck_alerts_level")),
        sa.CheckConstraint(
            "status IN ('open', 'acknowledged', 'resolved')", name=op.f("ck_alerts_status")
        ),
        sa.CheckConstraint(
            "end_chainage_m >= start_chainage_m", name=op.f("ck_alerts_chainage_order")
        ),
        sa.CheckConstraint("wire >= 0", name=op.f("ck_alerts_wire_not_negative")),
        sa.ForeignKeyConstraint(
            ["resolved_by_action_id"],
            ["maintenance_actions.id"],
            name=op.f("fk_alerts_resolved_by_action_id_maintenance_actions"),
            ondelete="SET NULL",
        ),
        sa.ForeignKeyConstraint(
            ["resolved_by_run_id"],
            ["runs.id"],
            name=op.f("fk_alerts_resolved_by_run_id_runs"),
            ondelete="SET NULL",
        ),
        sa.ForeignKeyConstraint(
            ["span_measurement_id"],
            ["span_measurements.id"],
            name=op.f("fk_alerts_span_measurement_id_span_measurements"),
            ondelete="SET NULL",
        ),
        sa.ForeignKeyConstraint(
            ["track_id"], ["tracks.id"], name=op.f("fk_alerts_track_id_tracks"), ondelete="RESTRICT"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_alerts")),
        sa.UniqueConstraint("condition_key", name=op.f("uq_alerts_condition_key")),
    )
    op.create_index(
        op.f("ix_alerts_resolved_by_run_id"), "alerts", ["resolved_by_run_id"], unique=False
    )
    op.create_index(
        op.f("ix_alerts_span_measurement_id"), "alerts", ["span_measurement_id"], unique=False
    )
    op.create_index(op.f("ix_alerts_status"), "alerts", ["status"], unique=False)
    op.create_index(
        op.f("ix_alerts_track_id_start_chainage_m"),
        "alerts",
        ["track_id", "start_chainage_m"],
        unique=False,
    )
    op.create_table(
        "alert_notifications",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("alert_id", sa.Integer(), nullable=False),
        sa.Column("notifier", sa.String(length=200), nullable=False),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("attempts", sa.Integer(), nullable=False),
        sa.Column("last_error", sa.Text(), nullable=True),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False),
        sa.CheckConstraint(
            "status IN ('pending', 'sent', 'failed')", name=op.f("ck_alert_notifications_status")
        ),
        sa.CheckConstraint(
            "attempts >= 0", name=op.f("ck_alert_notifications_attempts_not_negative")
        ),
        sa.ForeignKeyConstraint(
            ["alert_id"],
            ["alerts.id"],
            name=op.f("fk_alert_notifications_alert_id_alerts"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_alert_notifications")),
        sa.UniqueConstraint(
            "alert_id", "notifier", name=op.f("uq_alert_notifications_alert_id_notifier")
        ),
    )
    op.create_index(
        op.f("ix_alert_notifications_status"), "alert_notifications", ["status"], unique=False
    )


def downgrade() -> None:
    # children before parents
    op.drop_index(op.f("ix_alert_notifications_status"), table_name="alert_notifications")
    op.drop_table("alert_notifications")
    op.drop_index(op.f("ix_alerts_track_id_start_chainage_m"), table_name="alerts")
    op.drop_index(op.f("ix_alerts_status"), table_name="alerts")
    op.drop_index(op.f("ix_alerts_span_measurement_id"), table_name="alerts")
    op.drop_index(op.f("ix_alerts_resolved_by_run_id"), table_name="alerts")
    op.drop_table("alerts")
    op.drop_index(
        op.f("ix_span_measurements_track_id_start_chainage_m"), table_name="span_measurements"
    )
    op.drop_table("span_measurements")
    op.drop_index(op.f("ix_runs_line_id_track_id_started_at"), table_name="runs")
    op.drop_table("runs")
    op.drop_index(op.f("ix_masts_track_id_chainage_m"), table_name="masts")
    op.drop_table("masts")
    op.drop_index(
        op.f("ix_maintenance_actions_track_id_from_chainage_m"), table_name="maintenance_actions"
    )
    op.drop_table("maintenance_actions")
    op.drop_table("tracks")
    op.drop_table("rig_calibrations")
    op.drop_table("vehicles")
    op.drop_table("lines")
