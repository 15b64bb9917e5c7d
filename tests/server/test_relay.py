"""Two server processes sharing one SQLite file and a real Redis relay.

Each server is its own app with its own hub and relay (two uvicorn servers in this test's
loop, or a separate process where one must be killed): nothing passes between them but
Redis and the database. A raw WebSocket client speaks the station protocol on one; a
viewer watches from the other.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Callable
from contextlib import AsyncExitStack, asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
from websockets.asyncio.client import ClientConnection

from server.config import Settings
from sessions import wire
from sessions.recording import SessionEvent
from tests.server.live_server import (
    STRENGTH,
    Live,
    Seeds,
    Store,
    World,
    bearer,
    copy_seeded,
    login,
    on_store,
    running,
)
from tests.server.redis_server import free_port, spawned_redis
from tests.server.ws_client import (
    closed_with,
    station_ws,
    telemetry,
    viewer_ws,
    welcomed,
)

WAIT_S = 15.0
"""Deadline for what crosses processes, on a shared 2-core machine."""
CLOSE_WITHIN_S = 3.0
"""Links close "within a second" of a change on another process; the test allows for load."""
LEASE_S = 1.5


def settings(data_dir: Path, relay_url: str) -> Settings:
    return Settings(data_dir=data_dir, relay_url=relay_url, relay_lease_s=LEASE_S)


@dataclass(frozen=True)
class Shared:
    """What two server processes share in a test: a copy of the seeded world on the test's
    store, and the relay."""

    seeds: Seeds
    store: Store
    seeded: tuple[Path | str, World]
    tmp_path: Path
    relay_url: str

    @property
    def world(self) -> World:
        return self.seeded[1]


@pytest.fixture
def shared(
    seeds: Seeds,
    store: Store,
    seeded_store: tuple[Path | str, World],
    tmp_path: Path,
    relay_url: str,
) -> Shared:
    return Shared(seeds, store, seeded_store, tmp_path, relay_url)


@asynccontextmanager
async def two_servers(shared: Shared) -> AsyncIterator[tuple[Live, Live]]:
    """Two servers on one copy of the seeded world (a SQLite file or a PostgreSQL database)
    and one Redis."""
    data_dir = shared.tmp_path / "data"
    with on_store(shared.seeds, shared.store, data_dir, shared.seeded[0]) as base:
        relayed = base.model_copy(update={"relay_url": shared.relay_url, "relay_lease_s": LEASE_S})
        async with running(relayed) as a, running(relayed) as b:
            assert a.app.state.hub is not b.app.state.hub
            assert a.app.state.hub.relay is not b.app.state.hub.relay
            yield a, b


async def next_where(
    ws: ClientConnection, want: Callable[[Any], bool], parse: Any = wire.VIEWER_DOWN
) -> Any:
    """The next message ``want`` accepts, reading past the others."""
    deadline = time.monotonic() + WAIT_S
    while True:
        left = deadline - time.monotonic()
        assert left > 0, "the message did not come"
        message = parse.validate_json(await asyncio.wait_for(ws.recv(), left))
        if want(message):
            return message


def is_(kind: type[Any]) -> Callable[[Any], bool]:
    return lambda m: isinstance(m, kind)


async def online(live: Live, token: str, station_id: int) -> bool:
    r = await live.client.get("/stations", headers=bearer(token))
    assert r.status_code == 200, r.text
    return bool({s["id"]: s["online"] for s in r.json()}[station_id])


async def until_online(live: Live, token: str, station_id: int, expected: bool) -> float:
    """Seconds until ``GET /stations`` says ``expected`` for the station."""
    began = time.monotonic()
    while await online(live, token, station_id) != expected:
        assert time.monotonic() - began < WAIT_S, f"station {station_id} never {expected}"
        await asyncio.sleep(0.05)
    return time.monotonic() - began


async def until_audited(live: Live, token: str, request_id: str, expected: list[str]) -> None:
    """Wait until the command's audit rows are ``expected`` (actions, sorted): outcomes are
    written just after the answer is relayed."""
    deadline = time.monotonic() + WAIT_S
    while True:
        r = await live.client.get(
            "/audit", params={"request_id": request_id}, headers=bearer(token)
        )
        assert r.status_code == 200, r.text
        actions = sorted(row["action"] for row in r.json())
        if actions == expected:
            return
        assert time.monotonic() < deadline, actions
        await asyncio.sleep(0.1)


async def stream(ws: ClientConnection, t: float) -> None:
    """Telemetry batches 25 times a second with device time ``t``, as a station sends them."""
    message = wire.TelemetryBatch.model_validate(telemetry(t=t)).model_dump_json()
    while True:
        await ws.send(message)
        await asyncio.sleep(0.04)


def command(request_id: str) -> str:
    return wire.Command(
        request_id=request_id, action="set_impedance", stiffness={"pitch": 12.0}
    ).model_dump_json()


@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_a_station_on_one_process_is_seen_and_commanded_from_another(
    shared: Shared,
) -> None:
    world = shared.world
    async with (
        two_servers(shared) as (a, b),
        station_ws(a, world.s1) as station,
    ):
        await welcomed(station)
        status = wire.StatusMsg(sent=time.time(), device_link="connected", device_mode="READY")
        await station.send(status.model_dump_json())
        # Both processes agree on who is online.
        for live in (a, b):
            await until_online(live, world.t1, world.s1_id, True)
            assert not await online(live, world.t1, world.s1_spare_id)
        async with viewer_ws(b, world.t1, world.s1_id) as view, AsyncExitStack() as stack:
            welcome = await next_where(view, is_(wire.Welcome))
            assert welcome.online and welcome.patient_id == world.p1
            assert welcome.status is not None and welcome.status.device_mode == "READY"
            streaming = asyncio.create_task(stream(station, t=42.5))
            stack.callback(streaming.cancel)
            batch = await next_where(view, is_(wire.TelemetryBatch))
            assert batch.newest().t == 42.5
            event = wire.StatusMsg(sent=time.time(), device_link="connected", device_mode="HOLD")
            await station.send(event.model_dump_json())
            got = await next_where(view, is_(wire.StatusMsg))
            assert got.device_mode == "HOLD"
            rep = wire.EventMsg(event=SessionEvent(wall=time.time(), kind="rep_done"))
            await station.send(rep.model_dump_json())
            assert (await next_where(view, is_(wire.EventMsg))).event.kind == "rep_done"

            # A K/B from the viewer on B reaches the station on A, and its answer comes back.
            await view.send(command("kb-1"))
            cmd = await next_where(station, is_(wire.Command), wire.STATION_DOWN)
            assert cmd.request_id == "kb-1" and cmd.by == f"therapist:{world.t1_id}"
            # While it is unanswered, the same request_id from a viewer on A is refused.
            async with viewer_ws(a, world.t1, world.s1_id) as other:
                await other.send(command("kb-1"))
                refused = await next_where(other, is_(wire.CommandResult))
                assert (refused.ok, refused.code) == (False, "DUPLICATE")
            answer = wire.CommandResult(request_id="kb-1", ok=True, text="acknowledged")
            await station.send(answer.model_dump_json())
            result = await next_where(view, is_(wire.CommandResult))
            assert (result.request_id, result.ok) == ("kb-1", True)
            # The station's process audited the single outcome (the refusal has its own row).
            expected = ["impedance.change", "impedance.refused", "impedance.request"]
            await until_audited(b, world.admin, "kb-1", expected)

            # The station leaves: the viewer on B is told, and both processes agree.
            streaming.cancel()
            await station.close()
            presence = await next_where(view, is_(wire.Presence))
            assert not presence.online
        for live in (a, b):
            await until_online(live, world.t1, world.s1_id, False)


@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_a_prescription_edited_on_one_process_reaches_the_station_on_another(
    shared: Shared,
) -> None:
    world = shared.world
    async with two_servers(shared) as (a, b), station_ws(b, world.s1) as ws:
        await welcomed(ws)
        first = await next_where(ws, is_(wire.Prescriptions), wire.STATION_DOWN)
        assert [p.id for p in first.items] == [world.rx1]
        await until_online(a, world.t1, world.s1_id, True)
        body = STRENGTH | {"repetitions": STRENGTH["repetitions"] + 1}
        r = await a.client.patch(f"/prescriptions/{world.rx1}", json=body, headers=bearer(world.t1))
        assert r.status_code == 200, r.text
        pushed = await next_where(ws, is_(wire.Prescriptions), wire.STATION_DOWN)
        assert [(p.id, p.version) for p in pushed.items] == [(world.rx1, 2)]
        assert pushed.items[0].body.repetitions == STRENGTH["repetitions"] + 1


@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_a_station_revoked_on_one_process_is_closed_on_another_and_refused(
    shared: Shared,
) -> None:
    world = shared.world
    async with (
        two_servers(shared) as (a, b),
        station_ws(b, world.s1) as ws,
        viewer_ws(a, world.t1, world.s1_id) as view,
    ):
        await welcomed(ws)
        await until_online(a, world.t1, world.s1_id, True)
        began = time.monotonic()
        r = await a.client.post(f"/stations/{world.s1_id}/revoke", headers=bearer(world.t1))
        assert r.status_code == 200, r.text
        code, _ = await closed_with(ws, CLOSE_WITHIN_S)
        assert code == wire.CLOSE_REVOKED
        assert time.monotonic() - began < CLOSE_WITHIN_S
        await next_where(view, lambda m: isinstance(m, wire.Presence) and not m.online)
        await view.send(command("after-revoke"))
        refused = await next_where(view, is_(wire.CommandResult))
        assert (refused.ok, refused.code) == (False, "OFFLINE")


@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_a_logout_on_one_process_closes_the_view_on_another(
    shared: Shared,
) -> None:
    world = shared.world
    async with two_servers(shared) as (a, b):
        token = await login(a.client, "t1@clinic.test")
        async with (
            viewer_ws(b, token, world.s1_id) as ended,
            viewer_ws(b, world.t1, world.s1_id) as kept,
        ):
            await next_where(ended, is_(wire.Welcome))
            began = time.monotonic()
            r = await a.client.post("/auth/logout", headers=bearer(token))
            assert r.status_code == 204, r.text
            code, _ = await closed_with(ended, CLOSE_WITHIN_S)
            assert code == wire.CLOSE_SIGNED_OUT
            assert time.monotonic() - began < CLOSE_WITHIN_S
            # The same therapist's other sign-in keeps its view.
            await kept.send(wire.Heartbeat(sent=time.time()).model_dump_json())
            await next_where(kept, is_(wire.Welcome))


@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_the_station_connecting_to_another_process_replaces_its_old_link(
    shared: Shared,
) -> None:
    world = shared.world
    async with (
        two_servers(shared) as (a, b),
        viewer_ws(a, world.t1, world.s1_id) as view,
    ):
        await next_where(view, is_(wire.Welcome))
        async with station_ws(a, world.s1) as old:
            await welcomed(old)
            assert (await next_where(view, is_(wire.Presence))).online
            async with station_ws(b, world.s1) as new:
                await welcomed(new)
                code, _ = await closed_with(old, CLOSE_WITHIN_S)
                assert code == wire.CLOSE_REPLACED
                # Still online, now through B: the viewer on A is told so, not "offline".
                presence = await next_where(view, is_(wire.Presence))
                assert presence.online
                assert await online(a, world.t1, world.s1_id)
                await new.send(json.dumps(telemetry(t=7.0)))
                # Telemetry from B reaches the viewer on A.
                streaming = asyncio.create_task(stream(new, t=7.0))
                try:
                    batch = await next_where(view, is_(wire.TelemetryBatch))
                    assert batch.newest().t == 7.0
                finally:
                    streaming.cancel()


def _spawn_server(data_dir: Path, relay_url: str, port: int) -> subprocess.Popen[bytes]:
    code = "from server.cli import serve; serve()"
    env = os.environ | {
        "ANKLE_DATA_DIR": str(data_dir),
        "ANKLE_RELAY_URL": relay_url,
        "ANKLE_RELAY_LEASE_S": str(LEASE_S),
        "ANKLE_PORT": str(port),
    }
    return subprocess.Popen(
        [sys.executable, "-c", code], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT
    )


@pytest.mark.asyncio
async def test_a_killed_process_s_stations_go_offline_within_the_lease(
    seeded: tuple[Path, World], tmp_path: Path, relay_url: str
) -> None:
    world = seeded[1]
    data_dir = copy_seeded(seeded[0], tmp_path / "data")
    port = free_port()
    proc = _spawn_server(data_dir, relay_url, port)
    try:
        async with running(settings(data_dir, relay_url)) as a:
            other = Live(
                a.app, httpx.AsyncClient(base_url=f"http://127.0.0.1:{port}/api/v1"), a.settings
            )
            deadline = time.monotonic() + 60
            while True:
                try:
                    if (await other.client.get("/health")).status_code == 200:
                        break
                except httpx.TransportError:
                    pass
                assert proc.poll() is None and time.monotonic() < deadline, "B did not start"
                await asyncio.sleep(0.1)
            async with (
                viewer_ws(a, world.t1, world.s1_id) as view,
                station_ws(other, world.s1) as ws,
            ):
                await next_where(view, is_(wire.Welcome))
                await welcomed(ws)
                assert (await next_where(view, is_(wire.Presence))).online
                await until_online(a, world.t1, world.s1_id, True)
                proc.send_signal(signal.SIGKILL)
                proc.wait(10)
                took = await until_online(a, world.t1, world.s1_id, False)
                assert took < LEASE_S + 2.0, took
                await next_where(view, lambda m: isinstance(m, wire.Presence) and not m.online)
            await other.client.aclose()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.asyncio
async def test_without_its_redis_a_process_keeps_its_own_links_and_answers(
    seeded: tuple[Path, World], tmp_path: Path
) -> None:
    """Redis going away is not a 500: each process goes on with the links it holds."""
    world = seeded[1]
    data_dir = copy_seeded(seeded[0], tmp_path / "data")
    (tmp_path / "redis").mkdir()
    with spawned_redis(tmp_path / "redis") as (proc, url):
        async with (
            running(settings(data_dir, f"{url}/0")) as a,
            station_ws(a, world.s1) as station,
            viewer_ws(a, world.t1, world.s1_id) as view,
        ):
            await welcomed(station)
            await until_online(a, world.t1, world.s1_id, True)
            proc.kill()
            proc.wait(10)
            assert await online(a, world.t1, world.s1_id)  # held here: still known
            assert not await online(a, world.t1, world.s1_spare_id)
            await view.send(command("no-redis"))
            cmd = await next_where(station, is_(wire.Command), wire.STATION_DOWN)
            await station.send(
                wire.CommandResult(request_id=cmd.request_id, ok=True).model_dump_json()
            )
            result = await next_where(view, is_(wire.CommandResult))
            assert (result.request_id, result.ok) == ("no-redis", True)


@pytest.mark.asyncio
async def test_a_process_that_stops_tells_the_others_its_stations_went_offline(
    seeded: tuple[Path, World], tmp_path: Path, relay_url: str
) -> None:
    """Without waiting for the lease: here it is far longer than the test's deadline."""
    world = seeded[1]
    data_dir = copy_seeded(seeded[0], tmp_path / "data")
    long = Settings(data_dir=data_dir, relay_url=relay_url, relay_lease_s=300.0)
    async with running(long) as a, viewer_ws(a, world.t1, world.s1_id) as view:
        await next_where(view, is_(wire.Welcome))
        async with running(long) as b, station_ws(b, world.s1) as station:
            await welcomed(station)
            assert (await next_where(view, is_(wire.Presence))).online
            await until_online(a, world.t1, world.s1_id, True)
        # B has shut down (the station's link with it).
        await next_where(view, lambda m: isinstance(m, wire.Presence) and not m.online)
        await until_online(a, world.t1, world.s1_id, False)


