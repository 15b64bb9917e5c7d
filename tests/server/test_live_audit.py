"""Every live command a therapist sends is on the audit log with its outcome.

A real uvicorn on a seeded database (``live``), a raw ``websockets`` station that answers
commands as a station relays its device's ACK or NACK (or does not answer), and a raw
viewer that sends them. The audit log is read through ``GET /audit`` as a clinic would.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from typing import Any

import pytest
from sqlalchemy import text
from websockets.asyncio.client import ClientConnection

from server import hub, live_audit, metrics
from server.hub import COMMAND_TIMEOUT_S
from server.relay import LocalRelay, Message
from sessions import wire
from sessions.prescription import AXIS_INDEX
from tests.server.live_server import Live, World, bearer
from tests.server.ws_client import station_ws, telemetry, viewer_ws, welcomed

pytestmark = pytest.mark.both_stores

WAIT_S = 15.0
"""Deadline for anything the server does on its own (a shared 2-core machine)."""
ACK_TEXT = "acknowledged by the device"


SET_BEFORE: tuple[dict[str, float], dict[str, float]] = ({"pitch": 60.0}, {"pitch": 2.5})
"""What the fake station says was set before a K/B change: not what its telemetry says is in
force (40 and 2, as during a HOLD), so a log that took the value in force would differ."""


def ack(cmd: wire.Command) -> wire.CommandResult:
    """The device's ACK, and for a K/B change the change as a station reports it."""
    change = None
    if cmd.action == "set_impedance":
        after = tuple(
            {**was, **dict(asked.items())}
            for was, asked in zip(SET_BEFORE, (cmd.stiffness or {}, cmd.damping or {}), strict=True)
        )
        change = wire.ImpedanceChange.between(SET_BEFORE, (after[0], after[1]), cmd, "on_resume")
    return wire.CommandResult(
        request_id=cmd.request_id, ok=True, text=ACK_TEXT, rtt_ms=4.0, change=change
    )


def silent(cmd: wire.Command) -> None:
    return None


async def heartbeats(ws: ClientConnection) -> None:
    while True:
        await ws.send(wire.Heartbeat(sent=time.time()).model_dump_json())
        await asyncio.sleep(wire.HEARTBEAT_S)


@dataclass
class Station:
    """A station link that answers each command with ``answer(cmd)`` (None: no answer)."""

    ws: ClientConnection
    commands: asyncio.Queue[wire.Command] = field(default_factory=asyncio.Queue)

    async def next_command(self) -> wire.Command:
        return await asyncio.wait_for(self.commands.get(), WAIT_S)

    async def send(self, message: Any) -> None:
        await self.ws.send(message.model_dump_json())


@asynccontextmanager
async def station(
    live: Live,
    world: World,
    answer: Callable[[wire.Command], wire.CommandResult | None],
    **sample: Any,
) -> AsyncIterator[Station]:
    async with station_ws(live, world.s1) as ws:
        await welcomed(ws)
        link = Station(ws)
        if sample:
            await ws.send(json.dumps(telemetry(**sample)))

        async def serve() -> None:
            async for raw in ws:
                message = wire.STATION_DOWN.validate_json(raw)
                if isinstance(message, wire.Command):
                    link.commands.put_nowait(message)
                    result = answer(message)
                    if result is not None:
                        await link.send(result)

        tasks = [asyncio.create_task(serve()), asyncio.create_task(heartbeats(ws))]
        try:
            yield link
        finally:
            for task in tasks:
                task.cancel()


