"""Files the browser loads: our pages and scripts, and the chart libraries from npm.

The libraries are installed from the npm registry with ``webui/package-lock.json`` by the
setup step (``make setup`` runs ``npm ci``); nothing third-party is committed. A wheel built
after that step carries the five files below (pyproject.toml's package-data). They are served
under ``/vendor/`` by a fixed name, so a page never depends on a package's folder layout.
"""

from __future__ import annotations

import os
from pathlib import Path

from fastapi import APIRouter, HTTPException
from fastapi.responses import FileResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.types import Scope

HERE = Path(__file__).resolve().parent
STATIC = HERE / "static"
PAGES = HERE / "pages"
NODE_MODULES = HERE / "node_modules"

VENDOR: dict[str, Path] = {
    "uPlot.iife.min.js": NODE_MODULES / "uplot" / "dist" / "uPlot.iife.min.js",
    "uPlot.min.css": NODE_MODULES / "uplot" / "dist" / "uPlot.min.css",
    "chart.umd.min.js": NODE_MODULES / "chart.js" / "dist" / "chart.umd.min.js",
    "swagger-ui-bundle.js": NODE_MODULES / "swagger-ui-dist" / "swagger-ui-bundle.js",
    "swagger-ui.css": NODE_MODULES / "swagger-ui-dist" / "swagger-ui.css",
}
"""Served name → installed file."""

CSP = (
    "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
    "img-src 'self' data: blob:; connect-src 'self' ws: wss:; frame-src 'self'; "
    "object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'self'"
)
"""No inline script; frames only from this server (the live 3D view and the session replay)."""
VIEWER_CSP = (
    "default-src 'none'; script-src 'unsafe-inline' 'unsafe-eval'; style-src 'unsafe-inline'; "
    "img-src data: blob:; font-src data:; connect-src 'self' blob: data:; worker-src blob:; "
    "base-uri 'none'; form-action 'none'; frame-ancestors 'self'"
)
"""viser's client (the live 3D view and the replay viewer) is inline scripts and styles that
evaluate code, compile WebAssembly and start a blob: worker, and fetch data: URLs of their
own; it may open a WebSocket to this server (the live view), read a recording from this
server or a blob: URL, and reach nothing else; only the dashboard may frame it."""


def missing_vendor() -> list[str]:
    """Library files the setup step has not installed yet."""
    return [name for name, path in VENDOR.items() if not path.is_file()]


vendor_router = APIRouter(include_in_schema=False)


@vendor_router.get("/vendor/{name}")
async def vendor(name: str) -> FileResponse:
    path = VENDOR.get(name)
    if path is None:
        raise HTTPException(404, "no such library file")
    if not path.is_file():
        raise HTTPException(
            503,
            f"{name} is not installed: run 'make setup' (npm ci in webui/) on this machine",
        )
    return FileResponse(
        path, headers={"Cache-Control": "public, max-age=86400", "Content-Security-Policy": CSP}
    )


class Static(StaticFiles):
    """Our scripts and styles, with the dashboard's policy: a script run as a worker (the
    live page's link) is governed by its own response's CSP, which must let it connect."""

    def file_response(
        self,
        full_path: str | os.PathLike[str],
        stat_result: os.stat_result,
        scope: Scope,
        status_code: int = 200,
    ) -> Response:
        response = super().file_response(full_path, stat_result, scope, status_code)
        response.headers["Content-Security-Policy"] = CSP
        return response


def page(name: str) -> FileResponse:
    """One of our HTML pages, with the content security policy."""
    return FileResponse(
        PAGES / name,
        media_type="text/html",
        headers={"Content-Security-Policy": CSP, "Cache-Control": "no-cache"},
    )
