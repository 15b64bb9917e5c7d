"""Telemetry batches through the relay: every sample to a viewer that keeps up, the newest to
one that fell behind, and a command's answer behind telemetry in the same socket.

A real uvicorn on a seeded database (``live``), a raw ``websockets`` station and viewer.
"""

from __future__ import annotations

import asyncio
import time
from typing import Any

import pytest
from websockets.asyncio.client import ClientConnection

from server.hub import StationConn
from server.relay import RECENT_BATCHES
from sessions import wire
from tests.server.live_server import Live, World
from tests.server.ws_client import sample, station_ws, viewer_ws, welcomed

WAIT_S = 15.0


def batch(first: int, n: int = 4) -> str:
    """Samples ``first`` .. ``first + n - 1``, their number in ``t`` (10 ms apart)."""
    rows = [sample(t=(first + i) / 100) for i in range(n)]
    return wire.TelemetryBatch.of(rows, sent=time.time()).model_dump_json()


def conn_with(batches: int) -> StationConn:
    ws: Any = None  # never used: the hub's record of a connected station
    conn = StationConn(ws, "", 1, 1)
    for i in range(batches):
        raw = batch(4 * i)
        conn.telemetry(raw, wire.STATION_UP.validate_json(raw))
    return conn


def test_a_viewer_is_sent_each_batch_it_missed_or_only_the_newest_once_behind() -> None:
    conn = conn_with(RECENT_BATCHES + 3)
    newest = conn.seq
    assert [n for n, _ in conn.after(newest - 2)] == [newest - 1, newest]
    assert conn.after(newest) == []
    oldest_kept = newest - RECENT_BATCHES + 1
    assert [n for n, _ in conn.after(oldest_kept - 1)] == list(range(oldest_kept, newest + 1))
    assert [n for n, _ in conn.after(oldest_kept - 2)] == [newest]  # fell behind
    assert [n for n, _ in conn.after(newest + 5)] == [newest]  # a number of a former link
    latest = conn.newest()
    assert latest is not None and latest.t == pytest.approx((4 * newest - 1) / 100)
    assert StationConn(None, "", 1, 1).after(0) == []  # type: ignore[arg-type]


async def viewer_heartbeats(ws: ClientConnection) -> None:
    while True:
        await ws.send(wire.Heartbeat(sent=time.time()).model_dump_json())
        await asyncio.sleep(wire.HEARTBEAT_S)


@pytest.mark.asyncio
async def test_every_sample_sent_in_bursts_reaches_a_viewer_that_keeps_up(
    live: Live, world: World
) -> None:
    bursts, per_burst, per_batch = 10, 4, 4  # each burst: four batches in one go
    async with station_ws(live, world.s1) as station:
        await welcomed(station)
        async with viewer_ws(live, world.t1, world.s1_id) as viewer:
            await watch_bursts(station, viewer, bursts, per_burst, per_batch)


async def next_command(station: ClientConnection) -> wire.Command:
    """The next command relayed to ``station`` (what else the server sends it passed over)."""
    while True:
        message = wire.STATION_DOWN.validate_json(await station.recv())
        if isinstance(message, wire.Command):
            return message


async def watch_bursts(
    station: ClientConnection, viewer: ClientConnection, bursts: int, per_burst: int, per_batch: int
) -> None:
    total = bursts * per_burst * per_batch
    welcome = wire.VIEWER_DOWN.validate_json(await asyncio.wait_for(viewer.recv(), WAIT_S))
    assert isinstance(welcome, wire.Welcome) and welcome.online
    beats = [asyncio.create_task(viewer_heartbeats(ws)) for ws in (station, viewer)]
    seen: list[float] = []
    results: list[wire.CommandResult] = []

    async def watch() -> None:
        while len(seen) < total or not results:
            message = wire.VIEWER_DOWN.validate_json(await viewer.recv())
            if isinstance(message, wire.TelemetryBatch):
                seen.extend(s.t for s in message.samples())
            elif isinstance(message, wire.CommandResult):
                results.append(message)

    watcher = asyncio.create_task(watch())
    try:
        first = 0
        for k in range(bursts):
            for _ in range(per_burst):
                await station.send(batch(first, per_batch))
                first += per_batch
            if k == bursts // 2:  # an answer behind telemetry in the same socket
                await viewer.send(wire.Command(request_id="asked", action="hold").model_dump_json())
                asked = await asyncio.wait_for(next_command(station), WAIT_S)
                answer = wire.CommandResult(request_id=asked.request_id, ok=True)
                await station.send(answer.model_dump_json())
            await asyncio.sleep(0.1)
        await asyncio.wait_for(watcher, WAIT_S)
    finally:
        watcher.cancel()
        for b in beats:
            b.cancel()
    assert seen == [i / 100 for i in range(total)]  # each one, once, in order
    assert [r.request_id for r in results] == ["asked"]
