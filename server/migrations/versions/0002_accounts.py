"""Accounts with a life cycle: a password that must be changed, archived patients.

``users.must_change_password`` marks a password that was printed or reset; existing
accounts chose their own, so they start false. ``patients.archived_at`` is null for every
existing patient (all current).

Revision ID: 0002_accounts
Revises: 0001
Create Date: 2026-01-12
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002_accounts"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # Plain ADD COLUMN (SQLite has it for a column with a default or nullable): batch mode
    # would have done the same, but needs a live database to reflect, and ``ankle db sql``
    # prints the SQL without one.
    op.add_column(
        "users",
        sa.Column("must_change_password", sa.Boolean(), nullable=False, server_default=sa.false()),
    )
    op.add_column("patients", sa.Column("archived_at", sa.DateTime(timezone=True), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("patients") as batch:
        batch.drop_column("archived_at")
    with op.batch_alter_table("users") as batch:
        batch.drop_column("must_change_password")
