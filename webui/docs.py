"""The API's docs page, Swagger UI served from this server.

FastAPI's default page loads Swagger UI from a public CDN: a clinic's browser would fetch
code from a third party to look at an API that carries patients' data. Here its files come
from ``swagger-ui-dist`` (npm, installed with the dashboard's libraries) under ``/vendor/``,
and the page's one inline script is allowed by its hash, so the policy needs no
``'unsafe-inline'`` for scripts.
"""

from __future__ import annotations

import base64
import hashlib
import re

from fastapi import APIRouter
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse

from server.routes import API_PREFIX

router = APIRouter(include_in_schema=False)

_INLINE_SCRIPT = re.compile(rb"<script>(.*?)</script>", re.DOTALL)


def docs_page(title: str) -> HTMLResponse:
    page = get_swagger_ui_html(
        openapi_url=f"{API_PREFIX}/openapi.json",
        title=f"{title} - API docs",
        swagger_js_url="/vendor/swagger-ui-bundle.js",
        swagger_css_url="/vendor/swagger-ui.css",
        swagger_favicon_url="/favicon.ico",
    )
    hashes = " ".join(
        "'sha256-" + base64.b64encode(hashlib.sha256(m).digest()).decode() + "'"
        for m in _INLINE_SCRIPT.findall(bytes(page.body))
    )
    page.headers["Content-Security-Policy"] = (
        f"default-src 'self'; script-src 'self' {hashes}; style-src 'self' 'unsafe-inline'; "
        "img-src 'self' data:; connect-src 'self'; object-src 'none'; base-uri 'none'; "
        "form-action 'self'; frame-ancestors 'none'"
    )
    page.headers["Cache-Control"] = "no-cache"
    return page


@router.get(f"{API_PREFIX}/docs")
async def docs() -> HTMLResponse:
    return docs_page("Ankle telerehabilitation server")
