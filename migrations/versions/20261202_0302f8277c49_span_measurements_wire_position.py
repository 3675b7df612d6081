"""span measurements' wire position

``span_measurements.wire_position``: the wire's rank among the processing's wires in the span,
left to right looking toward increasing chainage (by the middle of its stagger range, the run's
direction undone; ties by the run's wire number): the identity users see
(``catenary.positions``). Rows stored before it get theirs computed here.

Revision ID: 0302f8277c49
Revises: 5f3e39e9d5e9
Create Date: 2026-12-02 12:17:02.244001+00:00

Written for SQLite (batch mode) and PostgreSQL alike; the downgrade undoes all of the upgrade.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

# revision identifiers, used by Alembic.
revision: str = "0302f8277c49"
down_revision: str | Sequence[str] | None = "5f3e39e9d5e9"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

RANKED = """
UPDATE span_measurements SET wire_position = ranked.position
FROM (
    SELECT s.id, ROW_NUMBER() OVER (
        PARTITION BY s.processing_id, s.span
        ORDER BY CASE r.direction WHEN 'increasing' THEN 1 ELSE -1 END
                 * (s.stagger_min_mm + s.stagger_max_mm), s.wire
    ) - 1 AS position
    FROM span_measurements AS s JOIN runs AS r ON r.id = s.run_id
) AS ranked
WHERE span_measurements.id = ranked.id
"""


def upgrade() -> None:
    with op.batch_alter_table("span_measurements", schema=None) as batch_op:
        batch_op.add_column(sa.Column("wire_position", sa.Integer(), nullable=True))
    op.execute(RANKED)
    with op.batch_alter_table("span_measurements", schema=None) as batch_op:
        batch_op.alter_column("wire_position", existing_type=sa.Integer(), nullable=False)
        batch_op.create_check_constraint("wire_position_not_negative", "wire_position >= 0")


def downgrade() -> None:
    with op.batch_alter_table("span_measurements", schema=None) as batch_op:
        batch_op.drop_constraint(
            batch_op.f("ck_span_measurements_wire_position_not_negative"), type_="check"
        )
        batch_op.drop_column("wire_position")
