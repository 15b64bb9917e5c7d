"""Alembic environment: runs on the connection ``server.db.migrate`` hands over.

There is no alembic.ini and no URL here: the server migrates its own database at start, on
the engine its settings built. To write a new revision, copy the style of
``versions/0001_initial.py`` and let ``tests/server/test_migrations.py`` check it against the
ORM.
"""

from __future__ import annotations

from alembic import context
from sqlalchemy import Connection

from server.models import Base

connection = context.config.attributes.get("connection")
if not isinstance(connection, Connection):
    raise RuntimeError("run migrations through server.db.migrate(engine), not the alembic CLI")

context.configure(
    connection=connection,
    target_metadata=Base.metadata,
    # SQLite alters tables by copying them; batch mode does that for later revisions.
    render_as_batch=True,
)
with context.begin_transaction():
    context.run_migrations()
