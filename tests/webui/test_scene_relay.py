"""The live 3D view across server processes: two dashboards on one database and a real Redis.

A reverse proxy may send the ticket request to one process and the page, its WebSocket and
the station to others: the ticket is valid on each, the view on one process draws a station
connected to another, and a logout on one ends the view on the other.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

import pytest
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

from server.config import Settings
from tests.server.live_server import Live, World, bearer, copy_seeded, login, running, seeded
from tests.server.redis_server import redis_server, relay_url
from tests.server.test_relay import stream
from tests.server.ws_client import station_ws, welcomed
from tests.webui.test_sceneproxy import (
    VISER_PROTOCOL,
    eventually,
    get,
    node_names,
    scenes,
    ticket,
    until_closed,
    ws_url,
)
from webui.app import create_app

__all__ = ["redis_server", "relay_url", "seeded"]  # fixtures shared with the server tests

CLOSE_WITHIN_S = 3.0
"""Within a second of the logout, with room for a loaded machine."""


@asynccontextmanager
async def two_dashboards(
    seeded: tuple[Path, World], tmp_path: Path, relay_url: str
) -> AsyncIterator[tuple[Live, Live]]:
    data_dir = copy_seeded(seeded[0], tmp_path / "data")
    settings = Settings(data_dir=data_dir, relay_url=relay_url)
    async with running(settings, create_app) as a, running(settings, create_app) as b:
        yield a, b


@pytest.mark.asyncio
async def test_a_ticket_from_one_process_opens_the_view_on_another_until_logout(
    seeded: tuple[Path, World], tmp_path: Path, relay_url: str
) -> None:
    world = seeded[1]
    async with (
        two_dashboards(seeded, tmp_path, relay_url) as (a, b),
        station_ws(a, world.s1) as station,
    ):
        await welcomed(station)
        token = await login(a.client, "t1@clinic.test")
        path = await ticket(a, token, world.s1_id)  # issued by A
        page = await get(b, path)  # loaded from B
        assert page.status_code == 200, page.text
        assert page.headers["content-type"].startswith("text/html")
        streaming = asyncio.create_task(stream(station, t=3.0))
        try:
            async with connect(
                ws_url(b, path),
                subprotocols=[VISER_PROTOCOL],  # type: ignore[list-item]
                max_size=None,
            ) as ws:
                await node_names(ws, "/platform")
                # B's view draws the telemetry of the station connected to A.
                view = scenes(b).views[world.s1_id]
                await eventually(lambda: view.scene.updates > 0, "B's 3D view drew nothing")
                began = time.monotonic()
                r = await a.client.post("/auth/logout", headers=bearer(token))
                assert r.status_code == 204
                with pytest.raises(ConnectionClosed):
                    await until_closed(ws)
                assert time.monotonic() - began <= CLOSE_WITHIN_S
                assert ws.close_code == 1008
        finally:
            streaming.cancel()
        assert (await get(b, path)).status_code == 403
        assert (await get(a, path)).status_code == 403


@pytest.mark.asyncio
async def test_without_a_relay_a_ticket_is_known_to_its_own_process_only(
    seeded: tuple[Path, World], tmp_path: Path
) -> None:
    """What the relay is for: two processes without one do not share tickets."""
    world = seeded[1]
    settings = Settings(data_dir=copy_seeded(seeded[0], tmp_path / "data"))
    async with running(settings, create_app) as a, running(settings, create_app) as b:
        path = await ticket(a, world.t1, world.s1_id)
        assert (await get(b, path)).status_code == 403
        assert (await get(a, path)).status_code == 200
