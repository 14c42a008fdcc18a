"""Protocols and the trainer's workflow (issue 15): protocol templates, session phases
(each with its summary) and account preferences. The session summary's seeking columns
(at_bound, the optimum's times, targets, regret) are 0003's (issue 14).

Revision ID: 0004
Revises: 0003
Create Date: 2026-12-01
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

UTC_TIME = sa.DateTime(timezone=True)
PHASE_KINDS = "'warmup', 'seek', 'train', 'profile', 'cooldown', 'stop'"


def upgrade() -> None:
    op.create_table(
        "session_phases",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("session_id", sa.Integer(), nullable=False),
        sa.Column("position", sa.Integer(), nullable=False),
        sa.Column("kind", sa.String(length=16), nullable=False),
        sa.Column("name", sa.String(length=100), nullable=False),
        sa.Column("t_start", sa.Double(), nullable=False),
        sa.Column("t_end", sa.Double(), nullable=True),
        sa.Column("planned_end", sa.Double(), nullable=True),
        sa.Column("mean_power", sa.Double(), nullable=True),
        sa.Column("peak_power", sa.Double(), nullable=True),
        sa.Column("work", sa.Double(), nullable=True),
        sa.Column("mean_w", sa.Double(), nullable=True),
        sa.Column("optimum_w", sa.Double(), nullable=True),
        sa.Column("detail", sa.JSON(), nullable=False),
        sa.CheckConstraint(f"kind IN ({PHASE_KINDS})", name="ck_session_phases_kind"),
        sa.ForeignKeyConstraint(
            ["session_id"],
            ["sessions.id"],
            name="fk_session_phases_session_id_sessions",
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name="pk_session_phases"),
        sa.UniqueConstraint("session_id", "position", name="uq_session_phases_session_id_position"),
    )
    op.create_table(
        "protocol_templates",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("name", sa.String(length=100), nullable=False),
        sa.Column("description", sa.Text(), nullable=False),
        sa.Column("protocol", sa.JSON(), nullable=False),
        sa.Column("account_id", sa.Integer(), nullable=True),
        sa.Column("shared", sa.Boolean(), nullable=False),
        sa.Column("created_at", UTC_TIME, nullable=False),
        sa.Column("updated_at", UTC_TIME, nullable=False),
        sa.ForeignKeyConstraint(
            ["account_id"],
            ["accounts.id"],
            name="fk_protocol_templates_account_id_accounts",
            ondelete="SET NULL",
        ),
        sa.PrimaryKeyConstraint("id", name="pk_protocol_templates"),
    )
    op.create_index("ix_protocol_templates_account_id", "protocol_templates", ["account_id"])
    op.create_index("ix_protocol_templates_shared_name", "protocol_templates", ["shared", "name"])
    op.create_table(
        "account_preferences",
        sa.Column("account_id", sa.Integer(), nullable=False),
        sa.Column("velocity_unit", sa.String(length=8), nullable=False),
        sa.Column("updated_at", UTC_TIME, nullable=False),
        sa.CheckConstraint(
            "velocity_unit IN ('rpm', 'rad/s')", name="ck_account_preferences_velocity_unit"
        ),
        sa.ForeignKeyConstraint(
            ["account_id"],
            ["accounts.id"],
            name="fk_account_preferences_account_id_accounts",
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("account_id", name="pk_account_preferences"),
    )


def downgrade() -> None:
    op.drop_table("account_preferences")
    op.drop_index("ix_protocol_templates_shared_name", table_name="protocol_templates")
    op.drop_index("ix_protocol_templates_account_id", table_name="protocol_templates")
    op.drop_table("protocol_templates")
    op.drop_table("session_phases")
