"""The live WebSocket links refuse what is not theirs, with the close code the protocol names.

A real uvicorn on a seeded database (``live``) and a raw ``websockets`` client: what is
tested is the bytes and close frames a station or a browser would see. After each refusal
nothing has changed: the station is not reported online and no command reached anyone.
"""

from __future__ import annotations

import asyncio
import json
import logging
import re
import time
from typing import Any

import pytest
from websockets.asyncio.client import ClientConnection
from websockets.exceptions import ConnectionClosed, InvalidStatus

from sessions import wire
from tests.server.live_server import Live, World, bearer
from tests.server.ws_client import (
    HELLO,
    close_of,
    closed_with,
    station_ws,
    telemetry,
    viewer_ws,
    welcomed,
)


async def online(live: Live, world: World, station_id: int) -> bool:
    r = await live.client.get("/stations", headers=bearer(world.admin))
    assert r.status_code == 200, r.text
    (row,) = [s for s in r.json() if s["id"] == station_id]
    return bool(row["online"])


async def assert_offline(live: Live, world: World, station_id: int) -> None:
    """The station is (soon) reported offline: the server's handler may finish just after
    the client has seen the close frame."""
    deadline = time.monotonic() + 3.0
    while await online(live, world, station_id):
        assert time.monotonic() < deadline, f"station {station_id} still reported online"
        await asyncio.sleep(0.05)


# -- /ws/station: the handshake -------------------------------------------------------------
@pytest.mark.asyncio
async def test_a_welcomed_station_is_online_and_offline_after_it_leaves(
    live: Live, world: World
) -> None:
    """The baseline the other tests rely on: a good hello is welcomed, shows online."""
    async with station_ws(live, world.s1) as ws:
        welcome = await welcomed(ws)
        assert (welcome.station_id, welcome.patient_id) == (world.s1_id, world.p1)
        assert await online(live, world, world.s1_id)
    await assert_offline(live, world, world.s1_id)


@pytest.mark.asyncio
async def test_a_wrong_token_is_refused_at_the_handshake(live: Live, world: World) -> None:
    with pytest.raises(InvalidStatus) as info:
        async with station_ws(live, "not-a-station-token"):
            pass
    assert info.value.response.status_code == 403
    # A therapist's token is not a station's either.
    with pytest.raises(InvalidStatus) as info:
        async with station_ws(live, world.t1):
            pass
    assert info.value.response.status_code == 403
    await assert_offline(live, world, world.s1_id)


@pytest.mark.asyncio
async def test_a_foreign_origin_is_refused_even_with_a_good_token(live: Live, world: World) -> None:
    with pytest.raises(InvalidStatus) as info:
        async with station_ws(live, world.s1, {"Origin": "https://evil.example"}):
            pass
    assert info.value.response.status_code == 403
    await assert_offline(live, world, world.s1_id)


@pytest.mark.asyncio
async def test_the_first_message_must_be_hello(live: Live, world: World) -> None:
    async with station_ws(live, world.s1) as ws:
        await ws.send(wire.Heartbeat(sent=time.time()).model_dump_json())
        code, reason = await closed_with(ws)
    assert code == wire.CLOSE_MALFORMED
    assert "hello" in reason
    await assert_offline(live, world, world.s1_id)


@pytest.mark.asyncio
async def test_another_protocol_version_is_closed_naming_both(live: Live, world: World) -> None:
    async with station_ws(live, world.s1) as ws:
        await ws.send(json.dumps({"type": "hello", "protocol": 99, "software": "future"}))
        code, reason = await closed_with(ws)
    assert code == wire.CLOSE_VERSION
    assert {"99", str(wire.PROTOCOL)} <= set(re.findall(r"\d+", reason)), reason
    await assert_offline(live, world, world.s1_id)


# -- /ws/station: after the hello ------------------------------------------------------------
BAD_MESSAGES: list[tuple[str, str | bytes, int, str]] = [
    ("not JSON", "this is not json", wire.CLOSE_MALFORMED, "JSON"),
    ("unknown type", json.dumps({"type": "launch", "sent": 1.0}), wire.CLOSE_MALFORMED, "type"),
    ("no type", json.dumps({"sent": 1.0}), wire.CLOSE_MALFORMED, "type"),
    # Python's json writes NaN as the bare token, as a careless sender would.
    ("NaN", json.dumps(telemetry(t=float("nan"))), wire.CLOSE_MALFORMED, "telemetry.t"),
    (
        "NaN in a vector",
        json.dumps(telemetry(pose=[0.0, 0.0, float("nan"), 0.0, 0.0, 0.0])),
        wire.CLOSE_MALFORMED,
        "telemetry.pose",
    ),
    ("5-element pose", json.dumps(telemetry(pose=[0.0] * 5)), wire.CLOSE_MALFORMED, "pose"),
    (
        "extra field",
        json.dumps({"type": "heartbeat", "sent": 1.0, "admin": True}),
        wire.CLOSE_MALFORMED,
        "admin",
    ),
    ("binary frame", HELLO.encode(), wire.CLOSE_MALFORMED, "text"),
    (
        "too big",
        json.dumps(telemetry(mode="A" * wire.MAX_MESSAGE_BYTES)),
        wire.CLOSE_TOO_BIG,
        str(wire.MAX_MESSAGE_BYTES),
    ),
]


