"""PostgreSQL for real: 64-bit ids, and the audit log append-only there too.

On PostgreSQL the ids of 0001 are int4 (SERIAL, whose sequence also stops at 2**31-1): every
id and every column naming one becomes BIGINT, sequences included. SQLite's INTEGER primary
key is already a 64-bit rowid, so nothing changes there.

0001 made SQLite refuse UPDATE and DELETE on ``audit_log``; here PostgreSQL refuses them
and TRUNCATE, by one statement-level trigger (a DELETE that matches no row is refused too).
The application's role should also lack those privileges: ``ankle db grants`` prints the
SQL for a DBA.

Every statement is plain SQL that needs no answer from the database, so ``ankle db sql``
(Alembic's offline mode) prints exactly what would run.

Revision ID: 0003_postgres
Revises: 0002_accounts
Create Date: 2026-02-02
"""

from __future__ import annotations

from alembic import op

revision = "0003_postgres"
down_revision = "0002_accounts"
branch_labels = None
depends_on = None

APPEND_ONLY = "audit log is append-only"

PRIMARY_KEYS = (
    "users",
    "auth_tokens",
    "patients",
    "stations",
    "prescriptions",
    "sessions",
    "audit_log",
)
REFERENCES = (
    ("auth_tokens", "user_id"),
    ("patients", "therapist_id"),
    ("stations", "patient_id"),
    ("prescriptions", "patient_id"),
    ("prescriptions", "created_by"),
    ("sessions", "station_id"),
    ("sessions", "patient_id"),
    ("sessions", "prescription_id"),
    ("uploads", "station_id"),
    ("audit_log", "patient_id"),
)


def _postgresql() -> bool:
    return bool(op.get_context().dialect.name == "postgresql")


def _retype(kind: str) -> None:
    for table in PRIMARY_KEYS:
        op.execute(f"ALTER TABLE {table} ALTER COLUMN id TYPE {kind}")
        # SERIAL's sequence is typed too: as integer it would stop at 2**31-1.
        op.execute(
            "DO $$ BEGIN EXECUTE format('ALTER SEQUENCE %s AS "
            f"{kind}', pg_get_serial_sequence('{table}', 'id')); END $$"
        )
    for table, column in REFERENCES:
        op.execute(f"ALTER TABLE {table} ALTER COLUMN {column} TYPE {kind}")


def upgrade() -> None:
    if not _postgresql():
        return
    _retype("BIGINT")
    op.execute(
        "CREATE FUNCTION audit_log_append_only() RETURNS trigger LANGUAGE plpgsql AS $$ "
        f"BEGIN RAISE EXCEPTION '{APPEND_ONLY}' USING ERRCODE = 'insufficient_privilege'; "
        "END $$"
    )
    op.execute(
        "CREATE TRIGGER audit_log_append_only BEFORE UPDATE OR DELETE OR TRUNCATE "
        "ON audit_log FOR EACH STATEMENT EXECUTE FUNCTION audit_log_append_only()"
    )


def downgrade() -> None:
    if not _postgresql():
        return
    op.execute("DROP TRIGGER IF EXISTS audit_log_append_only ON audit_log")
    op.execute("DROP FUNCTION IF EXISTS audit_log_append_only()")
    _retype("INTEGER")
