"""Tickets for a view: one user, one subject, short-lived unless in use, revocable."""

from __future__ import annotations

import asyncio

import pytest

from server.tickets import TICKET_BYTES, ViewTickets


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_a_ticket_is_random_and_ends_after_its_time() -> None:
    clock = Clock()
    tickets = ViewTickets(ttl_s=60.0, clock=clock)
    a = tickets.issue(1, ("station", 7))
    b = tickets.issue(1, ("station", 7))
    assert a.value != b.value
    assert len(a.value) >= TICKET_BYTES * 4 // 3  # 256 bits, URL-safe base64
    assert tickets.valid(a.value) is a
    assert tickets.valid("not-" + a.value) is None
    clock.now += 59.9
    assert tickets.valid(a.value) is a
    clock.now += 0.2
    assert tickets.valid(a.value) is None
    # Ended tickets are dropped as new ones are issued: memory does not grow with views.
    tickets.issue(2, ("station", 8))
    assert len(tickets) == 1


def test_a_ticket_in_use_lives_on_and_ends_a_ttl_after_its_last_use() -> None:
    clock = Clock()
    tickets = ViewTickets(ttl_s=60.0, clock=clock)
    t = tickets.issue(1, ("station", 7))
    with tickets.using(t):
        with tickets.using(t):
            clock.now += 3600.0
            assert tickets.valid(t.value) is t
        clock.now += 100.0
        assert tickets.valid(t.value) is t  # one connection still open
    clock.now += 59.0
    assert tickets.valid(t.value) is t  # a client reconnecting finds it
    clock.now += 2.0
    assert tickets.valid(t.value) is None


@pytest.mark.asyncio
async def test_revoking_ends_tickets_and_tells_their_connections() -> None:
    tickets = ViewTickets()
    mine = tickets.issue(1, ("station", 7))
    other = tickets.issue(1, ("station", 8))
    theirs = tickets.issue(2, ("station", 7))
    waiting = asyncio.create_task(mine.ended.wait())
    with tickets.using(mine):
        assert tickets.revoke_user(1) == 2
        await asyncio.wait_for(waiting, 5.0)
        assert tickets.valid(mine.value) is None  # in use, yet ended
    assert tickets.valid(other.value) is None
    assert tickets.valid(theirs.value) is theirs
    assert tickets.revoke_subject(("station", 7)) == 1
    assert tickets.valid(theirs.value) is None
    assert tickets.revoke_user(1) == 0
