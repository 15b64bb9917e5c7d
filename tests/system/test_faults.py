"""Faults of the whole system, with real processes: the station killed mid-repetition, the
server killed mid-session. Nothing recorded is lost or doubled, the device is left safe and
an exercise is not stopped because the clinic's server went away."""

from __future__ import annotations

import asyncio
import contextlib
import signal
import time
from types import SimpleNamespace
from typing import Any

import httpx
import numpy as np
import pytest
from websockets.asyncio.client import ClientConnection
from websockets.asyncio.server import ServerConnection, serve
from websockets.exceptions import ConnectionClosed

from device.protocol.messages import DeviceMode
from sessions import wire
from sessions.recording import decode
from station import server_link
from tests.system.harness import (
    System,
    active,
    bearer,
    free_port,
    live,
    next_of,
    short_strength,
    start_exercise,
    status_until,
    uploaded,
)

SAFE_MODES = ("HOLD", "HOMING", "READY")
"""What a station that starts finds the device doing: held by its watchdog, or going home
(the station sends a platform held on a segment no exercise runs home), or home."""


def prescription(repetitions: int) -> dict[str, Any]:
    return short_strength("Fault test", repetitions)


async def presence(ws: ClientConnection, online: bool, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while (await next_of(ws, wire.Presence, max(0.1, deadline - time.monotonic()))).online != (
        online
    ):
        pass


@pytest.mark.asyncio
async def test_station_killed_mid_repetition_loses_nothing_and_leaves_the_device_safe(
    system: System, therapist: httpx.AsyncClient
) -> None:
    pid, ws, status = await start_exercise(system, therapist, prescription(3))
    sid = status.session_id
    assert sid is not None
    spool_file = system.spool / f"{sid}.rec"
    try:
        await active(ws, 30)
        await asyncio.sleep(1.0)  # well into the repetition: a second of samples on disk
        before = decode(spool_file.read_bytes())
        assert before.header.session_id == sid and before.end is None
        n, last_t = len(before.samples), float(before.samples["t"][-1])
        assert n > 50, n  # 100 Hz, flushed every 0.2 s
        assert (await next_of(ws, wire.TelemetryMsg)).mode == "ACTIVE"

        assert system.station is not None
        system.stop(system.station, signal.SIGKILL)
        assert system.station.returncode == -signal.SIGKILL
        await presence(ws, online=False, timeout=15)

        system.start_station()
        await presence(ws, online=True, timeout=60)  # a new process starts slowly when loaded
        # The device held by itself when the station's heartbeats stopped (its watchdog);
        # the new station neither resumes nor restarts the exercise: it sends it home.
        modes: set[str] = set()
        times: list[float] = []
        deadline = time.monotonic() + 1.5
        while time.monotonic() < deadline:
            t = await next_of(ws, wire.TelemetryMsg, 10)
            modes.add(t.mode)
            times.append(t.t)
        assert modes and modes <= set(SAFE_MODES), modes
        assert min(times) > last_t
        state = await status_until(
            ws, lambda s: s.device_link == "connected" and s.device_mode == "READY", 60
        )
        assert state.session_id is None, state
    finally:
        await ws.close()

    found = await uploaded(therapist, pid, timeout=20)
    assert [s["session_uuid"] for s in found] == [sid]
    (session,) = found
    assert session["end_reason"] == "interrupted"
    r = await therapist.get(session["downloads"]["rec"])
    assert r.status_code == 200
    rec = decode(r.content)
    assert not rec.damaged and rec.end is not None and rec.end.reason == "interrupted"
    assert rec.header.session_id == sid
    t = rec.samples["t"]
    assert len(t) >= n
    assert np.all(np.diff(t) > 0), "device times repeat or go back"
    assert np.any(t == last_t), "a sample on disk before the kill is missing"
    assert np.array_equal(t[:n], before.samples["t"]), "the uploaded prefix differs"

    # The spool copy goes once the server has confirmed it, and nothing is left pending.
    deadline = time.monotonic() + 10
    while spool_file.exists():
        assert time.monotonic() < deadline, "the spool file outlived its confirmed upload"
        await asyncio.sleep(0.1)
    assert list(system.spool.glob("*.rec")) == []


@pytest.mark.sqlite_only
@pytest.mark.asyncio
async def test_station_stopped_by_sigterm_stops_the_exercise_and_ends_its_session(
    system: System, therapist: httpx.AsyncClient
) -> None:
    """SIGTERM (a service manager, `ankle run` stopping) used to end the station with the
    session open: filed at the next start as killed, crashed or lost power, with the restart
    as its end. Now the exercise stops as on STOP (the platform holds, goes home) and the
    session ends "stopped", saying why, before the station exits."""
    pid, ws, status = await start_exercise(system, therapist, prescription(3))
    sid = status.session_id
    assert sid is not None and system.station is not None
    spool_file = system.spool / f"{sid}.rec"
    try:
        await active(ws, 30)
        await asyncio.sleep(1.0)  # well into the repetition
        asked_at = time.time()
        system.station.send_signal(signal.SIGTERM)
        assert await asyncio.to_thread(system.station.wait, 30) == 0
        await presence(ws, online=False, timeout=15)
    finally:
        await ws.close()
    log = system.logs[-1].read_text()
    assert "Traceback" not in log, log[-3000:]

    rec = decode(spool_file.read_bytes())
    assert rec.end is not None and rec.end.reason == "stopped", rec.end
    assert rec.end.text.startswith("the station was stopped (SIGTERM)"), rec.end
    assert rec.end.repetitions_completed < 3
    wall = rec.samples["wall"]
    assert asked_at <= rec.end.ended_at <= float(wall[-1]) + 1.0, (rec.end, float(wall[-1]))
    # Held at once, not run out, then sent home; recorded to its end.
    went = [(e.detail["from"], e.detail["to"]) for e in rec.events if e.by == "device"]
    went = went[went.index(("ACTIVE", "HOLD")) :]
    assert went[:2] == [("ACTIVE", "HOLD"), ("HOLD", "HOMING")], went
    last = DeviceMode(int(rec.samples["mode"][-1]))
    assert last in (DeviceMode.HOMING, DeviceMode.READY), last

    # Started again, the station sends it as it ended, and the device is where it was left.
    system.start_station()
    (session,) = await uploaded(therapist, pid, timeout=60)
    assert (session["session_uuid"], session["end_reason"]) == (sid, "stopped")
    ws = await live(system, bearer(therapist))
    try:
        state = await status_until(ws, lambda s: s.device_link == "connected", 30)
        assert state.device_mode in SAFE_MODES and state.session_id is None, state
    finally:
        await ws.close()


@pytest.mark.asyncio
async def test_server_killed_mid_session_the_exercise_runs_on_and_uploads(
    system: System, therapist: httpx.AsyncClient
) -> None:
    pid, ws, status = await start_exercise(system, therapist, prescription(3))
    sid = status.session_id
    try:
        first = await active(ws, 30)
        assert (first.set, first.rep) == (1, 1)
        system.stop_servers(signal.SIGKILL)  # every process: the clinic's server is gone
        assert [p.returncode for p in system.servers] == [-signal.SIGKILL] * len(system.servers)
        with pytest.raises(ConnectionClosed):  # noqa: PT012 - the open view sees it go
            while True:
                await asyncio.wait_for(ws.recv(), 5)
    finally:
        await ws.close()
    await asyncio.sleep(1.0)  # the station notices and backs off
    await asyncio.to_thread(system.start_servers)
    # From when the server answers again (its own start is slow on a loaded machine): the
    # station's reconnect waits are at most 10 s.
    up_at = time.monotonic()

    ws = await live(system, bearer(therapist))
    try:
        welcome = await next_of(ws, wire.Welcome)
        if not welcome.online:
            await presence(ws, online=True, timeout=30)
        back_after = time.monotonic() - up_at
        assert back_after < 20, back_after
        # The exercise went on meanwhile: the station reports it running (or already done),
        # never stopped or paused, and it runs to its end.
        statuses = [await next_of(ws, wire.StatusMsg, 15)]
        ages = [time.time() - statuses[0].sent]
        deadline = time.monotonic() + 30
        while statuses[-1].phase not in ("done", "stopped", "fault"):
            left = max(0.1, deadline - time.monotonic())
            statuses.append(await next_of(ws, wire.StatusMsg, left))
            ages.append(time.time() - statuses[-1].sent)
        assert statuses[-1].phase == "done", statuses[-1]
        assert {s.phase for s in statuses} <= {"running", "done"}, statuses
        assert {s.session_id for s in statuses if s.phase == "running"} <= {sid}, statuses
        # Status is state, not history: what the station had to say while the server was
        # away is not replayed to viewers once it is back (at most the one in flight).
        stale = [round(age, 1) for age in ages if age > 1.5]
        assert len(stale) <= 1, stale
    finally:
        await ws.close()

    (session,) = await uploaded(therapist, pid, timeout=20)
    assert session["session_uuid"] == sid
    assert session["end_reason"] == "completed"
    summary = session["summary"]
    assert summary["repetitions_completed"] == summary["repetitions_prescribed"] == 3
    r = await therapist.get(session["downloads"]["rec"])
    rec = decode(r.content)
    t = rec.samples["t"]
    assert np.all(np.diff(t) > 0)
    # Recorded throughout: no hole where the server was away.
    assert float(np.max(np.diff(t))) < 0.5, float(np.max(np.diff(t)))
    assert not [e for e in rec.events if e.kind in ("hold", "stop", "watchdog")], rec.events


@pytest.mark.asyncio
async def test_the_station_link_retries_soon_after_a_good_connection_drops(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The link side of the test above, in-process and on a fake clock: a server that was
    unreachable for a while (backoff grown), then up, then killed, is retried at once, not
    after the backoff the earlier failures had built up."""
    sleeps: list[float] = []

    async def sleep(seconds: float) -> None:
        sleeps.append(seconds)
        await asyncio.sleep(0.01)

    fake = SimpleNamespace(**{**vars(asyncio), "sleep": sleep})
    monkeypatch.setattr(server_link, "asyncio", fake)
    port = free_port()

    connected_after: list[int] = []  # sleeps taken before each connection

    async def killed_after_welcome(ws: ServerConnection) -> None:
        connected_after.append(len(sleeps))
        await ws.recv()
        await ws.send(wire.Welcome(station_id=1, patient_id=1, server_time=0).model_dump_json())
        await asyncio.sleep(0.05)
        ws.transport.abort()  # the server process dies: no close frame

    async def ignore(message: Any) -> None:
        pass

    link = server_link.ServerLink(
        f"http://127.0.0.1:{port}",
        "token",
        lambda: wire.StationHello(protocol=wire.PROTOCOL, software="test"),
        ignore,
    )
    task = asyncio.create_task(link.run())
    try:
        deadline = time.monotonic() + 10
        while len(sleeps) < 4:  # refused four times: the window is at 8 s
            assert time.monotonic() < deadline
            await asyncio.sleep(0.005)
        async with serve(killed_after_welcome, "127.0.0.1", port):
            while link.connects < 2:
                assert time.monotonic() < deadline, sleeps
                await asyncio.sleep(0.005)
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
    # jittered waits (station/backoff.py) inside windows that double: 0-1, 0-2, 0-4, 0-8 s
    window = server_link.RECONNECT_FIRST_S
    for n, wait in enumerate(sleeps[:4]):
        assert 0.0 <= wait <= window * 2**n, sleeps
    first = connected_after[0]
    assert first >= 4, sleeps  # the failures had grown the window before the server came
    # after a good connection the window starts again from the first one
    assert sleeps[first:] and all(0.0 <= w <= window for w in sleeps[first:]), sleeps
