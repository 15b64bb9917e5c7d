"""The server with its dashboard: ``create_app`` wraps ``server.app.create_app``.

webui is the top layer (DESIGN.md section 5): the server never imports it. This factory adds
the dashboard's pages under ``/app``, the scripts and styles under ``/static``, the chart
libraries under ``/vendor``, the live 3D views (one viser server per watched station on
loopback, whose lifetime is the app's) behind tickets under ``/scene``, and the API docs page
with Swagger UI from ``/vendor``.
"""

from __future__ import annotations

import json
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import httpx
from fastapi import FastAPI
from fastapi.responses import Response

from device.axes import AXIS_INDEX, ROTATION_AXES
from server.app import create_app as create_server_app
from server.config import Settings
from server.routes import API_PREFIX
from webui import docs, pages, replay, routes, sceneproxy
from webui.assets import CSP, STATIC, Static, missing_vendor, vendor_router
from webui.live3d import LiveScenes
from webui.sceneproxy import CONNECT_TIMEOUT_S

log = logging.getLogger("ankle.webui")


def create_app(settings: Settings | None = None) -> FastAPI:
    """The API, the live links and the dashboard, in one app."""
    app = create_server_app(settings)
    server_lifespan = app.router.lifespan_context

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        async with server_lifespan(app):
            missing = missing_vendor()
            if missing:
                log.warning("chart libraries not installed (%s): run 'make setup'", missing)
            scenes = LiveScenes(app.state.hub)
            app.state.scenes = scenes
            # Only ever asks the views on loopback: no proxy from the environment.
            app.state.scene_http = httpx.AsyncClient(trust_env=False, timeout=CONNECT_TIMEOUT_S)
            try:
                yield
            finally:
                await scenes.close()
                await app.state.scene_http.aclose()

    app.router.lifespan_context = lifespan
    app.include_router(routes.router, prefix=API_PREFIX)
    app.include_router(replay.router, prefix=API_PREFIX)
    app.include_router(pages.router)
    app.include_router(vendor_router)
    app.include_router(docs.router)
    app.include_router(sceneproxy.router)

    @app.get("/static/js/axes.js", include_in_schema=False)
    def axes_module() -> Response:
        """The ankle's axes for the pages' scripts, from the project's one table."""
        rotations = list(ROTATION_AXES)
        body = (
            "// Generated from device/axes.py, the project's one table of axes.\n"
            f"export const AXES = {json.dumps(rotations)};\n"
            f"export const AXIS_INDEX = {json.dumps({a: AXIS_INDEX[a] for a in rotations})};\n"
        )
        return Response(
            body,
            media_type="text/javascript",
            headers={"Cache-Control": "no-cache", "Content-Security-Policy": CSP},
        )

    app.mount("/static", Static(directory=STATIC), name="static")
    return app
