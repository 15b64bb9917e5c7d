"""The station's WebSocket to the server: reconnects by itself, never blocks the exercise.

Samples are sent in batches (:class:`~sessions.wire.TelemetryBatch`): about ``batch_hz``
messages a second, each with the samples that came since the last (4 at the device's 100 Hz
and the default 25 Hz). Outgoing messages go through two queues: telemetry is bounded and
drops the oldest batch (a live view wants the newest; the session file has every sample),
while events, status and command results are never dropped and wait for the next connection;
the writer sends every control message queued before the next batch goes. Incoming
prescriptions and commands are handed to the station's callbacks; a command is handled in a
task of its own, so one waiting for the device's answer never keeps the next from being read.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import logging
import secrets
import time
from collections.abc import Callable, Coroutine, Mapping
from typing import Any

from pydantic import BaseModel, ValidationError
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidStatus, WebSocketException

from sessions import wire
from sessions.wire import BATCH_HZ
from station.backoff import Backoff

log = logging.getLogger("ankle.station.server")

TELEMETRY_QUEUE = 32
"""Batches kept while the server is slow or away (about 1.3 s at 25 a second)."""
RECONNECT_FIRST_S = 1.0
"""The first wait after the link drops is drawn from 0..1 s, so stations that all lost a
restarted server come back spread over a second, not in the same instant."""
RECONNECT_MAX_S = 10.0
REFUSED_WAIT_S = 30.0
"""Added to the wait when the server refused this station (token, revoked, version)."""
DISPLACED_FIRST_S = 60.0
"""The least wait after this station's live link was taken over by another connection with
its token (:data:`~sessions.wire.CLOSE_REPLACED`). Its own reconnections come one after the
other, so the link being closed is its current one: the newer connection is another station
or program. Taking the link straight back made two such stations take turns about once a
second for as long as they ran, the therapist's view switching between two platforms; this
station steps back instead, for a minute and more."""
DISPLACED_GROWTH_S = 60.0
DISPLACED_MAX_S = 540.0
"""Added to ``DISPLACED_FIRST_S``, jittered: up to 60 s, then 120, 240, at most 540 more
(10 minutes in all) while the link keeps being taken over."""
DISPLACED_LOG = (
    "another station or process is connected with this station's token (a copied "
    "configuration or a stolen token) and took over its link to the server; this station "
    "tries again in %.0f s (its link taken over %s): ask the clinic to re-provision the "
    "station (a new token) and switch the other one off"
)
DISPLACED_NOTICE = (
    "Another device is connected to your therapist with this station's key, so this station "
    "is not connected now. Your exercises still work and are sent later. Please tell your "
    "clinic."
)
"""What the patient's page says while the station steps back."""


