"""The application factory: ``create_app(settings)`` builds one self-contained server.

Nothing is created at import time. The engine, the migrations and the live hub come to life
in the lifespan, so two apps with different settings (tests, the demo) never share state.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import re
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from sqlalchemy.exc import DBAPIError

from server import errors, live, metrics
from server.config import Settings
from server.db import create_engine, create_sessionmaker, prepare
from server.export_workers import ExportWorkers
from server.guard import RequestGuard
from server.headers import AllowedMethods, SecurityHeaders
from server.hub import VIEW_HZ, Hub
from server.idempotency import HEADER, Replay, replayed
from server.logs import RequestIds
from server.relay import open_relay
from server.routes import API_PREFIX, ROUTERS
from server.routes.common import document_must_change
from server.routes.health import server_version
from server.routes.uploads import CHUNK_MAX, UploadAnswer, expire_uploads_forever, upload_answer
from server.security import HashingSlots
from server.throttle import LoginGate, LoginThrottle
from server.tickets import ViewTickets

DESCRIPTION = """\
The server of the ankle telerehabilitation system: therapists manage their patients,
prescribe exercises and provision home stations; stations fetch what to run.

Authenticate with `Authorization: Bearer <token>`: a user's token from `POST /auth/login`,
or a station's token from its provisioning. Angles are degrees, stiffness N·m/rad, damping
N·m·s/rad, times seconds, timestamps UTC.
"""


GC_YOUNG_THRESHOLD = 20_000
"""Allocations less deallocations between two collections of the youngest generation
(CPython's default is 700). Fewer young collections promote fewer objects, and so start
fewer full ones: one in a 10 s window at 150 stations instead of three."""


def settle_garbage_collector() -> None:
    """Once the server has started: collect, then freeze what is left (modules, routes, the
    ORM's tables, the hub) into the permanent generation, which no collection walks again,
    and collect the young generation less often (:data:`GC_YOUNG_THRESHOLD`).

    Measured with ``ankle bench server --stations 150`` on one process (10 s windows): without
    it, full collections that found 0-25 objects to free stopped the event loop for 95-145 ms,
    1-3 times a window, and alone set telemetry p99 to 82-133 ms and K/B p99 to 146-174 ms
    at 64-70 % of a core. Frozen: p99 4.8-9.1 ms; with the young threshold too, 2.7-5.5 ms
    and one full collection a window instead of three. Memory: the start-up's objects are
    never freed, which they never were anyway; what is made later is collected as before.
    """
    gc.collect()
    gc.freeze()
    _, middle, old = gc.get_threshold()
    gc.set_threshold(GC_YOUNG_THRESHOLD, middle, old)


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    settings: Settings = app.state.settings
    engine = create_engine(settings)
    metrics.watch_database(engine)
    relay = open_relay(settings.relay_url, settings.relay_lease_s, VIEW_HZ)
    hub = Hub(recheck_s=settings.live_recheck_s, relay=relay)
    hub.writer.backlog_max = settings.audit_backlog_max
    expiry: asyncio.Task[None] | None = None
    try:
        await prepare(engine, settings.migrate_on_start)
        app.state.engine = engine
        app.state.sessionmaker = hub.sessionmaker = create_sessionmaker(engine)
        app.state.hub = hub
        await hub.start()
        app.state.hashing = HashingSlots(settings.password_hash_concurrency)
        app.state.exports = ExportWorkers(
            settings.export_workers, settings.export_queue_max, settings.export_timeout_s
        )
        app.state.login_throttle = LoginThrottle(settings)
        # Here, not in the dashboard, so that whatever ends a user's access can end theirs.
        app.state.view_tickets = hub.tickets = ViewTickets(settings.view_ticket_ttl_s)
        expiry = asyncio.create_task(expire_uploads_forever(app))
        if settings.gc_freeze:
            settle_garbage_collector()
        yield
    finally:
        if expiry is not None:
            expiry.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await expiry
        await hub.close()
        if hasattr(app.state, "login_throttle"):
            await app.state.login_throttle.close()
        if hasattr(app.state, "hashing"):
            app.state.hashing.close()
        if hasattr(app.state, "exports"):
            app.state.exports.close()
        await engine.dispose()


_UPLOAD_CHUNK = re.compile(rf"^{API_PREFIX}/uploads/[^/]+$")


def body_limit(method: str, path: str) -> int | None:
    """The routes whose bodies are not JSON of ordinary size: an upload's chunks."""
    if method == "PATCH" and _UPLOAD_CHUNK.match(path):
        return CHUNK_MAX
    return None


def create_app(settings: Settings | None = None) -> FastAPI:
    """The API with its routes; the database is opened and migrated when it starts."""
    settings = Settings() if settings is None else settings
    app = FastAPI(
        title="Ankle telerehabilitation server",
        version=server_version(),
        description=DESCRIPTION,
        lifespan=lifespan,
        openapi_url=f"{API_PREFIX}/openapi.json",
        # The docs page needs Swagger UI's files, which the dashboard installs and serves
        # (webui.app): never a CDN's.
        docs_url=None,
        redoc_url=None,
    )
    app.state.settings = settings
    app.add_exception_handler(RequestValidationError, errors.validation_error)
    app.add_exception_handler(OverflowError, errors.overflow_error)
    app.add_exception_handler(OSError, errors.os_error)
    app.add_exception_handler(DBAPIError, errors.database_error)
    app.add_exception_handler(errors.CommitUnknown, errors.commit_unknown)
    app.add_exception_handler(Replay, replayed)
    app.add_exception_handler(UploadAnswer, upload_answer)
    # Bearer tokens, not cookies: no credentials mode, so a listed origin can call the API
    # but a browser never attaches anything on its own.
    app.add_middleware(
        CORSMiddleware,
        allow_origins=settings.allowed_origins,
        allow_methods=["GET", "POST", "PATCH", "PUT", "DELETE"],
        allow_headers=["Authorization", "Content-Type", HEADER],
    )
    # Added last, so outermost: a body is refused before CORS or any route sees it, and
    # every answer, refusals included, carries the security headers.
    app.add_middleware(RequestGuard, default=settings.body_max_bytes, limit_for=body_limit)
    app.add_middleware(LoginGate, path=f"{API_PREFIX}/auth/login")
    app.add_middleware(SecurityHeaders)
    app.add_middleware(AllowedMethods)
    app.add_middleware(metrics.HttpMetrics)
    app.add_middleware(RequestIds)  # outermost: every log line of a request carries its id
    for router in ROUTERS:
        app.include_router(router, prefix=API_PREFIX)
    document_must_change(app)  # on every route, the dashboard's included
    # The live router names its own full paths (/ws/..., /api/v1/schemas/ws).
    app.include_router(live.router)
    app.include_router(metrics.router)
    return app
