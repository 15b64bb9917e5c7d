"""Live links: home stations stream in, therapists watch and adjust, over WebSocket.

One :class:`Hub` per process keeps who is connected. A station's telemetry is never queued
for a viewer: the hub keeps the latest sample per station and each viewer is sent the newest
one at most ``VIEW_HZ`` times a second (a slow browser sees fresh data late, never old data
later). Events, status and command results are never dropped. A therapist's command goes to
the station, which asks the device; the device's own ACK or NACK comes back to the viewers
as a :class:`~sessions.wire.CommandResult` (or TIMEOUT / OFFLINE if it cannot).

Message schemas: ``GET /api/v1/schemas/ws`` (WebSocket routes are not in OpenAPI).
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import logging
import time
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

from fastapi import APIRouter, WebSocket, WebSocketDisconnect
from pydantic import ValidationError
from sqlalchemy import select
from sqlalchemy.ext.asyncio import AsyncSession, async_sessionmaker
from starlette.websockets import WebSocketState

from server import audit, live_audit
from server.deps import (
    Id,
    LoginFailure,
    LoginStanding,
    authenticate_station,
    login_standing,
    may_read,
)
from server.models import Patient, Prescription, Station, utcnow
from server.tickets import ViewTickets
from sessions import wire
from sessions.prescription import PrescriptionBody

log = logging.getLogger("ankle.server.live")
router = APIRouter()

VIEW_HZ = 50.0
"""Most telemetry messages a viewer gets per second (the station sends 100)."""
COMMAND_TIMEOUT_S = 3.0
"""A command with no answer from the station by then is reported as TIMEOUT."""
LATE_KEPT = 1000
"""Timed-out commands remembered so that a late answer still has its outcome audited."""
AUDIT_FLUSH_S = 5.0
"""How long shutdown waits for queued audit rows to be written."""
CONTROL_QUEUE_MAX = 1000
"""Events and status a viewer may fall behind by before it is closed as too slow."""
_LOGIN_CLOSE: dict[LoginFailure, tuple[int, str]] = {
    "unknown": (wire.CLOSE_SIGNED_OUT, "signed out; sign in again"),
    "expired": (wire.CLOSE_EXPIRED, "the sign-in expired; sign in again"),
    "inactive": (wire.CLOSE_DEACTIVATED, "this account was deactivated"),
    "must_change": (wire.CLOSE_MUST_CHANGE, "change your password first"),
}
NO_ACCESS = "you may no longer see this patient"


@dataclass(eq=False)
class Viewer:
    ws: WebSocket
    token: str
    """The login it was opened with: re-checked whenever credentials may have changed."""
    user_id: int
    station_id: int
    patient_id: int
    may_command: bool
    control: collections.deque[str] = field(default_factory=collections.deque)
    wake: asyncio.Event = field(default_factory=asyncio.Event)
    seq: int = 0

    def push(self, text: str) -> None:
        self.control.append(text)
        self.wake.set()


@dataclass(eq=False)
class StationConn:
    ws: WebSocket
    token: str
    station_id: int
    patient_id: int
    status: wire.StatusMsg | None = None
    latest: str | None = None
    seq: int = 0
    messages: int = 0


@dataclass(eq=False)
class InFlight:
    """A command claimed by its request_id: being audited, then on its way to the device."""

    asked: live_audit.Asked
    conn: StationConn
    timer: asyncio.TimerHandle | None = None
    """Runs from the moment it is sent."""


class Hub:
    """Connected stations and their viewers, in one process."""

    def __init__(self, recheck_s: float = 30.0) -> None:
        self.recheck_s = recheck_s
        """How often every open link's credentials are checked again even when nothing in
        this process changed them (``Settings.live_recheck_s``)."""
        self.stations: dict[int, StationConn] = {}
        self.viewers: dict[int, set[Viewer]] = collections.defaultdict(set)
        self._pending: dict[str, InFlight] = {}
        self._late: collections.OrderedDict[str, InFlight] = collections.OrderedDict()
        self.sessionmaker: async_sessionmaker[AsyncSession] | None = None
        self._audit: asyncio.Queue[tuple[dict[str, Any], asyncio.Future[None] | None]] = (
            asyncio.Queue()
        )
        self._audit_task: asyncio.Task[None] | None = None
        self._recheck_lock = asyncio.Lock()
        self._recheck_asked = 0
        self._recheck_done = 0
        self._recheck_task: asyncio.Task[None] | None = None
        self.tickets: ViewTickets | None = None
        """The 3D views' tickets, ended with the sign-in they were issued to."""

    async def audit(self, **row: Any) -> None:
        """Write one audit row; returns once it is committed.

        One writer commits every row waiting at that moment in one transaction: with one
        database session per live change, a hundred therapists' changes contended for
        SQLite's write lock and their acknowledgements took seconds (``ankle bench server``).
        """
        done: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self._queue_audit(row, done)
        await done

    def audit_soon(self, row: dict[str, Any]) -> None:
        """Queue one audit row without waiting for it: rows queued before it are written
        before it or in its transaction. A row that cannot be written is logged."""
        self._queue_audit(row, None)

    def _queue_audit(self, row: dict[str, Any], done: asyncio.Future[None] | None) -> None:
        if self._audit_task is None or self._audit_task.done():
            self._audit_task = asyncio.create_task(self._audit_writer())
        self._audit.put_nowait((row, done))

    async def _audit_writer(self) -> None:
        while True:
            batch = [await self._audit.get()]
            while not self._audit.empty():
                batch.append(self._audit.get_nowait())
            try:
                error = await self._commit(batch)
                failed = [] if error is None else [(batch[0], error)]
                if error is not None and len(batch) > 1:
                    # One row the database refuses must not take the others: one at a time.
                    failed = [(one, e) for one in batch if (e := await self._commit([one]))]
                for (row, done), exc in failed:  # its waiter hears of it; the writer goes on
                    if done is None:
                        log.error("audit row %s %s not written: %s", row["action"], row["new"], exc)
                    elif not done.done():
                        done.set_exception(exc)
            finally:
                for _ in batch:
                    self._audit.task_done()

    async def _commit(
        self, batch: list[tuple[dict[str, Any], asyncio.Future[None] | None]]
    ) -> Exception | None:
        """Write ``batch`` in one transaction and tell its waiters; the error if it failed."""
        assert self.sessionmaker is not None
        try:
            async with self.sessionmaker() as db:
                for row, _ in batch:
                    audit.record(db, **row)
                await db.commit()
        except Exception as exc:
            return exc
        for _, done in batch:
            if done is not None and not done.done():
                done.set_result(None)
        return None

    async def recheck(self) -> None:
        """Check the credentials of every open link against the database now, and close
        each link whose credentials no longer hold, with the close code that says why.

        Every route that ends or narrows someone's trust (logout, a password change or
        reset, deactivation, a patient moved or archived, a station revoked) calls this
        after its commit, so the link closes within the request. Callers that arrive while a
        pass runs share the next pass: a burst of changes costs two passes, not one each.
        """
        self._recheck_asked += 1
        asked = self._recheck_asked
        async with self._recheck_lock:
            if self._recheck_done >= asked:
                return  # a pass that began after this call was made has covered it
            began = self._recheck_asked
            await self._recheck_pass()
            self._recheck_done = began

    async def _recheck_pass(self) -> None:
        tickets = self.tickets.live() if self.tickets is not None else []
        if self.sessionmaker is None or not (
            self.stations or any(self.viewers.values()) or tickets
        ):
            return
        ends: list[tuple[WebSocket, int, str]] = []
        async with self.sessionmaker() as db:
            for ticket in tickets:
                kind, station_id = ticket.subject
                if kind != "station":  # the only kind of view today
                    continue
                _, code, reason = await view_standing(db, ticket.login, station_id)
                if code and self.tickets is not None:
                    log.info("3D view ticket ended (%d): %s", code, reason)
                    self.tickets.revoke(ticket)
            for viewers in list(self.viewers.values()):
                for v in list(viewers):
                    _, code, reason = await view_standing(db, v.token, v.station_id)
                    if code:
                        ends.append((v.ws, code, reason))
            for conn in list(self.stations.values()):
                if await authenticate_station(db, conn.token) is None:
                    ends.append((conn.ws, wire.CLOSE_REVOKED, "the station's token was revoked"))
        for ws, code, reason in ends:
            log.info("live link closed (%d): %s", code, reason)
            await _close(ws, code, reason)

    def start_rechecks(self) -> None:
        """Re-check every ``recheck_s`` in the background (idempotent)."""
        if self._recheck_task is None or self._recheck_task.done():
            self._recheck_task = asyncio.create_task(self._recheck_forever())

    async def _recheck_forever(self) -> None:
        while True:
            await asyncio.sleep(self.recheck_s)
            try:
                await self.recheck()
            except Exception:  # the database is away: the next pass tries again
                log.exception("re-checking live links' credentials failed")

    def online(self, station_id: int) -> bool:
        return station_id in self.stations

    async def prescriptions_changed(self, station_id: int) -> None:
        """Push a station's patient's active prescriptions to it, if it is connected."""
        conn = self.stations.get(station_id)
        if conn is not None and self.sessionmaker is not None:
            async with self.sessionmaker() as db:
                message = await _prescriptions(db, conn.patient_id)
            with contextlib.suppress(Exception):
                await conn.ws.send_text(message.model_dump_json())

    async def close(self) -> None:
        """Close every live connection (at shutdown), after writing every queued audit row."""
        for request_id in list(self._pending):
            self._unanswered(request_id, "OFFLINE", "the server shut down before an answer came")
        writer = self._audit_task
        if writer is not None and not writer.done():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._audit.join(), AUDIT_FLUSH_S)
        for task in (self._audit_task, self._recheck_task):
            if task is not None:
                task.cancel()
        for conn in list(self.stations.values()):
            with contextlib.suppress(Exception):
                await conn.ws.close(wire.CLOSE_NORMAL, "server shutting down")
        for viewers in list(self.viewers.values()):
            for v in list(viewers):
                with contextlib.suppress(Exception):
                    await v.ws.close(wire.CLOSE_NORMAL, "server shutting down")

    def broadcast(self, station_id: int, text: str) -> None:
        for v in list(self.viewers.get(station_id, ())):
            if len(v.control) >= CONTROL_QUEUE_MAX:
                continue  # its writer closes it as too slow
            v.push(text)

    # -- commands in flight: each ends in exactly one audited outcome ----------------------
    def claim(self, asked: live_audit.Asked, conn: StationConn) -> bool:
        """Hold ``asked``'s request_id until its outcome; False if a command sent with it may
        still be answered (the answers could not be told apart)."""
        request_id = asked.command.request_id
        if request_id in self._pending or request_id in self._late:
            return False
        self._pending[request_id] = InFlight(asked, conn)
        return True

    def release(self, request_id: str) -> None:
        """Forget a claimed command that was not sent."""
        self._pending.pop(request_id, None)

    def sent(self, request_id: str) -> None:
        """The command is on its way: TIMEOUT unless answered within COMMAND_TIMEOUT_S."""
        entry = self._pending.get(request_id)
        if entry is not None:
            loop = asyncio.get_running_loop()
            entry.timer = loop.call_later(COMMAND_TIMEOUT_S, self._timeout, request_id)

    def result(self, station_id: int, result: wire.CommandResult) -> None:
        """A station's answer: to the viewers, and its outcome to the audit log."""
        for book in (self._pending, self._late):
            entry = book.get(result.request_id)
            if entry is not None and entry.asked.station_id == station_id:
                del book[result.request_id]
                if entry.timer is not None:
                    entry.timer.cancel()
                row = entry.asked.outcome_row(
                    live_audit.outcome_of(result), result, late=book is self._late
                )
                self.audit_soon(row)
                break
        self.broadcast(station_id, result.model_dump_json())

    def _unanswered(self, request_id: str, code: str, text: str) -> InFlight | None:
        entry = self._pending.pop(request_id, None)
        if entry is not None:
            if entry.timer is not None:
                entry.timer.cancel()
            result = wire.CommandResult(request_id=request_id, ok=False, code=code, text=text)
            self.audit_soon(entry.asked.outcome_row("unanswered", result))
            self.broadcast(entry.asked.station_id, result.model_dump_json())
        return entry

    def _timeout(self, request_id: str) -> None:
        text = f"no answer from the station within {COMMAND_TIMEOUT_S:g} s"
        entry = self._unanswered(request_id, "TIMEOUT", text)
        if entry is not None:
            self._late[request_id] = entry
            while len(self._late) > LATE_KEPT:
                self._late.popitem(last=False)

    def link_lost(self, conn: StationConn, request_id: str | None = None) -> None:
        """The link ``conn`` ended: its commands sent and not answered (or just
        ``request_id``) will never be answered."""
        for rid, entry in list(self._pending.items()):
            if entry.conn is conn and (rid == request_id or (request_id is None and entry.timer)):
                self._unanswered(rid, "OFFLINE", "the station's link closed before it answered")