@pytest.mark.asyncio
@pytest.mark.parametrize(
    ("message", "code", "named"),
    [pytest.param(m, c, n, id=name) for name, m, c, n in BAD_MESSAGES],
)
async def test_a_bad_message_closes_the_station_link(
    live: Live, world: World, message: str | bytes, code: int, named: str
) -> None:
    async with viewer_ws(live, world.t1, world.s1_id) as viewer:
        async with station_ws(live, world.s1) as ws:
            await welcomed(ws)
            await ws.send(message)
            got, reason = await closed_with(ws)
        assert got == code, (got, reason)
        assert named in reason, reason
        assert reason, "a close reason says what was wrong"
        await assert_offline(live, world, world.s1_id)
        # The viewer saw the station come and go, and nothing of the bad message.
        seen = await drain(viewer, 0.3)
    assert not [m for m in seen if isinstance(m, wire.TelemetryBatch)], seen
    presence = [m.online for m in seen if isinstance(m, wire.Presence)]
    assert presence == [True, False]


@pytest.mark.asyncio
async def test_a_text_frame_that_is_not_utf8_is_closed_with_one_log_line(
    live: Live, world: World, caplog: pytest.LogCaptureFixture
) -> None:
    """1007 with a reason and one warning, not uvicorn's ERROR with a traceback; the
    station's viewer and another station's link go on, and the station may come back."""
    caplog.set_level(logging.INFO)
    uvicorn_log = logging.getLogger("uvicorn")  # it does not propagate to the root logger
    uvicorn_log.addHandler(caplog.handler)
    try:
        async with (
            station_ws(live, world.s2) as other,
            viewer_ws(live, world.t1, world.s1_id) as viewer,
        ):
            await welcomed(other)
            async with station_ws(live, world.s1) as ws:
                await welcomed(ws)
                await asyncio.wait_for(ws.recv(), 5)  # its prescriptions: it is online now
                await ws.send(b'{"type": "heartbeat", "sent": 1.0, "x": "\xff"}', text=True)
                code, reason = await closed_with(ws)
            assert (code, reason) == (wire.CLOSE_MALFORMED, "text messages must be UTF-8")
            await assert_offline(live, world, world.s1_id)
            seen = await drain(viewer, 0.3)
            assert [m.online for m in seen if isinstance(m, wire.Presence)] == [True, False]
            assert await close_of(viewer, 0.1) is None, "the viewer's link closed too"
            await other.send(wire.Heartbeat(sent=time.time()).model_dump_json())
            assert await close_of(other, 0.3) is None, "another station's link closed too"
            assert await online(live, world, world.s2_id)
            async with station_ws(live, world.s1) as again:
                await welcomed(again)
    finally:
        uvicorn_log.removeHandler(caplog.handler)
    assert not [r for r in caplog.records if r.exc_info or r.levelno >= logging.ERROR]
    (line,) = [r.getMessage() for r in caplog.records if "UTF-8" in r.getMessage()]
    assert "(1007): a text message is not UTF-8 (byte " in line, line


