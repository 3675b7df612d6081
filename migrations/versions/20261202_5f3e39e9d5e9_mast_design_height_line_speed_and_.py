"""mast design height, line speed and position

The mast register's optional columns of FORMATS.md: ``design_height_mm`` (the contact wire's
height at the mast by design), ``line_speed_kmh`` (the line speed from the mast on), and
``latitude``, ``longitude`` (WGS 84 degrees). None: not given.

Revision ID: 5f3e39e9d5e9
Revises: 6638ba43c1b6
Create Date: 2026-12-02 12:01:40.023469+00:00

Written for SQLite (batch mode) and PostgreSQL alike; the downgrade undoes all of the upgrade.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


# revision identifiers, used by Alembic.
revision: str = "5f3e39e9d5e9"
down_revision: str | Sequence[str] | None = "6638ba43c1b6"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("masts", schema=None) as batch_op:
        batch_op.add_column(sa.Column("design_height_mm", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("line_speed_kmh", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("latitude", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("longitude", sa.Float(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("masts", schema=None) as batch_op:
        batch_op.drop_column("longitude")
        batch_op.drop_column("latitude")
        batch_op.drop_column("line_speed_kmh")
        batch_op.drop_column("design_height_mm")
