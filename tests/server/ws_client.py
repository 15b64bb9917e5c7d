"""Raw WebSocket clients of the live links, as a station and as a browser would speak."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed

from sessions import wire
from tests.server.live_server import Live

HELLO = wire.StationHello(protocol=wire.PROTOCOL, software="test-station").model_dump_json()


def ws_url(live: Live, path: str) -> str:
    return f"ws://127.0.0.1:{live.client.base_url.port}{path}"


@asynccontextmanager
async def station_ws(
    live: Live, token: str, headers: dict[str, str] | None = None
) -> AsyncIterator[ClientConnection]:
    async with connect(
        ws_url(live, "/ws/station"),
        additional_headers={"Authorization": f"Bearer {token}", **(headers or {})},
        max_size=None,  # the test reads what the server sends, whatever its size
        ping_interval=None,
        open_timeout=30,  # a loaded machine's server answers late, not never
    ) as ws:
        yield ws


@asynccontextmanager
async def viewer_ws(
    live: Live, token: str, station_id: int, headers: dict[str, str] | None = None
) -> AsyncIterator[ClientConnection]:
    async with connect(
        ws_url(live, f"/ws/live/{station_id}"),
        subprotocols=[wire.SUBPROTOCOL, f"{wire.BEARER_PREFIX}{token}"],  # type: ignore[list-item]
        additional_headers=headers,
        ping_interval=None,
        open_timeout=30,  # a loaded machine's server answers late, not never
    ) as ws:
        yield ws


async def close_of(ws: ClientConnection, timeout: float) -> tuple[int, str] | None:
    """Read (and drop) whatever comes until the server closes: its code and reason; None if
    the link is still open after ``timeout``."""
    deadline = time.monotonic() + timeout
    try:
        while (left := deadline - time.monotonic()) > 0:
            await asyncio.wait_for(ws.recv(), left)
    except TimeoutError:
        return None
    except ConnectionClosed:
        assert ws.close_code is not None
        return ws.close_code, ws.close_reason or ""
    return None


async def closed_with(ws: ClientConnection, timeout: float = 3.0) -> tuple[int, str]:
    closed = await close_of(ws, timeout)
    assert closed is not None, f"the server did not close the link within {timeout} s"
    return closed


async def welcomed(ws: ClientConnection) -> wire.Welcome:
    """Say hello as a station; the server's welcome (its prescriptions are read past)."""
    await ws.send(HELLO)
    welcome = wire.STATION_DOWN.validate_json(await asyncio.wait_for(ws.recv(), 5))
    assert isinstance(welcome, wire.Welcome), welcome
    return welcome


def sample(**change: Any) -> dict[str, Any]:
    """One sample's fields (a TelemetryMsg but ``type`` and ``sent``), at rest, READY."""
    six = [0.0] * 6
    body: dict[str, Any] = {
        "t": 1.0,
        "mode": "READY",
        "trip": 0,
        "segment_id": 0,
        "set": 0,
        "rep": 0,
        "pose": six,
        "pose_cmd": six,
        "legs": six,
        "pressures": [0.0] * 12,
        "wrench": six,
        "stiffness": six,
        "damping": six,
        "lag_ms": 0.0,
        "overruns": 0,
        "frames_dropped": 0,
    }
    return body | change


def telemetry(**change: Any) -> dict[str, Any]:
    """A telemetry message as a station sends it: a batch of one sample with ``change``
    (JSON-ready, so that tests can also send what validation would refuse)."""
    one = sample(**change)
    return {"type": "telemetry", "sent": time.time()} | {k: [v] for k, v in one.items()}
