"""Every stored e-mail address in the one form sign-in looks it up in (NFKC, lower case).

Addresses were stored lower-cased only, so a decomposed "tá" (a + U+0301) or a fullwidth
"ｔａ" stayed as typed; sign-in now normalises what is typed (``sessions.text``), and such an
account would no longer be found by the form its owner always used. This rewrites each to
its normal form. The rule is copied here, not imported, so that this revision does what it
did the day it was written.

An address whose normal form another account already holds (a look-alike made before the
rule, e.g. "ｔａ@x" beside "ta@x") is left as it is and logged as a warning naming both
accounts: the address signs in to the account that holds the normal form, and an admin
should deactivate the look-alike (it keeps its data and its audit trail).

The rewrite needs Python (its Unicode tables, and a choice where two addresses meet), so
``ankle db sql`` cannot print it. For PostgreSQL it prints a check in its place that stops
the script (and so its transaction) if any stored address is not NFKC-normal, which, as
every stored address was lower-cased, is exactly when there is something to rewrite; that
DBA runs ``ankle db upgrade`` instead. For SQLite it prints a comment saying so.

Revision ID: 0005_normal_emails
Revises: 0004_patient_weight
Create Date: 2026-12-07
"""

from __future__ import annotations

import logging
import unicodedata

import sqlalchemy as sa
from alembic import op

revision = "0005_normal_emails"
down_revision = "0004_patient_weight"
branch_labels = None
depends_on = None

log = logging.getLogger("ankle.server.migrations")

OFFLINE_REFUSAL = (
    "stored e-mail addresses that are not NFKC-normal must be rewritten by "
    "`ankle db upgrade`: run it instead of this script"
)
_USERS = sa.table("users", sa.column("id", sa.BigInteger), sa.column("email", sa.String))


def _normal(address: str) -> str:
    return unicodedata.normalize("NFKC", unicodedata.normalize("NFKC", address).strip().lower())


def upgrade() -> None:
    context = op.get_context()
    if context.as_sql:
        if context.dialect.name == "postgresql":
            op.execute(
                "DO $$ BEGIN IF EXISTS (SELECT 1 FROM users WHERE email IS NOT NFKC NORMALIZED) "
                f"THEN RAISE EXCEPTION '{OFFLINE_REFUSAL}'; END IF; END $$"
            )
        else:
            context.impl.static_output(
                "-- 0005_normal_emails: if a stored e-mail address is not NFKC-normal, run "
                "`ankle db upgrade` instead of this script (it rewrites them).\n"
            )
        return
    connection = op.get_bind()
    rows = connection.execute(sa.select(_USERS.c.id, _USERS.c.email).order_by(_USERS.c.id))
    holder = {email: user_id for user_id, email in rows}
    for email, user_id in sorted(holder.items(), key=lambda item: item[1]):
        normal = _normal(email)
        if normal == email:
            continue
        if normal in holder:
            log.warning(
                "account %d's address %r is account %d's %r once normalised: it is left as "
                "stored, and signing in with either reaches account %d; deactivate the "
                "look-alike",
                user_id,
                email,
                holder[normal],
                normal,
                holder[normal],
            )
            continue
        connection.execute(sa.update(_USERS).where(_USERS.c.id == user_id).values(email=normal))
        holder[normal] = user_id
        del holder[email]


def downgrade() -> None:
    """Nothing to undo: the normal form is a valid address for the old code too."""
