"""The live 3D view on the API's port behind a ticket, through a real server on a real port.

viser's page and WebSocket come through ``/scene/{ticket}/`` and nothing without a ticket;
a ticket is issued only to who may watch the station; viser itself listens on loopback only.
"""

from __future__ import annotations

import asyncio
import socket
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import httpx
import msgspec
import pytest
import pytest_asyncio
import viser
import zstandard
from viser._messages import ViewerCameraMessage
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

from server.config import Settings
from tests.server.live_server import (
    Live,
    World,
    bearer,
    copy_seeded,
    login,
    running,
    seeded,
    world,
)
from webui.app import create_app
from webui.assets import CSP, VIEWER_CSP
from webui.live3d import LiveScenes
from webui.replay import CLIENT_HTML

__all__ = ["seeded", "world"]  # the seeded database's fixtures, shared with the server tests

VISER_PROTOCOL = f"viser-v{viser.__version__}"


@pytest_asyncio.fixture
async def dash(seeded: tuple[Path, World], tmp_path: Path) -> AsyncIterator[Live]:
    """The dashboard's server (API and 3D views) on a copy of the seeded database, told to
    listen on every interface: viser must still take loopback only."""
    template, _ = seeded
    settings = Settings(data_dir=copy_seeded(template, tmp_path), host="0.0.0.0")
    async with running(settings, create_app) as live:
        yield live


def origin(live: Live) -> str:
    return f"http://127.0.0.1:{live.client.base_url.port}"


def ws_url(live: Live, path: str) -> str:
    # viser's client opens its WebSocket at the page's address without the trailing slash.
    return f"ws://127.0.0.1:{live.client.base_url.port}{path.rstrip('/')}"


async def ticket(live: Live, token: str, station_id: int) -> str:
    r = await live.client.post(f"/stations/{station_id}/scene/ticket", headers=bearer(token))
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["station_id"] == station_id and body["expires_s"] == 60.0
    path: str = body["path"]
    return path


async def get(live: Live, path: str, **kw: Any) -> httpx.Response:
    return await live.client.get(origin(live) + path, **kw)


def scenes(live: Live) -> LiveScenes:
    s: LiveScenes = live.app.state.scenes
    return s