@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_an_unanswered_command_ends_once_on_the_station_s_process(
    shared: Shared,
) -> None:
    """The station's process keeps the timer (TIMEOUT) and hears the link end (OFFLINE); the
    viewer on the other process is told, and each command has one outcome row."""
    world = shared.world
    async with (
        two_servers(shared) as (a, b),
        viewer_ws(b, world.t1, world.s1_id) as view,
    ):
        await next_where(view, is_(wire.Welcome))
        async with station_ws(a, world.s1) as station:
            await welcomed(station)
            await next_where(view, lambda m: isinstance(m, wire.Presence) and m.online)
            hold = wire.Command(request_id="hold-late", action="hold").model_dump_json()
            await view.send(hold)
            assert (
                await next_where(station, is_(wire.Command), wire.STATION_DOWN)
            ).action == "hold"
            beats = [asyncio.create_task(_beat(station)), asyncio.create_task(_beat(view))]
            try:
                timeout = await next_where(view, is_(wire.CommandResult))
            finally:
                for task in beats:
                    task.cancel()
            assert (timeout.request_id, timeout.code) == ("hold-late", "TIMEOUT")
            await view.send(wire.Command(request_id="stop-lost", action="stop").model_dump_json())
            await next_where(station, is_(wire.Command), wire.STATION_DOWN)
        lost = await next_where(view, is_(wire.CommandResult))
        assert (lost.request_id, lost.code) == ("stop-lost", "OFFLINE")
        for request_id, action in (("hold-late", "hold"), ("stop-lost", "stop")):
            await until_audited(
                b, world.admin, request_id, [f"{action}.request", f"{action}.unanswered"]
            )


async def _beat(ws: ClientConnection) -> None:
    """Heartbeats, so that a silent wait is not taken for a dead link."""
    while True:
        await ws.send(wire.Heartbeat(sent=time.time()).model_dump_json())
        await asyncio.sleep(wire.HEARTBEAT_S)
