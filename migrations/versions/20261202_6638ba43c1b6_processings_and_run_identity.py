"""processings and run identity

A run's identity becomes its content: ``runs.rig_sha256`` (its rig calibration's content
SHA-256) beside ``source_sha256``, unique together, and ``runs.uuid`` derived from both (a
name-based UUID, the same on every machine). What a run measured moves to ``processings``: one
row per processing (processor, package version, settings and their hash, rig calibration, when,
the chainage alignment, the length, the samples file's key, size and SHA-256);
``span_measurements.processing_id`` names the processing a row belongs to, and
``runs.processing_id`` the run's latest; ``runs.source_key`` the run file in the store once it
is sent there. Each existing run becomes its first processing, with
its processor, package version and settings "unrecorded" (they were not kept) and its samples
file's key the path it had (relative to the data directory, the local store's root).

The downgrade keeps each run's latest processing and drops the others.

Revision ID: 6638ba43c1b6
Revises: 8b51c0d2e7a3
Create Date: 2026-12-02 11:20:00.167636+00:00

Written for SQLite (batch mode) and PostgreSQL alike.
"""

import hashlib
import uuid
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects import postgresql

# revision identifiers, used by Alembic.
revision: str = "6638ba43c1b6"
down_revision: str | Sequence[str] | None = "8b51c0d2e7a3"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

#: ``catenary.storage.models.RUN_NAMESPACE`` (a test checks they agree; neither ever changes)
RUN_NAMESPACE = uuid.UUID("5a8e3b0c-6f1d-4c2a-9e47-c4a7e2b1d0f3")
UNRECORDED = "unrecorded"
#: the processing columns that were the run's
MOVED = (
    "processed_at",
    "wire_type",
    "length_m",
    "chainage_aligned",
    "chainage_offset_m",
    "encoder_scale",
    "alignment_matched",
    "alignment_rms_m",
)

runs = sa.table(
    "runs",
    sa.column("id", sa.Integer),
    sa.column("uuid", sa.String),
    sa.column("source_sha256", sa.String),
    sa.column("rig_sha256", sa.String),
    sa.column("rig_calibration_id", sa.Integer),
    sa.column("started_at", sa.DateTime(timezone=True)),
    sa.column("processing_id", sa.Integer),
    sa.column("samples_path", sa.String),
    *(sa.column(name) for name in MOVED),
)
processings = sa.table(
    "processings",
    sa.column("id", sa.Integer),
    sa.column("uuid", sa.String),
    sa.column("run_id", sa.Integer),
    sa.column("processor", sa.String),
    sa.column("package_version", sa.String),
    sa.column("settings_sha256", sa.String),
    sa.column("rig_calibration_id", sa.Integer),
    sa.column("samples_key", sa.String),
    *(sa.column(name) for name in MOVED),
)
span_measurements = sa.table(
    "span_measurements",
    sa.column("run_id", sa.Integer),
    sa.column("processing_id", sa.Integer),
)
rig_calibrations = sa.table(
    "rig_calibrations", sa.column("id", sa.Integer), sa.column("sha256", sa.String)
)


def _first_processings() -> None:
    """Each run's identity, and its first processing from the columns it had."""
    bind = op.get_bind()
    rows = bind.execute(
        sa.select(runs, rig_calibrations.c.sha256.label("rig"))
        .join(rig_calibrations, runs.c.rig_calibration_id == rig_calibrations.c.id)
        .order_by(runs.c.id)
    ).mappings()
    unrecorded = hashlib.sha256(b"null").hexdigest()  # the settings None, as JSON
    for row in list(rows):
        moved = {name: row[name] for name in MOVED}
        moved["processed_at"] = row["processed_at"] or row["started_at"]
        moved["length_m"] = row["length_m"] or 0.0
        processing = bind.execute(
            processings.insert()
            .values(
                uuid=str(uuid.uuid4()),
                run_id=row["id"],
                processor=UNRECORDED,
                package_version=UNRECORDED,
                settings_sha256=unrecorded,
                rig_calibration_id=row["rig_calibration_id"],
                samples_key=row["samples_path"],
                **moved,
            )
            .returning(processings.c.id)
        ).scalar_one()
        run_uuid = uuid.uuid5(RUN_NAMESPACE, f"{row['source_sha256']}:{row['rig']}")
        bind.execute(
            runs.update()
            .where(runs.c.id == row["id"])
            .values(uuid=str(run_uuid), rig_sha256=row["rig"], processing_id=processing)
        )
        bind.execute(
            span_measurements.update()
            .where(span_measurements.c.run_id == row["id"])
            .values(processing_id=processing)
        )