def _hub(ws: WebSocket) -> Hub:
    hub: Hub = ws.app.state.hub
    return hub


def _origin_ok(ws: WebSocket) -> bool:
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


async def _prescriptions(db: AsyncSession, patient_id: int) -> wire.Prescriptions:
    rows = await db.scalars(
        select(Prescription)
        .where(Prescription.patient_id == patient_id, Prescription.status == "active")
        .order_by(Prescription.id)
    )
    return wire.Prescriptions(
        items=[
            wire.PrescriptionItem(
                id=p.id,
                version=p.version,
                patient_id=p.patient_id,
                body=PrescriptionBody.model_validate(p.body),
            )
            for p in rows
        ]
    )


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


async def _close(ws: WebSocket, code: int, reason: str) -> None:
    if ws.client_state != WebSocketState.DISCONNECTED:
        with contextlib.suppress(Exception):
            await ws.close(code, reason[:120])


# -- /ws/station ---------------------------------------------------------------------------
@router.websocket("/ws/station")
async def station_socket(ws: WebSocket) -> None:
    hub = _hub(ws)
    token, _ = _bearer(ws)
    station: Station | None = None
    if token and _origin_ok(ws):
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
        if hello.protocol != wire.PROTOCOL:
            raise _Close(
                wire.CLOSE_VERSION,
                f"station speaks protocol {hello.protocol}, server {wire.PROTOCOL}: update one",
            )
        old = hub.stations.get(station.id)
        if old is not None:
            await _close(old.ws, wire.CLOSE_REPLACED, "the station connected again")
        hub.stations[station.id] = conn
        await _seen(hub, station.id)
        await ws.send_text(
            wire.Welcome(
                station_id=station.id, patient_id=station.patient_id, server_time=time.time()
            ).model_dump_json()
        )
        assert hub.sessionmaker is not None
        async with hub.sessionmaker() as db:
            await ws.send_text((await _prescriptions(db, station.patient_id)).model_dump_json())
        hub.broadcast(station.id, wire.Presence(online=True).model_dump_json())
        beat = asyncio.create_task(_heartbeats(ws))
        try:
            while True:
                raw = await _receive(ws, silence)
                _on_station_message(hub, conn, raw, wire.STATION_UP.validate_json(raw))
        finally:
            beat.cancel()
    except ValidationError as exc:
        await _close(ws, wire.CLOSE_MALFORMED, wire.error_text(exc))
    except _Close as exc:
        await _close(ws, exc.code, exc.reason)
    except WebSocketDisconnect:
        pass
    finally:
        silence.stop()
        hub.link_lost(conn)
        if hub.stations.get(station.id) is conn:
            del hub.stations[station.id]
            hub.broadcast(station.id, wire.Presence(online=False).model_dump_json())
            with contextlib.suppress(Exception):
                await _seen(hub, station.id)


