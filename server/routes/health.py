"""Liveness and readiness in one answer, for the launcher and for monitoring."""

from __future__ import annotations

import asyncio
import functools
import logging
import shutil
from collections.abc import Awaitable

from fastapi import APIRouter, Request, Response, status
from limits.aio.storage import MemoryStorage
from sqlalchemy import text
from sqlalchemy.ext.asyncio import AsyncEngine

from device import installed_version
from server.errors import RETRY_AFTER_S
from server.schemas import HealthPublic

router = APIRouter(tags=["health"])
log = logging.getLogger("ankle.server")

server_version = functools.cache(installed_version)
"""Read once: the package metadata was about 44 % of the event loop's busy time with /health
polled every 10 ms, and a running process serves the version it started with."""

HEALTH_WAIT_S = 2.0
"""How long ``/health`` waits for each thing it asks (the database, the relay, the store of
failed sign-ins), all at once: a monitor polling it gets an answer within this whatever
stopped answering, and a dependency that takes longer is reported down."""


_LEFT: set[asyncio.Future[object]] = set()
"""Checks past the wait, left to end by themselves (see :func:`_answers`)."""


def _forget(task: asyncio.Future[object]) -> None:
    _LEFT.discard(task)
    if not task.cancelled():
        task.exception()  # retrieved: a check that failed late is not an unhandled error


async def _answers(what: str, call: Awaitable[object]) -> bool:
    """Whether ``call`` returned within ``HEALTH_WAIT_S``; why not is logged.

    A check past the wait is not cancelled but left to end by itself (each has its own
    bound: the database's connect and statement timeouts, Redis's socket timeout):
    cancelling a query on a database that answers nothing waits for the driver's cancel
    request, which it does not answer either, and ``/health`` took 4.0 s on a frozen
    PostgreSQL instead of its 2."""
    task = asyncio.ensure_future(call)
    done, _ = await asyncio.wait({task}, timeout=HEALTH_WAIT_S)
    if not done:
        _LEFT.add(task)
        task.add_done_callback(_forget)
        log.warning("health: %s did not answer within %g s", what, HEALTH_WAIT_S)
        return False
    if (exc := task.exception()) is not None:  # whatever the driver raised: "down"
        log.warning("health: %s did not answer: %s", what, exc)
        return False
    return True


async def _select_one(engine: AsyncEngine) -> None:
    async with engine.connect() as connection:
        await connection.execute(text("SELECT 1"))


async def _counts_answer(request: Request) -> bool | None:
    throttle = getattr(request.app.state, "login_throttle", None)
    if throttle is None or isinstance(throttle.storage, MemoryStorage):
        return None  # this process's own memory: nothing to ask
    storage = throttle.storage

    async def check() -> None:
        if not await storage.check():  # limits' own health check: False, never a raise
            raise ConnectionError("the storage's check failed")

    return await _answers("the store of failed sign-ins", check())


@router.get("/health", response_model=HealthPublic, summary="Server version and dependencies")
async def health(request: Request, response: Response) -> HealthPublic:
    """No authentication: it says nothing about patients. 503 ("degraded") when the
    database, the relay between server processes or the store of failed sign-ins does not
    answer within ``HEALTH_WAIT_S``, or the data directory has less free space than
    ``disk_free_min_bytes`` (uploads and sign-ins would soon fail)."""
    settings = request.app.state.settings
    hub = getattr(request.app.state, "hub", None)
    relay = hub.relay if hub is not None and settings.relay_url else None
    database, relayed, counts = await asyncio.gather(
        _answers("the database", _select_one(request.app.state.engine)),
        _answers("the relay", relay.answers()) if relay is not None else _none(),
        _counts_answer(request),
    )
    free = shutil.disk_usage(settings.data_dir).free
    disk = free >= settings.disk_free_min_bytes
    away = not database or relayed is False or counts is False
    if away or not disk:
        response.status_code = status.HTTP_503_SERVICE_UNAVAILABLE
    if away:
        response.headers["Retry-After"] = str(RETRY_AFTER_S)
    return HealthPublic(
        audit_backlog=hub.writer.backlog if hub is not None else 0,
        status="degraded" if away or not disk else "ok",
        version=server_version(),
        database=database,
        relay=relayed,
        login_throttle_storage=counts,
        disk_free_bytes=free,
        disk_ok=disk,
    )


async def _none() -> None:
    return None