@dataclass
class Viewer:
    ws: ClientConnection
    welcome: wire.Welcome
    seen: list[Any] = field(default_factory=list)

    async def send(self, request_id: str, action: str, **fields: Any) -> None:
        command = {"type": "command", "request_id": request_id, "action": action, **fields}
        await self.ws.send(json.dumps(command))

    async def next_of(self, kind: type[Any], request_id: str | None = None) -> Any:
        """The next message of ``kind`` (a result: the one for ``request_id``)."""
        deadline = time.monotonic() + WAIT_S
        while True:
            left = deadline - time.monotonic()
            assert left > 0, f"no {kind.__name__} {request_id or ''} within {WAIT_S} s"
            message = wire.VIEWER_DOWN.validate_json(await asyncio.wait_for(self.ws.recv(), left))
            self.seen.append(message)
            if isinstance(message, kind) and getattr(message, "request_id", None) in (
                None,
                request_id,
            ):
                return message


@asynccontextmanager
async def viewer(live: Live, token: str, station_id: int) -> AsyncIterator[Viewer]:
    async with viewer_ws(live, token, station_id) as ws:
        welcome = wire.VIEWER_DOWN.validate_json(await asyncio.wait_for(ws.recv(), WAIT_S))
        assert isinstance(welcome, wire.Welcome)
        beat = asyncio.create_task(heartbeats(ws))
        try:
            yield Viewer(ws, welcome)
        finally:
            beat.cancel()


async def audit_rows(live: Live, token: str, **params: Any) -> list[dict[str, Any]]:
    r = await live.client.get("/audit", params={"limit": 500, **params}, headers=bearer(token))
    assert r.status_code == 200, r.text
    rows: list[dict[str, Any]] = r.json()
    return rows


async def rows_of(live: Live, world: World, request_id: str, n: int) -> list[dict[str, Any]]:
    """The audit rows of one command, oldest first, once there are ``n`` of them (outcomes
    are written just after the answer is relayed)."""
    deadline = time.monotonic() + WAIT_S
    while len(rows := await audit_rows(live, world.admin, request_id=request_id)) < n:
        assert time.monotonic() < deadline, f"{request_id}: {len(rows)} audit rows, not {n}"
        await asyncio.sleep(0.05)
    assert len(rows) == n, rows
    return rows[::-1]


def vector(**axes: float) -> list[float]:
    v = [0.0] * 6
    for axis, value in axes.items():
        v[AXIS_INDEX[axis]] = value
    return v


@pytest.mark.asyncio
async def test_each_command_is_audited_when_sent_and_with_the_devices_answer(
    live: Live, world: World
) -> None:
    in_force = {"stiffness": vector(pitch=40.0), "damping": vector(pitch=2.0)}
    actor = f"user:{world.t1_id}"
    async with (
        station(live, world, ack, **in_force) as link,
        viewer(live, world.t1, world.s1_id) as v,
    ):
        await v.next_of(wire.TelemetryBatch)  # the K/B in force reached the server
        asked: list[tuple[str, str, dict[str, Any]]] = [
            ("kb", "set_impedance", {"stiffness": {"pitch": 80.0}, "damping": {"pitch": 3.0}}),
            ("hold", "hold", {}),
            ("resume", "resume", {}),
            ("stop", "stop", {}),
            ("start", "start", {"prescription_id": world.rx1}),
        ]
        for request_id, action, fields in asked:
            await v.send(request_id, action, **fields)
            result = await v.next_of(wire.CommandResult, request_id)
            assert result.ok and result.text == ACK_TEXT, result
            relayed = await link.next_command()
            assert (relayed.request_id, relayed.by) == (request_id, f"therapist:{world.t1_id}")

    # The change is recorded as the station made it (what was set before, not what the
    # telemetry showed in force), with when it applies; the request says only what was asked.
    replaced = {"stiffness": {"pitch": 60.0}, "damping": {"pitch": 2.5}}
    expected = {
        "kb": ("impedance.request", "impedance.change", replaced, {"applies": "on_resume"}),
        "hold": ("hold.request", "hold.accepted", None, {}),
        "resume": ("resume.request", "resume.accepted", None, {}),
        "stop": ("stop.request", "stop.accepted", None, {}),
        "start": ("start.request", "start.accepted", None, {}),
    }
    for request_id, _, fields in asked:
        request, outcome = await rows_of(live, world, request_id, 2)
        first, then, old, when = expected[request_id]
        for row in (request, outcome):
            assert (row["actor"], row["entity"], row["entity_id"], row["patient_id"]) == (
                actor,
                "station",
                str(world.s1_id),
                world.p1,
            ), row
        assert (request["action"], request["old"]) == (first, None)
        assert request["new"] == {"request_id": request_id, **fields}
        assert (outcome["action"], outcome["old"]) == (then, old)
        assert outcome["new"] == {
            "request_id": request_id,
            **fields,
            **when,
            "code": "",
            "field": "",
            "text": ACK_TEXT,
        }
        assert request["id"] < outcome["id"]
    # The patient's own therapist reads them; another therapist does not.
    mine = await audit_rows(live, world.t1, station_id=world.s1_id)
    assert {r["new"].get("request_id") for r in mine} >= {r for r, _, _ in asked}
    assert await audit_rows(live, world.t2, station_id=world.s1_id) == []


