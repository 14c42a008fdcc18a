"""Each phase's summary says whether its optimum is the bracket's edge (issue 15): a phase
row's ``at_bound`` (lower, upper; NULL: a peak inside the bracket, or no optimum), as the
session's own (0003).

Revision ID: 0005
Revises: 0004
Create Date: 2026-12-01
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0005"
down_revision: str | None = "0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("session_phases") as batch:
        batch.add_column(sa.Column("at_bound", sa.String(length=8), nullable=True))
        batch.create_check_constraint(
            "ck_session_phases_at_bound", "at_bound IN ('lower', 'upper')"
        )


def downgrade() -> None:
    with op.batch_alter_table("session_phases") as batch:
        batch.drop_constraint("ck_session_phases_at_bound", type_="check")
        batch.drop_column("at_bound")
