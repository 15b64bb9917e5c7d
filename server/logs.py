"""The server's log lines: plain text (the default, for ``make run``) or one JSON object a line.

``ANKLE_LOG_FORMAT=json`` gives each line as a JSON object (python-json-logger's formatter:
a kept library that serialises exceptions, stack traces and ``extra=`` fields, which a
home-made formatter would have to get right one by one) with ``time``, ``level``, ``logger``,
``message``, and ``request_id`` on every line logged while an HTTP request is handled
(uvicorn's access line included), ``link_id`` on every line of a live WebSocket link.

The ids come from :class:`RequestIds`, an ASGI middleware: a request's id is its
``X-Request-ID`` header when it sends a sane one (the proxy's, so both logs share it),
otherwise a new one, and is sent back in the answer's ``X-Request-ID``.
"""

from __future__ import annotations

import contextvars
import logging
import re
import uuid
from typing import Any, Literal

from starlette.types import ASGIApp, Message, Receive, Scope, Send
from uvicorn.config import LOGGING_CONFIG

LogFormat = Literal["text", "json"]

request_id: contextvars.ContextVar[str | None] = contextvars.ContextVar("request_id", default=None)
link_id: contextvars.ContextVar[str | None] = contextvars.ContextVar("link_id", default=None)

_SANE_ID = re.compile(r"^[A-Za-z0-9._-]{8,64}$")


class RequestIds:
    """Sets :data:`request_id` for each HTTP request and :data:`link_id` for each WebSocket."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "websocket":
            token = link_id.set(uuid.uuid4().hex[:16])
            try:
                await self.app(scope, receive, send)
            finally:
                link_id.reset(token)
            return
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        given = dict(scope["headers"]).get(b"x-request-id", b"").decode("latin-1")
        rid = given if _SANE_ID.match(given) else uuid.uuid4().hex

        async def send_id(message: Message) -> None:
            if message["type"] == "http.response.start":
                message["headers"] = [*message.get("headers", []), (b"x-request-id", rid.encode())]
            await send(message)

        token = request_id.set(rid)
        try:
            await self.app(scope, receive, send_id)
        finally:
            request_id.reset(token)


class _Ids(logging.Filter):
    """Puts the current request and link ids on every record (None outside them)."""

    def filter(self, record: logging.LogRecord) -> bool:
        record.request_id = request_id.get()
        record.link_id = link_id.get()
        return True


def uvicorn_log_config(fmt: LogFormat) -> dict[str, Any]:
    """``logging.config`` for uvicorn.Config's ``log_config``: ``text`` is uvicorn's own;
    ``json`` sends the root logger and uvicorn's through one JSON handler."""
    if fmt == "text":
        return LOGGING_CONFIG
    handler = {
        "class": "logging.StreamHandler",
        "formatter": "json",
        "filters": ["ids"],
        "stream": "ext://sys.stderr",
    }
    return {
        "version": 1,
        "disable_existing_loggers": False,
        "filters": {"ids": {"()": _Ids}},
        "formatters": {
            "json": {
                "()": "pythonjsonlogger.json.JsonFormatter",
                "fmt": "%(asctime)s %(levelname)s %(name)s %(message)s %(request_id)s %(link_id)s",
                "rename_fields": {"asctime": "time", "levelname": "level", "name": "logger"},
            }
        },
        "handlers": {"default": handler},
        "root": {"handlers": ["default"], "level": "INFO"},
        "loggers": {
            "uvicorn": {"handlers": [], "level": "INFO", "propagate": True},
            "uvicorn.error": {"handlers": [], "level": "INFO", "propagate": True},
            "uvicorn.access": {"handlers": [], "level": "INFO", "propagate": True},
        },
    }
