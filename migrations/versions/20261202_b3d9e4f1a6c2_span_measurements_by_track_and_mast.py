"""span measurements by track and start mast

A span's history (the web service's span page and ``GET /api/v1/spans/history``, ``catenary
history --mast``) reads the rows of one track measured from one mast, over every run: an index
on span measurements by track and start mast finds them without reading the track's other
spans.

Revision ID: b3d9e4f1a6c2
Revises: 5a7ab590c8c0
Create Date: 2026-12-02 17:40:00.000000+00:00

Written for SQLite and PostgreSQL alike; the downgrade undoes all of the upgrade.
"""

from collections.abc import Sequence

from alembic import op

# revision identifiers, used by Alembic.
revision: str = "b3d9e4f1a6c2"
down_revision: str | Sequence[str] | None = "5a7ab590c8c0"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_index(
        op.f("ix_span_measurements_track_id_mast_from"),
        "span_measurements",
        ["track_id", "mast_from"],
        unique=False,
    )


def downgrade() -> None:
    op.drop_index(op.f("ix_span_measurements_track_id_mast_from"), table_name="span_measurements")
