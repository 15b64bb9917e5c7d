"""A live view that misbehaves costs the server a bounded amount, and tells its client so.

A real uvicorn on a seeded database (``live``) and raw ``websockets`` clients: a viewer that
sends what no dashboard does (a request_id with a NUL, a flood of commands), and viewers
that stop reading what the server sends them. The audit log is read through ``GET /audit``.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import math
import os
import random
import socket
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import pytest
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed

from server import hub as hub_module
from server.hub import COMMAND_BURST, REFUSAL_ROWS_BURST, REFUSAL_ROWS_PER_S, REFUSALS_ACTION
from server.protocols import SEND_STALL_S
from sessions import wire
from tests.server.live_server import Live, World, bearer
from tests.server.ws_client import (
    closed_with,
    sample,
    station_ws,
    viewer_ws,
    welcomed,
    ws_url,
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


# -- a flood of commands ----------------------------------------------------------------------
@pytest.mark.asyncio
@pytest.mark.parametrize("who", ["t1", "admin"])
async def test_a_flood_of_commands_closes_the_link_and_writes_a_few_rows(
    live: Live, world: World, who: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """1,000 K/B changes a second to an offline station (a therapist's, refused OFFLINE; an
    admin's, refused FORBIDDEN) wrote a permanent audit row each. The link is closed past
    its budget, and the refusals beyond a few are counted in one row."""
    monkeypatch.setattr(hub_module, "REFUSAL_SUMMARY_S", 1.0)
    command = {"type": "command", "action": "set_impedance", "stiffness": {"pitch": 40.0}}
    async with viewer_ws(live, world.token(who) or "", world.s1_id) as viewer:
        await welcome_of(viewer)
        began = time.monotonic()
        with contextlib.suppress(ConnectionClosed):
            for n in range(1000):
                await viewer.send(json.dumps(command | {"request_id": f"f-{n}"}))
        code, reason = await closed_with(viewer, WAIT_S)
        flooded_s = time.monotonic() - began
    assert (code, reason) == (
        wire.CLOSE_TOO_FAST,
        "more than 30 commands at once or 10 a second: the link was closed",
    )
    deadline = time.monotonic() + WAIT_S
    while not (counted := await audit(live, world, action=REFUSALS_ACTION)):
        assert time.monotonic() < deadline, "the refusals were never counted"
        await asyncio.sleep(0.1)
    rows = await audit(live, world, action="impedance.refused")
    most = REFUSAL_ROWS_BURST + math.ceil(flooded_s * REFUSAL_ROWS_PER_S)
    assert REFUSAL_ROWS_BURST <= len(rows) <= most, (len(rows), flooded_s)
    (summary,) = counted
    refused = summary["new"]["count"]
    assert COMMAND_BURST <= len(rows) + refused < 100, "refused before the link was closed"
    refusal = "FORBIDDEN" if who == "admin" else "OFFLINE"
    assert summary["new"]["codes"] == {refusal: refused}
    assert summary["new"]["actions"] == {"impedance.refused": refused}
    one_each = {r["new"]["request_id"] for r in rows}
    assert {f"f-{n}" for n in range(REFUSAL_ROWS_BURST)} <= one_each
    assert summary["new"]["first_request_id"] not in one_each
    assert (summary["entity"], summary["entity_id"], summary["patient_id"]) == (
        "station",
        str(world.s1_id),
        world.p1,
    )
    assert summary["actor"] == rows[0]["actor"]
    assert {r["new"]["code"] for r in rows} == {refusal}


@pytest.mark.asyncio
async def test_a_therapist_clicking_fast_is_never_closed(live: Live, world: World) -> None:
    """Each click of HOLD or Resume sends one command: five a second for five seconds (fewer
    than the burst, however the server happens to read them) all go through."""
    async with (
        station_ws(live, world.s1) as station,
        viewer_ws(live, world.t1, world.s1_id) as viewer,
    ):
        await welcomed(station)
        await welcome_of(viewer)
        beats = asyncio.create_task(beat(station, viewer))

        async def answer() -> None:
            async for raw in station:
                message = wire.STATION_DOWN.validate_json(raw)
                if isinstance(message, wire.Command):
                    result = wire.CommandResult(request_id=message.request_id, ok=True)
                    await station.send(result.model_dump_json())

        answering = asyncio.create_task(answer())
        clicks = COMMAND_BURST - 5
        for n in range(clicks):
            action = "hold" if n % 2 == 0 else "resume"
            await viewer.send(
                json.dumps({"type": "command", "request_id": f"c-{n}", "action": action})
            )
            await asyncio.sleep(0.2)
        results: set[str] = set()
        deadline = time.monotonic() + WAIT_S
        while len(results) < clicks:
            left = deadline - time.monotonic()
            assert left > 0, f"{len(results)} of {clicks} answered"
            message = wire.VIEWER_DOWN.validate_json(await asyncio.wait_for(viewer.recv(), left))
            if isinstance(message, wire.CommandResult):
                assert message.ok, message
                results.add(message.request_id)
        beats.cancel()
        answering.cancel()
    assert viewer.close_code in (None, wire.CLOSE_NORMAL)


# -- viewers that stop reading -------------------------------------------------------------
@asynccontextmanager
async def slow_viewer(live: Live, world: World) -> AsyncIterator[ClientConnection]:
    """A viewer that reads nothing until told: its client stops taking frames off the
    socket at the first one waiting (``max_queue=1``), as a stuck browser tab would, and
    its socket's receive buffer is small, as on a slow network (on loopback the kernel
    lets it grow to 32 MB here)."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 64 * 1024)
    sock.connect(("127.0.0.1", live.client.base_url.port or 0))
    sock.setblocking(False)
    async with connect(
        ws_url(live, f"/ws/live/{world.s1_id}"),
        sock=sock,
        subprotocols=[wire.SUBPROTOCOL, f"{wire.BEARER_PREFIX}{world.t1}"],  # type: ignore[list-item]
        max_size=None,
        max_queue=1,
        ping_interval=None,
        open_timeout=30,
    ) as ws:
        yield ws


