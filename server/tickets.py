"""Short-lived tickets that open one view (today the live 3D view of one station) for one user.

A page framed in the dashboard cannot send the API's bearer token: a browser loads a frame and
its WebSocket by URL alone. So an authenticated route checks the user's access once and issues
a ticket, 256 random bits, that names the user and the one thing it shows; the frame's URL
carries the ticket. Tickets live in this process's memory; with a relay between server
processes the hub also shares each one (``Ticket.shared``), and a process asked for a ticket
it does not know adopts it from there (``ViewTickets.adopt``).

A ticket ends :data:`TICKET_TTL_S` after it was issued or last in use (a connection open on
it keeps it alive, so a view watched for an hour keeps working), or at once when revoked:
``revoke_user`` (the user's credentials changed or ended) and ``revoke_subject`` (the thing
shown is no longer theirs to see) also close every connection open on the user's tickets.
"""

from __future__ import annotations

import asyncio
import secrets
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

TICKET_TTL_S = 60.0
"""How long an unused ticket works, s: enough to load a frame, too short to be worth stealing."""
TICKET_BYTES = 32
"""256 random bits."""

Subject = tuple[str, int]
"""What a ticket shows: a kind and an id, e.g. ``("station", 7)``."""


@dataclass(eq=False)
class Ticket:
    value: str
    user_id: int
    subject: Subject
    """One thing per ticket."""
    expires_at: float
    """On the store's clock; ignored while ``in_use``."""
    login: str = ""
    """The sign-in (bearer token) it was issued to: the live links' re-checks end the ticket
    when that sign-in ends or may no longer see ``subject``."""
    in_use: int = 0
    ended: asyncio.Event = field(default_factory=asyncio.Event)
    """Set when the ticket is revoked: whoever holds a connection on it closes it."""

    def shared(self) -> dict[str, Any]:
        """What another process needs to adopt it."""
        return {"user_id": self.user_id, "subject": list(self.subject), "login": self.login}


class ViewTickets:
    """The tickets of one server process."""

    def __init__(
        self, ttl_s: float = TICKET_TTL_S, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.ttl_s = ttl_s
        self.clock = clock
        self._tickets: dict[str, Ticket] = {}

    def __len__(self) -> int:
        return len(self._tickets)

    def issue(self, user_id: int, subject: Subject, login: str = "") -> Ticket:
        self._purge()
        ticket = Ticket(
            secrets.token_urlsafe(TICKET_BYTES),
            user_id,
            subject,
            login=login,
            expires_at=self.clock() + self.ttl_s,
        )
        self._tickets[ticket.value] = ticket
        return ticket

    def adopt(self, value: str, shared: dict[str, Any]) -> Ticket:
        """A ticket another process issued (``Ticket.shared``), known here from now on."""
        kind, subject_id = shared["subject"]
        ticket = Ticket(
            value,
            int(shared["user_id"]),
            (str(kind), int(subject_id)),
            login=str(shared["login"]),
            expires_at=self.clock() + self.ttl_s,
        )
        self._tickets[value] = ticket
        return ticket

    def valid(self, value: str) -> Ticket | None:
        """The live ticket ``value`` names, or None (unknown, expired or revoked)."""
        ticket = self._tickets.get(value)
        return ticket if ticket is not None and self._live(ticket) else None

    @contextmanager
    def using(self, ticket: Ticket) -> Iterator[Ticket]:
        """Keeps ``ticket`` alive while the block runs (a connection open on it)."""
        ticket.in_use += 1
        try:
            yield ticket
        finally:
            ticket.in_use -= 1
            ticket.expires_at = max(ticket.expires_at, self.clock() + self.ttl_s)

    def revoke_user(self, user_id: int) -> int:
        """Ends every ticket of ``user_id`` and its connections; the count ended."""
        return self._revoke(lambda t: t.user_id == user_id)

    def live(self) -> list[Ticket]:
        """Every ticket that still works."""
        self._purge()
        return list(self._tickets.values())

    def revoke(self, ticket: Ticket) -> int:
        """Ends one ticket and its connections; 1, or 0 if it had ended already."""
        return self._revoke(lambda t: t is ticket)

    def revoke_subject(self, subject: Subject) -> int:
        """Ends every ticket showing ``subject`` and its connections; the count ended."""
        return self._revoke(lambda t: t.subject == subject)

    def _revoke(self, match: Callable[[Ticket], bool]) -> int:
        ended = [t for t in self._tickets.values() if match(t)]
        for ticket in ended:
            del self._tickets[ticket.value]
            ticket.ended.set()
        return len(ended)

    def _live(self, ticket: Ticket) -> bool:
        return not ticket.ended.is_set() and (ticket.in_use > 0 or self.clock() < ticket.expires_at)

    def _purge(self) -> None:
        for value in [v for v, t in self._tickets.items() if not self._live(t)]:
            del self._tickets[value]