def _on_station_message(hub: Hub, conn: StationConn, raw: str, message: Any) -> None:
    conn.messages += 1
    if isinstance(message, wire.TelemetryMsg):
        conn.latest = raw
        conn.seq += 1
        for v in hub.viewers.get(conn.station_id, ()):
            v.wake.set()
    elif isinstance(message, wire.StatusMsg):
        conn.status = message
        hub.broadcast(conn.station_id, raw)
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
            await ws.send_text(wire.Heartbeat(sent=time.time()).model_dump_json())


# -- /ws/live/{station_id} -----------------------------------------------------------------
@router.websocket("/ws/live/{station_id}")
async def live_socket(ws: WebSocket, station_id: Id) -> None:
    hub = _hub(ws)
    token, subprotocol = _bearer(ws)
    standing: LoginStanding | None = None
    station: Station | None = None
    refused = True
    if token and _origin_ok(ws):
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
    hub.viewers[station_id].add(viewer)
    expiry = _close_at_expiry(hub, ws, standing.expires_at)
    conn = hub.stations.get(station_id)
    silence = _Silence()
    writer: asyncio.Task[None] | None = None
    try:
        await ws.send_text(
            wire.Welcome(
                station_id=station_id,
                patient_id=conn.patient_id if conn else 0,
                online=conn is not None,
                status=conn.status if conn else None,
                server_time=time.time(),
            ).model_dump_json()
        )
        writer = asyncio.create_task(_viewer_writer(hub, viewer))  # after the welcome
        while not writer.done():
            raw = await _receive(ws, silence)
            message = wire.VIEWER_UP.validate_json(raw)
            if isinstance(message, wire.Command):
                await _on_command(hub, viewer, message)
    except ValidationError as exc:
        await _close(ws, wire.CLOSE_MALFORMED, wire.error_text(exc))
    except _Close as exc:
        await _close(ws, exc.code, exc.reason)
    except WebSocketDisconnect:
        pass
    finally:
        silence.stop()
        expiry.cancel()
        hub.viewers[station_id].discard(viewer)
        if writer is not None:
            writer.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await writer