def decode(frame: bytes) -> dict[str, Any]:
    """One of viser's WebSocket frames: sizes, zstd-compressed msgpack, raw buffers."""
    size = int.from_bytes(frame[:8], "little")
    packed = int.from_bytes(frame[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(frame[16 : 16 + packed], max_output_size=size)
    out: dict[str, Any] = msgspec.msgpack.decode(inner)
    return out


async def node_names(ws: ClientConnection, want: str, timeout: float = 30.0) -> set[str]:
    """Names of the scene nodes viser sends, until ``want`` is among them."""
    names: set[str] = set()
    deadline = time.monotonic() + timeout
    while want not in names:
        frame = await asyncio.wait_for(ws.recv(), max(0.1, deadline - time.monotonic()))
        assert isinstance(frame, bytes), "viser sends binary frames"
        for message in decode(frame)["messages"]:
            name = message.get("name")
            if isinstance(name, str):
                names.add(name)
    return names


async def eventually(condition: Callable[[], bool], failure: str, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, failure
        await asyncio.sleep(0.05)


async def until_closed(ws: ClientConnection) -> None:
    while True:
        await asyncio.wait_for(ws.recv(), 30.0)


def accepts(host: str, port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(5.0)
        return s.connect_ex((host, port)) == 0


@pytest.mark.asyncio
async def test_without_a_ticket_there_is_no_scene(dash: Live, world: World) -> None:
    for path in ("/scene", "/scene/", "/scene/not-a-ticket/", "/scene/not-a-ticket/index.html"):
        r = await get(dash, path)
        assert r.status_code == 403, path
        assert "ticket is missing, expired or revoked" in r.json()["detail"]
        assert r.headers["x-content-type-options"] == "nosniff"
    with pytest.raises(InvalidStatus) as refused:
        await connect(ws_url(dash, "/scene/not-a-ticket/"), subprotocols=[VISER_PROTOCOL])  # type: ignore[list-item]
    assert refused.value.response.status_code == 403
    # The login token is no ticket.
    assert (await get(dash, f"/scene/{world.t1}/")).status_code == 403
    # Nothing was asked of viser: no view was even started.
    assert not scenes(dash).views


@pytest.mark.asyncio
async def test_a_ticket_serves_viser_page_and_websocket_on_the_api_port(
    dash: Live, world: World
) -> None:
    path = await ticket(dash, world.t1, world.s1_id)
    assert path.startswith("/scene/") and path.endswith("/")
    assert len(path.split("/")[2]) >= 43  # 256 random bits

    page = await get(dash, path)
    assert page.status_code == 200
    assert page.headers["content-type"].startswith("text/html")
    assert page.content == CLIENT_HTML.read_bytes()  # viser's own client, whole
    assert page.headers["content-encoding"] == "gzip"  # streamed as viser compressed it
    assert page.headers["content-security-policy"] == VIEWER_CSP
    assert page.headers["x-content-type-options"] == "nosniff"
    assert page.headers["referrer-policy"] == "no-referrer"
    assert page.headers["cache-control"] == "no-store"
    assert "set-cookie" not in page.headers and "server" in page.headers  # uvicorn's, not viser's
    # The client's file by name, and without the slash (a redirect to the page).
    named = await get(dash, path + "index.html")
    assert named.status_code == 200 and named.content == page.content
    bare = await get(dash, path.rstrip("/") + "?hideViserLogo")
    assert bare.status_code == 307
    assert bare.headers["location"] == path.split("/")[2] + "/?hideViserLogo"
    # What is not a plain file name, or not a GET, goes nowhere.
    assert (await get(dash, path + ".hidden")).status_code == 404
    assert (await get(dash, path + "a/%2e%2e/index.html")).status_code == 404
    assert (await get(dash, path + "missing.js")).status_code == 404
    assert (await dash.client.post(origin(dash) + path)).status_code == 405

    # The WebSocket, through the proxy, speaks viser: its version's subprotocol and the scene.
    view = scenes(dash).views[world.s1_id]
    async with connect(
        ws_url(dash, path),
        subprotocols=[VISER_PROTOCOL],  # type: ignore[list-item]
        # A page of the dashboard's own origin, as the server is told it (settings).
        origin=dash.settings.allowed_origins[0],  # type: ignore[arg-type]
        max_size=None,
    ) as ws:
        assert ws.subprotocol == VISER_PROTOCOL
        names = await node_names(ws, "/platform")
        assert {"/base", "/legs", "/ghost"} <= names
        assert view.clients == 1  # the client keeps the view running
        # The other way: the client's camera reaches viser, as the browser's does.
        camera = ViewerCameraMessage(
            wxyz=(1.0, 0.0, 0.0, 0.0),
            position=(0.1, 0.2, 0.3),
            fov=1.0,
            near=0.01,
            far=10.0,
            image_height=480,
            image_width=640,
            look_at=(0.0, 0.0, 0.0),
            up_direction=(0.0, 0.0, 1.0),
        )
        await ws.send(msgspec.msgpack.encode(camera.as_serializable_dict()))
        await eventually(
            lambda: any(
                tuple(c.camera.position) == pytest.approx((0.1, 0.2, 0.3))
                for c in view.server.get_clients().values()
            ),
            "viser never saw the client's camera",
        )

    # viser listens on loopback only, though the API was told every interface.
    assert accepts("127.0.0.1", view.port)
    assert not accepts("127.0.0.2", view.port)
    assert view.port != dash.client.base_url.port


@pytest.mark.asyncio
async def test_only_who_may_watch_the_station_gets_a_ticket(dash: Live, world: World) -> None:
    path = f"/stations/{world.s1_id}/scene/ticket"
    assert (await dash.client.post(path)).status_code == 401
    other = await dash.client.post(path, headers=bearer(world.t2))
    assert other.status_code == 404 and other.json()["detail"] == "station not found"
    missing = await dash.client.post("/stations/999999/scene/ticket", headers=bearer(world.t1))
    assert missing.status_code == 404
    station = await dash.client.post(path, headers=bearer(world.s1))
    assert station.status_code == 403  # a valid token, but a station's: not its route
    # An admin reads every patient: the view too (read-only, as the live view).
    await ticket(dash, world.admin, world.s1_id)
    # A ticket shows one station: t2's ticket for their own opens theirs, not s1's.
    theirs = await ticket(dash, world.t2, world.s2_id)
    assert (await get(dash, theirs)).status_code == 200
    assert set(scenes(dash).views) == {world.s2_id}


@pytest.mark.asyncio
async def test_another_origin_cannot_open_the_view(dash: Live, world: World) -> None:
    path = await ticket(dash, world.t1, world.s1_id)
    with pytest.raises(InvalidStatus) as refused:
        await connect(
            ws_url(dash, path),
            subprotocols=[VISER_PROTOCOL],  # type: ignore[list-item]
            origin="http://evil.example",  # type: ignore[arg-type]
        )
    assert refused.value.response.status_code == 403


@pytest.mark.asyncio
async def test_revoking_a_users_tickets_closes_their_view(dash: Live, world: World) -> None:
    path = await ticket(dash, world.t1, world.s1_id)
    async with connect(
        ws_url(dash, path),
        subprotocols=[VISER_PROTOCOL],  # type: ignore[list-item]
        max_size=None,
    ) as ws:
        await node_names(ws, "/platform")
        # What a credential change calls: the open view closes, the ticket stops working.
        assert dash.app.state.view_tickets.revoke_user(world.t1_id) == 1
        with pytest.raises(ConnectionClosed):
            await until_closed(ws)
        assert ws.close_code == 1008
        assert ws.close_reason == "the 3D view's ticket was revoked"
    assert (await get(dash, path)).status_code == 403
    # The view is no longer held open by that client.
    view = scenes(dash).views[world.s1_id]
    await eventually(lambda: view.clients == 0, "the closed client still holds the view")


@pytest.mark.asyncio
async def test_logging_out_closes_the_3d_view_opened_with_that_sign_in(
    dash: Live, world: World
) -> None:
    token = await login(dash.client, "t1@clinic.test")
    path = await ticket(dash, token, world.s1_id)
    async with connect(
        ws_url(dash, path),
        subprotocols=[VISER_PROTOCOL],  # type: ignore[list-item]
        max_size=None,
    ) as ws:
        await node_names(ws, "/platform")
        began = time.monotonic()
        assert (await dash.client.post("/auth/logout", headers=bearer(token))).status_code == 204
        with pytest.raises(ConnectionClosed):
            await until_closed(ws)
        assert time.monotonic() - began <= 1.0
        assert ws.close_code == 1008
    assert (await get(dash, path)).status_code == 403


@pytest.mark.asyncio
async def test_an_expired_ticket_is_refused(seeded: tuple[Path, World], tmp_path: Path) -> None:
    template, world = seeded
    settings = Settings(data_dir=copy_seeded(template, tmp_path), view_ticket_ttl_s=0.5)
    async with running(settings, create_app) as live:
        r = await live.client.post(
            f"/stations/{world.s1_id}/scene/ticket", headers=bearer(world.t1)
        )
        assert r.status_code == 200 and r.json()["expires_s"] == 0.5
        path = r.json()["path"]
        await asyncio.sleep(1.0)  # past its time, however slowly the machine ran
        assert (await get(live, path)).status_code == 403
        with pytest.raises(InvalidStatus) as refused:
            await connect(ws_url(live, path), subprotocols=[VISER_PROTOCOL])  # type: ignore[list-item]
        assert refused.value.response.status_code == 403


@pytest.mark.asyncio
async def test_the_dashboard_frames_only_this_server(dash: Live) -> None:
    page = await get(dash, "/app/login")
    assert page.headers["content-security-policy"] == CSP
    frames = CSP.split("frame-src", 1)[1].split(";")[0].split()
    assert frames == ["'self'"]
