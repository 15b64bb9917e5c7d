"""Two server processes sharing one SQLite file and a real Redis relay.

Each server is its own app with its own hub and relay (two uvicorn servers in this test's
loop, or a separate process where one must be killed): nothing passes between them but
Redis and the database. A raw WebSocket client speaks the station protocol on one; a
viewer watches from the other.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import json
import logging
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Callable
from contextlib import AsyncExitStack, ExitStack, asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
import redis.asyncio as aioredis
from websockets.asyncio.client import ClientConnection

from server.config import Settings
from server.hub import (
    COMMAND_TIMEOUT_S,
    EXPIRED,
    RELAY_LOST,
    RELAY_REFUSED,
    RELAY_SLACK_S,
    RELAY_SLOW,
)
from server.redis_relay import RedisRelay
from server.relay import Message
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
            # The station's status reaches the relay's store in the writer's next batch:
            # a viewer that came first hears it as a message right after the welcome (its
            # process watched the station before it read the store).
            told = welcome.status or await next_where(view, is_(wire.StatusMsg))
            assert told.device_mode == "READY"
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


@asynccontextmanager
async def served_apart(
    beside: Live, relay_url: str, lease_s: float = LEASE_S
) -> AsyncIterator[tuple[subprocess.Popen[bytes], Live]]:
    """A server in a process of its own (so that it can be killed) on ``beside``'s data
    directory and ``relay_url``: the process, and a client of it (its ``app`` is
    ``beside``'s: only the client is its own)."""
    port = free_port()
    code = "from server.cli import serve; serve()"
    env = os.environ | {
        "ANKLE_DATA_DIR": str(beside.settings.data_dir),
        "ANKLE_RELAY_URL": relay_url,
        "ANKLE_RELAY_LEASE_S": str(lease_s),
        "ANKLE_PORT": str(port),
    }
    proc = subprocess.Popen(
        [sys.executable, "-c", code], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT
    )
    try:
        async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{port}/api/v1") as client:
            deadline = time.monotonic() + 60
            while True:
                try:
                    if (await client.get("/health")).status_code == 200:
                        break
                except httpx.TransportError:
                    pass
                assert proc.poll() is None and time.monotonic() < deadline, "B did not start"
                await asyncio.sleep(0.1)
            yield proc, Live(beside.app, client, beside.settings)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()


@pytest.mark.asyncio
async def test_a_killed_process_s_stations_go_offline_within_the_lease(
    seeded: tuple[Path, World], tmp_path: Path, relay_url: str
) -> None:
    world = seeded[1]
    data_dir = copy_seeded(seeded[0], tmp_path / "data")
    async with (
        running(settings(data_dir, relay_url)) as a,
        served_apart(a, relay_url) as (proc, other),
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


async def audit_rows(live: Live, token: str, request_id: str) -> list[dict[str, Any]]:
    r = await live.client.get("/audit", params={"request_id": request_id}, headers=bearer(token))
    assert r.status_code == 200, r.text
    rows: list[dict[str, Any]] = r.json()
    return rows


def result_of(request_id: str) -> Callable[[Any], bool]:
    return lambda m: isinstance(m, wire.CommandResult) and m.request_id == request_id


@pytest.mark.asyncio
async def test_a_command_whose_station_s_process_died_ends_on_the_viewer_s_process(
    seeded: tuple[Path, World], tmp_path: Path, relay_url: str
) -> None:
    """B dies holding the station: until its lease runs out A still names it the station's
    server and sends it the viewer's HOLD and K/B change, which nobody will answer. A's own
    timer ends each with TIMEOUT, and audits it (the request, then unanswered)."""
    world = seeded[1]
    data_dir = copy_seeded(seeded[0], tmp_path / "data")
    lease_s = 120.0  # longer than the test: B stays the station's named server once dead
    long = Settings(data_dir=data_dir, relay_url=relay_url, relay_lease_s=lease_s)
    async with (
        running(long) as a,
        served_apart(a, relay_url, lease_s) as (proc, b),
        viewer_ws(a, world.t1, world.s1_id) as view,
        station_ws(b, world.s1) as station,
    ):
        await next_where(view, is_(wire.Welcome))
        await welcomed(station)
        assert (await next_where(view, is_(wire.Presence))).online
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        beat = asyncio.create_task(_beat(view))
        try:
            for request_id, action, asked in (
                ("hold-dead", "hold", wire.Command(request_id="hold-dead", action="hold")),
                ("kb-dead", "impedance", wire.Command.model_validate_json(command("kb-dead"))),
            ):
                began = time.monotonic()
                await view.send(asked.model_dump_json())
                result = await next_where(view, result_of(request_id))
                assert time.monotonic() - began >= COMMAND_TIMEOUT_S - 0.05
                assert (result.ok, result.code) == (False, "TIMEOUT")
                assert "the station's server did not answer" in result.text
                await until_audited(
                    a, world.admin, request_id, [f"{action}.request", f"{action}.unanswered"]
                )
                rows = await audit_rows(a, world.admin, request_id)
                outcome = next(r for r in rows if r["action"] == f"{action}.unanswered")
                assert outcome["new"]["code"] == "TIMEOUT"
                assert outcome["actor"] == f"user:{world.t1_id}"
        finally:
            beat.cancel()


@dataclass
class Ghost:
    """A make-believe server process on the relay, named ``ghost``: a Redis client that
    hears what is sent to it, and sends what the test writes, as a server process would."""

    redis: aioredis.Redis
    pubsub: Any

    async def publish(self, channel: str, text: str) -> None:
        await self.redis.publish(f"ankle:{channel}", text)

    async def heard(self, kind: str) -> dict[str, Any]:
        """The next message of type ``kind`` sent to it, reading past the others."""
        deadline = time.monotonic() + WAIT_S
        while True:
            left = deadline - time.monotonic()
            assert left > 0, f"no {kind} came"
            item = await self.pubsub.get_message(timeout=min(left, 1.0))
            if item is not None and item["type"] == "message":
                message: dict[str, Any] = json.loads(item["data"])
                if message["type"] == kind:
                    return message


@asynccontextmanager
async def ghost(relay_url: str) -> AsyncIterator[Ghost]:
    client = aioredis.Redis.from_url(relay_url, decode_responses=True)
    pubsub = client.pubsub(ignore_subscribe_messages=True)
    await pubsub.subscribe("ankle:proc:ghost")
    try:
        yield Ghost(client, pubsub)
    finally:
        await pubsub.aclose()
        await client.aclose()


@pytest.mark.asyncio
async def test_the_viewer_s_process_gives_up_on_an_unanswered_command_and_says_so(
    seeded: tuple[Path, World], tmp_path: Path, relay_url: str
) -> None:
    """The station is held by a process that hears but never answers (as if the answer was
    lost): A ends the command at COMMAND_TIMEOUT_S and tells that process it gave up. A
    command whose end that process reports in time is not ended again, and an answer after
    A gave up is no second outcome on A."""
    world = seeded[1]
    data_dir = copy_seeded(seeded[0], tmp_path / "data")
    async with running(settings(data_dir, relay_url)) as a, ghost(relay_url) as owner:
        # The ghost holds the station before the viewer comes, so the welcome says online
        # (set once the viewer's socket was open, it raced the welcome on a busy machine).
        await owner.redis.set(f"ankle:station:{world.s1_id}", "ghost", px=120_000)
        async with viewer_ws(a, world.t1, world.s1_id) as view:
            assert (await next_where(view, is_(wire.Welcome))).online
            process = a.app.state.hub.relay.process
            beat = asyncio.create_task(_beat(view))
            try:
                await view.send(wire.Command(request_id="h-lost", action="hold").model_dump_json())
                forward = await owner.heard("command")
                assert forward["command"]["request_id"] == "h-lost"
                assert forward["reply_to"] == process
                assert forward["timeout_s"] == COMMAND_TIMEOUT_S - RELAY_SLACK_S
                # A K/B change the owner answers, as a station's process does: to the viewers,
                # and to the asking process that it ended.
                await view.send(command("kb-done"))
                assert (await owner.heard("command"))["command"]["request_id"] == "kb-done"
                done = wire.CommandResult(request_id="kb-done", ok=True, text="acknowledged")
                await owner.publish(f"view:{world.s1_id}", f"ghost {done.model_dump_json()}")
                settled = {"type": "settled", "station_id": world.s1_id, "request_id": "kb-done"}
                await owner.publish(f"proc:{process}", json.dumps(settled))
                assert (await next_where(view, result_of("kb-done"))).ok

                lost = await next_where(view, result_of("h-lost"))
                assert (lost.ok, lost.code) == (False, "TIMEOUT")
                assert "the station's server did not answer" in lost.text
                gave_up = await owner.heard("gave_up")
                assert (gave_up["request_id"], gave_up["from"]) == ("h-lost", process)
                # The owner's answer after that: shown to the viewers, but no outcome of A's.
                late = wire.CommandResult(request_id="h-lost", ok=True, text="acknowledged")
                await owner.publish(f"view:{world.s1_id}", f"ghost {late.model_dump_json()}")
                settled |= {"request_id": "h-lost"}
                await owner.publish(f"proc:{process}", json.dumps(settled))
                assert (await next_where(view, result_of("h-lost"))).ok

                # A later command's TIMEOUT comes after any of kb-done's would have, and its row
                # after any A would have written for either.
                await view.send(wire.Command(request_id="h-last", action="hold").model_dump_json())
                seen: list[str] = []

                def last(m: Any) -> bool:
                    if isinstance(m, wire.CommandResult):
                        seen.append(f"{m.request_id} {m.code}")
                    return result_of("h-last")(m)

                assert (await next_where(view, last)).code == "TIMEOUT"
                assert seen == ["h-last TIMEOUT"]
            finally:
                beat.cancel()
        await until_audited(a, world.admin, "h-last", ["hold.request", "hold.unanswered"])
        assert sorted(r["action"] for r in await audit_rows(a, world.admin, "h-lost")) == [
            "hold.request",
            "hold.unanswered",
        ]
        # The owner writes the outcome of what it answered; A, only the request.
        assert [r["action"] for r in await audit_rows(a, world.admin, "kb-done")] == [
            "impedance.request"
        ]


def asked_by(world: World) -> dict[str, object]:
    """Who a forwarded command says asked for it: the first therapist, from a viewer."""
    return {
        "user_id": world.t1_id,
        "station_id": world.s1_id,
        "patient_id": world.p1,
        "may_command": True,
        "viewer": 7,
    }


@pytest.mark.asyncio
async def test_the_station_s_process_records_an_answer_after_the_asker_gave_up_as_late(
    seeded: tuple[Path, World], tmp_path: Path, relay_url: str
) -> None:
    """A forwarded command: the station's process waits for the station the time the asking
    process gives it, tells that process when the command ended, and once told that the
    asking process gave up, writes no outcome of its own but the late answer's, marked so."""
    world = seeded[1]
    data_dir = copy_seeded(seeded[0], tmp_path / "data")
    async with (
        running(settings(data_dir, relay_url)) as b,
        ghost(relay_url) as asker,
        station_ws(b, world.s1) as station,
    ):
        await welcomed(station)
        await until_online(b, world.t1, world.s1_id, True)
        process = b.app.state.hub.relay.process
        by = asked_by(world)

        async def forward(request_id: str, timeout_s: float) -> wire.Command:
            message = {
                "type": "command",
                "station_id": world.s1_id,
                "asker": by,
                "command": {"request_id": request_id, "action": "hold"},
                "reply_to": "ghost",
                "timeout_s": timeout_s,
            }
            await asker.publish(f"proc:{process}", json.dumps(message))
            got: wire.Command = await next_where(station, is_(wire.Command), wire.STATION_DOWN)
            assert got.request_id == request_id
            return got

        beat = asyncio.create_task(_beat(station))
        try:
            await forward("h-given-up", 60.0)
            gave_up = {
                "type": "gave_up",
                "station_id": world.s1_id,
                "request_id": "h-given-up",
                "from": "ghost",
            }
            await asker.publish(f"proc:{process}", json.dumps(gave_up))
            # Relayed messages are handled in order: once this one reaches the station,
            # the word that the asker gave up has been.
            await forward("h-short", 0.5)
            ended = await asker.heard("settled")
            assert ended["request_id"] == "h-short"  # its own TIMEOUT, at the time given
            answer = wire.CommandResult(request_id="h-given-up", ok=True, text="acknowledged")
            await station.send(answer.model_dump_json())
            await until_audited(b, world.admin, "h-given-up", ["hold.accepted"])
            (row,) = await audit_rows(b, world.admin, "h-given-up")
            assert row["new"]["late"] is True
            (short,) = await audit_rows(b, world.admin, "h-short")
            assert (short["action"], short["new"]["code"]) == ("hold.unanswered", "TIMEOUT")
            assert "within 0.5 s" in short["new"]["text"]
        finally:
            beat.cancel()


@pytest.mark.asyncio
async def test_while_the_relay_is_away_the_other_process_s_viewers_are_told_it_is_unknown(
    seeded: tuple[Path, World], tmp_path: Path
) -> None:
    """Redis dies: A cannot tell whether B's station is online, and says so to its viewer
    (not "online" with frozen values), and refuses a command saying why; B's own viewer
    is told nothing. Redis back, A's viewer is told the station is online, and its
    telemetry comes again."""
    world = seeded[1]
    data_dir = copy_seeded(seeded[0], tmp_path / "data")
    port = free_port()
    with ExitStack() as first, ExitStack() as again:
        proc, url = first.enter_context(spawned_redis(tmp_path / "redis", port))
        relayed = settings(data_dir, f"{url}/0")
        async with (
            running(relayed) as a,
            running(relayed) as b,
            station_ws(b, world.s1) as station,
            viewer_ws(a, world.t1, world.s1_id) as view,
            viewer_ws(b, world.t1, world.s1_id) as near,
        ):
            await welcomed(station)
            await next_where(view, lambda m: isinstance(m, wire.Presence) and m.online)
            streaming = asyncio.create_task(stream(station, t=3.0))
            beats = [asyncio.create_task(_beat(ws)) for ws in (view, near)]
            try:
                await next_where(view, is_(wire.TelemetryBatch))
                proc.kill()
                proc.wait(10)
                unknown = await next_where(
                    view, lambda m: isinstance(m, wire.Presence) and not m.online
                )
                assert unknown.text == RELAY_LOST
                await view.send(command("kb-away"))
                refused = await next_where(view, result_of("kb-away"))
                assert (refused.ok, refused.code, refused.text) == (False, "OFFLINE", RELAY_REFUSED)

                first.close()
                again.enter_context(spawned_redis(tmp_path / "redis", port))
                back = await next_where(view, lambda m: isinstance(m, wire.Presence) and m.online)
                assert back.text and back.known
                # Heard again: telemetry sent from now on reaches A's viewer.
                streaming.cancel()
                streaming = asyncio.create_task(stream(station, t=4.0))
                await next_where(
                    view, lambda m: isinstance(m, wire.TelemetryBatch) and m.newest().t == 4.0
                )
            finally:
                streaming.cancel()
                for task in beats:
                    task.cancel()
            # B's viewer, beside the station, was never told it went away.
            told: list[Any] = []
            with contextlib.suppress(TimeoutError):
                while True:
                    told.append(
                        wire.VIEWER_DOWN.validate_json(await asyncio.wait_for(near.recv(), 0.2))
                    )
            assert not [m for m in told if isinstance(m, wire.Presence) and not m.online]


class Heard:
    """A hub as a relay sees it (``server.relay.Listener``): the batches it was told of."""

    def __init__(self) -> None:
        self.batches = 0

    def deliver(self, station_id: int, text: str) -> None:
        return None

    def telemetry_came(self, station_id: int) -> None:
        self.batches += 1

    def gone(self, station_id: int) -> None:
        return None

    def back(self, station_id: int) -> None:
        return None

    def relay_reachable(self, up: bool) -> None:
        return None

    async def on_message(self, message: Message) -> None:
        return None


async def until(done: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not done():
        assert time.monotonic() < deadline, what
        await asyncio.sleep(0.05)


@pytest.mark.asyncio
async def test_a_redis_outage_is_logged_when_it_begins_and_ends_not_per_message(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A station's telemetry is 25 publishes a second: while Redis is away each kind of
    call logs once that it fails, and once that it works again with how much was lost."""
    port = free_port()
    with ExitStack() as first, ExitStack() as again:
        _, url = first.enter_context(spawned_redis(tmp_path / "redis", port))
        holder = RedisRelay(f"{url}/0", lease_s=LEASE_S)
        watcher = RedisRelay(f"{url}/0", lease_s=LEASE_S)
        heard = Heard()
        await holder.start(Heard())
        await watcher.start(heard)
        raw = wire.TelemetryBatch.model_validate(telemetry(t=1.0)).model_dump_json()

        async def station() -> None:
            while True:
                holder.telemetry(1, raw)
                await asyncio.sleep(0.04)

        feeding = asyncio.create_task(station())
        try:
            await holder.claim(1)
            await watcher.watch(1)
            await until(lambda: heard.batches > 0, "the watcher heard no telemetry")
            caplog.set_level(logging.WARNING, logger="ankle.server.relay")
            caplog.clear()

            def logged(start: str) -> int:
                return sum(r.getMessage().startswith(start) for r in caplog.records)

            first.close()
            await until(lambda: logged("publishing telemetry failed") > 0, "nothing logged")
            sent = heard.batches
            await asyncio.sleep(1.0)  # about 25 batches that cannot be published
            again.enter_context(spawned_redis(tmp_path / "redis", port))
            await until(lambda: logged("publishing telemetry works") > 0, "nothing logged")
            await until(lambda: heard.batches > sent, "the watcher heard no telemetry again")
        finally:
            feeding.cancel()
            await holder.close()
            await watcher.close()
    lines = collections.Counter(r.getMessage().partition(":")[0] for r in caplog.records)
    assert lines["publishing telemetry failed"] == 1, lines
    assert lines["the relay's subscription failed"] <= 2, lines  # once by each relay
    assert lines["refreshing the relay's leases failed"] <= 2, lines
    (works,) = [
        r.getMessage() for r in caplog.records if "publishing telemetry works" in r.getMessage()
    ]
    lost = re.search(r"; (\d+) telemetry batches were lost", works)
    assert lost is not None and int(lost[1]) >= 1, works


@pytest.mark.asyncio
async def test_a_forwarded_command_past_its_budget_is_not_sent_but_a_hold_is(
    seeded: tuple[Path, World], tmp_path: Path, relay_url: str
) -> None:
    """The relay held a forwarded command (Redis paused for a failover) until after the
    asking process told its viewer TIMEOUT: the station's process refuses a K/B change
    (EXPIRED, audited as refused) instead of carrying it out; a HOLD goes out all the same."""
    world = seeded[1]
    data_dir = copy_seeded(seeded[0], tmp_path / "data")
    async with (
        running(settings(data_dir, relay_url)) as b,
        ghost(relay_url) as asker,
        station_ws(b, world.s1) as station,
    ):
        await welcomed(station)
        await until_online(b, world.t1, world.s1_id, True)
        process = b.app.state.hub.relay.process
        by = asked_by(world)
        past = time.time() - 8.0  # as measured with Redis paused: 8 s after its TIMEOUT
        for request_id, asked in (
            (
                "kb-stale",
                {"request_id": "kb-stale", "action": "set_impedance", "stiffness": {"pitch": 60.0}},
            ),
            ("h-stale", {"request_id": "h-stale", "action": "hold"}),
        ):
            message = {
                "type": "command",
                "station_id": world.s1_id,
                "asker": by,
                "command": asked,
                "reply_to": "ghost",
                "timeout_s": COMMAND_TIMEOUT_S - RELAY_SLACK_S,
                "expires_at": past,
            }
            await asker.publish(f"proc:{process}", json.dumps(message))
            if request_id == "kb-stale":
                reply = await asker.heard("reply")
                refused = wire.CommandResult.model_validate_json(reply["text"])
                assert (refused.request_id, refused.ok, refused.code, refused.text) == (
                    "kb-stale",
                    False,
                    "EXPIRED",
                    EXPIRED,
                )
        got = await next_where(station, is_(wire.Command), wire.STATION_DOWN)
        assert (got.request_id, got.action) == ("h-stale", "hold")  # the K change never came
        await until_audited(b, world.admin, "kb-stale", ["impedance.refused"])
        (row,) = await audit_rows(b, world.admin, "kb-stale")
        assert row["new"]["code"] == "EXPIRED"


async def pause(relay_url: str, ms: int, which: str) -> None:
    """Redis holds its clients' commands (``WRITE``: writes only, as in a failover) for
    ``ms``."""
    client = aioredis.Redis.from_url(relay_url)
    try:
        await client.execute_command("CLIENT", "PAUSE", str(ms), which)  # type: ignore[no-untyped-call]
    finally:
        await client.aclose()


@asynccontextmanager
async def paused_apart(relay_url: str) -> AsyncIterator[None]:
    """Within it, Redis may be paused; after it, Redis answers again (the next test's
    emptying of the database does not meet the pause)."""
    try:
        yield
    finally:
        client = aioredis.Redis.from_url(relay_url, socket_timeout=30.0)
        try:
            await client.ping()
        finally:
            await client.aclose()


async def until_away(live: Live) -> None:
    await until(lambda: not live.app.state.hub.relay.reachable, "the relay never went away")


@pytest.mark.asyncio
async def test_a_hold_is_refused_at_once_while_redis_hangs(
    seeded: tuple[Path, World], tmp_path: Path, relay_url: str
) -> None:
    """Redis answers nothing (paused): a HOLD of a station held elsewhere waits at most
    SAFE_OWNER_WAIT_S to find its server, not Redis's 5 s socket timeout; once the relay is
    known away, a HOLD or K/B change is refused OFFLINE at once."""
    world = seeded[1]
    data_dir = copy_seeded(seeded[0], tmp_path / "data")
    async with (
        paused_apart(relay_url),
        running(settings(data_dir, relay_url)) as a,
        ghost(relay_url) as owner,
    ):
        await owner.redis.set(f"ankle:station:{world.s1_id}", "ghost", px=120_000)
        async with viewer_ws(a, world.t1, world.s1_id) as view:
            assert (await next_where(view, is_(wire.Welcome))).online
            beat = asyncio.create_task(_beat(view))
            try:
                await pause(relay_url, 4000, "ALL")
                began = time.monotonic()
                await view.send(wire.Command(request_id="h-hang", action="hold").model_dump_json())
                refused = await next_where(view, result_of("h-hang"))
                assert time.monotonic() - began < 2.5  # else 4 s, the pause, then TIMEOUT
                assert (refused.code, refused.text) == ("OFFLINE", RELAY_SLOW)
                await asyncio.sleep(4.0)  # the pause ends

                await pause(relay_url, 15_000, "ALL")
                await until_away(a)
                for asked in (
                    wire.Command(request_id="h-away", action="hold"),
                    wire.Command.model_validate_json(command("kb-away")),
                ):
                    began = time.monotonic()
                    await view.send(asked.model_dump_json())
                    refused = await next_where(view, result_of(asked.request_id))
                    assert time.monotonic() - began < 2.5, asked.request_id  # else 5 s
                    assert (refused.code, refused.text) == ("OFFLINE", RELAY_REFUSED)
            finally:
                beat.cancel()


@pytest.mark.asyncio
async def test_while_redis_hangs_a_prescription_is_saved_without_waiting_for_it(
    seeded: tuple[Path, World], tmp_path: Path, relay_url: str
) -> None:
    """The patient's two stations are held elsewhere: with the relay known away, saving a
    prescription and listing the stations do not wait on Redis (5 s a station before)."""
    world = seeded[1]
    data_dir = copy_seeded(seeded[0], tmp_path / "data")
    async with (
        paused_apart(relay_url),
        running(settings(data_dir, relay_url)) as a,
        ghost(relay_url) as owner,
    ):
        for station_id in (world.s1_id, world.s1_spare_id):
            await owner.redis.set(f"ankle:station:{station_id}", "ghost", px=120_000)
        await pause(relay_url, 15_000, "ALL")
        await until_away(a)
        began = time.monotonic()
        r = await a.client.post(
            f"/patients/{world.p1}/prescriptions", json=STRENGTH, headers=bearer(world.t1)
        )
        assert r.status_code == 201, r.text
        assert time.monotonic() - began < 2.5  # else 5 s a station
        began = time.monotonic()
        r = await a.client.get("/stations", headers=bearer(world.t1))
        assert r.status_code == 200, r.text
        assert time.monotonic() - began < 2.5  # else 5 s


@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_a_redis_hang_longer_than_the_lease_is_not_told_as_the_station_gone(
    shared: Shared,
) -> None:
    """Redis takes no writes for longer than the lease (a failover): every lease runs out
    though the station stays connected. Its viewer on the other process is told the relay
    is away, or nothing, never that the station went offline; and no presence is blank."""
    world = shared.world
    async with (
        paused_apart(shared.relay_url),
        two_servers(shared) as (a, b),
        station_ws(b, world.s1) as station,
        viewer_ws(a, world.t1, world.s1_id) as view,
    ):
        await welcomed(station)
        await next_where(view, lambda m: isinstance(m, wire.Presence) and m.online)
        beats = [asyncio.create_task(_beat(ws)) for ws in (station, view)]
        told: list[wire.Presence] = []
        try:
            await pause(shared.relay_url, round(LEASE_S * 1000 * 3), "WRITE")
            deadline = time.monotonic() + LEASE_S * 3 + 4.0
            while (left := deadline - time.monotonic()) > 0:
                with contextlib.suppress(TimeoutError):
                    m = wire.VIEWER_DOWN.validate_json(await asyncio.wait_for(view.recv(), left))
                    if isinstance(m, wire.Presence):
                        told.append(m)
        finally:
            for task in beats:
                task.cancel()
        assert all(m.text for m in told), told
        assert not [m for m in told if not m.online and m.known], told
        assert await online(a, world.t1, world.s1_id)
