"""Migrations run once, however many processes start together; ``ankle db`` for operators
and DBAs; a server that may not migrate refuses a schema that is not current."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from sqlalchemy import text
from sqlalchemy.exc import DBAPIError

from ankle.cli import main
from server.app import create_app
from server.cli import ensure_user_async
from server.config import Settings
from server.db import (
    SchemaNotCurrent,
    create_engine,
    grants_sql,
    head_revision,
    migrate,
    revisions,
)
from tests.server.live_server import PASSWORD, Seeds, Store, bearer, login, on_store, running
from tests.server.postgres import Cluster

pytestmark = pytest.mark.both_stores

PROCESSES = 4
MIGRATE_WHEN_TOLD = """
import asyncio, sys
from server.config import Settings
from server.db import create_engine, migrate, revisions

async def main():
    engine = create_engine(Settings())
    print("ready", flush=True)
    sys.stdin.readline()
    await migrate(engine)
    print((await revisions(engine)).current)
    await engine.dispose()

asyncio.run(main())
"""


def _environment(settings: Settings) -> dict[str, str]:
    return {
        **os.environ,
        "ANKLE_DATA_DIR": str(settings.data_dir),
        "ANKLE_DATABASE_URL": settings.database_url,
    }


def _ankle(settings: Settings, *argv: str, capsys: pytest.CaptureFixture[str]) -> str:
    """``ankle`` in this process, with the store's settings in the environment."""
    with pytest.MonkeyPatch.context() as env:
        for name, value in _environment(settings).items():
            env.setenv(name, value)
        assert main(list(argv)) == 0
    out: str = capsys.readouterr().out
    return out


def test_processes_starting_together_on_an_empty_database_all_migrate(
    fresh: Settings,
) -> None:
    """Four processes run the migration every server runs at start (and ``ankle db
    upgrade``), released together once all are loaded: all succeed and reach head."""
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", MIGRATE_WHEN_TOLD],
            env=_environment(fresh),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(PROCESSES)
    ]
    for p in procs:  # every one imported and waiting
        assert p.stdout is not None and p.stdout.readline() == "ready\n", p.communicate()
    for p in procs:
        assert p.stdin is not None
        p.stdin.write("go\n")
        p.stdin.flush()
    results = [(*p.communicate(timeout=120), p.returncode) for p in procs]
    for out, err, code in results:
        assert code == 0, err
        assert out == f"{head_revision()}\n"


def test_ankle_db_current_upgrade_and_sql(
    fresh: Settings, store: Store, capsys: pytest.CaptureFixture[str]
) -> None:
    head = head_revision()
    out = _ankle(fresh, "db", "current", capsys=capsys)
    assert out == f"revision none (empty database); head {head}; behind: run `ankle db upgrade`\n"
    out = _ankle(fresh, "db", "upgrade", capsys=capsys)
    assert out == f"revision {head}; head {head}; up to date\n"
    assert _ankle(fresh, "db", "current", capsys=capsys) == out

    everything = _ankle(fresh, "db", "sql", capsys=capsys)
    assert "CREATE TABLE audit_log" in everything
    assert "INSERT INTO alembic_version (version_num) VALUES ('0001')" in everything
    later = _ankle(fresh, "db", "sql", "--from", "0002_accounts", capsys=capsys)
    assert "CREATE TABLE audit_log" not in later and f"'{head}'" in later
    assert "CREATE TABLE idempotency_keys" in later  # 0006, after 0002
    grants = _ankle(fresh, "db", "grants", "--role", "ankle_app", capsys=capsys)
    assert 'REVOKE UPDATE, DELETE, TRUNCATE ON audit_log FROM "ankle_app";' in grants
    if store == "postgres":
        assert "ALTER TABLE patients ALTER COLUMN id TYPE BIGINT" in later
        assert "BEFORE UPDATE OR DELETE OR TRUNCATE ON audit_log" in later


@pytest.mark.asyncio
async def test_a_server_that_may_not_migrate_wants_a_current_schema(fresh: Settings) -> None:
    settings = fresh.model_copy(update={"migrate_on_start": False})
    app = create_app(settings)
    with pytest.raises(SchemaNotCurrent, match="ankle db upgrade"):
        async with app.router.lifespan_context(app):
            pass  # pragma: no cover
    engine = create_engine(settings)
    try:
        assert (await revisions(engine)).current is None  # it changed nothing
    finally:
        await engine.dispose()


def test_grants_refuse_a_role_that_is_not_an_identifier(
    fresh: Settings, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.MonkeyPatch.context() as env:
        env.setenv("ANKLE_DATABASE_URL", fresh.database_url)
        assert main(["db", "grants", "--role", "app; DROP TABLE users"]) == 2
    assert "not a plain SQL identifier" in capsys.readouterr().err


@pytest.mark.asyncio
async def test_the_server_role_of_the_grants_cannot_rewrite_the_audit_log(
    seeds: Seeds, tmp_path: Path
) -> None:
    """On PostgreSQL the grants ``ankle db grants`` prints let the server do its work and
    leave its role unable to change the audit log, even with the trigger gone."""
    cluster: Cluster = seeds.cluster
    with on_store(seeds, "postgres", tmp_path) as owner:
        engine = create_engine(owner)
        try:
            await migrate(engine)  # as the owner, as `ankle db upgrade` would
        finally:
            await engine.dispose()
        grants = grants_sql(owner.database_url, "ankle_app")  # `ankle db grants --role ...`
        database = owner.database_url.rsplit("/", 1)[1]
        cluster.psql(
            "DO $$ BEGIN CREATE ROLE ankle_app LOGIN; EXCEPTION WHEN duplicate_object "
            "THEN NULL; END $$"
        )
        cluster.psql(grants, database)
        app_url = owner.database_url.replace("//postgres@", "//ankle_app@")
        settings = owner.model_copy(update={"database_url": app_url, "migrate_on_start": False})
        await ensure_user_async(settings, "t@clinic.test", "T", "therapist", PASSWORD)
        async with running(settings) as live:
            token = await login(live.client, "t@clinic.test")
            r = await live.client.post(
                "/patients", json={"display_name": "Audited"}, headers=bearer(token)
            )
            assert r.status_code == 201, r.text
            cluster.psql("DROP TRIGGER audit_log_append_only ON audit_log", database)
            async with live.sessionmaker() as db:
                for statement in (
                    "UPDATE audit_log SET action = 'forged'",
                    "DELETE FROM audit_log",
                    "TRUNCATE audit_log",
                ):
                    with pytest.raises(DBAPIError, match="permission denied"):
                        await db.execute(text(statement))
                    await db.rollback()
        rows = cluster.psql("SELECT count(*) FROM audit_log WHERE action <> 'forged'", database)
        assert int(rows) >= 2
