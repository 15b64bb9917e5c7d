"""A hold that ends, with real processes: the device's watchdog holds an exercise when the
station stalls, the station ends it once it has been held past its limit (platform home,
session ``interrupted`` with the reason), and every viewer is told why the device holds,
also one that opens after the hold began."""

from __future__ import annotations

import json
import os
import signal
import time

import httpx
import pytest
from pydantic import BaseModel
from websockets.asyncio.client import ClientConnection, connect
from websockets.typing import Origin

from sessions import wire
from sessions.prescription import AXIS_INDEX
from sessions.recording import decode
from station.reasons import HOLD_LIMIT_S
from tests.system.harness import (
    WATCHDOG_MS,
    System,
    active,
    bearer,
    live,
    next_of,
    short_strength,
    start_exercise,
    status_until,
    until,
    uploaded,
)

LIMIT_S = 3.0
STALL_S = 2 * WATCHDOG_MS / 1000
"""Twice the device's watchdog time in these tests (``harness.WATCHDOG_MS``): it holds for
certain."""


def stall(system: System, seconds: float) -> None:
    """Freeze the station process (its heartbeats to the device stop), then let it go on."""
    assert system.station is not None
    os.kill(system.station.pid, signal.SIGSTOP)
    try:
        time.sleep(seconds)
    finally:
        os.kill(system.station.pid, signal.SIGCONT)


@pytest.mark.asyncio
async def test_a_watchdog_hold_past_the_limit_ends_the_exercise_homed_and_interrupted(
    system: System, therapist: httpx.AsyncClient
) -> None:
    body = short_strength("Held too long", repetitions=3)
    pid, ws, status = await start_exercise(system, therapist, body, "--hold-limit", f"{LIMIT_S:g}")
    sid = status.session_id
    try:
        await active(ws, 30)
        stall(system, STALL_S)

        held = await status_until(ws, lambda s: s.hold is not None, 15)
        hold = held.hold
        assert hold is not None
        assert (hold.code, hold.by, hold.patient_may_resume) == ("watchdog", "device", False)
        assert "no frame from the station" in hold.text, hold
        assert (held.phase, held.device_mode, held.session_id) == ("paused", "HOLD", sid), held
        # The station's heartbeats left as late as it was frozen: the hold names this
        # computer, not the cable (within a status or two of the station waking).
        named = await status_until(
            ws,
            lambda s: (
                s.hold is not None and "the home station's computer stood still" in s.hold.text
            ),
            15,
        )
        assert named.hold is not None and named.hold.since == hold.since, named.hold
        assert hold.ends_at is not None and hold.ends_at - hold.since == pytest.approx(LIMIT_S)
        assert held.fault == "", held  # held, not faulted

        # Nobody resumes: the station ends the exercise, the platform goes home, and the
        # viewer is told why, in the events and in the status.
        seen: list[BaseModel] = []
        while True:
            m = await next_of(ws, BaseModel, 60)
            seen.append(m)
            if isinstance(m, wire.StatusMsg) and m.phase == "interrupted" and m.session_id is None:
                ended = m
                break
        modes = [m.device_mode for m in seen if isinstance(m, wire.StatusMsg)]
        assert "ACTIVE" not in modes, modes  # it never resumed by itself
        (event,) = [
            m.event for m in seen if isinstance(m, wire.EventMsg) and m.event.kind == "interrupted"
        ]
        assert event.by == "station" and event.detail["hold"] == "watchdog", event
        assert event.wall >= hold.ends_at, (event.wall, hold)
        assert f"longer than the {LIMIT_S:g} s limit" in event.detail["text"], event
        home = await status_until(ws, lambda s: s.device_mode == "READY", 60)
        assert home.phase == "interrupted" and home.hold is None, home
        assert "the platform went home" in ended.message + home.message, (ended, home)
    finally:
        await ws.close()

    (session,) = await uploaded(therapist, pid, timeout=30)
    assert session["session_uuid"] == sid
    assert session["end_reason"] == "interrupted", session
    summary = session["summary"]
    assert f"longer than the {LIMIT_S:g} s limit" in summary["end_text"], summary
    assert "watchdog" in summary["end_text"] and "went home" in summary["end_text"], summary
    kinds = [f["kind"] for f in summary["faults"]]
    assert "watchdog" in kinds and "interrupted" in kinds, summary["faults"]
    assert summary["repetitions_completed"] < 3, summary
    r = await therapist.get(session["downloads"]["rec"])
    rec = decode(r.content)
    assert rec.end is not None and rec.end.reason == "interrupted"
    assert rec.end.text == summary["end_text"]


