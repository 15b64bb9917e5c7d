"""The live hub: the stations and viewers connected to this server process, and, through the
relay (:mod:`server.relay`), those connected to the others.

A station's telemetry comes in batches of samples and is never queued for a viewer: the hub
keeps the newest few batches per station, and each viewer is sent every batch while it keeps
up and the newest one when it falls behind (a slow browser sees fresh data late, never a
growing backlog). Events, status and command results are never dropped, and a viewer is sent
them before any telemetry waiting with them; one ``CONTROL_QUEUE_MAX`` behind is closed.

A viewer's commands are each handled in a task of their own (:mod:`server.live`): a HOLD
or Stop goes out at once whatever else waits; a K/B change, Resume or Start waits, within
``AUDIT_WAIT_S``, for its request row, and is not sent after a HOLD or Stop that passed it.
A command is judged, timed and its outcome audited by the process that holds the station's
link, wherever its viewer is; its result reaches the station's viewers on every process. A
command from a viewer on another process is recorded (its request row) on the viewer's
process, which also keeps a timer of its own: if the station's process does not answer
within ``COMMAND_TIMEOUT_S`` (it died, or the relay lost a message), the viewer's process
ends the command itself (TIMEOUT, audited), and tells the station's process, which records
an answer that still comes as late. While this process cannot reach the relay, the viewers
of stations held elsewhere are told that whether the station is online is not known.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import dataclasses
import itertools
import json
import logging
import time
from collections.abc import Awaitable, Callable, Coroutine, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any, TypeVar

from fastapi import WebSocket, WebSocketDisconnect
from limits import (
    RateLimitItem,
    RateLimitItemPerHour,
    RateLimitItemPerMinute,
    RateLimitItemPerSecond,
)
from limits.storage import MemoryStorage
from limits.strategies import MovingWindowRateLimiter
from sqlalchemy import select
from sqlalchemy.ext.asyncio import AsyncSession, async_sessionmaker
from starlette.websockets import WebSocketState

from server import live_audit, metrics
from server.audit import AuditWriter
from server.deps import LoginFailure, LoginStanding, authenticate_station, login_standing, may_read
from server.models import Patient, Prescription, Station
from server.relay import RECENT_BATCHES, LocalRelay, Message, Relay
from server.tickets import Ticket, ViewTickets
from sessions import wire
from sessions.prescription import PrescriptionBody

log = logging.getLogger("ankle.server.live")

VIEW_HZ = 50.0
"""How often a process sends the telemetry batches of its stations to the other processes
watching them, per second (a station sends 25 batches a second)."""
COMMAND_TIMEOUT_S = 3.0
"""A command with no answer from the station by then is reported as TIMEOUT."""
RELAY_SLACK_S = 0.5
"""Of a command forwarded from another process, what the station's process leaves of
COMMAND_TIMEOUT_S for the relay: it waits this much less for the station, so that its own
outcome (the answer, or its TIMEOUT) reaches the asking process before that process's timer
ends the command as unanswered by the station's server."""
AUDIT_WAIT_S = 2.0
"""How long a K/B change, Resume or Start may wait, from the moment its view's link reads
it, to be sent: for its request row to be committed and, for a Start, its prescription to
be checked. Past it, it is refused (``AUDIT``) and never sent. A K/B change, its row
committed, is answered by the device in 5-7 ms at the median and 23-32 ms at p99 with 100
stations (README, "The live audit writer on its own connection"); only a database that is
away, locked or stalled takes seconds, and a change sent seconds after the click,
when the therapist has moved on, is not the one they asked for. Before, the only bounds
were SQLite's busy timeout (5 s) and, on PostgreSQL, none: a K change was applied 12 s
after it was asked, once a stalled database answered. HOLD and Stop never wait for it."""
CLOCK_SKEW_S = 0.1
"""How far apart the clocks of two server hosts may be (they keep NTP time, within
milliseconds of each other): a forwarded command carries, by the asking host's wall clock,
when the station's process's share of its budget ends (``COMMAND_TIMEOUT_S - RELAY_SLACK_S``
after it was sent), and is still sent up to this much after that by the station host's
clock. It is less than ``RELAY_SLACK_S``: a command sent in time reaches the device before
the asking process ends it as TIMEOUT."""
SAFE_OWNER_WAIT_S = 0.5
"""How long a HOLD or Stop of a station held elsewhere waits for the relay to name the
station's process, while the relay is not yet known to be away (a Redis that hangs answers
nothing until the client's 5 s socket timeout); past it, it is refused at once (OFFLINE)."""
LATE_KEPT = 1000
"""Timed-out commands remembered so that a late answer still has its outcome audited."""
AUDIT_FLUSH_S = 5.0
"""How long shutdown waits for queued audit rows to be written."""
CONTROL_QUEUE_MAX = 1000
"""Events, status and results a viewer may fall behind by: at the next one it is closed at
once (:data:`~sessions.wire.CLOSE_TOO_SLOW`) rather than sent some and not others."""
CONTROL_QUEUE_BYTES = 8 * 1024 * 1024
"""The same in bytes: a thousand events of 60 KB held for one viewer that reads nothing
were 60 MB of the server's memory."""
COMMAND_BURST = 30
"""Commands a viewer's link may send at once, and in any ``COMMAND_BURST / COMMANDS_PER_S``
seconds (:data:`COMMAND_WINDOW`). The dashboard sends
one per click of HOLD, Resume, Stop, Start or "Set K/B": a therapist clicking as fast as a
person can (some 7 a second) never meets it. Past it the link is closed
(:data:`~sessions.wire.CLOSE_TOO_FAST`)."""
COMMANDS_PER_S = 10.0
VIEW_COMMANDS_MAX = COMMAND_BURST
"""Commands of one view being handled at once (each in a task of its own, so that the link
goes on being read): past it a command is refused (``BUSY``) and not sent. Each ends within
``AUDIT_WAIT_S`` plus a relay look-up, so a view within its budget (:data:`COMMAND_WINDOW`)
meets this only while the relay does not answer."""
REFUSAL_ROWS_BURST = 5
"""Of the commands the server itself refuses (never sent: FORBIDDEN, OFFLINE, DUPLICATE,
AUDIT, BUSY, a Start's REFUSED), those of one user to one station that get an audit row each:
this many at once, and in any ``REFUSAL_ROWS_BURST / REFUSAL_ROWS_PER_S`` seconds; the rest
are counted into one ``command.refusals`` row per ``REFUSAL_SUMMARY_S``. Each refusal costs
nothing on the device, but its row is kept for good: one browser tab sending 1,000 K/B
changes a second to an offline station wrote a row for each (2,850 in 3 s)."""
REFUSAL_ROWS_PER_S = 1.0
REFUSAL_SUMMARY_S = 10.0
REFUSALS_ACTION = "command.refusals"
LOGIN_CLOSE: dict[LoginFailure, tuple[int, str]] = {
    "unknown": (wire.CLOSE_SIGNED_OUT, "signed out; sign in again"),
    "expired": (wire.CLOSE_EXPIRED, "the sign-in expired; sign in again"),
    "inactive": (wire.CLOSE_DEACTIVATED, "this account was deactivated"),
    "must_change": (wire.CLOSE_MUST_CHANGE, "change your password first"),
}
NO_ACCESS = "you may no longer see this patient"
RELAY_LOST = "this server has lost its link to the other server processes (the relay is down)"
"""Told to the viewers of a station held elsewhere while the relay cannot be reached."""
CONNECTED = "the station is connected"
LEFT = "the station's link to its server closed"
NOT_CONNECTED = "the station is not connected"
GONE = (
    "no server holds the station's link any more (it closed, or its server stopped), so the "
    "station is offline"
)
TOKEN_SHARED = (
    "two stations are using this station's token: another station or program connected with "
    "it and took over the link, so the platform shown here may not be the one the patient "
    "is using; ask the clinic to re-provision the station (a copied configuration or a "
    "stolen token)"
)
"""Told to the viewers (as the connected station's presence) when a link of another run of
the station program took over a live one, or a station says it was displaced."""
REPLACED = "a newer connection with this station's token took over this link"
TOKEN_SHARED_ACTION = live_audit.TOKEN_SHARED_ACTION
SHARED_ROWS_WINDOW = RateLimitItemPerHour(6)
"""Audit rows of one station's token in use twice: 6 in any hour. Two stations fighting
over one token take turns every minute or more (each steps back when displaced), an older
station without that every second; the rows left out are counted into the next one."""
RELAY_REFUSED = (
    "this server cannot reach the other server processes (the relay is down), so the command "
    "could not be sent to the station; try again when the station shows online"
)

