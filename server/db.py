"""The database: an async engine for the configured URL, and Alembic migrations, run once
however many processes start at the same time."""

from __future__ import annotations

import asyncio
import fcntl
import io
import os
import re
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any, NamedTuple

from alembic import command
from alembic.config import Config
from alembic.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Connection, event, make_url, text
from sqlalchemy.exc import DBAPIError
from sqlalchemy.ext.asyncio import (
    AsyncEngine,
    AsyncSession,
    async_sessionmaker,
    create_async_engine,
)
from sqlalchemy.pool import NullPool

from server.config import Settings
from sessions.private import PRIVATE_FILE, private_data_dir

MIGRATIONS = Path(__file__).resolve().parent / "migrations"

DATABASE_WAIT_S = 5.0
"""The longest a request waits on the database before it is answered 503 (the database is
away or busy): SQLite's busy timeout; on PostgreSQL the connect timeout, the lock timeout
and the time a statement may go unanswered (a server that stopped answering, a table
locked by another client). Before PostgreSQL had these, a frozen server held every route,
``/health`` included, until it answered again (150 s), and a table lock held elsewhere held
``GET /stations`` for as long as the lock (39 s)."""

# WAL lets the dashboard read while a station's upload writes; FULL makes an acknowledged
# write (an audit row, an upload's progress) survive a power cut, not only a process kill.
_SQLITE_PRAGMAS = (
    "PRAGMA journal_mode=WAL",
    f"PRAGMA busy_timeout={DATABASE_WAIT_S * 1000:.0f}",
    "PRAGMA foreign_keys=ON",
    "PRAGMA synchronous=FULL",
)


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    cursor = dbapi_connection.cursor()
    for pragma in _SQLITE_PRAGMAS:
        cursor.execute(pragma)
    cursor.close()


LOCK_SUFFIX = ".migrate-lock"
"""Beside an SQLite file, the file whose lock one migrating process holds."""


def private_sqlite_file(path: Path) -> None:
    """The database file, created empty with mode 0600 before SQLite opens it. SQLite gives
    its -wal and -shm files the mode of the database, so they are private too; a database
    made before this rule is brought to it, with its companions (and the migration lock)."""
    fd = os.open(path, os.O_RDWR | os.O_CREAT, PRIVATE_FILE)
    os.close(fd)
    for p in (path, *(path.with_name(path.name + s) for s in ("-wal", "-shm", LOCK_SUFFIX))):
        if p.exists():
            os.chmod(p, PRIVATE_FILE)


def sqlite_file(database_url: str) -> Path | None:
    """The file of an SQLite URL, or None (in memory, or another database)."""
    url = make_url(database_url)
    if url.get_backend_name() != "sqlite" or url.database in (None, "", ":memory:"):
        return None
    return Path(url.database)


def create_engine(settings: Settings) -> AsyncEngine:
    """The engine for ``settings.database_url``; creates ``data_dir`` (0700) and the
    SQLite file (0600) first."""
    private_data_dir(settings.data_dir)
    db_file = sqlite_file(settings.database_url)
    if db_file is not None:
        private_sqlite_file(db_file)
    # Pre-ping: a pooled connection the database dropped (it restarted) is replaced before a
    # request uses it, instead of failing that request.
    engine = create_async_engine(
        settings.database_url, pool_pre_ping=True, connect_args=_bounded_waits(settings)
    )
    if engine.dialect.name == "sqlite":
        event.listen(engine.sync_engine, "connect", _sqlite_pragmas)
    return engine


def _bounded_waits(settings: Settings) -> dict[str, Any]:
    """asyncpg's arguments bounding each wait by ``DATABASE_WAIT_S``: the connection
    (``timeout``), every statement's answer (``command_timeout``: the driver gives up and
    cancels it) and, on the server, a lock (``lock_timeout``: SQLSTATE 55P03).
    Nothing for SQLite, whose busy timeout is a PRAGMA; migrations lift them
    (:func:`_unbounded`)."""
    if settings.is_sqlite:
        return {}
    return {
        "timeout": DATABASE_WAIT_S,
        "command_timeout": DATABASE_WAIT_S,
        "server_settings": {"lock_timeout": f"{DATABASE_WAIT_S * 1000:.0f}"},
    }