@pytest.mark.asyncio
async def test_a_therapists_hold_is_shown_to_a_later_viewer_and_only_the_therapist_resumes(
    system: System, therapist: httpx.AsyncClient
) -> None:
    body = short_strength("Held by the therapist", repetitions=5)
    _, ws, status = await start_exercise(system, therapist, body)
    try:
        await active(ws, 30)
        await ws.send(wire.Command(request_id="hold", action="hold").model_dump_json())
        result = await next_of(ws, wire.CommandResult, 10)
        assert result.request_id == "hold" and result.ok, result
        held = await status_until(ws, lambda s: s.hold is not None and s.device_mode == "HOLD", 10)
        hold = held.hold
        assert hold is not None
        assert hold.code == "therapist" and hold.by.startswith("therapist:"), hold
        assert hold.since <= time.time() and not hold.patient_may_resume
        assert hold.ends_at is not None  # the default limit:
        assert hold.ends_at - hold.since == pytest.approx(HOLD_LIMIT_S), hold
        assert held.phase == "paused"

        # A view opened now learns from the server's welcome why the device holds.
        later = await live(system, bearer(therapist))
        try:
            welcome = await next_of(later, wire.Welcome, 10)
            assert welcome.status is not None and welcome.status.hold == hold, welcome
        finally:
            await later.close()

        # The patient's page may not continue the therapist's hold: the station refuses and
        # nothing moves.
        async with connect(
            f"ws://127.0.0.1:{system.page_port}/ws", origin=Origin(system.page_url.rstrip("/"))
        ) as page:
            await page.send(json.dumps({"type": "resume", "id": "r1"}))
            while (answer := json.loads(await page.recv()))["type"] != "result":
                pass
        assert answer["ok"] is False, answer
        assert "your therapist is holding the exercise" in answer["text"], answer
        still = await status_until(ws, lambda s: True, 5)
        assert still.device_mode == "HOLD" and still.hold == hold, still

        # The therapist's Resume carries on, and the hold is gone.
        await ws.send(wire.Command(request_id="resume", action="resume").model_dump_json())
        result = await next_of(ws, wire.CommandResult, 10)
        assert result.request_id == "resume" and result.ok, result
        going = await status_until(ws, lambda s: s.hold is None, 10)
        assert going.phase == "running" and going.session_id == status.session_id, going
    finally:
        await ws.close()


async def result_of(ws: ClientConnection, request_id: str) -> wire.CommandResult:
    while True:
        result: wire.CommandResult = await next_of(ws, wire.CommandResult, 10)
        if result.request_id == request_id:
            return result


@pytest.mark.asyncio
async def test_a_kb_change_while_held_applies_on_resume_and_both_logs_record_it_alike(
    system: System, therapist: httpx.AsyncClient
) -> None:
    """Held, the device keeps rendering the old K and B: the answer says the change applies
    on Resume, and it does. Two changes while held (40 -> 60 -> 80, while 40 stays in force)
    are recorded with the same old and new values in the audit log and the session's own
    event log."""
    pitch = AXIS_INDEX["pitch"]
    body = short_strength("Changed while held", repetitions=8)
    pid, ws, _ = await start_exercise(system, therapist, body)
    changes: list[wire.ImpedanceChange] = []
    try:
        await active(ws, 30)
        await ws.send(wire.Command(request_id="hold", action="hold").model_dump_json())
        assert (await result_of(ws, "hold")).ok
        await status_until(ws, lambda s: s.device_mode == "HOLD", 10)
        for n, k in enumerate((60.0, 80.0)):
            cmd = wire.Command(request_id=f"kb-{n}", action="set_impedance", stiffness={"pitch": k})
            await ws.send(cmd.model_dump_json())
            result = await result_of(ws, f"kb-{n}")
            assert result.ok, result
            assert result.code == "DEFERRED" and "applies on Resume" in result.text, result
            assert result.change is not None and result.change.applies == "on_resume", result
            changes.append(result.change)
        assert [c.old.stiffness for c in changes] == [{"pitch": 40.0}, {"pitch": 60.0}]
        assert [c.new.stiffness for c in changes] == [{"pitch": 60.0}, {"pitch": 80.0}]
        held = await until(ws, wire.TelemetryMsg, lambda t: t.mode == "HOLD", 10)
        assert held.stiffness[pitch] == pytest.approx(40.0), "held: the old K stays in force"

        await ws.send(wire.Command(request_id="resume", action="resume").model_dump_json())
        assert (await result_of(ws, "resume")).ok
        now = await until(ws, wire.TelemetryMsg, lambda t: t.stiffness[pitch] > 79.9, 15)
        assert now.mode == "ACTIVE", now
        await ws.send(wire.Command(request_id="stop", action="stop").model_dump_json())
        assert (await result_of(ws, "stop")).ok
    finally:
        await ws.close()

    r = await therapist.get("/api/v1/audit", params={"action": "impedance.change"})
    assert r.status_code == 200, r.text
    audited = sorted(r.json(), key=lambda row: row["id"])
    (session,) = await uploaded(therapist, pid, timeout=60)
    rec = decode((await therapist.get(session["downloads"]["rec"])).content)
    recorded = [e.detail for e in rec.events if e.kind == "impedance"]
    assert len(audited) == len(recorded) == 2, (audited, recorded)
    for row, event, change in zip(audited, recorded, changes, strict=True):
        assert row["old"] == event["old"] == change.old.model_dump(), (row, event)
        made = {key: row["new"][key] for key in ("stiffness", "damping", "applies")}
        assert made == event["new"] | {"applies": event["applies"]}, (row, event)
        assert event["new"] == change.new.model_dump() and event["applies"] == "on_resume"