_viewer_keys = itertools.count(1)
T = TypeVar("T")


_COUNTS = MovingWindowRateLimiter(MemoryStorage())
"""The budgets below, counted in this process (a link and its refusals live in one)."""
_hubs = itertools.count(1)


def _window(burst: int, per_s: float) -> RateLimitItem:
    """``burst`` at once, ``per_s`` a second on average: ``burst`` in any moving window of
    ``burst / per_s`` seconds."""
    return RateLimitItemPerSecond(burst, max(1, round(burst / per_s)))


COMMAND_WINDOW = _window(COMMAND_BURST, COMMANDS_PER_S)
REFUSAL_ROWS_WINDOW = _window(REFUSAL_ROWS_BURST, int(REFUSAL_ROWS_PER_S))
DROPPED_LOG_WINDOW = RateLimitItemPerMinute(5)
"""Warnings of dropped results a station may cause: 5 in any minute. A station answering
request ids nobody sent, thousands a second, wrote a warning each; the metric
``ankle_live_results_dropped`` still counts every one, and the next warning let through
says how many went unlogged."""


TOO_SLOW = "the viewer fell too far behind the events sent to it; reconnect"


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
    key: int = field(default_factory=lambda: next(_viewer_keys))
    """Names it to this process, for an answer that comes back through the relay."""
    queued: int = 0
    """Characters in ``control``."""
    too_slow: bool = False
    """Closed for falling behind: nothing more is queued for it."""
    handling: set[asyncio.Task[None]] = field(default_factory=set)
    """Its commands being handled (:data:`VIEW_COMMANDS_MAX`)."""
    in_turn: asyncio.Lock = field(default_factory=asyncio.Lock)
    """Held by the K/B change, Resume or Start of this view being handled: they go out in
    the order they were asked (HOLD and Stop do not wait for it)."""

    def push(self, text: str) -> None:
        """Queue a control message; a viewer this far behind is closed at once instead:
        it reconnects and is sent the state afresh, and never misses some messages and
        not others without knowing."""
        if self.too_slow:
            return
        if len(self.control) >= CONTROL_QUEUE_MAX or self.queued + len(text) > CONTROL_QUEUE_BYTES:
            self.too_slow = True
            self.control.clear()
            self.queued = 0
            log.info("live view closed (%d): %s", wire.CLOSE_TOO_SLOW, TOO_SLOW)
            task = asyncio.get_running_loop().create_task(
                close_link(self.ws, wire.CLOSE_TOO_SLOW, TOO_SLOW)
            )
            _closing.add(task)
            task.add_done_callback(_closing.discard)
        else:
            self.control.append(text)
            self.queued += len(text)
        self.wake.set()

    def command_allowed(self) -> bool:
        """One more command within the link's budget (:data:`COMMAND_WINDOW`)."""
        return _COUNTS.hit(COMMAND_WINDOW, "link", str(self.key))

    def pop(self) -> str:
        text = self.control.popleft()
        self.queued -= len(text)
        return text


_closing: set[asyncio.Task[None]] = set()
"""Closes of viewers too slow, held until they end."""


@dataclass(eq=False)
class StationConn:
    ws: WebSocket
    token: str
    station_id: int
    patient_id: int
    status: wire.StatusMsg | None = None
    recent: collections.deque[tuple[int, str]] = field(
        default_factory=lambda: collections.deque(maxlen=RECENT_BATCHES)
    )
    """The newest telemetry batches with their numbers, as received (what viewers are sent)."""
    batch: wire.TelemetryBatchBase | None = None
    """The newest batch, validated."""
    seq: int = 0
    """The newest batch's number."""
    messages: int = 0
    instance: str = ""
    """The run of the station program that holds the link (its hello's; empty from an older
    station): a link replaced by one of another run is a second station with this token."""
    displaced: int = 0
    """How often its link was taken over since its last one that ended otherwise (hello)."""
    presence: str = CONNECTED
    """What its viewers are told while it holds the link."""
    announced: bool = False
    """Its viewers were told it is online (:meth:`Hub.announce`)."""

    def telemetry(self, raw: str, batch: wire.TelemetryBatchBase) -> None:
        self.seq += 1
        self.recent.append((self.seq, raw))
        self.batch = batch

    def newest(self) -> wire.TelemetryMsg | None:
        """The station's newest sample, if any came."""
        return self.batch.newest() if self.batch is not None else None

    def after(self, seq: int) -> list[tuple[int, str]]:
        """The batches a viewer that has had batch ``seq`` has not had, oldest first; only the
        newest if it missed more than ``RECENT_BATCHES`` (or ``seq`` is another link's)."""
        return unseen(self.recent, seq)


def unseen(recent: Sequence[tuple[int, str]], seq: int) -> list[tuple[int, str]]:
    """Of the numbered batches ``recent`` (oldest first, numbered one by one), those after
    ``seq``; only the newest if batches between ``seq`` and the oldest kept were missed."""
    if not recent:
        return []
    if recent[0][0] - 1 <= seq <= recent[-1][0]:
        return [(n, raw) for n, raw in recent if n > seq]
    return [recent[-1]]


@dataclass(frozen=True)
class Asker:
    """Who sends a command to which station: what the station's process needs to judge and
    audit it, wherever the viewer is."""

    user_id: int
    station_id: int
    patient_id: int
    may_command: bool
    viewer: int = 0
    """The viewer's key on its own process: where a refusal goes back to."""


@dataclass(eq=False)
class InFlight:
    """A command claimed by its request_id: being audited, then on its way to the device."""

    asked: live_audit.Asked
    conn: StationConn
    timer: asyncio.TimerHandle | None = None
    """Runs from the moment it is sent."""
    asked_on: str | None = None
    """The process of the viewer that sent it, if another: told when it ends, and may give
    up on it first."""


@dataclass(eq=False)
class Forwarded:
    """A command of a viewer here sent on to the process that holds its station: ended here
    (TIMEOUT) unless that process says it ended within COMMAND_TIMEOUT_S."""

    asked: live_audit.Asked
    owner: str
    timer: asyncio.TimerHandle | None = None


