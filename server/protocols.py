"""The protocols the server runs uvicorn with: uvicorn's own (h11 and websockets' sans-I/O,
the ones it picks here), with two gaps closed.

- Time to send a request, which matters where no reverse proxy (``deploy/``) bounds it in
  front. uvicorn bounds only the idle time between one request's answer and the next
  request (``timeout_keep_alive``). A connection that sends nothing, or a request whose
  headers never end (a byte now and then: "slowloris"), stayed open for good, and enough
  of them take every file descriptor the process has. Here a new connection that sends
  nothing is closed after the same keep-alive time, and a request's headers must all
  arrive within ``header_timeout_s`` of their first byte (nginx's
  ``client_header_timeout``); the connection is closed otherwise. A request's body must
  not stall: ``body_timeout_s`` with no byte of it while the server is reading it (nginx's
  ``client_body_timeout``, the time between two reads, not the whole body's) is answered
  408 and the connection closed, as a declared ``Content-Length`` never met would hold it
  for good. A body sent slowly but steadily, a station's 1 MiB chunk over a poor mobile
  link, is never cut; nor one the server does not read yet (its reading paused while the
  route works, or a client waiting for ``100 Continue``).
- A WebSocket text frame that is not UTF-8. uvicorn closes the link with 1007, as the
  protocol says, but logs it as a server failure: an ERROR and a traceback for each. Here
  it is one line, and the close says why.
- A WebSocket peer that stops reading. Once what it has not taken fills the socket's
  buffers, uvicorn makes every send wait until it takes some, with no end: a viewer that
  stopped reading but still sent its heartbeats held its writer (and any close of it) for
  good, and what was queued for it grew. Here a send that has waited ``SEND_STALL_S`` cuts
  the connection; a close does not wait at all: it goes behind what the peer has not read
  yet (a peer that reads again gets everything, then the close with its code and reason),
  and the connection is cut if the peer has not answered it within ``SEND_STALL_S``.

:func:`protocols` gives uvicorn.Config's ``http`` and ``ws`` for a server's settings.
"""

from __future__ import annotations

import asyncio
import functools
import json
import logging
from typing import Any

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol
from uvicorn.protocols.utils import ClientDisconnected
from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol

from server.config import Settings
from server.headers import API_CSP
from sessions import wire

log = logging.getLogger("ankle.server")


def _peer(client: tuple[str, int] | None) -> str:
    return f"{client[0]}:{client[1]}" if client else "a client"


class TimedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol, closing a connection whose request headers are late."""

    def __init__(
        self, *args: Any, header_timeout_s: float, body_timeout_s: float, **kwargs: Any
    ) -> None:
        super().__init__(*args, **kwargs)
        self.header_timeout_s = header_timeout_s
        self._header_timer: asyncio.TimerHandle | None = None
        self.body_timeout_s = body_timeout_s
        self._body_timer: asyncio.TimerHandle | None = None
        self._body_seen = 0.0
        """When the request's body last moved (a byte, or the server not reading it)."""

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        # Idle before its first request as between two: uvicorn's keep-alive timer (the
        # first byte cancels it, as it does between requests).
        self.timeout_keep_alive_task = self.loop.call_later(
            self.timeout_keep_alive, self.timeout_keep_alive_handler
        )

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        if self.conn.their_state is h11.IDLE and not self.transport.is_closing():
            if self._header_timer is None:  # the first byte of a request's headers
                self._header_timer = self.loop.call_later(self.header_timeout_s, self._headers_late)
        else:  # the headers are in (or the request was refused, or became a WebSocket)
            self._stop_header_timer()
        if self.conn.their_state is h11.SEND_BODY and self._reads_body():
            self._body_seen = self.loop.time()  # the headers, or a part of the body
            if self._body_timer is None:
                self._body_timer = self.loop.call_later(self.body_timeout_s, self._body_late)
        else:
            self._stop_body_timer()

    def connection_lost(self, exc: Exception | None) -> None:
        self._stop_header_timer()
        self._stop_body_timer()
        super().connection_lost(exc)

    def _stop_body_timer(self) -> None:
        if self._body_timer is not None:
            self._body_timer.cancel()
            self._body_timer = None

    def _reads_body(self) -> bool:
        """Whether this connection is still an HTTP one reading a request: not closing, and
        not handed to a WebSocket. An upgrade request leaves h11 in ``SEND_BODY`` when the
        link is handed over; timed as a body, every live link was cut after 60 s."""
        return not self.transport.is_closing() and self.transport.get_protocol() is self

    def _body_late(self) -> None:
        """The body timer (one per request, moved on rather than made again per read)."""
        self._body_timer = None
        if not self._reads_body() or self.conn.their_state is not h11.SEND_BODY:
            return
        now = self.loop.time()
        cycle = self.cycle
        if self.flow.read_paused or (cycle is not None and cycle.waiting_for_100_continue):
            self._body_seen = now  # the server is not reading: the client is not late
        idle = now - self._body_seen
        if idle < self.body_timeout_s:
            self._body_timer = self.loop.call_later(self.body_timeout_s - idle, self._body_late)
            return
        log.warning(
            "closed the connection of %s: no byte of its request body (%s %s) for %g s",
            _peer(self.client),
            self.scope.get("method", "?") if cycle is not None else "?",
            self.scope.get("path", "?") if cycle is not None else "?",
            self.body_timeout_s,
        )
        if cycle is not None and not cycle.response_started:
            self._send_408()
            # The route waiting for the body reads a disconnect now, and what it sends is
            # dropped, as when the client leaves (uvicorn does so once the socket closes).
            cycle.disconnected = True
            cycle.message_event.set()
        self.transport.close()

    def _send_408(self) -> None:
        body = json.dumps(
            {"detail": f"the request body stalled: no byte of it for {self.body_timeout_s:g} s"}
        ).encode()
        # What every other answer carries: uvicorn's date and server headers, and the
        # security headers (written here, outside the app and its middleware).
        headers = [
            *self.server_state.default_headers,
            (b"content-type", b"application/json"),
            (b"content-length", str(len(body)).encode()),
            (b"connection", b"close"),
            (b"x-content-type-options", b"nosniff"),
            (b"content-security-policy", API_CSP.encode()),
        ]
        try:
            for event in (
                h11.Response(status_code=408, headers=headers, reason=b"Request Timeout"),
                h11.Data(data=body),
                h11.EndOfMessage(),
            ):
                self.transport.write(self.conn.send(event) or b"")
        except h11.LocalProtocolError:  # no answer can be sent on this connection now
            pass

    def _stop_header_timer(self) -> None:
        if self._header_timer is not None:
            self._header_timer.cancel()
            self._header_timer = None

    def _headers_late(self) -> None:
        self._header_timer = None
        if self.transport.is_closing() or self.conn.their_state is not h11.IDLE:
            return
        log.warning(
            "closed the connection of %s: its request headers did not all arrive within %g s",
            _peer(self.client),
            self.header_timeout_s,
        )
        self.conn.send(h11.ConnectionClosed())
        self.transport.close()