class ServerLink:
    def __init__(
        self,
        url: str,
        token: str,
        hello: Callable[[], wire.StationHello],
        on_message: Callable[[Any], Coroutine[Any, Any, None]],
        batch_hz: float = BATCH_HZ,
    ) -> None:
        self.url = url.rstrip("/").replace("http://", "ws://").replace("https://", "wss://")
        self.token = token
        self._hello = hello
        self._on_message = on_message
        self.connected = asyncio.Event()
        self.welcome: wire.Welcome | None = None
        self.telemetry: collections.deque[str] = collections.deque(maxlen=TELEMETRY_QUEUE)
        self.control: collections.deque[str] = collections.deque()
        self._wake = asyncio.Event()
        self.last_error = ""
        self.connects = 0
        self.instance = secrets.token_urlsafe(12)
        """Names this run of the station program to the server, on every reconnection."""
        self.displaced = 0
        """Times in a row its live link was taken over (told to the server in the hello)."""
        self.notice = ""
        """For the patient's page: why the station is not connected, when it is news."""
        self.retry_in = 0.0
        """The wait chosen after the last link ended, in seconds."""
        self.telemetry_dropped = 0
        self.batch_hz = batch_hz
        self._rows: list[Mapping[str, Any]] = []
        self._handling: set[asyncio.Task[None]] = set()

    def send_sample(self, row: Mapping[str, Any], device_hz: float) -> None:
        """Add one device sample (a :class:`~sessions.wire.TelemetryMsg`'s fields but
        ``sent``) to the batch; the batch is queued once it holds ``device_hz / batch_hz``."""
        self._rows.append(row)
        if len(self._rows) >= max(1, round(device_hz / self.batch_hz)):
            rows, self._rows = self._rows, []
            batch = wire.TelemetryBatch.of(rows, sent=time.time())
            if len(self.telemetry) == self.telemetry.maxlen:
                self.telemetry_dropped += 1
            self.telemetry.append(batch.model_dump_json())
            self._wake.set()

    def send(self, message: BaseModel) -> None:
        """Queue a message that must arrive (event, status, result)."""
        self.control.append(message.model_dump_json())
        self._wake.set()

    async def run(self) -> None:
        backoff = Backoff(RECONNECT_FIRST_S, RECONNECT_MAX_S)
        displacement = Backoff(DISPLACED_GROWTH_S, DISPLACED_MAX_S)
        while True:
            connects = self.connects
            refused = False
            displaced = False
            try:
                async with connect(
                    f"{self.url}/ws/station",
                    additional_headers={"Authorization": f"Bearer {self.token}"},
                    max_size=wire.MAX_MESSAGE_BYTES,
                    open_timeout=5.0,
                    ping_interval=None,  # the application heartbeat is ours, once a second
                ) as ws:
                    await self._session(ws)
            except InvalidStatus as exc:
                self.last_error = refused_words(exc.response.status_code)
            except (OSError, WebSocketException, TimeoutError) as exc:
                self.last_error = f"server unreachable ({type(exc).__name__})"
            except _Closed as exc:
                self.last_error = str(exc)
                refused = exc.code in (wire.CLOSE_POLICY, wire.CLOSE_REVOKED, wire.CLOSE_VERSION)
                displaced = exc.code == wire.CLOSE_REPLACED
            finally:
                self.connected.clear()
                self.welcome = None
            if displaced:
                self.retry_in = self._displaced(displacement)
                await asyncio.sleep(self.retry_in)
                continue
            if self.connects != connects:
                backoff.reset()  # the link was up: a server that just went away is retried soon
                displacement.reset()
                self.displaced = 0
            wait = backoff.next() + (REFUSED_WAIT_S if refused else 0.0)
            self.retry_in = wait
            log.info("server link down: %s; retrying in %.2f s", self.last_error, wait)
            await asyncio.sleep(wait)

    def _displaced(self, displacement: Backoff) -> float:
        """The live link was taken over (only ever raised once it was up): step back."""
        self.displaced += 1
        self.notice = DISPLACED_NOTICE
        wait = DISPLACED_FIRST_S + displacement.next()
        times = "once" if self.displaced == 1 else f"{self.displaced} times in a row"
        log.warning(DISPLACED_LOG, wait, times)
        return wait

    async def _session(self, ws: ClientConnection) -> None:
        hello = self._hello().model_copy(
            update={"instance": self.instance, "displaced": self.displaced}
        )
        await ws.send(hello.model_dump_json())
        # asyncio.timeout, not wait_for, throughout: on Python 3.11 wait_for drops a
        # cancellation that arrives together with a result, and the link would not stop.
        async with asyncio.timeout(wire.HEARTBEAT_TIMEOUT_S):
            first = await ws.recv()
        welcome = wire.STATION_DOWN.validate_json(first)
        if not isinstance(welcome, wire.Welcome):
            raise _Closed(wire.CLOSE_MALFORMED, "the server did not answer hello with welcome")
        self.welcome = welcome
        self.connects += 1
        self.last_error = ""
        self.notice = ""
        self.connected.set()
        log.info("connected to %s as station %d", self.url, welcome.station_id)
        reader = asyncio.create_task(self._read(ws))
        try:
            await self._write(ws, reader)
        finally:
            reader.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await reader
        if ws.close_code not in (None, wire.CLOSE_NORMAL):
            raise _Closed(ws.close_code or 0, f"closed by the server: {ws.close_reason}")

    async def _read(self, ws: ClientConnection) -> None:
        while True:
            try:
                async with asyncio.timeout(wire.HEARTBEAT_TIMEOUT_S):
                    raw = await ws.recv()
            except TimeoutError:
                await ws.close(wire.CLOSE_TIMEOUT, "no heartbeat from the server")
                return
            except ConnectionClosed:
                return
            try:
                message = wire.STATION_DOWN.validate_json(raw)
            except ValidationError as exc:
                await ws.close(wire.CLOSE_MALFORMED, wire.error_text(exc))
                return
            if isinstance(message, wire.Command):
                # Not awaited here: a K/B change waiting for the device's ACK must not hold a
                # HOLD behind it. Tasks start in order, so the device is asked in order.
                task = asyncio.create_task(self._on_message(message))
                self._handling.add(task)
                task.add_done_callback(self._handling.discard)
            elif not isinstance(message, wire.Heartbeat):
                await self._on_message(message)

    async def _write(self, ws: ClientConnection, reader: asyncio.Task[None]) -> None:
        next_beat = 0.0
        while not reader.done():
            now = time.monotonic()
            try:
                if now >= next_beat:
                    await ws.send(wire.Heartbeat(sent=time.time()).model_dump_json())
                    next_beat = now + wire.HEARTBEAT_S
                # Control first, and looked at again before each batch: a result queued
                # while a batch was being sent goes next.
                while self.control or self.telemetry:
                    if self.control:
                        await ws.send(self.control[0])
                        self.control.popleft()  # only once the library has taken it
                    else:
                        await ws.send(self.telemetry.popleft())
            except ConnectionClosed:
                return
            self._wake.clear()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(max(0.0, next_beat - now)):
                    await self._wake.wait()


def refused_words(status: int) -> str:
    """Why the server refused this station's link (the HTTP status of its handshake)."""
    if status in (401, 403):
        # The server answers one way for both, so as not to tell a stranger which it is.
        return (
            f"the server refused this station's token ({status}): it was revoked, or the "
            "server does not know it; provision the station again and start it with the "
            "new token"
        )
    return f"server refused the station ({status})"


class _Closed(Exception):
    def __init__(self, code: int, text: str) -> None:
        super().__init__(text)
        self.code = code
