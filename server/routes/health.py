"""Liveness and readiness in one answer, for the launcher and for monitoring."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

from fastapi import APIRouter, Response, status
from sqlalchemy import text
from sqlalchemy.exc import SQLAlchemyError

from server.deps import Db
from server.schemas import HealthPublic

router = APIRouter(tags=["health"])


def server_version() -> str:
    try:
        return version("ankle-telerehab")
    except PackageNotFoundError:  # running from a source tree that was never installed
        return "0+unknown"


@router.get("/health", response_model=HealthPublic, summary="Server version and database state")
async def health(db: Db, response: Response) -> HealthPublic:
    """No authentication: it says nothing about patients. 503 when the database fails."""
    try:
        await db.execute(text("SELECT 1"))
        ok = True
    except SQLAlchemyError:
        ok = False
        response.status_code = status.HTTP_503_SERVICE_UNAVAILABLE
    return HealthPublic(status="ok" if ok else "degraded", version=server_version(), database=ok)
