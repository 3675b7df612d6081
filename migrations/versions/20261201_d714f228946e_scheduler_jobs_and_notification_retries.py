"""scheduler job store and notification retries

The table of APScheduler's job store (``apscheduler_jobs``: the layout of APScheduler 3's
``SQLAlchemyJobStore``, which ``catenary scheduler`` uses; not a model, so ``db check`` leaves it
alone), and the time the next attempt of an alert notification is due.

Revision ID: d714f228946e
Revises: 5e3a32fbe18d
Create Date: 2026-12-01 15:45:00.000000+00:00

Written for SQLite (batch mode) and PostgreSQL alike; the downgrade undoes all of the upgrade.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


# revision identifiers, used by Alembic.
revision: str = "d714f228946e"
down_revision: str | Sequence[str] | None = "5e3a32fbe18d"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "apscheduler_jobs",
        sa.Column("id", sa.Unicode(length=191), nullable=False),
        sa.Column("next_run_time", sa.Float(precision=25), nullable=True),
        sa.Column("job_state", sa.LargeBinary(), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_apscheduler_jobs")),
    )
    op.create_index(
        op.f("ix_apscheduler_jobs_next_run_time"),
        "apscheduler_jobs",
        ["next_run_time"],
        unique=False,
    )
    with op.batch_alter_table("alert_notifications", schema=None) as batch_op:
        batch_op.add_column(sa.Column("next_attempt_at", sa.DateTime(timezone=True), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("alert_notifications", schema=None) as batch_op:
        batch_op.drop_column("next_attempt_at")
    op.drop_index(op.f("ix_apscheduler_jobs_next_run_time"), table_name="apscheduler_jobs")
    op.drop_table("apscheduler_jobs")
