"""Who may use the patient's page: only this computer (or the address the station was told to
listen on), and only the page itself.

The platform moves a person's foot, so only the page itself may drive it: the WebSocket
refuses (HTTP 403) any ``Origin`` but the page's own, and every request must name this
computer in ``Host`` (a page on another website cannot use DNS rebinding to look local).
"""

from __future__ import annotations

from collections.abc import Collection
from urllib.parse import urlsplit

LOOPBACK = frozenset({"localhost", "127.0.0.1", "::1"})
WILDCARD = frozenset({"", "0.0.0.0", "::"})


def allowed_hosts(host: str) -> frozenset[str]:
    """Names the page answers to: this computer's, and the address it listens on if that is
    a particular one (a station serving its page to a tablet on the home network)."""
    name = host.strip("[]").lower()
    return LOOPBACK if name in WILDCARD else LOOPBACK | {name}


def _hostname(netloc: str) -> str | None:
    try:
        parts = urlsplit("//" + netloc)
        _ = parts.port  # a port that is not a number raises
    except ValueError:
        return None
    return parts.hostname


def host_ok(host_header: str | None, hosts: Collection[str]) -> bool:
    return bool(host_header) and _hostname(host_header or "") in hosts


def origin_ok(origin: str | None, host_header: str | None, hosts: Collection[str]) -> bool:
    """The page's own origin only: the scheme and the ``Host`` it was loaded from."""
    if not origin or not host_ok(host_header, hosts):
        return False
    return origin.lower() == f"http://{(host_header or '').lower()}"
