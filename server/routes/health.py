"""Liveness and readiness in one answer, for the launcher and for monitoring."""

from __future__ import annotations

import shutil

from fastapi import APIRouter, Request, Response, status
from sqlalchemy import text
from sqlalchemy.exc import SQLAlchemyError

from device import installed_version
from server.deps import Db
from server.errors import RETRY_AFTER_S
from server.schemas import HealthPublic

router = APIRouter(tags=["health"])


server_version = installed_version


@router.get("/health", response_model=HealthPublic, summary="Server version and database state")
async def health(db: Db, request: Request, response: Response) -> HealthPublic:
    """No authentication: it says nothing about patients. 503 ("degraded") when the
    database fails or the data directory has less free space than ``disk_free_min_bytes``
    (uploads and sign-ins would soon fail)."""
    settings = request.app.state.settings
    try:
        await db.execute(text("SELECT 1"))
        database = True
    except (SQLAlchemyError, OSError):  # OSError: the driver could not even connect
        database = False
    free = shutil.disk_usage(settings.data_dir).free
    disk = free >= settings.disk_free_min_bytes
    if not (database and disk):
        response.status_code = status.HTTP_503_SERVICE_UNAVAILABLE
    if not database:
        response.headers["Retry-After"] = str(RETRY_AFTER_S)
    hub = getattr(request.app.state, "hub", None)
    return HealthPublic(
        audit_backlog=hub.writer.backlog if hub is not None else 0,
        status="ok" if database and disk else "degraded",
        version=server_version(),
        database=database,
        disk_free_bytes=free,
        disk_ok=disk,
    )