@pytest.mark.asyncio
async def test_a_refused_kb_change_is_recorded_as_refused_and_never_as_a_change(
    live: Live, world: World
) -> None:
    def nack(cmd: wire.Command) -> wire.CommandResult:
        return wire.CommandResult(
            request_id=cmd.request_id,
            ok=False,
            code="OUT_OF_RANGE",
            field="damping",
            text="pitch damping 0.1 is below the stable envelope's 0.6 N m s/rad",
        )

    async with (
        station(live, world, nack, stiffness=vector(pitch=40.0)),
        viewer(live, world.t1, world.s1_id) as v,
    ):
        await v.next_of(wire.TelemetryBatch)
        await v.send("kb-low", "set_impedance", damping={"pitch": 0.1})
        result = await v.next_of(wire.CommandResult, "kb-low")
        assert (result.ok, result.code) == (False, "OUT_OF_RANGE")
    request, outcome = await rows_of(live, world, "kb-low", 2)
    assert request["action"] == "impedance.request"
    assert outcome["action"] == "impedance.refused"
    assert outcome["old"] is None, "a refusal replaced nothing"
    assert outcome["new"] == {
        "request_id": "kb-low",
        "stiffness": {},
        "damping": {"pitch": 0.1},
        "code": "OUT_OF_RANGE",
        "field": "damping",
        "text": "pitch damping 0.1 is below the stable envelope's 0.6 N m s/rad",
    }
    assert await audit_rows(live, world.admin, action="impedance.change") == []


@pytest.mark.asyncio
async def test_an_unanswered_command_is_recorded_as_such_and_a_late_answer_too(
    live: Live, world: World
) -> None:
    """No answer within COMMAND_TIMEOUT_S: unanswered (TIMEOUT). The device may still have
    acted: an ACK that comes after it is recorded as the change it is, marked late."""
    async with (
        station(live, world, silent, stiffness=vector(pitch=40.0)) as link,
        viewer(live, world.t1, world.s1_id) as v,
    ):
        await v.next_of(wire.TelemetryBatch)
        t0 = time.monotonic()
        await v.send("kb-slow", "set_impedance", stiffness={"pitch": 70.0})
        cmd = await link.next_command()
        result = await v.next_of(wire.CommandResult, "kb-slow")
        assert (result.ok, result.code) == (False, "TIMEOUT")
        assert time.monotonic() - t0 >= COMMAND_TIMEOUT_S - 0.1
        request, unanswered = await rows_of(live, world, "kb-slow", 2)
        assert (request["action"], unanswered["action"]) == (
            "impedance.request",
            "impedance.unanswered",
        )
        assert unanswered["new"]["code"] == "TIMEOUT" and unanswered["old"] is None
        assert await audit_rows(live, world.admin, action="impedance.change") == []
        await link.send(ack(cmd))
        late = await v.next_of(wire.CommandResult, "kb-slow")
        assert late.ok
    *_, change = await rows_of(live, world, "kb-slow", 3)
    assert change["action"] == "impedance.change"
    assert change["new"]["late"] is True
    assert change["old"] == {"stiffness": {"pitch": 60.0}, "damping": {}}
    assert change["new"]["stiffness"] == {"pitch": 70.0} and change["new"]["damping"] == {}


