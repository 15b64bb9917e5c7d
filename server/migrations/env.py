"""Alembic environment: runs on the connection ``server.db.migrate`` hands over, or offline
for ``server.db.migration_sql`` (the SQL for a DBA, for the URL's kind of database).

There is no alembic.ini and no URL here: the server migrates its own database (at start,
or by ``ankle db upgrade``) on the engine its settings built. To write a new revision, copy
the style of ``versions/0001_initial.py`` and let ``tests/server/test_db.py`` check it
against the ORM.
"""

from __future__ import annotations

from alembic import context
from sqlalchemy import Connection

from server.models import Base

# SQLite alters tables by copying them; batch mode does that for later revisions.
if context.is_offline_mode():
    context.configure(
        url=context.config.attributes["offline_url"],
        target_metadata=Base.metadata,
        render_as_batch=True,
        literal_binds=True,
    )
else:
    connection = context.config.attributes.get("connection")
    if not isinstance(connection, Connection):
        raise RuntimeError("run migrations through server.db.migrate(engine), not alembic's CLI")
    context.configure(connection=connection, target_metadata=Base.metadata, render_as_batch=True)
with context.begin_transaction():
    context.run_migrations()
