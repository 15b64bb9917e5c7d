"""The patient's body weight, optional: torque is also shown per kilogram where it is known.

Nullable, so every existing patient reads as "not recorded". The API bounds it
(``server.schemas.WeightKg``); the column holds kilograms.

Revision ID: 0004_patient_weight
Revises: 0003_postgres
Create Date: 2026-02-16
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0004_patient_weight"
down_revision = "0003_postgres"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # Plain ADD COLUMN, as in 0002: ``ankle db sql`` prints it without a live database.
    op.add_column("patients", sa.Column("weight_kg", sa.Float(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("patients") as batch:
        batch.drop_column("weight_kg")
