"""The schema the migrations build is the schema the ORM expects; SQLite runs safely."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Column, Connection, Integer, MetaData
from sqlalchemy.ext.asyncio import AsyncEngine

from server.config import Settings
from server.db import alembic_config, create_engine, migrate
from server.models import Base


def _diff(connection: Connection, metadata: MetaData) -> list[Any]:
    context = MigrationContext.configure(connection, opts={"compare_type": True})
    return list(compare_metadata(context, metadata))


async def _migrated(settings: Settings) -> AsyncEngine:
    engine = create_engine(settings)
    await migrate(engine)
    return engine


@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_migrations_build_exactly_the_orm_schema(fresh: Settings) -> None:
    engine = await _migrated(fresh)
    try:
        async with engine.connect() as connection:
            assert await connection.run_sync(_diff, Base.metadata) == []
            # The comparison does see a difference when there is one.
            changed = MetaData(naming_convention=Base.metadata.naming_convention)
            for table in Base.metadata.tables.values():
                table.to_metadata(changed)
            changed.tables["patients"].append_column(Column("extra", Integer))
            assert await connection.run_sync(_diff, changed) != []
    finally:
        await engine.dispose()


@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_migrating_twice_is_harmless_and_reaches_head(fresh: Settings) -> None:
    engine = await _migrated(fresh)
    try:
        await migrate(engine)
        head = ScriptDirectory.from_config(alembic_config()).get_current_head()
        async with engine.connect() as connection:
            version = (await connection.exec_driver_sql("SELECT * FROM alembic_version")).all()
        assert version == [(head,)]
    finally:
        await engine.dispose()


@pytest.mark.asyncio
async def test_sqlite_runs_with_wal_foreign_keys_and_full_sync(tmp_path: Path) -> None:
    engine = await _migrated(Settings(data_dir=tmp_path / "data"))
    try:
        async with engine.connect() as connection:

            async def pragma(name: str) -> Any:
                return (await connection.exec_driver_sql(f"PRAGMA {name}")).scalar()

            assert await pragma("journal_mode") == "wal"
            assert await pragma("foreign_keys") == 1
            assert await pragma("synchronous") == 2  # FULL
            assert await pragma("busy_timeout") == 5000
    finally:
        await engine.dispose()
