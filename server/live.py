"""Live links: home stations stream in, therapists watch and adjust, over WebSocket.

The hub (:mod:`server.hub`) keeps who is connected, here and, through the relay, on the
other server processes; this module holds the two sockets. A station's telemetry comes in
batches of samples and is never queued for a viewer: each viewer is sent every batch while
it keeps up and the newest one when it falls behind (a slow browser sees fresh data late,
never a growing backlog). Events, status and command results are never dropped, and a viewer
is sent them before any telemetry waiting with them; a viewer too far behind on them is
closed (:data:`~sessions.wire.CLOSE_TOO_SLOW`) and reconnects. A viewer's commands have a
budget per link (:data:`~server.hub.COMMAND_WINDOW`): past it the link is closed
(:data:`~sessions.wire.CLOSE_TOO_FAST`). A therapist's command goes to the
station, which asks the device; the device's own ACK or NACK comes back to the viewers as a
:class:`~sessions.wire.CommandResult` (or TIMEOUT / OFFLINE if it cannot).

Message schemas: ``GET /api/v1/schemas/ws`` (WebSocket routes are not in OpenAPI).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from datetime import datetime
from typing import Any

from fastapi import APIRouter, WebSocket, WebSocketDisconnect
from pydantic import ValidationError

from server import live_audit, metrics
from server.deps import Id, LoginStanding, authenticate_station
from server.hub import (
    BUSY,
    COMMAND_BURST,
    COMMANDS_PER_S,
    LOGIN_CLOSE,
    VIEW_COMMANDS_MAX,
    Arrival,
    Asker,
    Hub,
    StationConn,
    Viewer,
    close_link,
    prescriptions_of,
    send_text,
    view_standing,
)
from server.models import Station, utcnow
from sessions import wire

log = logging.getLogger("ankle.server.live")
router = APIRouter()


def _hub(ws: WebSocket) -> Hub:
    hub: Hub = ws.app.state.hub
    return hub


def origin_ok(ws: WebSocket) -> bool:
    """Browsers always send Origin: only our own pages may open a live view. Stations and
    other non-browser clients send none and are judged by their token alone."""
    origin = ws.headers.get("origin")
    return origin is None or origin in ws.app.state.settings.allowed_origins


def _bearer(ws: WebSocket) -> tuple[str | None, str | None]:
    """The token (header or subprotocol) and the subprotocol to accept with."""
    header = ws.headers.get("authorization", "")
    if header.lower().startswith("bearer "):
        return header[7:].strip(), None
    offered = [p.strip() for p in ws.headers.get("sec-websocket-protocol", "").split(",")]
    token = next((p[len(wire.BEARER_PREFIX) :] for p in offered if p.startswith("bearer.")), None)
    return token, wire.SUBPROTOCOL if wire.SUBPROTOCOL in offered else None


class _Silence:
    """The heartbeat timeout of one link: a wait for its next message longer than
    ``HEARTBEAT_TIMEOUT_S`` is cancelled and becomes :data:`~sessions.wire.CLOSE_TIMEOUT`.

    ``asyncio.wait_for`` around each receive does the same with a new task and a new timer
    for every message, which at a station's 100 messages a second was a good part of the
    relay's CPU time. Here a message only stamps when the next wait began; the link's one
    timer, when it falls due, looks at that stamp and either cancels the wait or sets
    itself for the new due time.
    """

    def __init__(self) -> None:
        self.loop = asyncio.get_running_loop()
        task = asyncio.current_task()
        assert task is not None
        self.task = task
        self.since = self.loop.time()
        self.waiting = False
        self.expired = False
        self._timer = self.loop.call_at(self.since + wire.HEARTBEAT_TIMEOUT_S, self._due)

    def _due(self) -> None:
        now = self.loop.time()
        due = self.since + wire.HEARTBEAT_TIMEOUT_S
        if not self.waiting:  # busy with the last message: its next wait starts later
            due = now + wire.HEARTBEAT_TIMEOUT_S
        elif now >= due:
            self.expired = True
            self.task.cancel()
            return
        self._timer = self.loop.call_at(due, self._due)

    def stop(self) -> None:
        self._timer.cancel()


async def _receive(ws: WebSocket, silence: _Silence) -> str:
    """One text message, within the heartbeat timeout and the size limit."""
    silence.since = silence.loop.time()
    silence.waiting = True
    try:
        message = await ws.receive()
    except asyncio.CancelledError:
        if silence.expired and silence.task.uncancel() == 0:
            raise _Close(wire.CLOSE_TIMEOUT, "no message within the heartbeat timeout") from None
        raise
    finally:
        silence.waiting = False
    if message["type"] == "websocket.disconnect":
        raise WebSocketDisconnect(message.get("code", 1000))
    text = message.get("text")
    if text is None:
        raise _Close(wire.CLOSE_MALFORMED, "messages are JSON text frames")
    # Characters are at most 4 bytes: count bytes only when characters alone cannot tell.
    if len(text) * 4 > wire.MAX_MESSAGE_BYTES and len(text.encode()) > wire.MAX_MESSAGE_BYTES:
        raise _Close(wire.CLOSE_TOO_BIG, f"message over {wire.MAX_MESSAGE_BYTES} bytes")
    return str(text)


class _Close(Exception):
    def __init__(self, code: int, reason: str) -> None:
        super().__init__(reason)
        self.code = code
        self.reason = reason


# -- /ws/station ---------------------------------------------------------------------------
@router.websocket("/ws/station")
async def station_socket(ws: WebSocket) -> None:
    hub = _hub(ws)
    token, _ = _bearer(ws)
    station: Station | None = None
    if token and origin_ok(ws):
        assert hub.sessionmaker is not None
        async with hub.sessionmaker() as db:
            station = await authenticate_station(db, token)
    if station is None:
        await ws.close(wire.CLOSE_POLICY)  # before accept: the client sees HTTP 403
        return
    await ws.accept()
    assert token is not None
    conn = StationConn(ws, token, station.id, station.patient_id)
    silence = _Silence()
    try:
        hello = wire.STATION_UP.validate_json(await _receive(ws, silence))
        if not isinstance(hello, wire.StationHello):
            raise _Close(wire.CLOSE_MALFORMED, "the first message must be hello")
        if not wire.PROTOCOL_OLDEST <= hello.protocol <= wire.PROTOCOL:
            raise _Close(
                wire.CLOSE_VERSION,
                f"station speaks protocol {hello.protocol}, server {wire.PROTOCOL}: update one",
            )
        conn.instance, conn.displaced = hello.instance, hello.displaced
        await hub.station_joined(conn)
        await _seen(hub, station.id)
        await send_text(
            ws,
            wire.Welcome(
                station_id=station.id, patient_id=station.patient_id, server_time=time.time()
            ).model_dump_json(),
        )
        assert hub.sessionmaker is not None
        async with hub.sessionmaker() as db:
            await send_text(ws, (await prescriptions_of(db, station.patient_id)).model_dump_json())
        hub.announce(conn)
        beat = asyncio.create_task(_heartbeats(ws))
        try:
            while True:
                raw = await _receive(ws, silence)
                _on_station_message(hub, conn, raw, wire.STATION_UP.validate_json(raw))
        finally:
            beat.cancel()
    except ValidationError as exc:
        await close_link(ws, wire.CLOSE_MALFORMED, wire.error_text(exc))
    except _Close as exc:
        await close_link(ws, exc.code, exc.reason)
    except WebSocketDisconnect:
        pass
    finally:
        silence.stop()
        if hub.stations.get(station.id) is conn:
            with contextlib.suppress(Exception):
                await _seen(hub, station.id)
        await hub.station_left(conn)


def _on_station_message(hub: Hub, conn: StationConn, raw: str, message: Any) -> None:
    conn.messages += 1
    metrics.received("station", message)
    if isinstance(message, wire.TelemetryBatch):
        conn.telemetry(raw, message)
        hub.telemetry_came(conn.station_id)
        hub.relay.telemetry(conn.station_id, raw)
    elif isinstance(message, wire.StatusMsg):
        conn.status = message
        hub.broadcast(conn.station_id, raw, status=True)
    elif isinstance(message, wire.EventMsg):
        hub.broadcast(conn.station_id, raw)
    elif isinstance(message, wire.CommandResult):
        hub.result(conn.station_id, message)


async def _seen(hub: Hub, station_id: int) -> None:
    assert hub.sessionmaker is not None
    async with hub.sessionmaker() as db:
        station = await db.get(Station, station_id)
        if station is not None:
            station.last_seen_at = utcnow()
            await db.commit()


async def _heartbeats(ws: WebSocket) -> None:
    with contextlib.suppress(Exception):
        while True:
            await asyncio.sleep(wire.HEARTBEAT_S)
            await send_text(ws, wire.Heartbeat(sent=time.time()).model_dump_json())


# -- /ws/live/{station_id} -----------------------------------------------------------------
@router.websocket("/ws/live/{station_id}")
async def live_socket(ws: WebSocket, station_id: Id) -> None:
    hub = _hub(ws)
    token, subprotocol = _bearer(ws)
    standing: LoginStanding | None = None
    station: Station | None = None
    refused = True
    if token and origin_ok(ws):
        assert hub.sessionmaker is not None
        async with hub.sessionmaker() as db:
            standing, code, _ = await view_standing(db, token, station_id)
            station = await db.get(Station, station_id)  # loaded by view_standing already
        refused = code != 0
    if refused or token is None or standing is None or standing.user is None or not station:
        await ws.close(wire.CLOSE_POLICY)  # the same for a station that does not exist
        return
    user = standing.user
    await ws.accept(subprotocol=subprotocol)
    viewer = Viewer(
        ws, token, user.id, station_id, station.patient_id, may_command=user.role == "therapist"
    )
    await hub.viewer_joined(viewer)
    expiry = _close_at_expiry(hub, ws, standing.expires_at)
    silence = _Silence()
    writer: asyncio.Task[None] | None = None
    try:
        await send_text(ws, (await hub.welcome(station_id, station.patient_id)).model_dump_json())
        writer = asyncio.create_task(_viewer_writer(hub, viewer))  # after the welcome
        while not writer.done():
            raw = await _receive(ws, silence)
            message = wire.VIEWER_UP.validate_json(raw)
            metrics.received("viewer", message)
            if isinstance(message, wire.Command):
                if not viewer.command_allowed():
                    raise _Close(wire.CLOSE_TOO_FAST, TOO_FAST)
                _on_command(hub, viewer, message)
    except ValidationError as exc:
        await close_link(ws, wire.CLOSE_MALFORMED, wire.error_text(exc))
    except _Close as exc:
        await close_link(ws, exc.code, exc.reason)
    except WebSocketDisconnect:
        pass
    finally:
        silence.stop()
        expiry.cancel()
        await hub.viewer_left(viewer)
        if writer is not None:
            writer.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await writer


TOO_FAST = (
    f"more than {COMMAND_BURST} commands at once or {COMMANDS_PER_S:g} a second: "
    "the link was closed"
)


def _close_at_expiry(hub: Hub, ws: WebSocket, expires_at: datetime | None) -> asyncio.TimerHandle:
    """A timer that closes the view the moment its sign-in expires, and then re-checks the
    rest (the 3D view opened with the same sign-in ends with it)."""
    loop = asyncio.get_running_loop()
    left = 0.0 if expires_at is None else (expires_at - utcnow()).total_seconds()
    code, reason = LOGIN_CLOSE["expired"]

    async def end() -> None:
        await close_link(ws, code, reason)
        await hub.recheck()

    def expire() -> None:
        task = loop.create_task(end())
        _background.add(task)
        task.add_done_callback(_background.discard)

    return loop.call_later(max(left, 0.0), expire)


_background: set[asyncio.Task[None]] = set()
"""Tasks nobody awaits, held so that they are not collected before they run."""


async def _viewer_writer(hub: Hub, v: Viewer) -> None:
    """Send control messages as they come, then the telemetry batches the viewer has not had
    (:meth:`Hub.after`), control again before each; a heartbeat every HEARTBEAT_S."""
    last_beat = 0.0
    loop = asyncio.get_running_loop()
    while True:
        if not v.wake.is_set():
            # Wait at most HEARTBEAT_S (the heartbeat is due): one timer, not wait_for's task.
            timer = loop.call_later(wire.HEARTBEAT_S, v.wake.set)
            try:
                await v.wake.wait()
            finally:
                timer.cancel()
        v.wake.clear()
        if v.too_slow:
            return  # being closed (Viewer.push)
        while v.control:  # never behind telemetry: results and events go first
            await send_text(v.ws, v.pop())
            metrics.sent("viewer", "control")
        for seq, raw in hub.after(v.station_id, v.seq):
            while v.control:
                await send_text(v.ws, v.pop())
                metrics.sent("viewer", "control")
            v.seq = seq
            await send_text(v.ws, raw)
            metrics.sent("viewer", "telemetry")
        now = loop.time()
        if now - last_beat >= wire.HEARTBEAT_S:
            await send_text(v.ws, wire.Heartbeat(sent=time.time()).model_dump_json())
            last_beat = now


def _on_command(hub: Hub, viewer: Viewer, cmd: wire.Command) -> None:
    """Relay a viewer's command to its station, on whichever process it is connected; every
    command ends in one audited outcome (``server/live_audit.py``), whoever refuses it.

    Each command is handled in a task of its own, so the link goes on being read while one
    waits: a HOLD or Stop goes out at once whatever else is pending (a K/B change waiting
    for its audit row), and heartbeats keep being read. Awaited here, a K/B change held the
    HOLD read after it for as long as the database took: 4.85 s late behind a locked SQLite
    file, and on a stalled PostgreSQL until it answered, 12 s, while the view, read by no
    one, was closed for silence. The K/B changes, Resumes and Starts of one view still go
    out one at a time, in the order asked (``Viewer.in_turn``); a task is bounded by
    ``AUDIT_WAIT_S`` from the moment it was read, and a view by ``VIEW_COMMANDS_MAX``."""
    asker = Asker(
        viewer.user_id, viewer.station_id, viewer.patient_id, viewer.may_command, viewer.key
    )
    if len(viewer.handling) >= VIEW_COMMANDS_MAX:
        hub.refuse(asker, cmd, viewer.push, "BUSY", BUSY)
        return
    arrival = hub.arrival(asker, cmd)  # now, before any other command of the view is read
    task = hub.spawn(_command(hub, viewer, asker, cmd, arrival))
    viewer.handling.add(task)
    task.add_done_callback(viewer.handling.discard)


async def _command(
    hub: Hub, viewer: Viewer, asker: Asker, cmd: wire.Command, arrival: Arrival
) -> None:
    """One command of a view, to its end: it goes on if the view closes meanwhile (a HOLD
    sent just before the tab closed is still a HOLD)."""
    try:
        if cmd.action in live_audit.SAFE_ACTIONS:
            await hub.command(asker, cmd, viewer.push, arrival)
        else:
            async with viewer.in_turn:
                await hub.command(asker, cmd, viewer.push, arrival)
    except Exception:
        log.exception("a live command (%s) failed", cmd.action)


@router.get("/api/v1/schemas/ws", tags=["live"], summary="WebSocket message schemas")
async def ws_schemas() -> dict[str, Any]:
    """JSON Schema of every message on ``/ws/station`` and ``/ws/live/{station_id}``, by
    direction (WebSocket routes are not part of OpenAPI)."""
    return wire.json_schemas()