@pytest.mark.asyncio
async def test_the_size_limit_counts_bytes_not_characters(live: Live, world: World) -> None:
    """A message over MAX_MESSAGE_BYTES in UTF-8 but under it in characters."""
    text = "é" * (wire.MAX_MESSAGE_BYTES // 2 + 100)
    message = wire.StatusMsg(sent=time.time(), message=text).model_dump_json()
    assert len(message) < wire.MAX_MESSAGE_BYTES < len(message.encode())
    async with station_ws(live, world.s1) as ws:
        await welcomed(ws)
        await ws.send(message)
        closed = await close_of(ws, timeout=2.0)
    assert closed is not None, "the over-size message was taken"
    assert closed[0] == wire.CLOSE_TOO_BIG, closed


@pytest.mark.asyncio
async def test_a_silent_station_is_closed_after_the_heartbeat_timeout(
    live: Live, world: World
) -> None:
    async with station_ws(live, world.s1) as ws:
        await welcomed(ws)
        t0 = time.monotonic()
        code, reason = await closed_with(ws, timeout=wire.HEARTBEAT_TIMEOUT_S + 3.0)
        waited = time.monotonic() - t0
    assert code == wire.CLOSE_TIMEOUT, reason
    assert reason
    assert wire.HEARTBEAT_TIMEOUT_S - 0.5 < waited < wire.HEARTBEAT_TIMEOUT_S + 2.0, waited
    await assert_offline(live, world, world.s1_id)


# -- /ws/live/{station_id} --------------------------------------------------------------------
async def drain(ws: ClientConnection, seconds: float) -> list[Any]:
    """Every message that arrives within ``seconds`` (the link may close meanwhile)."""
    out: list[Any] = []
    deadline = time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0:
        try:
            raw = await asyncio.wait_for(ws.recv(), left)
        except (TimeoutError, ConnectionClosed):
            break
        out.append(wire.VIEWER_DOWN.validate_json(raw))
    return out


@pytest.mark.asyncio
async def test_a_therapist_of_another_patient_and_a_missing_station_look_the_same(
    live: Live, world: World
) -> None:
    refusals = []
    for token, station_id in ((world.t2, world.s1_id), (world.t1, 999_999)):
        with pytest.raises(InvalidStatus) as info:
            async with viewer_ws(live, token, station_id):
                pass
        response = info.value.response
        refusals.append((response.status_code, response.body))
    assert refusals[0][0] == 403
    assert refusals[0] == refusals[1]
    # Her own station she may watch; with a foreign Origin she may not.
    async with viewer_ws(live, world.t1, world.s1_id) as ws:
        welcome = wire.VIEWER_DOWN.validate_json(await asyncio.wait_for(ws.recv(), 5))
        assert isinstance(welcome, wire.Welcome) and welcome.online is False
    with pytest.raises(InvalidStatus) as info:
        async with viewer_ws(live, world.t1, world.s1_id, {"Origin": "https://evil.example"}):
            pass
    assert info.value.response.status_code == 403
    await assert_offline(live, world, world.s1_id)


@pytest.mark.asyncio
@pytest.mark.parametrize("stiffness", [900.0, "40", True], ids=["900", "text", "boolean"])
async def test_an_out_of_range_command_is_closed_and_never_reaches_the_station(
    live: Live, world: World, stiffness: Any
) -> None:
    """Out of range, or not a number at all: a K sent as "40" or true is refused too."""
    too_stiff = json.dumps(
        {
            "type": "command",
            "request_id": "k-900",
            "action": "set_impedance",
            "stiffness": {"pitch": stiffness},
        }
    )
    async with station_ws(live, world.s1) as station:
        await welcomed(station)
        async with viewer_ws(live, world.t1, world.s1_id) as viewer:
            welcome = wire.VIEWER_DOWN.validate_json(await asyncio.wait_for(viewer.recv(), 5))
            assert isinstance(welcome, wire.Welcome) and welcome.online
            await viewer.send(too_stiff)
            code, reason = await closed_with(viewer)
        assert code == wire.CLOSE_MALFORMED
        assert "stiffness.pitch" in reason, reason
        # The station got its prescriptions and heartbeats, and no command.
        await station.send(wire.Heartbeat(sent=time.time()).model_dump_json())
        got = []
        deadline = time.monotonic() + 1.5
        while (left := deadline - time.monotonic()) > 0:
            try:
                got.append(
                    wire.STATION_DOWN.validate_json(await asyncio.wait_for(station.recv(), left))
                )
            except TimeoutError:
                break
        assert not [m for m in got if isinstance(m, wire.Command)], got
        assert any(isinstance(m, wire.Heartbeat) for m in got), "the station link stays up"
    r = await live.client.get(
        "/audit", params={"action": "impedance.request"}, headers=bearer(world.admin)
    )
    assert r.status_code == 200 and r.json() == [], r.text
    await assert_offline(live, world, world.s1_id)


@pytest.mark.asyncio
async def test_a_valid_command_is_relayed_and_audited(live: Live, world: World) -> None:
    """The control case for the test above: the same path with K in range does change
    something (so its "nothing changed" can fail)."""
    async with station_ws(live, world.s1) as station:
        await welcomed(station)
        async with viewer_ws(live, world.t1, world.s1_id) as viewer:
            await asyncio.wait_for(viewer.recv(), 5)
            await viewer.send(
                wire.Command(
                    request_id="k-80", action="set_impedance", stiffness={"pitch": 80.0}
                ).model_dump_json()
            )
            deadline = time.monotonic() + 3
            while True:
                left = deadline - time.monotonic()
                assert left > 0, "the command never reached the station"
                message = wire.STATION_DOWN.validate_json(
                    await asyncio.wait_for(station.recv(), left)
                )
                if isinstance(message, wire.Command):
                    break
    assert message.stiffness == {"pitch": 80.0}
    assert message.by == f"therapist:{world.t1_id}"
    r = await live.client.get(
        "/audit", params={"action": "impedance.request"}, headers=bearer(world.admin)
    )
    assert [row["new"]["stiffness"] for row in r.json()] == [{"pitch": 80.0}]