@pytest.mark.asyncio
async def test_only_the_first_answer_to_a_command_sent_reaches_the_viewers(
    live: Live, world: World
) -> None:
    """A station answered one Resume twice (ACK, then a refusal): the viewers were shown it
    accepted, then refused, and only the ACK was audited; a result for a request id nobody
    sent reached them too. Each is dropped: the viewers see the one audited answer."""
    async with (
        viewer(live, world.t1, world.s1_id) as v,
        station(live, world, silent) as link,
    ):
        await v.next_of(wire.Presence)
        await v.send("twice", "resume")
        cmd = await link.next_command()
        await link.send(ack(cmd))
        await link.send(wire.CommandResult(request_id="twice", ok=False, code="E", text="no"))
        await link.send(wire.CommandResult(request_id="invented", ok=True, text=ACK_TEXT))
        await v.send("after", "resume")
        await link.send(ack(await link.next_command()))
        await v.next_of(wire.CommandResult, "after")
    results = [(m.request_id, m.ok) for m in v.seen if isinstance(m, wire.CommandResult)]
    assert results == [("twice", True), ("after", True)]
    request, outcome = await rows_of(live, world, "twice", 2)
    assert (request["action"], outcome["action"]) == ("resume.request", "resume.accepted")


@pytest.mark.asyncio
async def test_a_flood_of_answers_to_nothing_is_counted_and_logged_a_few_times(
    live: Live, world: World, caplog: pytest.LogCaptureFixture
) -> None:
    """A station answering request ids nobody sent, as fast as it can, wrote a warning for
    each: the log grew as fast as the station could send. The metric counts every one; the
    log says a few, then how many it left out."""
    caplog.set_level(logging.WARNING, "ankle.server.live")
    dropped = metrics.RESULTS_DROPPED._value.get()
    async with viewer(live, world.t1, world.s1_id) as v, station(live, world, silent) as link:
        await v.next_of(wire.Presence)
        for k in range(40):
            await link.send(wire.CommandResult(request_id=f"n{k}", ok=True, text=ACK_TEXT))
        await v.send("after", "resume")
        await link.send(ack(await link.next_command()))
        await v.next_of(wire.CommandResult, "after")
    warned = [r.getMessage() for r in caplog.records if "not awaiting its answer" in r.getMessage()]
    assert metrics.RESULTS_DROPPED._value.get() - dropped == 40
    assert len(warned) == hub.DROPPED_LOG_WINDOW.amount, warned
    assert "'n0'" in warned[0] and "more like it" not in warned[0]


@pytest.mark.asyncio
async def test_a_command_whose_station_link_closes_is_unanswered(live: Live, world: World) -> None:
    async with viewer(live, world.t1, world.s1_id) as v:
        async with station(live, world, silent) as link:
            await v.next_of(wire.Presence)
            await v.send("gone", "resume")
            await link.next_command()
        result = await v.next_of(wire.CommandResult, "gone")
    assert (result.ok, result.code) == (False, "OFFLINE")
    request, outcome = await rows_of(live, world, "gone", 2)
    assert (request["action"], outcome["action"]) == ("resume.request", "resume.unanswered")
    assert outcome["new"]["code"] == "OFFLINE"