def _latest_processings_back() -> None:
    """Each run's columns from its latest processing; the other processings' rows go."""
    bind = op.get_bind()
    rows = bind.execute(
        sa.select(runs.c.id, processings)
        .join(processings, processings.c.id == runs.c.processing_id)
        .order_by(runs.c.id)
    ).mappings()
    for row in list(rows):
        bind.execute(
            runs.update()
            .where(runs.c.id == row["id"])
            .values(samples_path=row["samples_key"], **{name: row[name] for name in MOVED})
        )
    bind.execute(runs.update().where(runs.c.length_m.is_(None)).values(length_m=0.0))
    bind.execute(
        span_measurements.delete().where(
            ~sa.exists().where(
                runs.c.id == span_measurements.c.run_id,
                runs.c.processing_id == span_measurements.c.processing_id,
            )
        )
    )


def upgrade() -> None:
    op.create_table(
        "processings",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("uuid", sa.String(length=36), nullable=False),
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("processor", sa.String(length=200), nullable=False),
        sa.Column("package_version", sa.String(length=32), nullable=False),
        sa.Column("settings_sha256", sa.String(length=64), nullable=False),
        sa.Column(
            "settings",
            sa.JSON().with_variant(postgresql.JSONB(astext_type=sa.Text()), "postgresql"),
            nullable=True,
        ),
        sa.Column("rig_calibration_id", sa.Integer(), nullable=False),
        sa.Column("processed_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("wire_type", sa.String(length=32), nullable=True),
        sa.Column("length_m", sa.Float(), nullable=False),
        sa.Column("chainage_aligned", sa.Boolean(), nullable=True),
        sa.Column("chainage_offset_m", sa.Float(), nullable=True),
        sa.Column("encoder_scale", sa.Float(), nullable=True),
        sa.Column("alignment_matched", sa.Integer(), nullable=True),
        sa.Column("alignment_rms_m", sa.Float(), nullable=True),
        sa.Column("samples_key", sa.String(length=1024), nullable=True),
        sa.Column("samples_size_bytes", sa.BigInteger(), nullable=True),
        sa.Column("samples_sha256", sa.String(length=64), nullable=True),
        sa.CheckConstraint(
            "samples_size_bytes >= 0", name=op.f("ck_processings_samples_size_not_negative")
        ),
        sa.ForeignKeyConstraint(
            ["rig_calibration_id"],
            ["rig_calibrations.id"],
            name=op.f("fk_processings_rig_calibration_id_rig_calibrations"),
            ondelete="RESTRICT",
        ),
        sa.ForeignKeyConstraint(
            ["run_id"], ["runs.id"], name=op.f("fk_processings_run_id_runs"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_processings")),
        sa.UniqueConstraint("uuid", name=op.f("uq_processings_uuid")),
    )
    with op.batch_alter_table("processings", schema=None) as batch_op:
        batch_op.create_index(
            batch_op.f("ix_processings_run_id_processed_at"),
            ["run_id", "processed_at"],
            unique=False,
        )

    with op.batch_alter_table("runs", schema=None) as batch_op:
        batch_op.add_column(sa.Column("uuid", sa.String(length=36), nullable=True))
        batch_op.add_column(sa.Column("rig_sha256", sa.String(length=64), nullable=True))
        batch_op.add_column(sa.Column("processing_id", sa.Integer(), nullable=True))
        batch_op.add_column(sa.Column("source_key", sa.String(length=1024), nullable=True))
    with op.batch_alter_table("span_measurements", schema=None) as batch_op:
        batch_op.add_column(sa.Column("processing_id", sa.Integer(), nullable=True))

    _first_processings()

    with op.batch_alter_table("runs", schema=None) as batch_op:
        batch_op.alter_column("uuid", existing_type=sa.String(length=36), nullable=False)
        batch_op.alter_column("rig_sha256", existing_type=sa.String(length=64), nullable=False)
        batch_op.drop_constraint(
            batch_op.f("uq_runs_source_sha256_rig_calibration_id"), type_="unique"
        )
        batch_op.create_unique_constraint(
            batch_op.f("uq_runs_source_sha256_rig_sha256"), ["source_sha256", "rig_sha256"]
        )
        batch_op.create_unique_constraint(batch_op.f("uq_runs_uuid"), ["uuid"])
        batch_op.create_foreign_key(
            batch_op.f("fk_runs_processing_id_processings"),
            "processings",
            ["processing_id"],
            ["id"],
            ondelete="SET NULL",
            use_alter=True,
        )
        for name in (*MOVED, "samples_path"):
            batch_op.drop_column(name)

    with op.batch_alter_table("span_measurements", schema=None) as batch_op:
        batch_op.alter_column("processing_id", existing_type=sa.Integer(), nullable=False)
        batch_op.drop_constraint(
            batch_op.f("uq_span_measurements_run_id_span_wire"), type_="unique"
        )
        batch_op.create_index(batch_op.f("ix_span_measurements_run_id"), ["run_id"], unique=False)
        batch_op.create_unique_constraint(
            batch_op.f("uq_span_measurements_processing_id_span_wire"),
            ["processing_id", "span", "wire"],
        )
        batch_op.create_foreign_key(
            batch_op.f("fk_span_measurements_processing_id_processings"),
            "processings",
            ["processing_id"],
            ["id"],
            ondelete="CASCADE",
        )


def downgrade() -> None:
    with op.batch_alter_table("runs", schema=None) as batch_op:
        batch_op.add_column(sa.Column("processed_at", sa.DateTime(timezone=True), nullable=True))
        batch_op.add_column(sa.Column("wire_type", sa.String(length=32), nullable=True))
        batch_op.add_column(sa.Column("length_m", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("chainage_aligned", sa.Boolean(), nullable=True))
        batch_op.add_column(sa.Column("chainage_offset_m", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("encoder_scale", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("alignment_matched", sa.Integer(), nullable=True))
        batch_op.add_column(sa.Column("alignment_rms_m", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("samples_path", sa.String(length=1024), nullable=True))

    _latest_processings_back()

    with op.batch_alter_table("span_measurements", schema=None) as batch_op:
        batch_op.drop_constraint(
            batch_op.f("fk_span_measurements_processing_id_processings"), type_="foreignkey"
        )
        batch_op.drop_constraint(
            batch_op.f("uq_span_measurements_processing_id_span_wire"), type_="unique"
        )
        batch_op.drop_index(batch_op.f("ix_span_measurements_run_id"))
        batch_op.create_unique_constraint(
            batch_op.f("uq_span_measurements_run_id_span_wire"), ["run_id", "span", "wire"]
        )
        batch_op.drop_column("processing_id")

    with op.batch_alter_table("runs", schema=None) as batch_op:
        batch_op.alter_column("length_m", existing_type=sa.Float(), nullable=False)
        batch_op.drop_constraint(
            batch_op.f("fk_runs_processing_id_processings"), type_="foreignkey"
        )
        batch_op.drop_constraint(batch_op.f("uq_runs_uuid"), type_="unique")
        batch_op.drop_constraint(batch_op.f("uq_runs_source_sha256_rig_sha256"), type_="unique")
        batch_op.create_unique_constraint(
            batch_op.f("uq_runs_source_sha256_rig_calibration_id"),
            ["source_sha256", "rig_calibration_id"],
        )
        batch_op.drop_column("processing_id")
        batch_op.drop_column("source_key")
        batch_op.drop_column("rig_sha256")
        batch_op.drop_column("uuid")

    with op.batch_alter_table("processings", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_processings_run_id_processed_at"))

    op.drop_table("processings")