SEND_STALL_S = wire.HEARTBEAT_TIMEOUT_S
"""The longest a WebSocket send waits for a peer that takes nothing: as long as a live link
may stay silent."""


class Utf8WebSocketProtocol(WebSocketsSansIOProtocol):
    """uvicorn's WebSocket protocol, closing on a text message that is not UTF-8 with one
    log line and a reason, and cutting a peer that takes nothing for ``SEND_STALL_S``."""

    send_stall_s = SEND_STALL_S

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._paused = False
        self._cut_timer: asyncio.TimerHandle | None = None

    def pause_writing(self) -> None:
        self._paused = True
        super().pause_writing()

    def resume_writing(self) -> None:
        self._paused = False
        super().resume_writing()

    def connection_lost(self, exc: Exception | None) -> None:
        if self._cut_timer is not None:
            self._cut_timer.cancel()
            self._cut_timer = None
        super().connection_lost(exc)

    async def send(self, message: Any) -> None:
        if self._paused and not self.disconnected and self.handshake_complete:
            if message["type"] == "websocket.close" and not self.close_sent:
                self.writable.set()  # the close alone passes: the buffer takes it
                try:
                    await super().send(message)
                finally:
                    if self._paused:
                        self.writable.clear()
                self._cut_timer = self.loop.call_later(self.send_stall_s, self._cut)
                return
            try:
                async with asyncio.timeout(self.send_stall_s):
                    await self.writable.wait()
            except TimeoutError:
                self._cut()
                raise ClientDisconnected from None
        await super().send(message)

    def _cut(self) -> None:
        """Drop the connection of a peer that takes nothing sent to it."""
        self._cut_timer = None
        if self.disconnected or not self._paused:
            return  # it took what it was sent: uvicorn's own close timer goes on
        log.warning(
            "cut the WebSocket of %s: it took nothing sent to it for %g s",
            _peer(self.client),
            self.send_stall_s,
        )
        self.transport.abort()

    def send_receive_event_to_app(self) -> None:
        if self.curr_msg_data_type == "text" and not self.close_sent:
            try:
                b"".join(self.frames).decode()
            except UnicodeDecodeError as exc:
                self.frames = []
                log.warning(
                    "closed the WebSocket of %s (%d): a text message is not UTF-8 (byte %d)",
                    _peer(self.client),
                    wire.CLOSE_MALFORMED,
                    exc.start,
                )
                self.conn.send_close(wire.CLOSE_MALFORMED, "text messages must be UTF-8")
                self.handle_parser_exception()  # tells the app, sends the close, ends
                return
        super().send_receive_event_to_app()


SHUTDOWN_WAIT_S = 10
"""How long a stopping server waits for its requests and live links to end before it
cancels them (uvicorn's ``timeout_graceful_shutdown``). Without a bound it waited for ever:
a link handler stuck on a store that no longer answered kept a stopping server (and a test
run, idle for an hour) from ending."""


def protocols(settings: Settings) -> dict[str, Any]:
    """uvicorn.Config's ``http`` and ``ws`` for ``settings`` (a partial, not a class made
    on the fly: worker processes receive the configuration pickled), and how long a
    shutdown waits (:data:`SHUTDOWN_WAIT_S`)."""
    return {
        "timeout_graceful_shutdown": SHUTDOWN_WAIT_S,
        "http": functools.partial(
            TimedH11Protocol,
            header_timeout_s=settings.header_timeout_s,
            body_timeout_s=settings.body_timeout_s,
        ),
        "ws": Utf8WebSocketProtocol,
    }