@pytest.mark.asyncio
async def test_commands_the_server_refuses_are_recorded_as_refused_and_never_sent(
    live: Live, world: World
) -> None:
    admin_id = (await live.client.get("/auth/me", headers=bearer(world.admin))).json()["id"]
    # The station is offline: refused by the server.
    async with viewer(live, world.t1, world.s1_id) as v:
        await v.send("offline", "start", prescription_id=world.rx1)
        result = await v.next_of(wire.CommandResult, "offline")
        assert (result.ok, result.code) == (False, "OFFLINE")
    (offline,) = await rows_of(live, world, "offline", 1)
    assert (offline["action"], offline["actor"]) == ("start.refused", f"user:{world.t1_id}")
    assert offline["new"]["prescription_id"] == world.rx1
    assert offline["new"]["code"] == "OFFLINE"

    async with (
        station(live, world, silent) as link,
        viewer(live, world.admin, world.s1_id) as v,
        viewer(live, world.t1, world.s1_id) as t1,
    ):
        # An admin watches but may not command.
        await v.send("admin-hold", "hold")
        result = await v.next_of(wire.CommandResult, "admin-hold")
        assert (result.ok, result.code) == (False, "FORBIDDEN")
        (forbidden,) = await rows_of(live, world, "admin-hold", 1)
        assert (forbidden["action"], forbidden["actor"]) == ("hold.refused", f"user:{admin_id}")
        assert (forbidden["patient_id"], forbidden["new"]["code"]) == (world.p1, "FORBIDDEN")
        # A request_id already awaiting its answer: the second is refused, the first goes on.
        await t1.send("twice", "hold")
        first = await link.next_command()
        await t1.send("twice", "stop")
        duplicate = await t1.next_of(wire.CommandResult, "twice")
        assert (duplicate.ok, duplicate.code, duplicate.field) == (False, "DUPLICATE", "request_id")
        await link.send(ack(first))
        answered = await t1.next_of(wire.CommandResult, "twice")
        assert answered.ok
        assert link.commands.empty(), "only the first command reached the station"
    rows = await rows_of(live, world, "twice", 3)
    assert [(r["action"], r["new"].get("code")) for r in rows] == [
        ("hold.request", None),
        ("stop.refused", "DUPLICATE"),
        ("hold.accepted", ""),
    ]


@pytest.mark.asyncio
async def test_a_start_of_no_prescription_or_another_patients_is_refused_by_the_server(
    live: Live, world: World
) -> None:
    """A Start of another therapist's patient's prescription went to the station and was
    audited as asked of this station's patient; one with no prescription_id reached the
    station as prescription 0. The server refuses both itself: never sent, audited."""
    async with (
        station(live, world, ack) as link,
        viewer(live, world.t1, world.s1_id) as v,
    ):
        asked: list[tuple[str, dict[str, Any], str]] = [
            ("theirs", {"prescription_id": world.rx2}, f"prescription {world.rx2} is not an"),
            ("nothing", {}, "start needs a prescription_id"),
        ]
        for request_id, fields, says in asked:
            await v.send(request_id, "start", **fields)
            result = await v.next_of(wire.CommandResult, request_id)
            assert (result.ok, result.code, result.field) == (
                False,
                "REFUSED",
                "prescription_id",
            ), result
            assert says in result.text, result
        # The patient's own prescription still starts: it is the only command sent.
        await v.send("mine", "start", prescription_id=world.rx1)
        assert (await v.next_of(wire.CommandResult, "mine")).ok
        assert (await link.next_command()).request_id == "mine"
        assert link.commands.empty(), "a refused Start reached the station"
    for request_id, fields, says in asked:
        (row,) = await rows_of(live, world, request_id, 1)
        assert (row["action"], row["actor"]) == ("start.refused", f"user:{world.t1_id}"), row
        assert (row["patient_id"], row["new"]["code"]) == (world.p1, "REFUSED"), row
        assert row["new"]["prescription_id"] == fields.get("prescription_id"), row
        assert says in row["new"]["text"], row


