"""Security headers on every HTTP answer: API, downloads, pages, errors.

A page or route that needs a looser Content-Security-Policy (the dashboard's pages, the API
docs) sets its own; everything else gets the strictest one, since JSON and file downloads
never run anything in a browser. ``nosniff`` stops a browser from running a download (a
CSV, a recording) that happens to look like HTML or script.
"""

from __future__ import annotations

import re

from fastapi.routing import iter_route_contexts
from starlette.routing import compile_path
from starlette.types import ASGIApp, Message, Receive, Scope, Send

API_CSP = "default-src 'none'; frame-ancestors 'none'; base-uri 'none'; form-action 'none'; sandbox"
"""For answers that are data: nothing may load, run or frame them."""


class SecurityHeaders:
    def __init__(self, app: ASGIApp, csp: str = API_CSP) -> None:
        self.app = app
        self.csp = csp.encode()

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                names = {name.lower() for name, _ in headers}
                if b"x-content-type-options" not in names:
                    headers.append((b"x-content-type-options", b"nosniff"))
                if b"content-security-policy" not in names:
                    headers.append((b"content-security-policy", self.csp))
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, with_headers)


class AllowedMethods:
    """A 405's ``Allow`` lists every method the path is served with.

    The router answers 405 from the first route whose path matched, so ``Allow`` named
    that route's methods only: ``GET`` on ``/patients/{id}``, which PATCH changes, and no
    POST on ``/patients``. The app's route table is read once, on the first 405."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app
        self._paths: list[tuple[re.Pattern[str], frozenset[str]]] | None = None

    def _table(self, scope: Scope) -> list[tuple[re.Pattern[str], frozenset[str]]]:
        if self._paths is None:
            paths: dict[str, set[str]] = {}
            for context in iter_route_contexts(scope["app"].routes):
                if context.path and context.methods:
                    paths.setdefault(context.path, set()).update(context.methods)
            self._paths = [(compile_path(p)[0], frozenset(m)) for p, m in paths.items()]
        return self._paths

    def allowed(self, scope: Scope) -> str:
        path, root = scope["path"], scope.get("root_path", "")
        if root and path.startswith(root):  # as the router reads it
            path = path[len(root) :]
        methods: set[str] = set()
        for regex, served in self._table(scope):
            if regex.match(path):
                methods |= served
        return ", ".join(sorted(methods))

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def with_allow(message: Message) -> None:
            if message["type"] == "http.response.start" and message["status"] == 405:
                allowed = self.allowed(scope)
                if allowed:
                    headers = [
                        (k, v) for k, v in message.get("headers", []) if k.lower() != b"allow"
                    ]
                    headers.append((b"allow", allowed.encode()))
                    message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, with_allow)
