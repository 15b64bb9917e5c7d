"""The server starts, migrates an empty directory and says it is healthy."""

from __future__ import annotations

import pytest

from tests.server.live_server import Live, World, bearer

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
