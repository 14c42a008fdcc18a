"""The search's figures of a session (issue 14): the bound it ended at, when and where it
first converged, the extremes of its targets, the time of the end optimum, the regret.

Revision ID: 0003
Revises: 0002
Create Date: 2026-12-01
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

FIGURES = (
    "optimum_t", "t_converged", "wd_converged", "p_converged", "target_min", "target_max",
    "regret",
)  # fmt: skip


def upgrade() -> None:
    with op.batch_alter_table("sessions") as batch:
        batch.add_column(sa.Column("at_bound", sa.String(length=8), nullable=True))
        for name in FIGURES:
            batch.add_column(sa.Column(name, sa.Double(), nullable=True))
        batch.create_check_constraint("ck_sessions_at_bound", "at_bound IN ('lower', 'upper')")


def downgrade() -> None:
    with op.batch_alter_table("sessions") as batch:
        batch.drop_constraint("ck_sessions_at_bound", type_="check")
        for name in reversed(FIGURES):
            batch.drop_column(name)
        batch.drop_column("at_bound")
