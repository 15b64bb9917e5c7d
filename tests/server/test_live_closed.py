"""A send on a live link the server has already closed ends the handler as a disconnect.

A station revoked just after its Welcome had its link closed by the re-check while its
handler went on to send its prescriptions: Starlette refuses a send after the close with a
``RuntimeError`` (``WebSocketDisconnected``), which no handler caught, and uvicorn logged
"Exception in ASGI application" with a traceback. The ASGI server is the boundary here: a
real Starlette ``WebSocket`` over a receive and a send that stand for it.
"""

from __future__ import annotations

import ast
import inspect
from collections.abc import MutableMapping
from typing import Any

import pytest
from starlette.websockets import WebSocket, WebSocketDisconnect

from server import hub, live


async def _closed_link() -> tuple[WebSocket, list[MutableMapping[str, Any]]]:
    sent: list[MutableMapping[str, Any]] = []

    async def receive() -> dict[str, Any]:
        return {"type": "websocket.connect"}

    async def send(message: MutableMapping[str, Any]) -> None:
        sent.append(message)

    ws = WebSocket({"type": "websocket", "path": "/ws/station", "headers": []}, receive, send)
    await ws.accept()
    await hub.close_link(ws, 4003, "revoked")  # what a re-check does to a revoked station
    return ws, sent


@pytest.mark.asyncio
async def test_a_send_after_the_server_closed_the_link_is_a_disconnect() -> None:
    ws, sent = await _closed_link()
    with pytest.raises(WebSocketDisconnect):
        await hub.send_text(ws, '{"type": "prescriptions", "items": []}')
    assert [m["type"] for m in sent] == ["websocket.accept", "websocket.close"]


def test_the_live_handlers_send_only_through_the_one_helper() -> None:
    """Every send of the station's and the viewer's handlers (and the hub's) goes through
    ``hub.send_text``: a send of their own would raise on a closed link again."""
    lines, first = inspect.getsourcelines(hub.send_text)
    helper = range(first, first + len(lines))
    own = []
    for module in (live, hub):
        for node in ast.walk(ast.parse(inspect.getsource(module))):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Attribute)
                and node.func.attr in ("send_text", "send_json", "send_bytes")
                and not (module is hub and node.lineno in helper)
            ):
                own.append((module.__name__, node.lineno, ast.unparse(node.func)))
    assert own == []
