"""The device's link lost mid-exercise, with real processes: the device process stands still
(SIGSTOP) for longer than the station waits for its telemetry, then goes on. The station
ends the session ``interrupted``, saying the link was lost, and uploads it like any other;
after it connects again it tells the truth about the hold the device is in and does not
send the device's past to the live view a second time; the platform, held on the ended
exercise's segment, it sends home."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import time
from collections.abc import Callable
from typing import Any

import httpx
import pytest
from websockets.asyncio.client import ClientConnection, connect
from websockets.typing import Origin

from sessions import wire
from sessions.recording import decode
from station.app import DEVICE_STALE_S
from tests.system.harness import (
    System,
    active,
    next_of,
    short_strength,
    start_exercise,
    uploaded,
)

FROZEN_S = DEVICE_STALE_S + 1.0
"""Longer than the station waits for the device's telemetry before it drops the link."""


async def gather_until(
    ws: ClientConnection, seen: list[Any], done: Callable[[wire.StatusMsg], bool], timeout: float
) -> wire.StatusMsg:
    """Read every message (kept in ``seen``) until a status for which ``done`` holds."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            message = await next_of(ws, object, max(0.1, deadline - time.monotonic()))
        except TimeoutError:
            said = [m for m in seen if isinstance(m, wire.StatusMsg | wire.EventMsg)]
            raise AssertionError(f"not within {timeout:g} s; the last said: {said[-8:]}") from None
        seen.append(message)
        if isinstance(message, wire.StatusMsg) and done(message):
            return message


@pytest.mark.asyncio
async def test_a_device_link_lost_mid_exercise_ends_the_session_and_it_is_uploaded(
    system: System, therapist: httpx.AsyncClient
) -> None:
    pid, ws, status = await start_exercise(system, therapist, short_strength("Link lost", 3))
    sid = status.session_id
    assert sid is not None
    seen: list[Any] = []
    try:
        # A repetition has just begun (seconds of it are left); the device's time now.
        frozen_at = (await active(ws, 30)).t
        os.kill(system.device.pid, signal.SIGSTOP)
        try:
            await asyncio.sleep(FROZEN_S)
        finally:
            os.kill(system.device.pid, signal.SIGCONT)
        # Connected again, the device holding what was under way, the exercise over: the
        # station sends the platform home (nothing would record it moving on a Resume).
        state = await gather_until(
            ws,
            seen,
            lambda s: s.device_link == "connected" and s.device_mode == "READY",
            60,
        )
        assert state.session_id is None and state.phase == "interrupted", state
        assert state.message.startswith("the platform's link was lost: "), state.message
        assert state.hold is None, state
        assert "HOMING" in [m.device_mode for m in seen if isinstance(m, wire.StatusMsg)]
        (sent,) = [m for m in seen if isinstance(m, wire.EventMsg) and m.event.kind == "stop"]
        assert (sent.event.by, sent.session_id) == ("station", None), sent
        assert "which no exercise runs now: sent home" in sent.event.detail["text"], sent
        # While it held, why: the lost link, not a silence of "0 ms" blamed on the station.
        for s in seen:
            if isinstance(s, wire.StatusMsg) and s.hold is not None and s.hold.code != "device":
                text = s.hold.text
                assert s.hold.code == "watchdog" and s.device_mode == "HOLD", s
                assert "link" in text and " 0 ms" not in text and "unknown" not in text, text
        # The patient's page says why in the patient's words (home.js reads link_lost).
        async with connect(
            f"ws://127.0.0.1:{system.page_port}/ws",
            origin=Origin(system.page_url.rstrip("/")),
            open_timeout=10,
        ) as page:
            while (said := json.loads(await asyncio.wait_for(page.recv(), 10)))["type"] != (
                "status"
            ):
                pass
        assert (said["phase"], said["link_lost"]) == ("interrupted", True), said
        await gather_until(ws, seen, lambda s: True, 5)  # what the reconnection brought
    finally:
        await ws.close()

    # The device's events since it stood still reached the live view (the hold), and none
    # from before: it replays its newest to a host that connects, and those the station
    # heard on the first link (homing, the repetition's start) are not news.
    device = [
        (m.event.t, m.event.kind, m.event.detail.get("text"))
        for m in seen
        if isinstance(m, wire.EventMsg) and m.event.by == "device"
    ]
    assert device and all(t is not None and t > frozen_at for t, _, _ in device), device
    assert ("watchdog", "HOLD") in [
        (m.event.kind, m.event.detail["to"])
        for m in seen
        if isinstance(m, wire.EventMsg) and m.event.by == "device"
    ], device

    # Recorded to the loss, ended and uploaded: not cut off, not refused.
    (session,) = await uploaded(therapist, pid, timeout=30)
    assert (session["session_uuid"], session["end_reason"]) == (sid, "interrupted"), session
    summary = session["summary"]
    assert summary["end_text"].startswith("the platform's link was lost: the platform sent "), (
        summary
    )
    assert "station stopped" not in summary["end_text"], summary
    assert [(f["kind"], f["by"]) for f in summary["faults"]] == [("interrupted", "station")], (
        summary["faults"]
    )
    assert summary["faults"][0]["text"].startswith("the platform's link was lost"), summary
    assert not list(system.spool.glob("refused/*")), list(system.spool.glob("refused/*"))
    r = await therapist.get(session["downloads"]["rec"])
    rec = decode(r.content)
    assert rec.end is not None and rec.end.reason == "interrupted" and len(rec.samples), rec.end
    assert rec.end.repetitions_completed < 3, rec.end

    r = await therapist.get("/api/v1/patients/attention")
    assert r.status_code == 200, r.text
    mine = [a for a in r.json() if a.get("session_id") == session["id"]]
    assert [a["kind"] for a in mine] == ["ended_early"], mine
    assert "the platform's link was lost" in mine[0]["text"], mine


@pytest.mark.sqlite_only
@pytest.mark.asyncio
async def test_a_device_killed_mid_exercise_is_the_sessions_end_not_the_stations(
    system: System, therapist: httpx.AsyncClient
) -> None:
    """The device process killed: its session was thrown away with the link, or (under
    ``ankle run``, which restarts the station with the device) closed at the station's next
    start as if the station had been killed, with no safety stop named."""
    pid, ws, status = await start_exercise(system, therapist, short_strength("Device killed", 3))
    sid = status.session_id
    try:
        await active(ws, 30)
        os.kill(system.device.pid, signal.SIGKILL)
        state = await next_of(ws, wire.StatusMsg, 30)
        while state.session_id is not None:
            state = await next_of(ws, wire.StatusMsg, 30)
        assert state.phase == "interrupted", state
    finally:
        await ws.close()
    (session,) = await uploaded(therapist, pid, timeout=30)
    assert (session["session_uuid"], session["end_reason"]) == (sid, "interrupted"), session
    summary = session["summary"]
    assert summary["end_text"].startswith("the platform's link was lost: the "), summary
    assert "station stopped" not in summary["end_text"], summary
    assert [(f["kind"], f["by"]) for f in summary["faults"]] == [("interrupted", "station")]
    assert system.station is not None and system.station.poll() is None  # it carries on
