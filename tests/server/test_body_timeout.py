"""A request whose body stalls is answered 408 and closed by the server alone (no proxy in
front), while a body sent slowly but steadily is served (``server.protocols``)."""

from __future__ import annotations

import asyncio
import json
import logging
import time
import uuid
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

import pytest

from server.headers import API_CSP
from sessions import wire
from station.uploader import CHUNK
from tests.server.live_server import Live, Seeds, Store, World, on_store, running
from tests.server.test_series import recording_bytes, samples
from tests.server.ws_client import close_of, station_ws, welcomed

BODY_TIMEOUT_S = 2.0
STEP_S = 0.2
"""The steady sender's pause between bytes: a tenth of the timeout, so that a loaded
machine's late wake-ups do not make it look stalled."""
GIVE_UP_S = 120.0
"""A busy machine answers late, never this late: the bound is asserted from below only."""


@asynccontextmanager
async def _served(
    seeds: Seeds, store: Store, seeded_store: tuple[Path | str, World], tmp_path: Path
) -> AsyncIterator[Live]:
    """The API on the seeded store, with a body timeout of :data:`BODY_TIMEOUT_S`."""
    with on_store(seeds, store, tmp_path, seeded_store[0]) as base:
        async with running(base.model_copy(update={"body_timeout_s": BODY_TIMEOUT_S})) as live:
            yield live


async def _answer(reader: asyncio.StreamReader) -> tuple[int, bytes]:
    """The status and body of the one answer on a connection the server then closes."""
    status, _, body = await _answer_with_headers(reader)
    return status, body


async def _answer_with_headers(
    reader: asyncio.StreamReader,
) -> tuple[int, dict[str, str], bytes]:
    """:func:`_answer` with the answer's headers (names lower case)."""
    raw = await asyncio.wait_for(reader.read(), GIVE_UP_S)  # to the server's close
    head, _, body = raw.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    headers = dict(line.split(": ", 1) for line in lines[1:])
    return int(lines[0].split(" ", 2)[1]), {k.lower(): v for k, v in headers.items()}, body


@pytest.mark.asyncio
async def test_a_stalled_body_is_answered_408_and_a_slow_steady_one_is_served(
    seeds: Seeds,
    store: Store,
    seeded_store: tuple[Path | str, World],
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Headers that declare more body than ever comes (the upload chunk of a station that
    went quiet halfway, a JSON body of 100 bytes of which 9 came) held the connection for
    good; now each is answered 408 once no byte has come for ``body_timeout_s``, the
    upload holds what it held, and the log says so in one line (no traceback). Meanwhile
    a JSON body trickling a byte at a time for longer than the timeout is served."""
    world = seeded_store[1]
    async with _served(seeds, store, seeded_store, tmp_path) as live:
        port = live.client.base_url.port
        assert port is not None
        sid = str(uuid.uuid4())
        data = recording_bytes(sid, samples(), world.s1_id, world.p1, world.rx1)
        stalled = {
            "chunk": (
                f"PATCH /api/v1/uploads/{sid} HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                f"Authorization: Bearer {world.s1}\r\nUpload-Offset: 0\r\n"
                "Content-Type: application/offset+octet-stream\r\n"
                f"Content-Length: {CHUNK}\r\n\r\n"
            ).encode()
            + data[: CHUNK // 2],
            "json": (
                b"POST /api/v1/auth/login HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                b"Content-Type: application/json\r\nContent-Length: 100\r\n\r\n"
                b'{"email":'
            ),
        }
        started = time.monotonic()
        waiting = []
        try:
            for first in stalled.values():
                reader, writer = await asyncio.open_connection("127.0.0.1", port)
                waiting.append((reader, writer))
                writer.write(first)
                await writer.drain()

            served = await _trickle(port)
            assert served == 401  # the login's answer: its body was read whole

            answers = await asyncio.gather(*(_answer_with_headers(reader) for reader, _ in waiting))
            elapsed = time.monotonic() - started
        finally:
            for _, writer in waiting:
                writer.close()
        for status, headers, body in answers:
            assert status == 408, body
            assert json.loads(body) == {"detail": "the request body stalled: no byte of it for 2 s"}
            # as every other answer: security headers, the date and the server
            assert headers["x-content-type-options"] == "nosniff"
            assert headers["content-security-policy"] == API_CSP
            assert headers["connection"] == "close" and "date" in headers
        assert elapsed >= BODY_TIMEOUT_S
        assert (
            await live.client.head(f"/uploads/{sid}", headers=_station(world))
        ).status_code == 404
        r = await live.client.patch(
            f"/uploads/{sid}",
            content=data[:CHUNK],
            headers={**_station(world), "Upload-Offset": "0"},
        )
        assert r.status_code == 204, r.text
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert sum("no byte of its request body" in w for w in warnings) == 2, warnings
    errors = [r for r in caplog.records if r.levelno >= logging.ERROR or r.exc_info]
    assert not errors, [r.getMessage() for r in errors]


def _station(world: World) -> dict[str, str]:
    return {"Authorization": f"Bearer {world.s1}"}


async def _trickle(port: int) -> int:
    """A sign-in whose body comes one byte every ``STEP_S``, for longer than the timeout;
    the answer's status."""
    body = json.dumps({"email": "nobody@clinic.test", "password": "wrong wrong"}).encode()
    assert len(body) * STEP_S > 2 * BODY_TIMEOUT_S
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(
            b"POST /api/v1/auth/login HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n"
            b"Content-Type: application/json\r\n" + f"Content-Length: {len(body)}\r\n\r\n".encode()
        )
        for i in range(len(body)):
            writer.write(body[i : i + 1])
            await writer.drain()
            await asyncio.sleep(STEP_S)
        status, _ = await _answer(reader)
        return status
    finally:
        writer.close()


@pytest.mark.asyncio
async def test_a_live_link_is_no_body_and_outlives_the_body_timeout(
    seeds: Seeds,
    store: Store,
    seeded_store: tuple[Path | str, World],
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A WebSocket starts as an HTTP request that h11 leaves expecting a body when the link
    is handed over: timed as one, every station's and viewer's link was cut once the body
    timeout passed (60 s), and the station reconnected each minute."""
    world = seeded_store[1]
    async with (
        _served(seeds, store, seeded_store, tmp_path) as live,
        station_ws(live, world.s1) as station,
    ):
        await welcomed(station)
        deadline = time.monotonic() + 3 * BODY_TIMEOUT_S
        while time.monotonic() < deadline:  # beats keep it from being closed as silent
            await station.send(wire.Heartbeat(sent=time.time()).model_dump_json())
            await asyncio.sleep(BODY_TIMEOUT_S / 4)
        await station.send(wire.Heartbeat(sent=time.time()).model_dump_json())
        assert await close_of(station, 0.5) is None  # still open
    assert "request body" not in caplog.text, caplog.text