class DatabaseUnreachable(Exception):
    """The database ``ANKLE_DATABASE_URL`` names cannot be opened: one line saying where
    and why, never the password."""


def where(database_url: str) -> str:
    """The database a URL names, for a message: the SQLite file, or PostgreSQL's host, port
    and database (no user, no password)."""
    url = make_url(database_url)
    if url.get_backend_name() == "sqlite":
        return f"the SQLite file {url.database}"
    return f"PostgreSQL at {url.host or 'localhost'}:{url.port or 5432}/{url.database or ''}"


def unreachable(database_url: str, exc: BaseException) -> DatabaseUnreachable:
    """``exc`` (a driver's, an OSError) as one line naming the database and the cause."""
    cause = exc.orig if isinstance(exc, DBAPIError) and exc.orig is not None else exc
    said = (str(cause).strip().splitlines() or [type(cause).__name__])[0]
    return DatabaseUnreachable(
        f"cannot open the database (ANKLE_DATABASE_URL: {where(database_url)}): {said}"
    )


async def check_reachable(settings: Settings, schema: bool = False) -> None:
    """Open one connection to the database and close it; :class:`DatabaseUnreachable` if
    that fails, so that a command says so in one line before anything else starts. With
    ``schema``, a server that may not migrate (``migrate_on_start`` false) also checks
    that the schema is current (:class:`SchemaNotCurrent`): found in each process's
    start-up instead, it was uvicorn's traceback of 130 lines."""
    engine = create_engine(settings)
    try:
        async with engine.connect():
            pass
        if schema and not settings.migrate_on_start:
            await require_current(engine)
    except (DBAPIError, OSError) as exc:
        raise unreachable(settings.database_url, exc) from None
    finally:
        await engine.dispose()


COMMIT_SENT = "commit_sent"
"""The key of a session's ``info`` set once it sent a COMMIT: from then on, a database
that goes away leaves the outcome unknown (``server.errors.CommitUnknown``)."""


class Session(AsyncSession):
    """A session that says when its commit was sent: its changes are flushed first (a
    failure there rolls them back: nothing was stored), then ``COMMIT_SENT`` is set."""

    async def commit(self) -> None:
        await self.flush()
        self.info[COMMIT_SENT] = True
        await super().commit()


def create_sessionmaker(engine: AsyncEngine) -> async_sessionmaker[AsyncSession]:
    # Objects stay readable after commit: a route commits, then builds its response from them.
    return async_sessionmaker(engine, class_=Session, expire_on_commit=False)


def alembic_config() -> Config:
    """Alembic's configuration built in code: no alembic.ini to find or keep in step."""
    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS))
    return config


def _upgrade(connection: Connection, revision: str) -> None:
    config = alembic_config()
    config.attributes["connection"] = connection
    command.upgrade(config, revision)


MIGRATION_LOCK = 0x616E6B6C65  # "ankle": the advisory lock key of migrations on PostgreSQL


