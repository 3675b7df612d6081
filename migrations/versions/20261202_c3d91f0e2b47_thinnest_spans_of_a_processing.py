"""the thinnest spans of a processing: an index

``span_measurements (processing_id, min_residual_thickness_mm)``: the fleet overview's worst
spans of each track's latest run are read from it without sorting the run's spans.

Revision ID: c3d91f0e2b47
Revises: b3d9e4f1a6c2
Create Date: 2026-12-02 17:40:00.000000+00:00

Written for SQLite and PostgreSQL alike; the downgrade undoes all of the upgrade.
"""

from collections.abc import Sequence

from alembic import op

# revision identifiers, used by Alembic.
revision: str = "c3d91f0e2b47"
down_revision: str | Sequence[str] | None = "b3d9e4f1a6c2"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

INDEX = "ix_span_measurements_processing_id_min_residual_thickness_mm"


def upgrade() -> None:
    op.create_index(
        INDEX, "span_measurements", ["processing_id", "min_residual_thickness_mm"], unique=False
    )


def downgrade() -> None:
    op.drop_index(INDEX, table_name="span_measurements")
