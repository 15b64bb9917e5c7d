"""The demo (``ankle run``'s station: --autostart --repeat-after S) through the patient's page:
it repeats an exercise that finished, and never moves after STOP until Start is pressed.

Real processes (server, simulated device, station); the test is the patient's page, over its
WebSocket, as the browser would be."""

from __future__ import annotations

import asyncio
import json
import time
from typing import Any

import httpx
import pytest
from websockets.asyncio.client import ClientConnection, connect
from websockets.typing import Origin

from tests.system.harness import System, short_strength

REPEAT_S = 2.5
"""The test's repeat: short, so that waiting three times as long is still quick."""
QUIET_S = 3 * REPEAT_S
MOVING = ("homing", "running", "rest", "paused")


async def page_socket(system: System, timeout: float = 60.0) -> ClientConnection:
    """The page's WebSocket, once the station serves it."""
    origin = f"http://127.0.0.1:{system.page_port}"
    deadline = time.monotonic() + timeout
    while True:
        try:
            return await connect(
                f"ws://127.0.0.1:{system.page_port}/ws", origin=Origin(origin), open_timeout=5
            )
        except OSError:
            assert system.station is not None and system.station.poll() is None, system.log_tail()
            assert time.monotonic() < deadline, "the page never answered:\n" + system.log_tail()
            time.sleep(0.3)


async def status_until(ws: ClientConnection, done: Any, timeout: float) -> dict[str, Any]:
    """The first status the page gets that ``done`` accepts."""
    deadline = time.monotonic() + timeout
    last: dict[str, Any] | None = None
    while True:
        left = deadline - time.monotonic()
        assert left > 0, f"no such status within {timeout} s; the last: {last}"
        try:
            message: dict[str, Any] = json.loads(await _recv(ws, left))
        except TimeoutError:
            continue
        if message["type"] == "status":
            last = message
            if done(message):
                return message


async def _recv(ws: ClientConnection, timeout: float) -> str | bytes:
    return await asyncio.wait_for(ws.recv(), timeout)


async def statuses_for(ws: ClientConnection, seconds: float) -> list[dict[str, Any]]:
    """Every status the page gets for ``seconds`` (it gets one at least every second)."""
    seen: list[dict[str, Any]] = []
    deadline = time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0:
        try:
            message = json.loads(await asyncio.wait_for(ws.recv(), left))
        except TimeoutError:
            break
        if message["type"] == "status":
            seen.append(message)
    return seen


async def press(ws: ClientConnection, action: dict[str, Any]) -> dict[str, Any]:
    await ws.send(json.dumps({**action, "id": action["type"]}))
    while True:
        message: dict[str, Any] = json.loads(await _recv(ws, 30))
        if message["type"] == "result" and message["id"] == action["type"]:
            return message


@pytest.mark.sqlite_only  # the station's own loop and page: no store or relay takes part
@pytest.mark.asyncio
async def test_the_demo_repeats_a_finished_exercise_but_never_moves_after_stop(
    system: System, therapist: httpx.AsyncClient
) -> None:
    pid = system.creds["prescription_id"]
    r = await therapist.patch(f"/api/v1/prescriptions/{pid}", json=short_strength("Demo", 1))
    assert r.status_code == 200, r.text
    system.start_station("--autostart", "--repeat-after", str(REPEAT_S))
    ws = await page_socket(system)
    try:
        # It starts by itself, finishes, says when it starts again, and does.
        first = await status_until(ws, lambda s: s["phase"] == "running", 90)
        done = await status_until(ws, lambda s: s["phase"] == "done", 90)
        assert done["starts_again_at"] is not None
        assert 0 < done["starts_again_at"] - time.time() <= REPEAT_S + 1
        again = await status_until(ws, lambda s: s["phase"] == "running", 60)
        assert again["session_id"] != first["session_id"]

        # STOP while it moves: it stops, and nothing starts again by itself.
        assert (await press(ws, {"type": "stop"}))["ok"]
        stopped = await status_until(ws, lambda s: s["phase"] == "stopped", 60)
        assert stopped["starts_again_at"] is None
        quiet = await statuses_for(ws, QUIET_S)
        assert len(quiet) >= QUIET_S / 2, "the page stopped hearing from the station"
        moved = [s for s in quiet if s["phase"] in MOVING or s["device_mode"] == "ACTIVE"]
        assert not moved, moved[0]
        assert all(s["starts_again_at"] is None for s in quiet)

        # Start by hand: the demo repeats again after a finished exercise...
        assert (await press(ws, {"type": "start", "prescription_id": pid}))["ok"]
        await status_until(ws, lambda s: s["phase"] == "running", 60)
        done = await status_until(ws, lambda s: s["phase"] == "done", 90)
        assert done["starts_again_at"] is not None
        # ... until STOP in the pause between two: "Well done!" stays still.
        await press(ws, {"type": "stop"})  # nothing runs: the platform is told to hold still
        quiet = await statuses_for(ws, QUIET_S)
        assert quiet and quiet[-1]["phase"] == "done"
        moved = [s for s in quiet if s["phase"] in MOVING or s["device_mode"] == "ACTIVE"]
        assert not moved, moved[0]
        assert quiet[-1]["starts_again_at"] is None
    finally:
        await ws.close()
