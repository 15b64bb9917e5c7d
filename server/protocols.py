"""The protocols the server runs uvicorn with: uvicorn's own (websockets' sans-I/O, the one
it picks here), with a gap closed.

- A WebSocket text frame that is not UTF-8. uvicorn closes the link with 1007, as the
  protocol says, but logs it as a server failure: an ERROR and a traceback for each. Here
  it is one line, and the close says why.

:func:`protocols` gives uvicorn.Config's ``ws`` for a server's settings.
"""

from __future__ import annotations

import logging
from typing import Any

from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol

from server.config import Settings
from sessions import wire

log = logging.getLogger("ankle.server")


def _peer(client: tuple[str, int] | None) -> str:
    return f"{client[0]}:{client[1]}" if client else "a client"


class Utf8WebSocketProtocol(WebSocketsSansIOProtocol):
    """uvicorn's WebSocket protocol, closing on a text message that is not UTF-8 with one
    log line and a reason."""

    def send_receive_event_to_app(self) -> None:
        if self.curr_msg_data_type == "text" and not self.close_sent:
            try:
                b"".join(self.frames).decode()
            except UnicodeDecodeError as exc:
                self.frames = []
                log.warning(
                    "closed the WebSocket of %s (%d): a text message is not UTF-8 (byte %d)",
                    _peer(self.client),
                    wire.CLOSE_MALFORMED,
                    exc.start,
                )
                self.conn.send_close(wire.CLOSE_MALFORMED, "text messages must be UTF-8")
                self.handle_parser_exception()  # tells the app, sends the close, ends
                return
        super().send_receive_event_to_app()


def protocols(settings: Settings) -> dict[str, Any]:
    """uvicorn.Config's ``ws`` for ``settings``."""
    return {"ws": Utf8WebSocketProtocol}
