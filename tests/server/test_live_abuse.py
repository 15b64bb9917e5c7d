"""A live view that misbehaves costs the server a bounded amount, and tells its client so.

A real uvicorn on a seeded database (``live``) and raw ``websockets`` clients: a viewer that
sends what no dashboard does (a request_id with a NUL). The audit log is read through
``GET /audit``.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from typing import Any

import pytest
from websockets.asyncio.client import ClientConnection
from websockets.exceptions import ConnectionClosed

from sessions import wire
from tests.server.live_server import Live, World, bearer
from tests.server.ws_client import (
    closed_with,
    station_ws,
    viewer_ws,
    welcomed,
)

WAIT_S = 30.0
"""Deadline for anything the server does on its own (a shared 2-core machine)."""


async def audit(live: Live, world: World, **params: Any) -> list[dict[str, Any]]:
    r = await live.client.get(
        "/audit", params={"limit": 500, **params}, headers=bearer(world.admin)
    )
    assert r.status_code == 200, r.text
    rows: list[dict[str, Any]] = r.json()
    return rows


async def commands(live: Live, world: World) -> list[dict[str, Any]]:
    """The audit rows of the live commands to station s1, newest first."""
    rows = await audit(live, world, station_id=world.s1_id)
    return [r for r in rows if "request_id" in (r["new"] or {})]


async def beat(*links: ClientConnection) -> None:
    """Heartbeats on each link, so that none is closed as silent."""
    while True:
        for ws in links:
            with contextlib.suppress(ConnectionClosed):
                await ws.send(wire.Heartbeat(sent=time.time()).model_dump_json())
        await asyncio.sleep(wire.HEARTBEAT_S / 2)


async def welcome_of(ws: ClientConnection) -> wire.Welcome:
    welcome = wire.VIEWER_DOWN.validate_json(await asyncio.wait_for(ws.recv(), WAIT_S))
    assert isinstance(welcome, wire.Welcome), welcome
    return welcome


# -- request ids ----------------------------------------------------------------------------
@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_a_control_character_in_a_request_id_or_an_answer_closes_the_link(
    live: Live, world: World
) -> None:
    """What a command and its answer carry goes into the audit log: no NUL gets there."""
    async with viewer_ws(live, world.t1, world.s1_id) as viewer:
        await welcome_of(viewer)
        await viewer.send(
            json.dumps({"type": "command", "request_id": "nul\0id", "action": "hold"})
        )
        code, reason = await closed_with(viewer, WAIT_S)
    assert code == wire.CLOSE_MALFORMED
    assert reason.startswith("command.request_id: must be 1 to 64 letters"), reason
    assert await commands(live, world) == [], "nothing was recorded"

    # A station's answer goes into the audit log as it is: no control character in it.
    async with station_ws(live, world.s1) as station:
        await welcomed(station)
        bad = {"type": "result", "request_id": "r-1", "ok": False, "text": "no\0pe"}
        await station.send(json.dumps(bad))
        code, reason = await closed_with(station, WAIT_S)
    assert (code, reason) == (
        wire.CLOSE_MALFORMED,
        "result.text: must not contain control characters (U+0000 at character 3)",
    )


@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_a_nul_stored_in_an_audit_row_breaks_no_look_up(live: Live, world: World) -> None:
    """A row stored before request_ids and answers were held to their rules stays for good
    (the log is append-only): on PostgreSQL every ``?request_id=`` look-up was then a 500
    ("\\u0000 cannot be converted to text"), whichever string of the row held it."""
    writer = live.app.state.hub.writer
    stored = {"request_id": "nul\0id", "code": "OFFLINE", "field": "", "text": "off\0line"}
    row = {"actor": f"user:{world.t1_id}", "entity": "station", "entity_id": world.s1_id}
    await writer.write(**row, action="resume.refused", patient_id=world.p1, old=None, new=stored)
    await writer.write(
        **row, action="hold.request", patient_id=world.p1, old=None, new={"request_id": "abc"}
    )
    (found,) = await audit(live, world, request_id="abc")
    assert found["action"] == "hold.request"
    assert await audit(live, world, request_id="nothing-such") == []
    assert [r["new"]["request_id"] for r in await commands(live, world)] == ["abc", "nul\0id"]
    # Asking for the NUL itself is a 422, not a look-up.
    r = await live.client.get(
        "/audit", params={"request_id": "nul\0id"}, headers=bearer(world.admin)
    )
    assert r.status_code == 422, r.text


def test_the_dashboards_request_ids_are_valid() -> None:
    """webui/static/js/live.js: ``<ms since 1970, base 36>-<counter>-<6 random base 36>``."""
    for request_id in ("mbx3k2lq-1-a8f3k2", "zzzzzzzzz-123456-zzzzzz", "page-1", "h12-99"):
        wire.Command(request_id=request_id, action="hold")