def viewers_of(live: Live, world: World) -> int:
    return len(live.app.state.hub.viewers.get(world.s1_id, ()))


async def until(what: str, check: Any, timeout: float = WAIT_S) -> None:
    deadline = time.monotonic() + timeout
    while not check():
        assert time.monotonic() < deadline, what
        await asyncio.sleep(0.05)


EVENTS = 1000


def pad() -> str:
    """30 KB that no compression makes smaller (the links use permessage-deflate)."""
    return base64.b64encode(os.urandom(22_500)).decode()


AHEAD = 50
"""Events the station sends beyond those the reading viewer has had: 1.5 MB."""


@pytest.mark.asyncio
async def test_a_viewer_that_falls_behind_is_closed_and_never_misses_events_unknowingly(
    live: Live, world: World
) -> None:
    """A viewer reading nothing while its station sent 1,890 events of 30 KB got 1,140 of
    them, not the 750 in between, and was never closed. Now it gets every event in order
    until it is closed (CLOSE_TOO_SLOW: it reconnects), and one that reads is not touched."""
    async with (
        station_ws(live, world.s1) as station,
        viewer_ws(live, world.t1, world.s1_id) as good,
        slow_viewer(live, world) as slow,
    ):
        await welcomed(station)
        await welcome_of(good)
        await until("both viewers joined", lambda: viewers_of(live, world) == 2)
        beats = asyncio.create_task(beat(station, good, slow))
        seen: list[int] = []

        async def read_all() -> None:
            async for raw in good:
                message = wire.VIEWER_DOWN.validate_json(raw)
                if isinstance(message, wire.EventMsg):
                    seen.append(message.event.detail["seq"])

        reader = asyncio.create_task(read_all())

        for n in range(EVENTS):
            # Never far ahead of the viewer that reads: it keeps up, however loaded the machine.
            await until("the good viewer reads", lambda: n - len(seen) < AHEAD)  # noqa: B023
            event = {"wall": time.time(), "kind": "note", "detail": {"seq": n, "pad": pad()}}
            await station.send(json.dumps({"type": "event", "event": event}))
        await until("the good viewer got every event", lambda: len(seen) == EVENTS)
        assert seen == list(range(EVENTS))
        await until("the slow viewer was let go", lambda: viewers_of(live, world) == 1)
        got: list[int] = []
        with contextlib.suppress(ConnectionClosed):
            while True:
                message = wire.VIEWER_DOWN.validate_json(
                    await asyncio.wait_for(slow.recv(), WAIT_S)
                )
                if isinstance(message, wire.EventMsg):
                    got.append(message.event.detail["seq"])
        beats.cancel()
        reader.cancel()
    assert got == list(range(len(got))) and len(got) < EVENTS, "a gap, or nothing held back"
    # It read everything within SEND_STALL_S of its close: the close itself, with its reason;
    # later, the connection was cut (a client that never reads again cannot get a close).
    assert slow.close_code in (wire.CLOSE_TOO_SLOW, 1006), slow.close_code
    if slow.close_code == wire.CLOSE_TOO_SLOW:
        assert "fell too far behind" in (slow.close_reason or "")


@pytest.mark.asyncio
async def test_a_viewer_that_takes_nothing_is_cut_while_it_still_beats(
    live: Live, world: World
) -> None:
    """Telemetry is never queued, so a viewer that stops reading does not fall behind on
    events: its writer waited on the full socket for good. It is cut after SEND_STALL_S,
    though its heartbeats still come in."""

    def noisy() -> dict[str, Any]:
        """A full batch of samples no compression makes much smaller."""
        six = [[random.uniform(-1, 1) for _ in range(6)] for _ in range(wire.BATCH_MAX)]
        samples = [sample(pose=p, wrench=p, pressures=p + p) for p in six]
        return {"type": "telemetry", "sent": time.time()} | {
            name: [row[name] for row in samples] for name in samples[0]
        }

    async with (
        station_ws(live, world.s1) as station,
        slow_viewer(live, world) as slow,
    ):
        await welcomed(station)
        await until("the viewer joined", lambda: viewers_of(live, world) == 1)
        beats = asyncio.create_task(beat(station, slow))
        began = time.monotonic()
        cut_after = None
        while time.monotonic() - began < WAIT_S:
            await station.send(json.dumps(noisy()))
            await asyncio.sleep(0.005)
            if viewers_of(live, world) == 0:
                cut_after = time.monotonic() - began
                break
        beats.cancel()
    assert cut_after is not None, "the viewer that took nothing was never let go"
    assert cut_after >= SEND_STALL_S
