"""anchor sections and alert evaluation indexes

Masts get the anchor section they belong to (the mast register's optional column
``anchor_section``); runs an index by track and time, which the alert evaluation (one track at
a time) looks runs up by.

Revision ID: 5e3a32fbe18d
Revises: 79a969434a84
Create Date: 2026-11-24 09:00:00.000000+00:00

Written for SQLite (batch mode) and PostgreSQL alike; the downgrade undoes all of the upgrade.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


# revision identifiers, used by Alembic.
revision: str = "5e3a32fbe18d"
down_revision: str | Sequence[str] | None = "79a969434a84"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("masts", schema=None) as batch_op:
        batch_op.add_column(sa.Column("anchor_section", sa.String(length=32), nullable=True))
    op.create_index(
        op.f("ix_runs_track_id_started_at"), "runs", ["track_id", "started_at"], unique=False
    )


def downgrade() -> None:
    op.drop_index(op.f("ix_runs_track_id_started_at"), table_name="runs")
    with op.batch_alter_table("masts", schema=None) as batch_op:
        batch_op.drop_column("anchor_section")