@pytest.mark.sqlite_only
@pytest.mark.asyncio
async def test_a_command_that_cannot_be_audited_is_not_sent_but_a_hold_always_is(
    live: Live, world: World
) -> None:
    """The database refuses the request rows: Resume (which moves the platform) is refused
    and never reaches the station; HOLD goes out all the same."""
    async with live.sessionmaker() as db:
        await db.execute(
            text(
                "CREATE TRIGGER no_requests BEFORE INSERT ON audit_log "
                "WHEN NEW.action LIKE '%.request' "
                "BEGIN SELECT RAISE(ABORT, 'the disk is failing'); END"
            )
        )
        await db.commit()
    async with (
        station(live, world, ack) as link,
        viewer(live, world.t1, world.s1_id) as v,
    ):
        await v.send("resume-1", "resume")
        result = await v.next_of(wire.CommandResult, "resume-1")
        assert (result.ok, result.code) == (False, "AUDIT")
        await v.send("hold-1", "hold")
        result = await v.next_of(wire.CommandResult, "hold-1")
        assert result.ok, result
        relayed = await link.next_command()
        assert relayed.request_id == "hold-1", "the resume was never sent"
    (refused,) = await rows_of(live, world, "resume-1", 1)
    assert (refused["action"], refused["new"]["code"]) == ("resume.refused", "AUDIT")
    (accepted,) = await rows_of(live, world, "hold-1", 1)
    assert accepted["action"] == "hold.accepted"


class Elsewhere(LocalRelay):
    """The in-process relay, as if another server process held every station that is not
    connected here: what is sent to that process is lost (there is none). ``send`` as the
    in-process relay's (nobody to send to: LookupError) unless ``lose``."""

    def __init__(self, lose: bool) -> None:
        self.lose = lose
        self.lost: list[Message] = []

    async def owners(self, station_ids: list[int]) -> dict[int, str]:
        return dict.fromkeys(station_ids, "elsewhere")

    def send(self, process: str, message: Message) -> None:
        if not self.lose:
            super().send(process, message)
        self.lost.append(message)


@pytest.mark.asyncio
async def test_a_command_sent_on_to_another_process_ends_here_if_it_is_lost(
    live: Live, world: World
) -> None:
    """The viewer's process times a command it sends on to the station's process, whatever
    the relay: lost, it ends as TIMEOUT here, and is audited here."""
    relay = Elsewhere(lose=True)
    live.app.state.hub.relay = relay
    async with viewer(live, world.t1, world.s1_id) as v:
        assert v.welcome.online  # held "elsewhere"
        for request_id, action, fields in (
            ("hold-lost", "hold", {}),
            ("kb-lost", "set_impedance", {"stiffness": {"pitch": 50.0}}),
        ):
            t0 = time.monotonic()
            await v.send(request_id, action, **fields)
            result = await v.next_of(wire.CommandResult, request_id)
            assert time.monotonic() - t0 >= COMMAND_TIMEOUT_S - 0.1
            assert (result.ok, result.code) == (False, "TIMEOUT")
            assert "the station's server did not answer" in result.text
            request, outcome = await rows_of(live, world, request_id, 2)
            kind = live_audit.KIND[action]
            assert (request["action"], outcome["action"]) == (
                f"{kind}.request",
                f"{kind}.unanswered",
            )
            assert outcome["new"]["code"] == "TIMEOUT"
    sent = [(m["type"], m.get("request_id") or m["command"]["request_id"]) for m in relay.lost]
    assert sent == [
        ("command", "hold-lost"),
        ("gave_up", "hold-lost"),
        ("command", "kb-lost"),
        ("gave_up", "kb-lost"),
    ]


@pytest.mark.asyncio
async def test_a_command_that_cannot_be_sent_on_is_refused_at_once(
    live: Live, world: World
) -> None:
    live.app.state.hub.relay = Elsewhere(lose=False)
    async with viewer(live, world.t1, world.s1_id) as v:
        await v.send("hold-nowhere", "hold")
        result = await v.next_of(wire.CommandResult, "hold-nowhere")
        assert (result.ok, result.code) == (False, "OFFLINE")
        assert "cannot reach the station's server" in result.text
    request, outcome = await rows_of(live, world, "hold-nowhere", 2)
    assert (request["action"], outcome["action"]) == ("hold.request", "hold.refused")
