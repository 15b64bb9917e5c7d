"""Request bodies are checked at the door: size first, then, for JSON, that it is text.

A pure ASGI middleware, outside every route, so nothing in FastAPI or pydantic ever holds
more than a route's limit:

- A ``Content-Length`` above the limit is answered 413 at once, before one byte of the body
  is read. A chunked body is counted as it arrives and refused the moment it passes the
  limit, whatever the route was doing with it.
- A JSON body (or one with no content type) is read whole, at most the limit, and
  parsed. A string in it holding a lone UTF-16 surrogate
  (``"\\ud800"``, legal JSON but no Unicode text) is refused with 422 naming the field. Left
  in, such a string is stored by one layer and cannot be encoded by the next: a 500 after
  a change. A body that does not parse, whatever stopped it (a syntax error, bytes that are
  not UTF-8, arrays nested past Python's recursion limit, an integer of more digits than
  Python reads, 4300), is refused with one 422, "The request is not valid JSON.", naming
  why in ``ctx.error`` (FastAPI answered the last three with a bare 400 of its own), when
  its content type says JSON; FastAPI reads a body with none as bytes, not JSON
  (:func:`body_error`).

What the server sends while refusing is small and fixed; the rest of a refused body is
read and dropped by uvicorn so that the client sees the answer. A client that leaves before
its body is whole gets nothing, as there is no one to answer, and nothing is logged as an
error: a route reads its whole body before it changes anything.
"""

from __future__ import annotations

import contextlib
import json
import re
import sys
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from starlette.requests import ClientDisconnect
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from sessions.sentences import JSON_INVALID

_SURROGATE_ESCAPE = re.compile(rb"\\u[dD][89a-fA-F]")
"""The only way a lone surrogate gets into JSON text that is valid UTF-8."""
_JSON_TYPES = re.compile(r"^application/([\w.+-]*\+)?json\b", re.IGNORECASE)


class BodyTooLarge(Exception):
    """Raised inside the app's ``receive`` when a streamed body passes its limit."""


def _mib(n: int) -> str:
    return f"{n / (1024 * 1024):g} MiB" if n >= 1024 * 1024 else f"{n} bytes"


def too_large_text(limit: int) -> str:
    return (
        f"the request body is larger than {_mib(limit)} ({limit} bytes), "
        "the most this route accepts"
    )


async def answer(
    send: Send, status: int, body: dict[str, Any], headers: Sequence[tuple[bytes, bytes]] = ()
) -> None:
    """A whole JSON answer from a middleware, before (or instead of) any route."""
    payload = json.dumps(body).encode()  # ensure_ascii: always encodable, whatever it quotes
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(payload)).encode()),
                *headers,
            ],
        }
    )
    await send({"type": "http.response.body", "body": payload})


def _strings(value: Any, loc: tuple[str | int, ...]) -> Iterator[tuple[tuple[str | int, ...], str]]:
    """Every string of a parsed JSON document (keys too) with where it is."""
    stack: list[tuple[Any, tuple[str | int, ...]]] = [(value, loc)]
    while stack:
        v, at = stack.pop()
        if isinstance(v, str):
            yield at, v
        elif isinstance(v, dict):
            for k, x in v.items():
                yield at, k
                stack.append((x, (*at, k)))
        elif isinstance(v, list):
            stack.extend((x, (*at, i)) for i, x in enumerate(v))


def lone_surrogate(body: bytes, doc: Any) -> dict[str, Any] | None:
    """A FastAPI-shaped validation error for the first string with a lone surrogate in
    ``doc`` (``body`` parsed), or None. Bodies without a surrogate escape (nearly all) are
    passed over by one scan."""
    if not _SURROGATE_ESCAPE.search(body):
        return None
    for loc, text in _strings(doc, ("body",)):
        try:
            text.encode("utf-8")
        except UnicodeEncodeError as exc:
            bad = text[exc.start]
            return {
                "type": "string_unicode",
                "loc": [str(p) if isinstance(p, str) else p for p in loc],
                "msg": f"the text holds a lone surrogate \\u{ord(bad):04x} at character "
                f"{exc.start}: only whole Unicode characters are accepted",
            }
    return None