async def send_text(ws: WebSocket, text: str) -> None:
    """Send on a live link; a link closed meanwhile ends as a disconnect
    (``WebSocketDisconnect``), as a read on it does. Starlette raises ``RuntimeError``
    (``WebSocketDisconnected``) for a send after the close, which the handlers did not
    expect: a station revoked just after its Welcome had the next send, its prescriptions,
    end in "Exception in ASGI application" with a traceback."""
    try:
        await ws.send_text(text)
    except RuntimeError as exc:
        raise WebSocketDisconnect(1006, str(exc)) from None


async def close_link(ws: WebSocket, code: int, reason: str) -> None:
    if ws.client_state != WebSocketState.DISCONNECTED:
        with contextlib.suppress(Exception):
            await ws.close(code, reason[:120])


async def view_standing(
    db: AsyncSession, token: str, station_id: int
) -> tuple[LoginStanding, int, str]:
    """Whether the login ``token`` may watch the station now: (standing, 0, "") if it may,
    else the close code and the reason. Checked at the handshake and at every re-check."""
    standing = await login_standing(db, token)
    if standing.failure is not None:
        return standing, *LOGIN_CLOSE[standing.failure]
    assert standing.user is not None
    station = await db.get(Station, station_id)
    patient = None if station is None else await db.get(Patient, station.patient_id)
    if patient is None or not may_read(standing.user, patient):
        return standing, wire.CLOSE_NO_ACCESS, NO_ACCESS
    return standing, 0, ""


async def prescriptions_of(db: AsyncSession, patient_id: int) -> wire.Prescriptions:
    """The patient's active prescriptions, as a station is sent them."""
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


def _ticket_key(value: str) -> str:
    return f"ticket:{value}"


