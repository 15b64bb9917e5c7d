"""The dashboard's answers: every one with nosniff and a policy; the API docs page with
Swagger UI from this server, never a CDN."""

from __future__ import annotations

import base64
import hashlib
import re
from pathlib import Path

import pytest

from server.config import Settings
from server.headers import API_CSP
from tests.server.live_server import running
from webui.app import create_app
from webui.assets import CSP, missing_vendor


@pytest.mark.asyncio
async def test_the_docs_page_loads_swagger_ui_from_this_server(tmp_path: Path) -> None:
    assert not missing_vendor(), "run 'make setup' (npm ci in webui/)"
    async with running(Settings(data_dir=tmp_path), create_app) as live:
        base = live.client.base_url
        page = await live.client.get("/docs")
        assert page.status_code == 200 and "text/html" in page.headers["content-type"]
        html = page.text
        assert "http://" not in html and "https://" not in html  # nothing from elsewhere
        sources = re.findall(r'(?:src|href)="([^"]+)"', html)
        assert set(sources) == {
            "/vendor/swagger-ui-bundle.js",
            "/vendor/swagger-ui.css",
            "/favicon.ico",
        }
        for src in sources:
            r = await live.client.get(str(base.join(src)))
            assert r.status_code == 200, src
            assert r.headers["x-content-type-options"] == "nosniff"
        bundle = await live.client.get(str(base.join("/vendor/swagger-ui-bundle.js")))
        assert "SwaggerUIBundle" in bundle.text
        assert "/api/v1/openapi.json" in html
    policy = page.headers["content-security-policy"]
    assert "'unsafe-inline'" not in policy.split("script-src", 1)[1].split(";")[0]
    (inline,) = re.findall(r"<script>(.*?)</script>", html, re.DOTALL)
    digest = base64.b64encode(hashlib.sha256(inline.encode()).digest()).decode()
    assert f"'sha256-{digest}'" in policy
    assert "frame-ancestors 'none'" in policy
    assert page.headers["x-content-type-options"] == "nosniff"


@pytest.mark.asyncio
async def test_pages_scripts_and_api_answers_carry_their_policies(tmp_path: Path) -> None:
    async with running(Settings(data_dir=tmp_path), create_app) as live:
        base = live.client.base_url

        async def get(path: str) -> tuple[int, str, str]:
            r = await live.client.get(str(base.join(path)))
            return (
                r.status_code,
                r.headers["content-security-policy"],
                r.headers["x-content-type-options"],
            )

        # Pages and our scripts: the dashboard's policy, which lets the live page's worker
        # (a script with its own policy) open its WebSocket.
        for path in ("/app/login", "/static/js/live-link.js", "/static/js/axes.js"):
            assert await get(path) == (200, CSP, "nosniff"), path
        assert "connect-src 'self' ws: wss:" in CSP
        assert await get("/vendor/uPlot.min.css") == (200, CSP, "nosniff")
        # Data and everything else: nothing may run.
        for path, status in (("/api/v1/health", 200), ("/favicon.ico", 200), ("/nothing", 404)):
            assert await get(path) == (status, API_CSP, "nosniff"), path