async def view_standing(
    db: AsyncSession, token: str, station_id: int
) -> tuple[LoginStanding, int, str]:
    """Whether the login ``token`` may watch the station now: (standing, 0, "") if it may,
    else the close code and the reason. Checked at the handshake and at every re-check."""
    standing = await login_standing(db, token)
    if standing.failure is not None:
        return standing, *_LOGIN_CLOSE[standing.failure]
    assert standing.user is not None
    station = await db.get(Station, station_id)
    patient = None if station is None else await db.get(Patient, station.patient_id)
    if patient is None or not may_read(standing.user, patient):
        return standing, wire.CLOSE_NO_ACCESS, NO_ACCESS
    return standing, 0, ""


def _close_at_expiry(hub: Hub, ws: WebSocket, expires_at: datetime | None) -> asyncio.TimerHandle:
    """A timer that closes the view the moment its sign-in expires, and then re-checks the
    rest (the 3D view opened with the same sign-in ends with it)."""
    loop = asyncio.get_running_loop()
    left = 0.0 if expires_at is None else (expires_at - utcnow()).total_seconds()
    code, reason = _LOGIN_CLOSE["expired"]

    async def end() -> None:
        await _close(ws, code, reason)
        await hub.recheck()

    def expire() -> None:
        task = loop.create_task(end())
        _background.add(task)
        task.add_done_callback(_background.discard)

    return loop.call_later(max(left, 0.0), expire)


