"""Prometheus metrics of one server process, served at ``/metrics``.

What an operator watches: HTTP requests by route and status, database latency, stations and
viewers connected, live messages in and out, and the round trip of live commands to the
device and back. The metric objects live here, on this module's registry; the rest of the
server reports through the small functions below (one line at each place), so the live
relay's code does not depend on how the numbers are kept.

Access: from loopback only, unless ``ANKLE_METRICS_TOKEN`` is set, then with
``Authorization: Bearer <that token>`` from anywhere. Behind the reverse proxy a client's
address is the one it forwards, so the proxy itself does not make a request loopback.
Each process counts its own: with several server processes, scrape each one.
"""

from __future__ import annotations

import hmac
import ipaddress
import time
from typing import Any

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import Response
from fastapi.routing import iter_route_contexts
from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    ProcessCollector,
    generate_latest,
)
from sqlalchemy import event
from sqlalchemy.ext.asyncio import AsyncEngine
from starlette.types import ASGIApp, Message, Receive, Scope, Send

REGISTRY = CollectorRegistry()
ProcessCollector(registry=REGISTRY)  # CPU seconds, memory, open files of this process

HTTP_REQUESTS = Counter(
    "ankle_http_requests",
    "HTTP requests answered, by route template and status.",
    ["method", "route", "status"],
    registry=REGISTRY,
)
HTTP_SECONDS = Histogram(
    "ankle_http_request_seconds",
    "Time from a request's arrival to its answer's headers, by route template.",
    ["method", "route"],
    registry=REGISTRY,
)
DB_SECONDS = Histogram(
    "ankle_db_statement_seconds",
    "Time the database took per SQL statement.",
    buckets=(0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5),
    registry=REGISTRY,
)
STATIONS = Gauge("ankle_live_stations", "Stations connected to this process.", registry=REGISTRY)
VIEWERS = Gauge("ankle_live_viewers", "Live views open on this process.", registry=REGISTRY)
LIVE_MESSAGES = Counter(
    "ankle_live_messages",
    "Live WebSocket messages: 'in' from stations and viewers, 'out' to them, by type.",
    ["direction", "peer", "type"],
    registry=REGISTRY,
)
RESULTS_DROPPED = Counter(
    "ankle_live_results_dropped",
    "Command results a station sent for no command awaiting its answer (a second answer to "
    "one command, or a request id never sent to it): not shown to the viewers, logged at most "
    "5 times a minute a station.",
    registry=REGISTRY,
)
COMMAND_SECONDS = Histogram(
    "ankle_live_command_round_trip_seconds",
    "From sending a live command to the station to its answer (the device's ACK or NACK), "
    "or to TIMEOUT / OFFLINE; by action and outcome.",
    ["action", "outcome"],
    buckets=(0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0),
    registry=REGISTRY,
)
AUDIT_BACKLOG = Gauge(
    "ankle_audit_backlog_rows",
    "Audit rows of live commands (a HOLD's, a Stop's, outcomes) waiting for the database: "
    "above 0 for more than a few seconds, the database is away and the rows are only in "
    "this process's memory.",
    registry=REGISTRY,
)
AUDIT_LOST = Counter(
    "ankle_audit_rows_lost",
    "Audit rows that will not be in the audit log (each is logged in full at ERROR): "
    "'backlog_full' (ANKLE_AUDIT_BACKLOG_MAX rows already waited for the database), "
    "'refused' (the database refused what the row holds), 'shutdown' (still waiting when "
    "the server stopped).",
    ["reason"],
    registry=REGISTRY,
)

UPLOAD_FAULTS = Counter(
    "ankle_upload_faults",
    "Uploads the server could not keep as the station sent them (each is logged at ERROR): "
    "'storage_full' (a chunk found no space or quota left in the data directory: answered "
    "507, the bytes before it kept), 'corrupted' (at complete, the server's bytes did not "
    "hash to the station's SHA-256), 'lost' (bytes acknowledged earlier were no longer on "
    "disk); the last two discard the upload and ask the station to send it again.",
    ["fault"],
    registry=REGISTRY,
)

_sent_at: dict[str, tuple[str, float]] = {}
"""request_id -> (action, when it was sent): commands awaiting their answer."""
_SENT_KEPT = 10_000


# -- what the live relay reports, one line at each place ---------------------------------
_live_series: dict[tuple[str, str, str], Any] = {}
"""(direction, peer, type) -> its counter: looking a labelled series up costs more than
counting on it, and this runs for every live message (the types are the wire's few)."""


def _live(direction: str, peer: str, kind: str) -> Any:
    series = _live_series.get((direction, peer, kind))
    if series is None:
        series = _live_series[direction, peer, kind] = LIVE_MESSAGES.labels(direction, peer, kind)
    return series


def received(peer: str, message: Any) -> None:
    """A live message arrived from a ``station`` or a ``viewer``."""
    _live("in", peer, getattr(message, "type", "unknown")).inc()