class Hub:
    """Connected stations and their viewers: this process's, and the others' by the relay."""

    def __init__(self, recheck_s: float = 30.0, relay: Relay | None = None) -> None:
        self.recheck_s = recheck_s
        """How often every open link's credentials are checked again even when nothing
        changed them through a server (``Settings.live_recheck_s``)."""
        self.relay: Relay = LocalRelay() if relay is None else relay
        self.stations: dict[int, StationConn] = {}
        self.viewers: dict[int, set[Viewer]] = collections.defaultdict(set)
        self._pending: dict[str, InFlight] = {}
        self._late: collections.OrderedDict[str, InFlight] = collections.OrderedDict()
        self._forwarded: dict[str, Forwarded] = {}
        self._holds: collections.Counter[int] = collections.Counter()
        """HOLDs and Stops asked of each station on this process (:meth:`arrival`)."""
        self._tasks: set[asyncio.Task[Any]] = set()
        self.writer = AuditWriter()
        self.refusals = Refusals(self.writer)
        self._serial = str(next(_hubs))
        self._unlogged: collections.Counter[int] = collections.Counter()
        """Dropped results of each station not logged (``DROPPED_LOG_WINDOW``)."""
        self._shared_unwritten: collections.Counter[int] = collections.Counter()
        """Sightings of each station's token in use twice not audited (``SHARED_ROWS_WINDOW``)."""
        self._recheck_lock = asyncio.Lock()
        self._recheck_asked = 0
        self._recheck_done = 0
        self._recheck_task: asyncio.Task[None] | None = None
        self.tickets: ViewTickets | None = None
        """The 3D views' tickets, ended with the sign-in they were issued to."""

    @property
    def sessionmaker(self) -> async_sessionmaker[AsyncSession] | None:
        return self.writer.sessionmaker

    @sessionmaker.setter
    def sessionmaker(self, maker: async_sessionmaker[AsyncSession] | None) -> None:
        self.writer.sessionmaker = maker

    async def start(self) -> None:
        """Re-check in the background and hear the other processes."""
        await self.relay.start(self)
        self.start_rechecks()

    # -- credentials -----------------------------------------------------------------------
    async def recheck(self) -> None:
        """Check the credentials of every open link, on every server process, and close
        each link whose credentials no longer hold, with the close code that says why.

        Every route that ends or narrows someone's trust (logout, a password change or
        reset, deactivation, a patient moved or archived, a station revoked) calls this
        after its commit: this process's links close within the request, the others' as
        soon as the relay carries the word. Callers that arrive while a pass runs share the
        next pass: a burst of changes costs two passes, not one each.
        """
        self.relay.everyone({"type": "recheck"})
        await self._recheck_here()

    async def _recheck_here(self) -> None:
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
                    await self._ask("ticket", self.relay.unshare(_ticket_key(ticket.value)), None)
                elif ticket.in_use:  # a view open on it keeps it alive on every process
                    await self.share_ticket(ticket)
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
            await close_link(ws, code, reason)

    def start_rechecks(self) -> None:
        """Re-check every ``recheck_s`` in the background (idempotent)."""
        if self._recheck_task is None or self._recheck_task.done():
            self._recheck_task = asyncio.create_task(self._recheck_forever())

    async def _recheck_forever(self) -> None:
        while True:
            await asyncio.sleep(self.recheck_s)
            try:
                await self._recheck_here()  # every process runs its own
            except Exception:  # the database is away: the next pass tries again
                log.exception("re-checking live links' credentials failed")

    # -- stations --------------------------------------------------------------------------
    async def online(self, station_id: int) -> bool:
        """Connected to this server process or another."""
        return station_id in await self.online_of([station_id])

    async def online_of(self, station_ids: list[int]) -> set[int]:
        """Those of ``station_ids`` connected to this server process or another."""
        here = {s for s in station_ids if s in self.stations}
        away = [s for s in station_ids if s not in here]
        if not away or not self.relay.reachable:  # not known: as if offline, at once
            return here
        elsewhere = await self._ask("owners", self.relay.owners(away), {})
        return here | elsewhere.keys()

    async def station_joined(self, conn: StationConn) -> None:
        """``conn`` is the station's link now: an older one, here or elsewhere, is closed.

        The newest link wins, always: a station whose network dropped reconnects over its
        own half-open link and must get in at once. A link that took over a live one of
        another run of the station program (``instance``), or a hello saying its station's
        link was taken over, means two stations are using one token: audited, and told to
        the viewers (:meth:`token_shared`). The process that held the older link compares
        the runs, since only it knows the older one's."""
        old = self.stations.get(conn.station_id)
        if old is not None:
            await close_link(old.ws, wire.CLOSE_REPLACED, REPLACED)
        self.stations[conn.station_id] = conn
        if old is not None and _other_run(old.instance, conn.instance):
            self.token_shared(conn, "took_over")
        elif conn.displaced:
            self.token_shared(conn, "reported")
        before = await self._ask("claim", self.relay.claim(conn.station_id), None)
        if before is not None:
            replaced = {
                "type": "replaced",
                "station_id": conn.station_id,
                "instance": conn.instance,
                "by": self.relay.process,
            }
            self.relay.send(before, replaced)

    def announce(self, conn: StationConn) -> None:
        """Tell the viewers, everywhere, that the station of ``conn`` is online (with what
        :meth:`token_shared` found, if it did)."""
        conn.announced = True
        self.broadcast(conn.station_id, _online(conn))

    def token_shared(self, conn: StationConn, seen: str) -> None:
        """Two stations use ``conn``'s token: the viewers are told while ``conn`` holds the
        link, and an audit row says so (:data:`SHARED_ROWS_WINDOW`; the rows left out are
        counted into the next). ``seen``: ``took_over`` (``conn`` replaced a live link of
        another run) or ``reported`` (its hello says its own was taken over)."""
        station_id = conn.station_id
        if conn.presence != TOKEN_SHARED:
            conn.presence = TOKEN_SHARED
            if conn.announced:
                self.announce(conn)
        if not _COUNTS.hit(SHARED_ROWS_WINDOW, "shared", self._serial, str(station_id)):
            self._shared_unwritten[station_id] += 1
            return
        unwritten = self._shared_unwritten.pop(station_id, 0)
        log.warning(
            "station %d: two stations are using its token (a link %s); ask the clinic to "
            "re-provision it%s",
            station_id,
            "took over a live one of another station program"
            if seen == "took_over"
            else f"reports it was taken over {conn.displaced} times",
            f" ({unwritten} more like it since the last such warning)" if unwritten else "",
        )
        self.writer.write_soon(
            {
                "actor": f"station:{station_id}",
                "action": TOKEN_SHARED_ACTION,
                "entity": "station",
                "entity_id": station_id,
                "patient_id": conn.patient_id,
                "old": None,
                "new": {
                    "seen": seen,
                    "displaced": conn.displaced,
                    "unwritten_before": unwritten,
                    "text": TOKEN_SHARED,
                },
            }
        )

    async def station_left(self, conn: StationConn) -> None:
        """``conn``'s link ended: its commands will not be answered; if it was still the
        station's link, the station is offline."""
        self.link_lost(conn)
        if self.stations.get(conn.station_id) is conn:
            del self.stations[conn.station_id]
            left = wire.Presence(online=False, text=LEFT).model_dump_json()
            self.broadcast(conn.station_id, left)
            with contextlib.suppress(Exception):
                await self.relay.release(conn.station_id)

    async def prescriptions_changed(self, station_id: int) -> None:
        """Push a station's patient's active prescriptions to it, wherever it is connected."""
        conn = self.stations.get(station_id)
        if conn is None:
            if not self.relay.reachable:  # sent its prescriptions when it connects again
                return
            owner = await self._ask("owner", self.relay.owner(station_id), None)
            if owner is not None and owner != self.relay.process:
                self.relay.send(owner, {"type": "prescriptions", "station_id": station_id})
            return
        if self.sessionmaker is not None:
            async with self.sessionmaker() as db:
                message = await prescriptions_of(db, conn.patient_id)
            with contextlib.suppress(Exception):
                await send_text(conn.ws, message.model_dump_json())

    def after(self, station_id: int, seq: int) -> list[tuple[int, str]]:
        """The telemetry batches (raw, numbered) of the station a viewer that has had batch
        ``seq`` has not had (:meth:`StationConn.after`). Of a station on another process,
        those the relay brought."""
        conn = self.stations.get(station_id)
        if conn is not None:
            return conn.after(seq)
        return unseen(self.relay.recent(station_id), seq)

    def newest(self, station_id: int, seen: int = 0) -> tuple[int, wire.TelemetryMsg] | None:
        """The station's newest sample, with the number of the batch it came in; None if none
        came or that batch is ``seen`` (a relayed batch is parsed only when it is new)."""
        conn = self.stations.get(station_id)
        if conn is not None:
            sample = conn.newest() if conn.seq != seen else None
            return None if sample is None else (conn.seq, sample)
        relayed = self.relay.recent(station_id)
        if not relayed or relayed[-1][0] == seen:
            return None
        batch = wire.STATION_UP.validate_json(relayed[-1][1])
        return (relayed[-1][0], batch.newest()) if isinstance(batch, wire.TelemetryBatch) else None

    async def welcome(self, station_id: int, patient_id: int) -> wire.Welcome:
        """What a new viewer of the station is told first."""
        conn = self.stations.get(station_id)
        online, status = conn is not None, conn.status if conn else None
        owner = None if conn else await self._ask("owner", self.relay.owner(station_id), None)
        if owner is not None:
            online = True
            text = await self._ask("status", self.relay.last_status(station_id), None)
            status = None if text is None else wire.StatusMsg.model_validate_json(text)
        return wire.Welcome(
            station_id=station_id,
            patient_id=patient_id if online else 0,
            online=online,
            status=status,
            server_time=time.time(),
        )

    async def _ask(self, what: str, call: Awaitable[T], away: T) -> T:
        """``call``'s answer, or ``away`` if the relay cannot be reached: this process's own
        links go on working, and the others are as if elsewhere unknown."""
        try:
            return await call
        except Exception as exc:
            # Once the relay knows it is away, it has said so: not again for each look-up.
            level = logging.WARNING if self.relay.reachable else logging.DEBUG
            log.log(level, "the relay is unreachable (%s): %s", what, exc)
            return away

    # -- 3D views' tickets ------------------------------------------------------------------
    async def share_ticket(self, ticket: Ticket) -> None:
        """Make a ticket just issued here valid on every process."""
        if self.tickets is not None:
            value = json.dumps(ticket.shared())
            await self._ask(
                "ticket",
                self.relay.share(_ticket_key(ticket.value), value, self.tickets.ttl_s),
                None,
            )

    async def ticket(self, value: str) -> Ticket | None:
        """The live ticket ``value`` names, issued on this process or another; each look-up
        keeps it alive for every process."""
        if self.tickets is None:
            return None
        look_up = self.relay.look_up(_ticket_key(value), self.tickets.ttl_s)
        shared = await self._ask("ticket", look_up, None)
        ticket = self.tickets.valid(value)
        if ticket is None and shared is not None:
            ticket = self.tickets.adopt(value, json.loads(shared))
        return ticket

    # -- viewers ---------------------------------------------------------------------------
    async def viewer_joined(self, viewer: Viewer) -> None:
        self.viewers[viewer.station_id].add(viewer)
        await self.watch(viewer.station_id)
        conn = self.stations.get(viewer.station_id)
        if conn is not None and conn.presence != CONNECTED:  # sent after its welcome
            viewer.push(_online(conn))
        if not self.relay.reachable and viewer.station_id not in self.stations:
            viewer.push(_unknown())

    async def viewer_left(self, viewer: Viewer) -> None:
        self.viewers[viewer.station_id].discard(viewer)
        await self.unwatch(viewer.station_id)

    async def watch(self, station_id: int) -> None:
        """Something here shows the station (a viewer, a 3D view): hear it from anywhere."""
        await self._ask("watch", self.relay.watch(station_id), None)

    async def unwatch(self, station_id: int) -> None:
        with contextlib.suppress(Exception):
            await self.relay.unwatch(station_id)

    def broadcast(self, station_id: int, text: str, status: bool = False) -> None:
        """To the station's viewers here and on every other process."""
        self.deliver(station_id, text)
        self.relay.publish(station_id, text, status)

    # -- what the relay brings (server.relay.Listener) ---------------------------------------
    def deliver(self, station_id: int, text: str) -> None:
        for v in list(self.viewers.get(station_id, ())):
            v.push(text)

    def telemetry_came(self, station_id: int) -> None:
        for v in self.viewers.get(station_id, ()):
            v.wake.set()

    def gone(self, station_id: int) -> None:
        if station_id not in self.stations:
            self.deliver(station_id, wire.Presence(online=False, text=GONE).model_dump_json())

    def back(self, station_id: int) -> None:
        if station_id not in self.stations:
            self._soon(self._tell_presence([station_id]))

    def relay_reachable(self, up: bool) -> None:
        """The relay stopped answering: the viewers of stations held elsewhere are told that
        their presence is not known. Once it answers again the relay tells each station's
        presence (``back``, ``gone``) as soon as it is known: a station whose lease ran out
        while Redis hung is given time for its process to renew it, and is not told gone
        meanwhile (:class:`server.redis_relay.RedisRelay`)."""
        if up:
            return
        away = [s for s, viewers in self.viewers.items() if viewers and s not in self.stations]
        for station_id in away:
            self.deliver(station_id, _unknown())

    async def _tell_presence(self, station_ids: list[int]) -> None:
        """Tell the viewers of these stations held elsewhere whether they are online, and
        the last status of those that are."""
        held = await self._ask("owners", self.relay.owners(station_ids), None)
        if held is None:
            return  # away again: the relay says so
        for station_id in station_ids:
            if station_id in self.stations:
                continue
            online = station_id in held
            text = CONNECTED if online else NOT_CONNECTED
            self.deliver(station_id, wire.Presence(online=online, text=text).model_dump_json())
            status = await self._ask("status", self.relay.last_status(station_id), None)
            if online and status is not None:
                self.deliver(station_id, status)

    def _soon(self, work: Coroutine[Any, Any, None]) -> None:
        self.spawn(work)

    async def on_message(self, message: Message) -> None:
        kind, station_id = message["type"], message.get("station_id")
        if kind == "recheck":
            await self._recheck_here()
        elif kind == "command" and isinstance(station_id, int):
            asker = Asker(**message["asker"])
            cmd = wire.Command.model_validate(message["command"])
            process, key = message["reply_to"], asker.viewer
            budget = float(message.get("timeout_s", COMMAND_TIMEOUT_S))
            expires = message.get("expires_at")

            def reply(text: str) -> None:
                self.relay.send(
                    process,
                    {
                        "type": "reply",
                        "station_id": station_id,
                        "viewer": key,
                        "request_id": cmd.request_id,
                        "text": text,
                    },
                )

            await self._command_here(
                asker,
                cmd,
                reply,
                asked_on=process,
                timeout_s=budget,
                expires_at=None if expires is None else float(expires),
            )
        elif kind == "reply" and isinstance(station_id, int):
            self._settled(station_id, message.get("request_id"))
            for v in self.viewers.get(station_id, ()):
                if v.key == message["viewer"]:
                    v.push(message["text"])
        elif kind == "settled" and isinstance(station_id, int):
            self._settled(station_id, message.get("request_id"))
        elif kind == "gave_up" and isinstance(station_id, int):
            self._given_up(station_id, message.get("request_id"), message.get("from"))
        elif kind == "prescriptions" and station_id in self.stations:
            assert isinstance(station_id, int)
            await self.prescriptions_changed(station_id)
        elif kind == "replaced" and isinstance(station_id, int):
            conn = self.stations.pop(station_id, None)
            if conn is not None:  # it stays online, elsewhere: no presence change to tell
                await self.relay.release(station_id)  # the other process's claim stays
                await close_link(conn.ws, wire.CLOSE_REPLACED, REPLACED)
                newer, by = message.get("instance"), message.get("by")
                if isinstance(newer, str) and _other_run(conn.instance, newer) and by:
                    shared = {"type": "token_shared", "station_id": station_id, "instance": newer}
                    with contextlib.suppress(Exception):
                        self.relay.send(str(by), shared)
        elif kind == "token_shared" and isinstance(station_id, int):
            conn = self.stations.get(station_id)
            if conn is not None and conn.instance == message.get("instance"):
                self.token_shared(conn, "took_over")

    # -- shutdown --------------------------------------------------------------------------
    async def close(self) -> None:
        """Close every live connection (at shutdown), after writing every queued audit row."""
        for request_id in list(self._pending):
            self._unanswered(request_id, "OFFLINE", "the server shut down before an answer came")
        for request_id in list(self._forwarded):
            text = "the server shut down before the station's server answered"
            self._give_up(request_id, "OFFLINE", text)
        for task in list(self._tasks):
            task.cancel()
        self.refusals.flush()
        await self.writer.close(AUDIT_FLUSH_S)
        if self._recheck_task is not None:
            self._recheck_task.cancel()
        for conn in list(self.stations.values()):
            with contextlib.suppress(Exception):
                await conn.ws.close(wire.CLOSE_NORMAL, "server shutting down")
        for viewers in list(self.viewers.values()):
            for v in list(viewers):
                with contextlib.suppress(Exception):
                    await v.ws.close(wire.CLOSE_NORMAL, "server shutting down")
        with contextlib.suppress(Exception):
            await self.relay.close()

    # -- commands: each ends in exactly one audited outcome ---------------------------------
    def arrival(self, asker: Asker, cmd: wire.Command) -> Arrival:
        """Note a command as its link reads it (before anything is awaited for it). A
        therapist's HOLD or Stop counts for its station at once: any K/B change, Resume or
        Start asked of that station on this process before it, and still waiting to be
        sent, is not sent after it (``SUPERSEDED``)."""
        if asker.may_command and cmd.action in live_audit.SAFE_ACTIONS:
            self._holds[asker.station_id] += 1
        return Arrival(asyncio.get_running_loop().time(), self._holds[asker.station_id])

    def spawn(self, work: Coroutine[Any, Any, None]) -> asyncio.Task[None]:
        """Run ``work`` in a task of its own, held until it ends (cancelled at shutdown)."""
        task = asyncio.create_task(work)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return task

    def refuse(
        self, asker: Asker, cmd: wire.Command, reply: Callable[[str], None], code: str, text: str
    ) -> None:
        """Refuse a command before anything is done with it (audited, never sent)."""
        _refuse(_asked(asker, cmd), reply, self.refusals, code, text)

    async def command(
        self,
        asker: Asker,
        cmd: wire.Command,
        reply: Callable[[str], None],
        arrival: Arrival | None = None,
    ) -> None:
        """A viewer's command to its station, wherever the station is connected; ``reply``
        takes a refusal meant for that viewer alone. ``arrival``: when its link read it
        (:meth:`arrival`; now if not given)."""
        arrival = arrival or self.arrival(asker, cmd)
        if asker.station_id not in self.stations:
            if not self.relay.reachable:  # known away: refused now, not after its timeout
                _refuse(_asked(asker, cmd), reply, self.refusals, "OFFLINE", RELAY_REFUSED)
                return
            try:
                owner = await self._owner(asker.station_id, cmd.action)
            except TimeoutError:
                log.warning("the relay named no station's server within %g s", SAFE_OWNER_WAIT_S)
                _refuse(_asked(asker, cmd), reply, self.refusals, "OFFLINE", RELAY_SLOW)
                return
            except Exception as exc:
                level = logging.WARNING if self.relay.reachable else logging.DEBUG
                log.log(level, "the relay is unreachable (command): %s", exc)
                _refuse(_asked(asker, cmd), reply, self.refusals, "OFFLINE", RELAY_REFUSED)
                return
            if owner is not None and owner != self.relay.process:
                await self._forward(owner, asker, cmd, reply, arrival)
                return
        await self._command_here(asker, cmd, reply, arrival=arrival)

    async def _owner(self, station_id: int, action: str) -> str | None:
        """The process the relay names as the station's. A HOLD or Stop waits for it at
        most ``SAFE_OWNER_WAIT_S`` (TimeoutError past it; the look-up goes on alone, as a
        call cut half way would leave Redis's connection in doubt)."""
        if action not in live_audit.SAFE_ACTIONS:
            return await self.relay.owner(station_id)
        task = asyncio.create_task(self.relay.owner(station_id))
        if not (await asyncio.wait({task}, timeout=SAFE_OWNER_WAIT_S))[0]:
            self._tasks.add(task)
            task.add_done_callback(_forgotten)
            task.add_done_callback(self._tasks.discard)
            raise TimeoutError
        return task.result()

    async def _forward(
        self,
        owner: str,
        asker: Asker,
        cmd: wire.Command,
        reply: Callable[[str], None],
        arrival: Arrival,
    ) -> None:
        """Record a command here and send it on to the process ``owner`` that holds its
        station; end it here if that process does not say within COMMAND_TIMEOUT_S that it
        ended (it may have died, or the relay lost a message)."""
        asked = _asked(asker, cmd)
        request_id = asked.command.request_id
        if not asker.may_command:
            _refuse(asked, reply, self.refusals, "FORBIDDEN", FORBIDDEN)
            return
        if request_id in self._forwarded:
            _refuse(asked, reply, self.refusals, "DUPLICATE", DUPLICATE, "request_id")
            return
        entry = self._forwarded[request_id] = Forwarded(asked, owner)
        if not await self._record_request(asked, reply, arrival) or self._superseded(
            asked, reply, arrival
        ):
            del self._forwarded[request_id]
            return
        forward = {
            "type": "command",
            "station_id": asker.station_id,
            "asker": dataclasses.asdict(asker),
            "command": cmd.model_dump(mode="json"),
            "reply_to": self.relay.process,
            "timeout_s": COMMAND_TIMEOUT_S - RELAY_SLACK_S,
            "expires_at": time.time() + COMMAND_TIMEOUT_S - RELAY_SLACK_S,
        }
        try:
            self.relay.send(owner, forward)
        except Exception as exc:  # the in-process relay has nobody to send to
            log.warning("a command could not be sent to the station's server: %s", exc)
            del self._forwarded[request_id]
            text = "this server cannot reach the station's server, so the command was not sent"
            _refuse(asked, reply, self.refusals, "OFFLINE", text)
            return
        loop = asyncio.get_running_loop()
        entry.timer = loop.call_later(COMMAND_TIMEOUT_S, self._forward_timeout, request_id)

    def _forward_timeout(self, request_id: str) -> None:
        text = (
            f"the station's server did not answer within {COMMAND_TIMEOUT_S:g} s (it may have "
            "stopped, or the message was lost): whether the device acted is not known"
        )
        self._give_up(request_id, "TIMEOUT", text)

    def _give_up(self, request_id: str, code: str, text: str) -> None:
        """End a forwarded command here, as unanswered; the station's process records an
        answer that still comes as late."""
        entry = self._forwarded.pop(request_id, None)
        if entry is None:
            return
        if entry.timer is not None:
            entry.timer.cancel()
        self._end_unanswered(entry.asked, code, text)
        gave_up = {
            "type": "gave_up",
            "station_id": entry.asked.station_id,
            "request_id": request_id,
            "from": self.relay.process,
        }
        with contextlib.suppress(Exception):
            self.relay.send(entry.owner, gave_up)

    def _settled(self, station_id: int, request_id: object) -> None:
        """The station's process ended a command forwarded from here (it answered, refused
        or timed it out, and audited that): no timer here any more."""
        if not isinstance(request_id, str):
            return
        entry = self._forwarded.get(request_id)
        if entry is not None and entry.asked.station_id == station_id:
            del self._forwarded[request_id]
            if entry.timer is not None:
                entry.timer.cancel()

    def _given_up(self, station_id: int, request_id: object, process: object) -> None:
        """The viewer's process ended a command it forwarded here (TIMEOUT): an answer that
        still comes is recorded as late, and no outcome of this process's own is."""
        if not isinstance(request_id, str):
            return
        entry = self._pending.get(request_id)
        if entry is None or entry.asked.station_id != station_id or entry.asked_on != process:
            return
        del self._pending[request_id]
        metrics.command_answered(request_id, "TIMEOUT")
        if entry.timer is not None:
            entry.timer.cancel()
        self._keep_late(request_id, entry)

    async def _record_request(
        self, asked: live_audit.Asked, reply: Callable[[str], None], arrival: Arrival
    ) -> bool:
        """Write a command's request row: at once for a HOLD or Stop, which never wait;
        awaited for the rest, which are refused (AUDIT) and not sent if it cannot be, or not
        within ``AUDIT_WAIT_S`` of their arrival.

        A row given up on may still be committed by a try of the writer already under way
        (a database that answers late): its refusal is then written after it, in the same
        queue, so the log never shows a request without the outcome that it was not sent."""
        if asked.command.action in live_audit.SAFE_ACTIONS:
            self.writer.write_soon(asked.request_row())
            return True
        left = arrival.at + AUDIT_WAIT_S - asyncio.get_running_loop().time()
        if left <= 0:  # waited its turn behind its view's commands: nothing was queued
            log.error("a live command was not recorded within %g s", AUDIT_WAIT_S)
            _refuse(asked, reply, self.refusals, "AUDIT", NOT_RECORDED_IN_TIME)
            return False
        try:
            done = self.writer.submit(**asked.request_row())
            if not (await asyncio.wait({done}, timeout=left))[0]:
                done.cancel()
                log.error("the audit of a live command took over %g s", AUDIT_WAIT_S)
                _refuse_recorded(asked, reply, self.writer, "AUDIT", NOT_RECORDED_IN_TIME)
                return False
            done.result()
        except Exception as exc:  # a command that cannot be audited is not sent
            log.error("audit of a live command failed: %s", exc)
            _refuse(asked, reply, self.refusals, "AUDIT", NOT_RECORDED)
            return False
        return True

    def _superseded(
        self, asked: live_audit.Asked, reply: Callable[[str], None], arrival: Arrival
    ) -> bool:
        """Whether a HOLD or Stop of the station came after this K/B change, Resume or
        Start while it waited (:meth:`arrival`): it is then refused, after its request
        row, rather than sent after the HOLD (a Resume would have undone it)."""
        if asked.command.action in live_audit.SAFE_ACTIONS:
            return False
        if self._holds[asked.station_id] == arrival.holds:
            return False
        _refuse_recorded(asked, reply, self.writer, "SUPERSEDED", SUPERSEDED)
        return True

    async def _command_here(
        self,
        asker: Asker,
        cmd: wire.Command,
        reply: Callable[[str], None],
        asked_on: str | None = None,
        timeout_s: float = COMMAND_TIMEOUT_S,
        arrival: Arrival | None = None,
        expires_at: float | None = None,
    ) -> None:
        """Judge, audit and send a command to a station connected here (or refuse it).
        ``asked_on``: the process it was forwarded from, which recorded its request;
        ``expires_at``: when its budget ends there (wall clock), past which it is not sent
        (:meth:`_expired`)."""
        arrival = arrival or self.arrival(asker, cmd)
        asked = _asked(asker, cmd)
        cmd = asked.command
        if not asker.may_command:
            _refuse(asked, reply, self.refusals, "FORBIDDEN", FORBIDDEN)
            return
        if cmd.action == "start":
            refused = await self._start_refusal(asker.patient_id, cmd.prescription_id, arrival)
            if refused:
                _refuse(asked, reply, self.refusals, *refused, "prescription_id")
                return
        conn = self.stations.get(asker.station_id)  # it may have gone meanwhile
        if conn is None:
            _refuse(asked, reply, self.refusals, "OFFLINE", "the station is not connected")
            return
        if not self.claim(asked, conn, asked_on):
            _refuse(asked, reply, self.refusals, "DUPLICATE", DUPLICATE, "request_id")
            return
        if asked_on is None and not await self._record_request(asked, reply, arrival):
            self.release(cmd.request_id)
            return
        if self._superseded(asked, reply, arrival) or self._expired(asked, reply, expires_at):
            self.release(cmd.request_id)
            return
        self.sent(cmd.request_id, timeout_s)
        try:
            await send_text(conn.ws, cmd.model_dump_json())
            metrics.sent("station", "command")
        except Exception:
            self.link_lost(conn, cmd.request_id)

    def _expired(
        self, asked: live_audit.Asked, reply: Callable[[str], None], expires_at: float | None
    ) -> bool:
        """Whether a command forwarded from another process arrived after its budget ended
        (the relay held it: a Redis paused or failing over delivers it seconds late, once
        the asking process has told its viewer TIMEOUT). It is then refused, audited as not
        sent, rather than carried out unasked-for: a K change applied 8 s after the viewer
        was told its fate is not known. A HOLD or Stop is sent whenever it arrives: it only
        brings the platform to rest, which is never wrong to do late."""
        if expires_at is None or asked.command.action in live_audit.SAFE_ACTIONS:
            return False
        late_s = time.time() - expires_at
        if late_s <= CLOCK_SKEW_S:
            return False
        log.warning("a forwarded command came %.1f s after its budget ended: not sent", late_s)
        _refuse_recorded(asked, reply, self.writer, "EXPIRED", EXPIRED)
        return True

    async def _start_refusal(
        self, patient_id: int, prescription_id: int | None, arrival: Arrival
    ) -> tuple[str, str] | None:
        """Why a Start cannot go to the station, as (code, sentence): it names no
        prescription, or one that is not an active prescription of the station's patient
        (another patient's, or one since ended); the server knows that as well as the
        station, which would refuse it only after it was sent and audited as asked of this
        patient. None when it may go. A database that does not answer within
        ``AUDIT_WAIT_S`` of the Start's arrival refuses it (the look-up goes on alone: one
        cancelled half way would call the stalled database again to clean up)."""
        if prescription_id is None:
            return "REFUSED", wire.START_NEEDS_PRESCRIPTION
        assert self.sessionmaker is not None
        maker = self.sessionmaker

        async def look_up() -> int | None:
            async with maker() as db:
                found: int | None = await db.scalar(
                    select(Prescription.id).where(
                        Prescription.id == prescription_id,
                        Prescription.patient_id == patient_id,
                        Prescription.status == "active",
                    )
                )
                return found

        left = arrival.at + AUDIT_WAIT_S - asyncio.get_running_loop().time()
        if left <= 0:
            log.error("a Start's prescription was not checked within %g s", AUDIT_WAIT_S)
            return "AUDIT", UNCHECKED
        task = asyncio.create_task(look_up())
        if not (await asyncio.wait({task}, timeout=left))[0]:
            self._tasks.add(task)  # held until it ends; its answer is not wanted any more
            task.add_done_callback(_forgotten)
            task.add_done_callback(self._tasks.discard)
            log.error("a Start's prescription was not checked within %g s", AUDIT_WAIT_S)
            return "AUDIT", UNCHECKED
        try:
            found = task.result()
        except Exception as exc:  # not sent unchecked
            log.error("a Start's prescription could not be checked: %s", exc)
            return "AUDIT", UNCHECKED
        if found is None:
            return "REFUSED", wire.not_prescribed(prescription_id)
        return None

    def claim(
        self, asked: live_audit.Asked, conn: StationConn, asked_on: str | None = None
    ) -> bool:
        """Hold ``asked``'s request_id until its outcome; False if a command sent with it may
        still be answered (the answers could not be told apart)."""
        request_id = asked.command.request_id
        if request_id in self._pending or request_id in self._late:
            return False
        self._pending[request_id] = InFlight(asked, conn, asked_on=asked_on)
        return True

    def release(self, request_id: str) -> None:
        """Forget a claimed command that was not sent."""
        self._pending.pop(request_id, None)

    def sent(self, request_id: str, timeout_s: float = COMMAND_TIMEOUT_S) -> None:
        """The command is on its way: TIMEOUT unless answered within ``timeout_s``."""
        entry = self._pending.get(request_id)
        if entry is not None:
            loop = asyncio.get_running_loop()
            entry.timer = loop.call_later(timeout_s, self._timeout, request_id, timeout_s)
            metrics.command_sent(request_id, entry.asked.command.action)

    def result(self, station_id: int, result: wire.CommandResult) -> None:
        """A station's answer to a command sent to it and not yet answered (or ended
        unanswered: then audited as late): to the viewers, and its outcome to the audit log.
        Any other is dropped: a second answer to one Resume (ok, then refused) showed the
        live page accepted then refused with only the first audited, and a station could
        show the viewers results for request ids nobody sent."""
        for book in (self._pending, self._late):
            entry = book.get(result.request_id)
            if entry is not None and entry.asked.station_id == station_id:
                del book[result.request_id]
                metrics.command_answered(result.request_id, "accepted" if result.ok else "refused")
                if entry.timer is not None:
                    entry.timer.cancel()
                row = entry.asked.outcome_row(
                    live_audit.outcome_of(result), result, late=book is self._late
                )
                self.writer.write_soon(row)
                self._tell_asker(entry)
                self.broadcast(station_id, result.model_dump_json())
                return
        metrics.result_dropped()
        if not _COUNTS.hit(DROPPED_LOG_WINDOW, "dropped", str(self._serial), str(station_id)):
            self._unlogged[station_id] += 1
            return
        unlogged = self._unlogged.pop(station_id, 0)
        log.warning(
            "station %d answered request %r, which is not awaiting its answer (answered "
            "already, or never sent to it): dropped%s",
            station_id,
            result.request_id[:64],
            f" ({unlogged} more like it since the last such warning)" if unlogged else "",
        )

    def _unanswered(self, request_id: str, code: str, text: str) -> InFlight | None:
        entry = self._pending.pop(request_id, None)
        if entry is not None:
            metrics.command_answered(request_id, code)
            if entry.timer is not None:
                entry.timer.cancel()
            self._end_unanswered(entry.asked, code, text)
            self._tell_asker(entry)
        return entry

    def _end_unanswered(self, asked: live_audit.Asked, code: str, text: str) -> None:
        """A command ends with no answer from the station: its viewers are told, and it is
        audited as unanswered."""
        request_id = asked.command.request_id
        result = wire.CommandResult(request_id=request_id, ok=False, code=code, text=text)
        self.writer.write_soon(asked.outcome_row("unanswered", result))
        self.broadcast(asked.station_id, result.model_dump_json())

    def _tell_asker(self, entry: InFlight) -> None:
        """A command forwarded from another process has its outcome: that process stops
        its own timer."""
        if entry.asked_on is not None:
            settled = {
                "type": "settled",
                "station_id": entry.asked.station_id,
                "request_id": entry.asked.command.request_id,
            }
            with contextlib.suppress(Exception):
                self.relay.send(entry.asked_on, settled)

    def _timeout(self, request_id: str, timeout_s: float = COMMAND_TIMEOUT_S) -> None:
        text = f"no answer from the station within {timeout_s:g} s"
        entry = self._unanswered(request_id, "TIMEOUT", text)
        if entry is not None:
            self._keep_late(request_id, entry)

    def _keep_late(self, request_id: str, entry: InFlight) -> None:
        """Remember a command that ended unanswered, so that a late answer is audited."""
        entry.timer = None
        self._late[request_id] = entry
        while len(self._late) > LATE_KEPT:
            self._late.popitem(last=False)

    def link_lost(self, conn: StationConn, request_id: str | None = None) -> None:
        """The link ``conn`` ended: its commands sent and not answered (or just
        ``request_id``) will never be answered."""
        for rid, entry in list(self._pending.items()):
            if entry.conn is conn and (rid == request_id or (request_id is None and entry.timer)):
                self._unanswered(rid, "OFFLINE", "the station's link closed before it answered")