_background: set[asyncio.Task[None]] = set()
"""Tasks nobody awaits, held so that they are not collected before they run."""


async def _viewer_writer(hub: Hub, v: Viewer) -> None:
    """Send control messages as they come and the newest telemetry at most VIEW_HZ."""
    period = 1.0 / VIEW_HZ
    last_beat = 0.0
    loop = asyncio.get_running_loop()
    while True:
        if not v.wake.is_set():  # while streaming it is: telemetry came during the sleep
            # Wait at most HEARTBEAT_S (the heartbeat is due): one timer, not wait_for's task.
            timer = loop.call_later(wire.HEARTBEAT_S, v.wake.set)
            try:
                await v.wake.wait()
            finally:
                timer.cancel()
        v.wake.clear()
        if len(v.control) >= CONTROL_QUEUE_MAX:
            await _close(v.ws, wire.CLOSE_TIMEOUT, "the viewer is not keeping up")
            return
        while v.control:
            await v.ws.send_text(v.control.popleft())
        conn = hub.stations.get(v.station_id)
        sent = False
        if conn is not None and conn.latest is not None and conn.seq != v.seq:
            v.seq = conn.seq
            await v.ws.send_text(conn.latest)
            sent = True
        now = time.monotonic()
        if now - last_beat >= wire.HEARTBEAT_S:
            await v.ws.send_text(wire.Heartbeat(sent=time.time()).model_dump_json())
            last_beat = now
        if sent:
            await asyncio.sleep(period)  # conflation: newer samples replace this one meanwhile


