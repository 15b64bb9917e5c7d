"""The live 3D view on the API's port, behind a ticket: viser's page and WebSocket, proxied.

Each watched station's viser server listens on loopback only (:mod:`webui.live3d`). A browser
reaches it at ``/scene/{ticket}/`` on the API's own port, so the dashboard works through one
HTTPS reverse proxy on one port, and without a ticket there is no scene. The ticket comes from
``POST /api/v1/stations/{id}/scene/ticket`` (:mod:`webui.routes`), which checks the user's
access to the station; it names one station (:mod:`server.tickets`).

- ``GET /scene/{ticket}/{path}``: viser's page (``index.html``, its only file: scripts, styles
  and the WebAssembly are inside it), streamed from the station's viser server. Only GET,
  only a plain relative path, and only the headers a static file needs, both ways.
- ``WebSocket /scene/{ticket}``: viser's client opens its WebSocket at the page's URL without
  the query and the trailing slash. Binary frames both ways, viser's version subprotocol
  passed through. The connection keeps the ticket and the view alive, and closes when the
  ticket is revoked or the view stops (the client then reconnects by itself, to a view started
  again, while its ticket lives).

A wrong, expired or revoked ticket is answered 403 with a sentence (a WebSocket is refused
before it is accepted, which a browser sees as 403), and nothing is asked of viser.
"""

from __future__ import annotations

import asyncio
import contextlib
import re
from collections.abc import AsyncIterator
from typing import Any

import httpx
from fastapi import APIRouter, FastAPI, Request, WebSocket
from fastapi.responses import JSONResponse, Response, StreamingResponse
from starlette.websockets import WebSocketDisconnect
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, WebSocketException

from server.hub import Hub
from server.live import origin_ok
from server.tickets import Ticket, ViewTickets
from sessions import wire
from webui.assets import VIEWER_CSP
from webui.live3d import VIEW_HOST, LiveScenes

SCENE_PREFIX = "/scene"

STATION = "station"
"""The kind of subject a live 3D view's ticket names."""

VISER_MAX_MESSAGE = 50 * 1024 * 1024
"""viser's own limit on a WebSocket message (it sends scenes with meshes in one)."""
CONNECT_TIMEOUT_S = 10.0
"""Opening the loopback connection to a view just started, on a busy machine."""

_FILE = re.compile(r"^([A-Za-z0-9_-][A-Za-z0-9._-]*/)*[A-Za-z0-9_-][A-Za-z0-9._-]*$")
"""A relative path of plain names, none starting with a dot: nothing to escape the client's
folder with, nothing to decode differently on the way."""
REQUEST_HEADERS = ("accept", "accept-encoding", "if-none-match", "if-modified-since")
RESPONSE_HEADERS = ("content-type", "content-length", "content-encoding", "etag", "last-modified")

REFUSED = (
    "the 3D view's ticket is missing, expired or revoked: open the live view again for a new one"
)


def scene_path(ticket: Ticket) -> str:
    """Where the browser opens the 3D view a ticket shows."""
    return f"{SCENE_PREFIX}/{ticket.value}/"


async def _station(app: FastAPI, value: str) -> tuple[Ticket, int] | None:
    hub: Hub = app.state.hub
    ticket = await hub.ticket(value)  # issued here, or by another server process
    if ticket is None or ticket.subject[0] != STATION:
        return None
    return ticket, ticket.subject[1]


def _refused(status: int, detail: str) -> JSONResponse:
    return JSONResponse({"detail": detail}, status)


router = APIRouter(include_in_schema=False)


@router.get(SCENE_PREFIX)
@router.get(SCENE_PREFIX + "/")
async def no_ticket() -> JSONResponse:
    return _refused(403, REFUSED)


