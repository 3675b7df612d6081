"""run alert evaluation and scheduler lease

``runs.alerts_evaluated_at``: when the run's track was last evaluated for alerts with the run in
it (None: not yet; runs stored before this revision count as not evaluated, so the next
evaluation takes them up). ``scheduler_leases``: the lease a running ``catenary scheduler``
holds on a database, renewed by a heartbeat; a second scheduler waits as a standby until the
lease expires.

Revision ID: 8b51c0d2e7a3
Revises: 3c1f0e7a9b42
Create Date: 2026-12-02 01:00:00.000000+00:00

Written for SQLite (batch mode) and PostgreSQL alike; the downgrade undoes all of the upgrade.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


# revision identifiers, used by Alembic.
revision: str = "8b51c0d2e7a3"
down_revision: str | Sequence[str] | None = "3c1f0e7a9b42"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("runs", schema=None) as batch_op:
        batch_op.add_column(
            sa.Column("alerts_evaluated_at", sa.DateTime(timezone=True), nullable=True)
        )
        batch_op.create_index(batch_op.f("ix_runs_alerts_evaluated_at"), ["alerts_evaluated_at"])
    op.create_table(
        "scheduler_leases",
        sa.Column("name", sa.String(length=64), nullable=False),
        sa.Column("holder", sa.String(length=200), nullable=False),
        sa.Column("host", sa.String(length=200), nullable=False),
        sa.Column("pid", sa.Integer(), nullable=False),
        sa.Column("acquired_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("heartbeat_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("expires_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("name", name=op.f("pk_scheduler_leases")),
    )


def downgrade() -> None:
    op.drop_table("scheduler_leases")
    with op.batch_alter_table("runs", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_runs_alerts_evaluated_at"))
        batch_op.drop_column("alerts_evaluated_at")