async def _on_command(hub: Hub, viewer: Viewer, cmd: wire.Command) -> None:
    """Relay a viewer's command to its station; every command ends in one audited outcome
    (``server/live_audit.py``), whoever refuses it."""
    conn = hub.stations.get(viewer.station_id)
    cmd = cmd.model_copy(update={"by": f"therapist:{viewer.user_id}"})
    asked = live_audit.Asked(
        actor=f"user:{viewer.user_id}",
        station_id=viewer.station_id,
        patient_id=viewer.patient_id,
        command=cmd,
        replaced=live_audit.in_force(conn.latest if conn else None, cmd),
    )

    def refuse(code: str, text: str, field: str = "") -> None:
        result = wire.CommandResult(
            request_id=cmd.request_id, ok=False, code=code, field=field, text=text
        )
        viewer.push(result.model_dump_json())
        hub.audit_soon(asked.outcome_row("refused", result))

    if not viewer.may_command:
        refuse("FORBIDDEN", "only the patient's therapist may change a running exercise")
        return
    if conn is None:
        refuse("OFFLINE", "the station is not connected")
        return
    if not hub.claim(asked, conn):
        refuse(
            "DUPLICATE", "a command sent with this request_id may still be answered", "request_id"
        )
        return
    if cmd.action in live_audit.SAFE_ACTIONS:
        hub.audit_soon(asked.request_row())  # a HOLD or Stop never waits for the database
    else:
        try:
            await hub.audit(**asked.request_row())
        except Exception as exc:  # a command that cannot be audited is not sent
            log.error("audit of a live command failed: %s", exc)
            hub.release(cmd.request_id)
            refuse("AUDIT", "the command could not be recorded, so it was not sent; try again")
            return
    hub.sent(cmd.request_id)
    try:
        await conn.ws.send_text(cmd.model_dump_json())
    except Exception:
        hub.link_lost(conn, cmd.request_id)


@router.get("/api/v1/schemas/ws", tags=["live"], summary="WebSocket message schemas")
async def ws_schemas() -> dict[str, Any]:
    """JSON Schema of every message on ``/ws/station`` and ``/ws/live/{station_id}``, by
    direction (WebSocket routes are not part of OpenAPI)."""
    return wire.json_schemas()