def sent(peer: str, kind: str, count: int = 1) -> None:
    """``count`` live messages of ``kind`` left for ``peer``s."""
    _live("out", peer, kind).inc(count)


def command_sent(request_id: str, action: str) -> None:
    if len(_sent_at) >= _SENT_KEPT:  # answers that never came through the hub's book
        _sent_at.pop(next(iter(_sent_at)))
    _sent_at[request_id] = (action, time.perf_counter())


def command_answered(request_id: str, outcome: str) -> None:
    """The command's first outcome: ``accepted``, ``refused``, ``TIMEOUT`` or ``OFFLINE``."""
    started = _sent_at.pop(request_id, None)
    if started is not None:
        action, at = started
        COMMAND_SECONDS.labels(action, outcome).observe(time.perf_counter() - at)


def result_dropped() -> None:
    """A station's command result answered nothing awaiting it (``RESULTS_DROPPED``)."""
    RESULTS_DROPPED.inc()


def audit_row_lost(reason: str) -> None:
    """One audit row will not be stored, for ``reason`` (see ``AUDIT_LOST``)."""
    AUDIT_LOST.labels(reason).inc()


def upload_fault(fault: str) -> None:
    """An upload met ``fault`` (see ``UPLOAD_FAULTS``)."""
    UPLOAD_FAULTS.labels(fault).inc()


def watch_database(engine: AsyncEngine) -> None:
    """Time every statement ``engine`` runs."""
    sync = engine.sync_engine

    @event.listens_for(sync, "before_cursor_execute")
    def _start(
        conn: Any, cursor: Any, statement: Any, params: Any, context: Any, many: Any
    ) -> None:
        conn.info.setdefault("ankle_t0", []).append(time.perf_counter())

    @event.listens_for(sync, "after_cursor_execute")
    def _end(conn: Any, *_: Any) -> None:
        starts = conn.info.get("ankle_t0")
        if starts:
            DB_SECONDS.observe(time.perf_counter() - starts.pop())


# -- HTTP ----------------------------------------------------------------------------------
METHODS = frozenset(
    {"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS", "CONNECT", "TRACE"}
)
"""The methods HTTP defines (RFC 9110, and PATCH): every other counts as ``other``. A
request line may carry any token as its method, so the label's values must be a closed
set: 20,000 pipelined requests with made-up methods, no token needed, made 20,000 series,
grew ``/metrics`` to 38 MB and blocked the event loop 4 s per scrape."""


def method_label(method: str) -> str:
    return method if method in METHODS else "other"


def status_label(status: int) -> str:
    """A status an ASGI app can send is any integer; HTTP's are 100-599."""
    return str(status) if 100 <= status <= 599 else "other"


class HttpMetrics:
    """Counts and times every HTTP request by its route's template (``/api/v1/patients/{id}``,
    never the path itself, so the number of series stays bounded); a request no route
    matched counts as ``unmatched``, a method HTTP does not define as ``other``: every
    label comes from a closed set, whatever a client sends."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app
        self._templates: dict[int, str] | None = None

    def _route(self, scope: Scope) -> str:
        """The full template of the route that answered: a route included from a router
        knows only its own part of the path, so the app's route table is read once."""
        if self._templates is None:
            self._templates = {}
            for context in iter_route_contexts(scope["app"].routes):
                if context.path:
                    self._templates.setdefault(id(context.original_route), context.path)
        route = scope.get("route")
        if route is None:
            return "unmatched"
        return self._templates.get(id(route)) or str(getattr(route, "path", "unmatched"))

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        start = time.perf_counter()
        status = 500

        async def send_status(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
                HTTP_SECONDS.labels(method_label(scope["method"]), self._route(scope)).observe(
                    time.perf_counter() - start
                )
            await send(message)

        try:
            await self.app(scope, receive, send_status)
        finally:
            HTTP_REQUESTS.labels(
                method_label(scope["method"]), self._route(scope), status_label(status)
            ).inc()


# -- /metrics --------------------------------------------------------------------------------
router = APIRouter(include_in_schema=False)


def _loopback(host: str | None) -> bool:
    try:
        return host is not None and ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@router.get("/metrics")
async def metrics(request: Request) -> Response:
    token = request.app.state.settings.metrics_token
    if token is not None:
        given = request.headers.get("authorization", "")
        expected = f"Bearer {token.get_secret_value()}"
        if not hmac.compare_digest(given.encode(), expected.encode()):
            raise HTTPException(
                401, "metrics need 'Authorization: Bearer' with ANKLE_METRICS_TOKEN"
            )
    elif not _loopback(request.client.host if request.client else None):
        raise HTTPException(
            403, "metrics are served to this machine only (set ANKLE_METRICS_TOKEN to allow more)"
        )
    hub = request.app.state.hub
    STATIONS.set(len(hub.stations))
    VIEWERS.set(sum(len(v) for v in hub.viewers.values()))
    AUDIT_BACKLOG.set(hub.writer.backlog)
    return Response(generate_latest(REGISTRY), media_type=CONTENT_TYPE_LATEST)
