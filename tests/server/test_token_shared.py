"""Two stations using one station token: the displaced one steps back, the server audits it
and tells the viewers; a station reconnecting over its own half-open link still gets in at
once, unreported.

A real uvicorn on a seeded database (``live``; two of them on one Redis relay for the link
taken over across processes), the station's own :class:`~station.server_link.ServerLink`
or a raw ``websockets`` station, and a raw viewer. The audit log is read through
``GET /audit`` as a clinic would.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from typing import Any

import pytest
from websockets.asyncio.client import ClientConnection

from server.hub import CONNECTED, TOKEN_SHARED, TOKEN_SHARED_ACTION
from sessions import wire
from station.server_link import DISPLACED_FIRST_S, DISPLACED_NOTICE, ServerLink
from tests.server.live_server import Live, World, bearer
from tests.server.test_relay import Shared, shared, two_servers
from tests.server.ws_client import closed_with, station_ws, viewer_ws

__all__ = ["shared"]  # the fixture, for the test across processes

WAIT_S = 15.0
"""Deadline for anything the server does on its own (a shared 2-core machine)."""
QUIET_S = 3.0
"""How long the displaced station is watched not to come back: its own reconnection would
come within 1 s (``RECONNECT_FIRST_S``), its step back takes a minute and more."""


def hello(instance: str, displaced: int = 0) -> str:
    return wire.StationHello(
        protocol=wire.PROTOCOL, software="test-station", instance=instance, displaced=displaced
    ).model_dump_json()


async def joined(ws: ClientConnection, instance: str, displaced: int = 0) -> None:
    await ws.send(hello(instance, displaced))
    welcome = wire.STATION_DOWN.validate_json(await asyncio.wait_for(ws.recv(), WAIT_S))
    assert isinstance(welcome, wire.Welcome), welcome


async def presence_where(view: ClientConnection, want: Callable[[str], bool]) -> wire.Presence:
    """The next Presence whose text ``want`` accepts, reading past everything else."""
    deadline = time.monotonic() + WAIT_S
    while True:
        left = deadline - time.monotonic()
        assert left > 0, "the presence did not come"
        message = wire.VIEWER_DOWN.validate_json(await asyncio.wait_for(view.recv(), left))
        if isinstance(message, wire.Presence) and want(message.text):
            return message


async def audit_rows(live: Live, world: World, action: str) -> list[dict[str, Any]]:
    r = await live.client.get(
        "/audit",
        params={"station_id": world.s1_id, "action": action},
        headers=bearer(world.admin),
    )
    assert r.status_code == 200, r.text
    rows: list[dict[str, Any]] = r.json()
    return rows


async def until_audited(live: Live, world: World, action: str) -> list[dict[str, Any]]:
    deadline = time.monotonic() + WAIT_S
    while not (rows := await audit_rows(live, world, action)):
        assert time.monotonic() < deadline, f"no {action} row"
        await asyncio.sleep(0.05)
    return rows


def station_hello() -> wire.StationHello:
    return wire.StationHello(protocol=wire.PROTOCOL, software="test-station")


async def ignore(message: Any) -> None:
    return None


@asynccontextmanager
async def running_link(live: Live, token: str) -> AsyncIterator[ServerLink]:
    url = f"http://127.0.0.1:{live.client.base_url.port}"  # the links are not under /api/v1
    link = ServerLink(url, token, station_hello, ignore)
    task = asyncio.create_task(link.run())
    try:
        yield link
    finally:
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task


async def until(done: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not done():
        assert time.monotonic() < deadline, what
        await asyncio.sleep(0.02)


@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_a_displaced_station_steps_back_and_the_server_says_two_use_its_token(
    live: Live, world: World
) -> None:
    async with viewer_ws(live, world.t1, world.s1_id) as view:
        wire.VIEWER_DOWN.validate_json(await asyncio.wait_for(view.recv(), WAIT_S))  # welcome
        async with running_link(live, world.s1) as first:
            async with asyncio.timeout(WAIT_S):
                await first.connected.wait()
            async with running_link(live, world.s1) as second:
                await until(lambda: first.displaced == 1, "the first station was not displaced")
                # It steps back for a minute and more, and tells the patient's page why.
                assert first.retry_in >= DISPLACED_FIRST_S
                assert first.notice == DISPLACED_NOTICE
                assert not first.connected.is_set()
                # The therapist is told, in the words of the presence, not a bare "online".
                presence = await presence_where(view, lambda text: text == TOKEN_SHARED)
                assert presence.online and presence.warning
                rows = await until_audited(live, world, TOKEN_SHARED_ACTION)
                assert len(rows) == 1, rows
                assert rows[0]["new"]["seen"] == "took_over"
                assert rows[0]["patient_id"] == world.p1
                # Where the therapist looks for what needs attention.
                r = await live.client.get("/patients/attention", headers=bearer(world.t1))
                shared = [i for i in r.json() if i["kind"] == "token_shared"]
                assert [(i["station_id"], i["link"]) for i in shared] == [
                    (world.s1_id, f"/app/patients/{world.p1}")
                ], shared
                assert "Two stations used the token" in shared[0]["text"]
                # Neither takes the link back: one connection each, however long we look.
                await asyncio.sleep(QUIET_S)
                assert (first.connects, second.connects) == (1, 1)
                assert second.connected.is_set() and second.displaced == 0
                assert len(await audit_rows(live, world, TOKEN_SHARED_ACTION)) == 1


@pytest.mark.asyncio
async def test_a_station_reconnecting_over_its_own_half_open_link_gets_in_unreported(
    live: Live, world: World
) -> None:
    async with viewer_ws(live, world.t1, world.s1_id) as view:
        wire.VIEWER_DOWN.validate_json(await asyncio.wait_for(view.recv(), WAIT_S))  # welcome
        async with station_ws(live, world.s1) as half_open:
            await joined(half_open, "run-1")
            await presence_where(view, lambda text: text == CONNECTED)
            # The network dropped; the server still holds the old link. Same run: it gets in.
            async with station_ws(live, world.s1) as again:
                await joined(again, "run-1")
                code, _ = await closed_with(half_open, WAIT_S)
                assert code == wire.CLOSE_REPLACED
                presence = await presence_where(view, lambda text: True)
                assert presence.online and presence.text == CONNECTED and not presence.warning
                # A HOLD's request row is queued after any row of the reconnection: once it
                # is stored, a row of a token used twice would be too.
                hold = wire.Command(request_id="after-reconnect", action="hold")
                await view.send(hold.model_dump_json())
                got = wire.STATION_DOWN.validate_json(await asyncio.wait_for(again.recv(), WAIT_S))
                while not isinstance(got, wire.Command):
                    got = wire.STATION_DOWN.validate_json(
                        await asyncio.wait_for(again.recv(), WAIT_S)
                    )
                await until_audited(live, world, "hold.request")
                assert await audit_rows(live, world, TOKEN_SHARED_ACTION) == []


@pytest.mark.asyncio
async def test_a_hello_saying_the_station_was_displaced_is_audited_and_told(
    live: Live, world: World
) -> None:
    """The displaced station, back after its step back while the other has gone: the server
    hears from its hello alone that its token was used twice."""
    async with viewer_ws(live, world.t1, world.s1_id) as view:
        wire.VIEWER_DOWN.validate_json(await asyncio.wait_for(view.recv(), WAIT_S))  # welcome
        async with station_ws(live, world.s1) as ws:
            await joined(ws, "run-2", displaced=3)
            presence = await presence_where(view, lambda text: True)
            assert presence.online and presence.text == TOKEN_SHARED
            rows = await until_audited(live, world, TOKEN_SHARED_ACTION)
            assert [(r["new"]["seen"], r["new"]["displaced"]) for r in rows] == [("reported", 3)]


@pytest.mark.asyncio
async def test_an_older_station_naming_no_run_still_connects(live: Live, world: World) -> None:
    async with station_ws(live, world.s1) as ws:
        old = wire.StationHello(protocol=wire.PROTOCOL_OLDEST, software="older station")
        await ws.send(old.model_dump_json(exclude={"instance", "displaced"}))
        welcome = wire.STATION_DOWN.validate_json(await asyncio.wait_for(ws.recv(), WAIT_S))
        assert isinstance(welcome, wire.Welcome), welcome


@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_a_second_station_on_another_server_process_is_found_out(shared: Shared) -> None:
    """The older link's process compares the two runs and tells the newer's, which holds the
    link now: its viewers everywhere are told, and the row is written once."""
    world = shared.world
    async with (
        two_servers(shared) as (a, b),
        viewer_ws(a, world.t1, world.s1_id) as view,
    ):
        wire.VIEWER_DOWN.validate_json(await asyncio.wait_for(view.recv(), WAIT_S))  # welcome
        async with station_ws(a, world.s1) as first:
            await joined(first, "run-a")
            await presence_where(view, lambda text: text == CONNECTED)
            async with station_ws(b, world.s1) as second:
                await joined(second, "run-b")
                code, _ = await closed_with(first, WAIT_S)
                assert code == wire.CLOSE_REPLACED
                presence = await presence_where(view, lambda text: text == TOKEN_SHARED)
                assert presence.online
                rows = await until_audited(a, world, TOKEN_SHARED_ACTION)
                assert [r["new"]["seen"] for r in rows] == ["took_over"]