@router.get(SCENE_PREFIX + "/{ticket}/{path:path}")
async def scene_file(ticket: str, path: str, request: Request) -> Response:
    found = await _station(request.app, ticket)
    if found is None:
        return _refused(403, REFUSED)
    if path and not _FILE.match(path):
        return _refused(404, "the 3D view has no such file: a path is plain names only")
    scenes: LiveScenes = request.app.state.scenes
    view = await scenes.open(found[1])
    client: httpx.AsyncClient = request.app.state.scene_http
    upstream = client.build_request(
        "GET",
        f"http://{VIEW_HOST}:{view.port}/{path}",
        headers={k: v for k in REQUEST_HEADERS if (v := request.headers.get(k)) is not None},
    )
    try:
        answer = await client.send(upstream, stream=True)
    except httpx.TransportError:
        return _refused(503, "the 3D view stopped while loading: load the page again")
    headers = {k: v for k in RESPONSE_HEADERS if (v := answer.headers.get(k)) is not None}
    return StreamingResponse(
        _body(answer),
        status_code=answer.status_code,
        headers=headers
        | {
            "Content-Security-Policy": VIEWER_CSP,
            # The ticket is in the URL: never cached, never sent on as a referrer.
            "Cache-Control": "no-store",
            "Referrer-Policy": "no-referrer",
        },
    )


async def _body(answer: httpx.Response) -> AsyncIterator[bytes]:
    """The upstream body as it comes (still compressed, if it was), closed however the
    answer ends: a browser that goes away mid-page must not leave the connection open."""
    try:
        async for chunk in answer.aiter_raw():
            yield chunk
    finally:
        await answer.aclose()


@router.get(SCENE_PREFIX + "/{ticket}")
async def scene_root(ticket: str, request: Request) -> Response:
    """The page's address without its slash: viser's client needs the slash, since it makes
    its WebSocket's address by dropping one."""
    if await _station(request.app, ticket) is None:
        return _refused(403, REFUSED)
    query = f"?{request.url.query}" if request.url.query else ""
    return Response(status_code=307, headers={"Location": f"{ticket}/{query}"})


@router.websocket(SCENE_PREFIX + "/{ticket}")
async def scene_socket(ws: WebSocket, ticket: str) -> None:
    found = await _station(ws.app, ticket)
    if found is None or not origin_ok(ws):
        await ws.close(wire.CLOSE_POLICY)
        return
    held, station_id = found
    tickets: ViewTickets = ws.app.state.view_tickets
    scenes: LiveScenes = ws.app.state.scenes
    offered = [p for p in ws.scope.get("subprotocols", []) if p.startswith("viser-v")]
    with tickets.using(held):
        async with scenes.client(station_id) as view:
            try:
                upstream = await connect(
                    f"ws://{VIEW_HOST}:{view.port}/",
                    subprotocols=offered,
                    proxy=None,  # loopback: never through a proxy from the environment
                    compression=None,  # as viser's server: compressing scenes is too slow
                    max_size=VISER_MAX_MESSAGE,
                    open_timeout=CONNECT_TIMEOUT_S,
                )
            except (OSError, TimeoutError, WebSocketException):
                await ws.accept()
                await ws.close(1011, "the 3D view is not running: it will be tried again")
                return
            async with upstream:
                await ws.accept(subprotocol=upstream.subprotocol)
                await _relay(ws, upstream, held)


async def _relay(ws: WebSocket, upstream: ClientConnection, ticket: Ticket) -> None:
    """Frames both ways until either side closes or the ticket is revoked."""

    async def down() -> None:
        async for message in upstream:
            if isinstance(message, bytes):
                await ws.send_bytes(message)
            else:
                await ws.send_text(message)

    async def up() -> None:
        while True:
            message = await ws.receive()
            if message["type"] == "websocket.disconnect":
                return
            data: Any = message.get("bytes")
            if data is None:
                data = message.get("text")
            if data is not None:
                await upstream.send(data)

    tasks = {
        asyncio.create_task(down(), name="scene-down"),
        asyncio.create_task(up(), name="scene-up"),
        asyncio.create_task(ticket.ended.wait(), name="scene-ticket"),
    }
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            task.cancel()
        # Either side may already be gone: its closing is what ended the relay.
        await asyncio.gather(*tasks, return_exceptions=True)
    if ticket.ended.is_set():
        code, reason = wire.CLOSE_POLICY, "the 3D view's ticket was revoked"
    else:
        code, reason = _close_code(upstream.close_code), upstream.close_reason or ""
    with contextlib.suppress(RuntimeError, WebSocketDisconnect, ConnectionClosed, OSError):
        await ws.close(code, reason)


_SENDABLE = frozenset((1000, 1001, 1002, 1003, 1007, 1008, 1009, 1011))


def _close_code(code: int | None) -> int:
    """viser's close code for the browser when it may be sent (1002 tells viser's client its
    version does not match), else 1011."""
    if code is not None and (code in _SENDABLE or 3000 <= code <= 4999):
        return code
    return 1011