@dataclass(frozen=True)
class Arrival:
    """When a command's link read it, and how many HOLDs and Stops its station had been
    asked on this process by then (:meth:`Hub.arrival`)."""

    at: float
    """The event loop's clock."""
    holds: int


def _online(conn: StationConn) -> str:
    """The presence of a station online through ``conn``, with what its viewers must know."""
    text = conn.presence
    return wire.Presence(online=True, text=text, warning=text != CONNECTED).model_dump_json()


def _other_run(older: str, newer: object) -> bool:
    """Whether two links' instances are different runs of the station program (an older
    station names none: then not known, and not reported)."""
    return bool(older) and isinstance(newer, str) and bool(newer) and older != newer


def _unknown() -> str:
    """The presence told while the relay is away."""
    return wire.Presence(online=False, text=RELAY_LOST, known=False).model_dump_json()


def _forgotten(task: asyncio.Task[Any]) -> None:
    """A task whose answer nobody waits for any more: its exception, if any, is read (and
    left) rather than reported as never retrieved."""
    if not task.cancelled():
        task.exception()


FORBIDDEN = "only the patient's therapist may change a running exercise"
DUPLICATE = "a command sent with this request_id may still be answered"
NOT_RECORDED = "the command could not be recorded, so it was not sent; try again"
NOT_RECORDED_IN_TIME = (
    f"the command could not be recorded within {AUDIT_WAIT_S:g} s (the database did not "
    "answer), so it was not sent; try again"
)
UNCHECKED = (
    f"the prescription could not be checked within {AUDIT_WAIT_S:g} s (the database did not "
    "answer), so the exercise was not started; try again"
)
SUPERSEDED = (
    "a HOLD or Stop was asked of the station while this waited to be recorded, so it was "
    "not sent after it; ask again if it is still wanted"
)
EXPIRED = (
    "the command reached the station's server after its time was up (the relay between the "
    "servers held it), so it was not sent; ask again if it is still wanted"
)
RELAY_SLOW = (
    f"this server could not find the station's server within {SAFE_OWNER_WAIT_S:g} s (the "
    "relay between the servers does not answer), so the command was not sent; try again"
)
BUSY = (
    f"{VIEW_COMMANDS_MAX} commands of this view are still being handled, so this one was "
    "not sent; try again"
)


