"""geometry alerts and span measurements' values at their masts

``alerts.kind`` may be ``geometry`` (a geometry rule of the policy: height, gradient, stagger,
or a mast's design value). ``span_measurements`` gain ``height_at_start_mm``,
``height_at_end_mm`` and ``stagger_at_start_mm``: the medians of the wire's samples within
1 m of the span's start and end masts (None: no sample there; rows stored before this
revision have none).

Revision ID: a7c4e2b9d013
Revises: 0302f8277c49
Create Date: 2026-12-02 12:20:00.000000+00:00

Written for SQLite (batch mode) and PostgreSQL alike; the downgrade undoes all of the upgrade
(geometry alerts are deleted by it: the old CHECK does not admit them).
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


# revision identifiers, used by Alembic.
revision: str = "a7c4e2b9d013"
down_revision: str | Sequence[str] | None = "0302f8277c49"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("alerts", schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f("ck_alerts_kind"), type_="check")
        batch_op.create_check_constraint(
            batch_op.f("ck_alerts_kind"), "kind IN ('threshold', 'forecast', 'geometry')"
        )
    with op.batch_alter_table("span_measurements", schema=None) as batch_op:
        batch_op.add_column(sa.Column("height_at_start_mm", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("height_at_end_mm", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("stagger_at_start_mm", sa.Float(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("span_measurements", schema=None) as batch_op:
        batch_op.drop_column("stagger_at_start_mm")
        batch_op.drop_column("height_at_end_mm")
        batch_op.drop_column("height_at_start_mm")
    op.execute("DELETE FROM alerts WHERE kind = 'geometry'")
    with op.batch_alter_table("alerts", schema=None) as batch_op:
        batch_op.drop_constraint(batch_op.f("ck_alerts_kind"), type_="check")
        batch_op.create_check_constraint(
            batch_op.f("ck_alerts_kind"), "kind IN ('threshold', 'forecast')"
        )
