"""sign-in failures: the web service's sign-in limit, shared by all its processes

Table ``sign_in_failures`` (key, at): each failed sign-in, counted per user name and per
client address within the limit's window (``catenary serve --workers N`` runs several
processes, which must all see the same count).

Revision ID: e5a1c7d2f9b4
Revises: c3d91f0e2b47
Create Date: 2026-12-02 18:40:00.000000+00:00

Written for SQLite and PostgreSQL alike; the downgrade undoes all of the upgrade.
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

# revision identifiers, used by Alembic.
revision: str = "e5a1c7d2f9b4"
down_revision: str | Sequence[str] | None = "c3d91f0e2b47"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "sign_in_failures",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("key", sa.String(length=200), nullable=False),
        sa.Column("at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_sign_in_failures")),
    )
    op.create_index(
        op.f("ix_sign_in_failures_key_at"), "sign_in_failures", ["key", "at"], unique=False
    )


def downgrade() -> None:
    op.drop_index(op.f("ix_sign_in_failures_key_at"), table_name="sign_in_failures")
    op.drop_table("sign_in_failures")