def _asked(asker: Asker, cmd: wire.Command) -> live_audit.Asked:
    """The command as its audit rows tell it, sent by ``asker``'s therapist."""
    return live_audit.Asked(
        actor=f"user:{asker.user_id}",
        station_id=asker.station_id,
        patient_id=asker.patient_id,
        command=cmd.model_copy(update={"by": f"therapist:{asker.user_id}"}),
    )


def _refuse_recorded(
    asked: live_audit.Asked, reply: Callable[[str], None], writer: AuditWriter, code: str, text: str
) -> None:
    """Refuse a command whose request row was queued, and may be stored: the asking viewer
    is told, and the refusal gets a row of its own, after the request's, never only a count
    (:class:`Refusals`)."""
    result = wire.CommandResult(request_id=asked.command.request_id, ok=False, code=code, text=text)
    reply(result.model_dump_json())
    writer.write_soon(asked.outcome_row("refused", result))


def _refuse(
    asked: live_audit.Asked,
    reply: Callable[[str], None],
    refusals: Refusals,
    code: str,
    text: str,
    field: str = "",
) -> None:
    """Refuse a command before it is sent: the asking viewer is told, the refusal audited."""
    result = wire.CommandResult(
        request_id=asked.command.request_id, ok=False, code=code, field=field, text=text
    )
    reply(result.model_dump_json())
    refusals.write(asked, asked.outcome_row("refused", result))


