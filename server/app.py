"""The application factory: ``create_app(settings)`` builds one self-contained server.

Nothing is created at import time. The engine, the migrations and the live hub come to life
in the lifespan, so two apps with different settings (tests, the demo) never share state.
"""

from __future__ import annotations

import math
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI, Request, status
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse

from server import live
from server.config import Settings
from server.db import create_engine, create_sessionmaker, migrate
from server.routes import API_PREFIX, ROUTERS
from server.routes.health import server_version

DESCRIPTION = """\
The server of the ankle telerehabilitation system: therapists manage their patients,
prescribe exercises and provision home stations; stations fetch what to run.

Authenticate with `Authorization: Bearer <token>`: a user's token from `POST /auth/login`,
or a station's token from its provisioning. Angles are degrees, stiffness N·m/rad, damping
N·m·s/rad, times seconds, timestamps UTC.
"""


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    settings: Settings = app.state.settings
    engine = create_engine(settings)
    hub = live.Hub()
    try:
        await migrate(engine)
        app.state.engine = engine
        app.state.sessionmaker = create_sessionmaker(engine)
        app.state.hub = hub
        yield
    finally:
        await hub.close()
        await engine.dispose()


def _json_safe(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_json_safe(v) for v in value]
    return value


async def validation_error(request: Request, exc: Exception) -> JSONResponse:
    """FastAPI's 422, except that a rejected NaN or Infinity, which the error echoes as its
    input, is written as a string: strict JSON has no such numbers, and rendering one
    would turn a refusal into a 500."""
    assert isinstance(exc, RequestValidationError)
    detail = _json_safe(jsonable_encoder(exc.errors()))
    return JSONResponse({"detail": detail}, status_code=status.HTTP_422_UNPROCESSABLE_CONTENT)


async def overflow_error(request: Request, exc: Exception) -> JSONResponse:
    """An id or offset beyond what the database stores (2**63-1) cannot name anything: a
    422 in FastAPI's own shape, not a 500 from the driver."""
    detail = [
        {
            "loc": ["request"],
            "msg": "a number in the request is beyond 2**63-1, the largest the server stores",
            "type": "overflow",
        }
    ]
    return JSONResponse({"detail": detail}, status_code=status.HTTP_422_UNPROCESSABLE_CONTENT)


def create_app(settings: Settings | None = None) -> FastAPI:
    """The API with its routes; the database is opened and migrated when it starts."""
    settings = Settings() if settings is None else settings
    app = FastAPI(
        title="Ankle telerehabilitation server",
        version=server_version(),
        description=DESCRIPTION,
        lifespan=lifespan,
        openapi_url=f"{API_PREFIX}/openapi.json",
        docs_url=f"{API_PREFIX}/docs",
        redoc_url=None,
    )
    app.state.settings = settings
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_exception_handler(OverflowError, overflow_error)
    # Bearer tokens, not cookies: no credentials mode, so a listed origin can call the API
    # but a browser never attaches anything on its own.
    app.add_middleware(
        CORSMiddleware,
        allow_origins=settings.allowed_origins,
        allow_methods=["GET", "POST", "PATCH", "PUT", "DELETE"],
        allow_headers=["Authorization", "Content-Type"],
    )
    for router in ROUTERS:
        app.include_router(router, prefix=API_PREFIX)
    # The live router names its own full paths (/ws/..., /api/v1/schemas/ws).
    app.include_router(live.router)
    return app
