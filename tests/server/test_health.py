"""The server starts, migrates an empty directory and says it is healthy."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import httpx
import pytest

from server.config import Settings
from server.routes.health import HEALTH_WAIT_S
from tests.server.live_server import Live, World, bearer, copy_seeded, running
from tests.server.redis_server import spawned_redis

pytestmark = pytest.mark.both_stores


@pytest.mark.sqlite_only
@pytest.mark.asyncio
async def test_health_on_an_empty_data_dir(empty: Live) -> None:
    r = await empty.client.get("/health")
    assert r.status_code == 200
    assert r.json()["database"] is True
    assert (empty.settings.data_dir / "ankle.db").is_file()


@pytest.mark.asyncio
async def test_seeded_world(live: Live, world: World) -> None:
    r = await live.client.get("/patients", headers=bearer(world.t1))
    assert [p["id"] for p in r.json()] == [world.p1]


@pytest.mark.sqlite_only
@pytest.mark.asyncio
async def test_health_names_a_redis_that_is_away_and_never_waits_for_it(
    seeded: tuple[Path, World], tmp_path: Path
) -> None:
    """Each dependency a process needs is in ``/health``: the relay between server
    processes and the shared store of failed sign-ins as well as the database. A Redis
    that stands still (no answer, no error) or is gone is reported down within
    ``HEALTH_WAIT_S``; before, ``/health`` said ok while every sign-in was refused 503."""
    (tmp_path / "redis").mkdir()
    with spawned_redis(tmp_path / "redis") as (proc, url):
        settings = Settings(
            data_dir=copy_seeded(seeded[0], tmp_path / "data"),
            relay_url=f"{url}/0",
            login_throttle_storage=f"{url}/1",
        )
        async with running(settings) as live:
            r = await live.client.get("/health")
            assert r.status_code == 200, r.text
            assert (r.json()["status"], r.json()["relay"], r.json()["login_throttle_storage"]) == (
                "ok",
                True,
                True,
            )
            proc.send_signal(signal.SIGSTOP)
            try:
                started = time.monotonic()
                r = await live.client.get("/health")
                took = time.monotonic() - started
            finally:
                proc.send_signal(signal.SIGCONT)
            print(f"/health with Redis stopped: {took:.2f} s")
            _says_redis_away(r)
            assert took < 2 * HEALTH_WAIT_S
            proc.kill()
            proc.wait()
            _says_redis_away(await live.client.get("/health"))


def _says_redis_away(r: httpx.Response) -> None:
    assert r.status_code == 503, r.text
    body = r.json()
    assert (body["status"], body["database"]) == ("degraded", True)
    assert (body["relay"], body["login_throttle_storage"]) == (False, False)
    assert int(r.headers["Retry-After"]) > 0


@pytest.mark.sqlite_only
@pytest.mark.asyncio
async def test_health_of_one_process_names_no_redis(empty: Live) -> None:
    body = (await empty.client.get("/health")).json()
    assert (body["status"], body["relay"], body["login_throttle_storage"]) == ("ok", None, None)
