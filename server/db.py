"""The database: an async engine for the configured URL and Alembic migrations on start."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from alembic import command
from alembic.config import Config
from sqlalchemy import Connection, event, make_url
from sqlalchemy.ext.asyncio import (
    AsyncEngine,
    AsyncSession,
    async_sessionmaker,
    create_async_engine,
)

from server.config import Settings

MIGRATIONS = Path(__file__).resolve().parent / "migrations"

# WAL lets the dashboard read while a station's upload writes; FULL makes an acknowledged
# write (an audit row, an upload's progress) survive a power cut, not only a process kill.
_SQLITE_PRAGMAS = (
    "PRAGMA journal_mode=WAL",
    "PRAGMA busy_timeout=5000",
    "PRAGMA foreign_keys=ON",
    "PRAGMA synchronous=FULL",
)


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    cursor = dbapi_connection.cursor()
    for pragma in _SQLITE_PRAGMAS:
        cursor.execute(pragma)
    cursor.close()


PRIVATE_DIR = 0o700
PRIVATE_FILE = 0o600
"""Patients' data: only the server's own account reads it, whatever the umask says."""


def private_data_dir(path: Path) -> None:
    """Create ``path`` (and missing parents) readable by the owner only. A directory that
    exists already keeps its mode: an administrator may have chosen it."""
    if not path.exists():
        path.mkdir(mode=PRIVATE_DIR, parents=True, exist_ok=True)
        os.chmod(path, PRIVATE_DIR)  # mkdir's mode is masked by the umask


def private_sqlite_file(path: Path) -> None:
    """The database file, created empty with mode 0600 before SQLite opens it. SQLite gives
    its -wal and -shm files the mode of the database, so they are private too; a database
    made before this rule is brought to it, with its companions."""
    fd = os.open(path, os.O_RDWR | os.O_CREAT, PRIVATE_FILE)
    os.close(fd)
    for p in (path, path.with_name(path.name + "-wal"), path.with_name(path.name + "-shm")):
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
    engine = create_async_engine(settings.database_url)
    if engine.dialect.name == "sqlite":
        event.listen(engine.sync_engine, "connect", _sqlite_pragmas)
    return engine


def create_sessionmaker(engine: AsyncEngine) -> async_sessionmaker[AsyncSession]:
    # Objects stay readable after commit: a route commits, then builds its response from them.
    return async_sessionmaker(engine, expire_on_commit=False)


def alembic_config() -> Config:
    """Alembic's configuration built in code: no alembic.ini to find or keep in step."""
    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS))
    return config


def _upgrade(connection: Connection, revision: str) -> None:
    config = alembic_config()
    config.attributes["connection"] = connection
    command.upgrade(config, revision)


async def migrate(engine: AsyncEngine, revision: str = "head") -> None:
    """Bring the schema to ``revision`` (all migrations by default), in one transaction."""
    async with engine.begin() as connection:
        await connection.run_sync(_upgrade, revision)