def parsed(body: bytes) -> tuple[Any, dict[str, Any] | None]:
    """``body`` parsed as FastAPI parses it (``json.loads``), or, for a body that does not
    parse, a FastAPI-shaped ``json_invalid`` error saying why, with where when known."""
    at: list[str | int] = ["body"]
    try:
        return json.loads(body), None
    except json.JSONDecodeError as exc:
        at.append(exc.pos)
        why = exc.msg
    except UnicodeDecodeError as exc:
        at.append(exc.start)
        why = f"it is not {exc.encoding} text (byte {exc.start})"
    except RecursionError:
        why = "its arrays or objects are nested too deeply"
    except ValueError:  # json's int() of a number past sys.get_int_max_str_digits()
        why = f"a number in it has more than {sys.get_int_max_str_digits()} digits"
    return None, {"type": "json_invalid", "loc": at, "msg": JSON_INVALID, "ctx": {"error": why}}


def body_error(body: bytes, typed: bool) -> dict[str, Any] | None:
    """The 422 entry for a JSON body (``typed``: its content type says JSON), or one with no
    content type, or None to let it through. A typed body is parsed, as FastAPI parses it
    for the route: one that does not parse gets :func:`parsed`'s error, whatever the route
    (the client said it was JSON). FastAPI reads an untyped body as bytes, never as JSON
    (its ``strict_content_type``): it is refused only for a lone surrogate, and parsed only
    if it holds a surrogate escape (an upload's chunk sent untyped is never refused)."""
    if not body or (not typed and not _SURROGATE_ESCAPE.search(body)):
        return None  # FastAPI parses no empty body: its model says what is missing
    doc, error = parsed(body)
    if error is not None:
        return error if typed else None
    return lone_surrogate(body, doc)


class RequestGuard:
    """Body limits and the JSON text check, for every HTTP request (WebSockets have their
    own message limit).

    ``limit_for(method, path)`` names a route's limit; everything else gets ``default``.
    """

    def __init__(
        self,
        app: ASGIApp,
        default: int,
        limit_for: Callable[[str, str], int | None] = lambda method, path: None,
    ) -> None:
        self.app = app
        self.default = default
        self.limit_for = limit_for

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = self.limit_for(scope["method"], scope["path"]) or self.default
        length: int | None = None
        chunked = False
        content_type = ""
        for name, value in scope["headers"]:
            if name == b"content-length":
                length = int(value) if value.isdigit() else None  # the HTTP parser checked it
            elif name == b"transfer-encoding":
                chunked = True
            elif name == b"content-type":
                content_type = value.decode("latin-1")
        if length is not None and length > limit:
            await answer(send, 413, {"detail": too_large_text(limit)})
            return
        if not (chunked or length):
            await self.app(scope, receive, send)
            return
        if not content_type or _JSON_TYPES.match(content_type):
            await self._json(scope, receive, send, limit, typed=bool(content_type))
        else:
            await self._stream(scope, receive, send, limit)

    async def _json(
        self, scope: Scope, receive: Receive, send: Send, limit: int, typed: bool
    ) -> None:
        parts: list[bytes] = []
        size = 0
        while True:
            message = await receive()
            if message["type"] != "http.request":  # the client left: nothing to answer
                return
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > limit:
                await answer(send, 413, {"detail": too_large_text(limit)})
                return
            parts.append(chunk)
            if not message.get("more_body", False):
                break
        body = b"".join(parts)
        error = body_error(body, typed)
        if error is not None:
            await answer(send, 422, {"detail": [error]})
            return
        replayed = False

        async def replay() -> Message:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()  # a disconnect, for streaming responses

        await self.app(scope, replay, send)

    async def _stream(self, scope: Scope, receive: Receive, send: Send, limit: int) -> None:
        size = 0
        over = False
        started = False
        left = False

        async def counted() -> Message:
            nonlocal size, over, left
            message = await receive()
            if message["type"] == "http.request":
                size += len(message.get("body", b""))
                if size > limit:
                    over = True
                    raise BodyTooLarge(too_large_text(limit))
            elif message["type"] == "http.disconnect":
                left = True
            return message

        async def watched(message: Message) -> None:
            nonlocal started
            if over and not started:
                return  # whatever the app made of the exception, the answer is our 413
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            with contextlib.suppress(BodyTooLarge):  # raised by counted(), answered here
                await self.app(scope, counted, watched)
        except ClientDisconnect:
            if not left:
                raise
            # The client left before its body was whole (a station stopped mid-chunk): the
            # route read no body, so it did nothing, and there is no one to answer. Let out,
            # the exception was logged as an error of the application, with its traceback.
            return
        if over and not started:
            await answer(send, 413, {"detail": too_large_text(limit)})