@dataclass
class _Tally:
    """Refusals counted rather than written one by one, since ``first_at``."""

    row: dict[str, Any]
    first_at: float
    first_request_id: str
    count: int = 0
    actions: collections.Counter[str] = field(default_factory=collections.Counter)
    codes: collections.Counter[str] = field(default_factory=collections.Counter)
    last_request_id: str = ""
    last_at: float = 0.0


class Refusals:
    """The audit rows of the commands the server refuses itself: one row each for the
    first ``REFUSAL_ROWS_BURST`` of a user to a station, then ``REFUSAL_ROWS_PER_S``; the
    others are counted, and each ``REFUSAL_SUMMARY_S`` one ``command.refusals`` row says
    how many there were, of which actions and codes, and the first and last request_id."""

    def __init__(self, writer: AuditWriter) -> None:
        self.writer = writer
        self._serial = str(next(_hubs))
        self._tallies: dict[tuple[str, int], _Tally] = {}
        self._timers: dict[tuple[str, int], asyncio.TimerHandle] = {}

    def write(self, asked: live_audit.Asked, row: dict[str, Any]) -> None:
        key = (asked.actor, asked.station_id)
        if _COUNTS.hit(REFUSAL_ROWS_WINDOW, "refusals", self._serial, *map(str, key)):
            self.writer.write_soon(row)
            return
        now = time.time()
        request_id = asked.command.request_id
        tally = self._tallies.get(key)
        if tally is None:
            tally = self._tallies[key] = _Tally(row, now, request_id)
            loop = asyncio.get_running_loop()
            self._timers[key] = loop.call_later(REFUSAL_SUMMARY_S, self._flush, key)
        tally.count += 1
        tally.actions[row["action"]] += 1
        tally.codes[row["new"]["code"]] += 1
        tally.last_request_id, tally.last_at = request_id, now

    def _flush(self, key: tuple[str, int]) -> None:
        self._timers.pop(key, None)
        tally = self._tallies.pop(key, None)
        if tally is None:
            return
        when = {"from": tally.first_at, "to": tally.last_at}
        self.writer.write_soon(
            tally.row
            | {
                "action": REFUSALS_ACTION,
                "old": None,
                "new": {
                    "count": tally.count,
                    "actions": dict(tally.actions),
                    "codes": dict(tally.codes),
                    "first_request_id": tally.first_request_id,
                    "last_request_id": tally.last_request_id,
                }
                | {k: datetime.fromtimestamp(t, UTC).isoformat() for k, t in when.items()},
            }
        )

    def flush(self) -> None:
        """Write every count now (at shutdown)."""
        for key in list(self._tallies):
            timer = self._timers.get(key)
            if timer is not None:
                timer.cancel()
            self._flush(key)
