"""The station's server link against a real WebSocket server: samples go in batches, and a
command waiting for the device never keeps the next one from being handled."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import pytest
from websockets.asyncio.server import Server, ServerConnection, serve

from sessions import wire
from station.server_link import ServerLink
from tests.server.ws_client import sample

WAIT_S = 15.0


class FakeServer:
    """Welcomes the station, records what it sends, and sends what a test asks."""

    def __init__(self) -> None:
        self.got: list[dict[str, Any]] = []
        self.conn: ServerConnection | None = None
        self.connected = asyncio.Event()
        self.changed = asyncio.Event()

    async def handler(self, ws: ServerConnection) -> None:
        await ws.recv()  # hello
        welcome = wire.Welcome(station_id=1, patient_id=1, server_time=time.time())
        await ws.send(welcome.model_dump_json())
        self.conn = ws
        self.connected.set()
        async for raw in ws:
            message = json.loads(raw)
            if message["type"] != "heartbeat":
                self.got.append(message)
                self.changed.set()

    async def until(self, done: Any) -> None:
        deadline = time.monotonic() + WAIT_S
        while not done():
            assert time.monotonic() < deadline, self.got[-5:]
            self.changed.clear()
            async with asyncio.timeout(WAIT_S):
                await self.changed.wait()


@asynccontextmanager
async def linked(link_of: Any) -> AsyncIterator[tuple[FakeServer, ServerLink]]:
    fake = FakeServer()
    server: Server
    async with serve(fake.handler, "127.0.0.1", 0, ping_interval=None) as server:
        port = server.sockets[0].getsockname()[1]
        link: ServerLink = link_of(f"http://127.0.0.1:{port}")
        task = asyncio.create_task(link.run())
        try:
            async with asyncio.timeout(WAIT_S):
                await fake.connected.wait()
            yield fake, link
        finally:
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task


def hello() -> wire.StationHello:
    return wire.StationHello(protocol=wire.PROTOCOL, software="test")


async def ignore(message: Any) -> None:
    return None


@pytest.mark.asyncio
async def test_samples_go_in_batches_of_the_device_rate_over_batch_hz() -> None:
    async with linked(lambda url: ServerLink(url, "t", hello, ignore, batch_hz=20.0)) as (
        fake,
        link,
    ):
        for i in range(12):
            link.send_sample(sample(t=i / 100), device_hz=100)
        await fake.until(lambda: len(fake.got) >= 2)
        await asyncio.sleep(0.2)  # nothing more comes: the last 2 samples wait for 3 more
        batches = [wire.STATION_UP.validate_python(m) for m in fake.got]
        assert [[s.t for s in b.samples()] for b in batches] == [
            [0.0, 0.01, 0.02, 0.03, 0.04],
            [0.05, 0.06, 0.07, 0.08, 0.09],
        ]


@pytest.mark.asyncio
async def test_a_hold_is_handled_while_a_kb_change_waits_for_the_device() -> None:
    device_answer = asyncio.Event()
    handled: list[str] = []

    async def on_message(message: Any) -> None:
        if isinstance(message, wire.Command):
            handled.append(f"{message.action} began")
            if message.action == "set_impedance":
                await device_answer.wait()  # the device is slow to ACK
            handled.append(f"{message.action} ended")

    async with linked(lambda url: ServerLink(url, "t", hello, on_message)) as (fake, _):
        assert fake.conn is not None
        kb = wire.Command(request_id="kb", action="set_impedance", stiffness={"pitch": 50.0})
        await fake.conn.send(kb.model_dump_json())
        await fake.conn.send(wire.Command(request_id="h", action="hold").model_dump_json())
        deadline = time.monotonic() + WAIT_S
        while "hold ended" not in handled:
            assert time.monotonic() < deadline, handled
            await asyncio.sleep(0.01)
        assert handled == ["set_impedance began", "hold began", "hold ended"]
        device_answer.set()
        while "set_impedance ended" not in handled:
            assert time.monotonic() < deadline, handled
            await asyncio.sleep(0.01)
