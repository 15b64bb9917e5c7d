"""One viser server per watched station: started on demand, fed from the hub, stopped idle."""

from __future__ import annotations

import asyncio
import math
import socket
from typing import Any

import pytest

from server.hub import Hub, StationConn
from sessions import wire
from tests.server.ws_client import sample
from webui.live3d import LiveScenes


def feed(conn: StationConn, seq: int, *pitch_deg: float) -> None:
    """A batch of samples at these pitches (the last is the newest), as the hub keeps it."""
    rows = []
    for deg in pitch_deg:
        pose = [0.0, 0.0, 0.0, 0.0, math.radians(deg), 0.0]
        rows.append(
            sample(pose=pose, pose_cmd=pose, pressures=[2e5] * 12)
            | {"wrench": [0.0, 0.0, -50.0, 0.0, 1.0, 0.0]}
        )
    batch = wire.TelemetryBatch.of(rows, sent=0.0)
    conn.telemetry(batch.model_dump_json(), batch)
    assert conn.seq == seq


def connected(hub: Hub, station_id: int) -> StationConn:
    # The hub's record of a connected station; its socket is never used by the scenes.
    ws: Any = None
    conn = StationConn(ws, "", station_id, patient_id=1)
    hub.stations[station_id] = conn
    return conn


def port_open(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


@pytest.mark.asyncio
async def test_a_view_follows_the_newest_sample_and_stops_when_unwatched() -> None:
    hub = Hub()
    scenes = LiveScenes(hub, hz=50.0, idle_s=0.5)
    conn = connected(hub, 7)
    try:
        view = await scenes.open(7)
        assert port_open(view.port)
        assert (await scenes.open(7)) is view  # one server per station, however many ask

        feed(conn, 1, 30.0, 10.0)  # the newest is drawn
        for _ in range(50):
            await asyncio.sleep(0.02)
            if view.scene.updates:
                break
        assert view.scene.updates == 1
        y = view.scene.platform.wxyz[2]
        assert y == pytest.approx(math.sin(math.radians(5.0)), abs=1e-6)

        # The same sample is not drawn twice; a new one is.
        await asyncio.sleep(0.1)
        assert view.scene.updates == 1
        feed(conn, 2, -5.0)
        await asyncio.sleep(0.1)
        assert view.scene.updates == 2
        assert view.scene.platform.wxyz[2] == pytest.approx(-math.sin(math.radians(2.5)), abs=1e-6)

        # Nobody watches: after idle_s the server stops and its port closes.
        port = view.port
        assert view.task is not None
        await asyncio.wait_for(view.task, 5.0)
        assert 7 not in scenes.views
        assert not port_open(port)
    finally:
        await scenes.close()


@pytest.mark.asyncio
async def test_close_stops_every_view() -> None:
    hub = Hub()
    scenes = LiveScenes(hub)
    a = await scenes.open(1)
    b = await scenes.open(2)
    assert a.port != b.port
    await scenes.close()
    assert not scenes.views
    assert not port_open(a.port) and not port_open(b.port)
