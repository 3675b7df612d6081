"""run chainage alignment

How each run's chainage was found (``catenary process``): aligned to the register or not,
the fitted offset and encoder scale, the registration points matched and their residual RMS.
Nullable: runs stored before have none.

Revision ID: 3c1f0e7a9b42
Revises: d714f228946e
Create Date: 2026-12-01 17:00:00.000000+00:00

Written for SQLite (batch mode) and PostgreSQL alike; the downgrade undoes all of the upgrade.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


# revision identifiers, used by Alembic.
revision: str = "3c1f0e7a9b42"
down_revision: str | Sequence[str] | None = "d714f228946e"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("runs", schema=None) as batch_op:
        batch_op.add_column(sa.Column("chainage_aligned", sa.Boolean(), nullable=True))
        batch_op.add_column(sa.Column("chainage_offset_m", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("encoder_scale", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("alignment_matched", sa.Integer(), nullable=True))
        batch_op.add_column(sa.Column("alignment_rms_m", sa.Float(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("runs", schema=None) as batch_op:
        batch_op.drop_column("alignment_rms_m")
        batch_op.drop_column("alignment_matched")
        batch_op.drop_column("encoder_scale")
        batch_op.drop_column("chainage_offset_m")
        batch_op.drop_column("chainage_aligned")