@asynccontextmanager
async def _sqlite_lock(engine: AsyncEngine) -> AsyncIterator[None]:
    """An exclusive lock on a file beside an SQLite database (``LOCK_SUFFIX``), held while
    one process migrates; an in-memory database is one process's alone."""
    database = engine.url.database
    if engine.dialect.name != "sqlite" or database in (None, "", ":memory:"):
        yield
        return
    fd = os.open(f"{database}{LOCK_SUFFIX}", os.O_RDWR | os.O_CREAT, PRIVATE_FILE)
    try:
        await asyncio.to_thread(fcntl.flock, fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the lock


@asynccontextmanager
async def _unbounded(engine: AsyncEngine) -> AsyncIterator[AsyncEngine]:
    """For migrating on PostgreSQL, an engine of one connection whose statements and locks
    may take as long as they need (``engine``'s give up after ``DATABASE_WAIT_S``): a
    migration of a large table takes longer, and a process starting beside the one that
    migrates waits for its lock until it is done."""
    if engine.dialect.name != "postgresql":
        yield engine
        return
    unbounded = create_async_engine(
        engine.url, poolclass=NullPool, connect_args={"timeout": DATABASE_WAIT_S}
    )
    try:
        yield unbounded
    finally:
        await unbounded.dispose()


async def migrate(engine: AsyncEngine, revision: str = "head") -> None:
    """Bring the schema to ``revision`` (all migrations by default), in one transaction.

    Processes starting together on one database take turns (an advisory lock on
    PostgreSQL, a file lock beside an SQLite file): the first migrates, the others then
    find the schema at ``revision`` and do nothing."""
    async with _sqlite_lock(engine), _unbounded(engine) as engine, engine.begin() as connection:
        if engine.dialect.name == "postgresql":
            # Released at commit, when the schema and alembic_version are both visible.
            await connection.execute(
                text("SELECT pg_advisory_xact_lock(:key)"), {"key": MIGRATION_LOCK}
            )
        await connection.run_sync(_upgrade, revision)


class SchemaNotCurrent(Exception):
    """The database's schema is not the one this server needs, and it may not migrate."""


async def require_current(engine: AsyncEngine) -> None:
    """Raise SchemaNotCurrent unless the database is at this server's newest revision."""
    found = await revisions(engine)
    if found.current != found.head:
        raise SchemaNotCurrent(
            f"the database's schema is at revision {found.current or 'none (empty)'} and this "
            f"server needs {found.head}: run `ankle db upgrade` (or set "
            "ANKLE_MIGRATE_ON_START=true)"
        )


async def prepare(engine: AsyncEngine, migrate_on_start: bool) -> None:
    """What a process does with the database before it serves: migrate, or check that
    someone did."""
    if migrate_on_start:
        await migrate(engine)
    else:
        await require_current(engine)


class Revisions(NamedTuple):
    current: str | None
    """The database's revision; None for a database never migrated."""
    head: str
    """The newest revision this version of the server knows."""


def head_revision() -> str:
    head = ScriptDirectory.from_config(alembic_config()).get_current_head()
    assert head is not None
    return head


async def revisions(engine: AsyncEngine) -> Revisions:
    """Where the database's schema is, and where this server would bring it."""

    def current(connection: Connection) -> str | None:
        return MigrationContext.configure(connection).get_current_revision()

    async with engine.connect() as connection:
        return Revisions(await connection.run_sync(current), head_revision())


def migration_sql(database_url: str, start: str | None = None, revision: str = "head") -> str:
    """The SQL that brings a database of ``database_url``'s kind from ``start`` (empty by
    default) to ``revision``, for a DBA to read or run (Alembic's offline mode; nothing
    connects)."""
    out = io.StringIO()
    config = Config(output_buffer=out)
    config.set_main_option("script_location", str(MIGRATIONS))
    config.attributes["offline_url"] = database_url
    command.upgrade(config, f"{start}:{revision}" if start else revision, sql=True)
    return out.getvalue()


_ROLE = re.compile(r"^[A-Za-z_][A-Za-z0-9_$]{0,62}$")


def grants_sql(database_url: str, role: str) -> str:
    """The SQL a DBA runs (as the owner of the tables, after ``ankle db upgrade``) so that
    the server's role ``role`` may read and write what it serves, but never change or
    remove an audit row (the trigger refuses that too; the missing privilege refuses it
    even should the trigger be dropped). Raises ValueError for a role that is not a plain
    identifier."""
    if not _ROLE.match(role):
        raise ValueError(f"--role {role!r} is not a plain SQL identifier (letters, digits, _)")
    database = make_url(database_url).database or "ankle"
    r = f'"{role}"'
    return "\n".join(
        (
            f"-- The server's role {role}: data, not schema (run `ankle db upgrade` as the owner",
            "-- and start the server with ANKLE_MIGRATE_ON_START=false).",
            f'GRANT CONNECT ON DATABASE "{database}" TO {r};',
            f"GRANT USAGE ON SCHEMA public TO {r};",
            f"GRANT SELECT, INSERT, UPDATE, DELETE ON ALL TABLES IN SCHEMA public TO {r};",
            f"GRANT USAGE, SELECT ON ALL SEQUENCES IN SCHEMA public TO {r};",
            "-- The audit log is append-only: insert and read, nothing else.",
            f"REVOKE UPDATE, DELETE, TRUNCATE ON audit_log FROM {r};",
            "",
        )
    )
