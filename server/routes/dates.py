"""The days and times a query may name (``since``, ``until``), the time zone whose days
they are (``tz``), and how a query is refused.

One range for every route that takes a period (the session list, the progress page, the
report and the FHIR bundle), one check (:func:`utc_time`), one reading of ``tz``
(:func:`zone`), one rule for when a day begins (:func:`midnight`) and one shape of refusal.
The range holds any day a record can hold, with room to count the day after the last (a
period's end is the next midnight), so no date a client sends reaches an overflow.

A day is the therapist's own: the dashboard sends the browser's zone, since a day of UTC
begins at 16:00 or 17:00 the evening before on the US Pacific coast and leaves out the last
evening of the period. Without ``tz`` a day is UTC's, as it always was.
"""

from __future__ import annotations

import re
from datetime import UTC, date, datetime, time, timedelta
from functools import cache
from typing import Annotated
from zoneinfo import ZoneInfo, available_timezones

from fastapi import HTTPException, Query

FIRST_DAY, LAST_DAY = date(1900, 1, 1), date(9998, 12, 31)
"""The days a query may name, both included."""


def refuse(field: str, sentence: str) -> HTTPException:
    """A 422 about one query parameter, in the shape of every other 422: a list of
    ``type``, ``loc`` and ``msg``."""
    return HTTPException(
        422, detail=[{"type": "value_error", "loc": ["query", field], "msg": sentence}]
    )


def shown(text: str) -> str:
    """A client's text as a refusal quotes it: at most 40 characters."""
    return text if len(text) <= 40 else text[:40] + "…"


def _outside(name: str, text: str) -> HTTPException:
    return refuse(
        name,
        f"{name} '{shown(text)}' is not a day or time the server takes: give a day as "
        f"YYYY-MM-DD or a time as ISO 8601 (2026-03-02T09:00:00Z), from {FIRST_DAY} to "
        f"{LAST_DAY}",
    )


def utc_time(name: str, when: datetime, text: str | None = None) -> datetime:
    """``when`` in UTC (one that names no offset is UTC already), on a day from
    ``FIRST_DAY`` to ``LAST_DAY``; else a 422 that names the parameter ``name`` and the
    range, quoting ``text`` (what the client wrote; by default ``when`` itself). The one
    check of every day and time a query names."""
    try:
        utc = when.replace(tzinfo=UTC) if when.tzinfo is None else when.astimezone(UTC)
    except OverflowError:  # an offset that moves it past year 1 or 9999
        raise _outside(name, text or when.isoformat()) from None
    if not FIRST_DAY <= utc.date() <= LAST_DAY:
        raise _outside(name, text or when.isoformat())
    return utc


_DAY = re.compile(r"([0-9]{4}-[0-9]{2}-[0-9]{2})([Tt ].*)?", re.DOTALL)


def iso_day(text: str) -> date | None:
    """The day ``text`` names if it is one written YYYY-MM-DD, else None. Python reads
    more as a date (``2025-W50``, ``20251207``, ``2025-341``), which every refusal and
    description here does not offer, and a client that sent them could not tell which day
    was meant."""
    if _DAY.fullmatch(text) is None or len(text) != 10:
        return None
    try:
        return date.fromisoformat(text)
    except ValueError:
        return None


TZ_EXAMPLE = "Europe/Berlin"
TZ_DOC = (
    "The IANA time zone whose calendar days since and until are (the dashboard sends the "
    f"browser's own). Default: UTC. Such as {TZ_EXAMPLE}, America/Los_Angeles or UTC."
)
Tz = Annotated[str | None, Query(description=TZ_DOC, examples=[TZ_EXAMPLE])]
"""The ``tz`` query parameter of a route whose days are a person's (read by :func:`zone`)."""


@cache
def _zone_names() -> frozenset[str]:
    """The IANA names the server knows (its system's tz database, else the tzdata package).
    The one test of a name: ``ZoneInfo`` alone also opens ``localtime`` (whatever the
    server's own clock is set to) and ``right/...`` files, and fails on a long name with an
    OSError rather than saying it knows no such zone."""
    return frozenset(available_timezones() - {"localtime"})


def zone(text: str | None) -> ZoneInfo:
    """The time zone ``tz`` names; UTC if none; a 422 naming ``tz`` for a name not known."""
    if text is None:
        return ZoneInfo("UTC")
    if text not in _zone_names():
        raise refuse(
            "tz",
            f"the time zone (tz) must be an IANA time zone name such as {TZ_EXAMPLE} or UTC; "
            f"got {shown(text)!r}",
        )
    return ZoneInfo(text)


def midnight(day: date, tz: ZoneInfo) -> datetime:
    """The instant ``day`` begins in ``tz``: its first wall-clock time, which zoneinfo
    places by that day's own offset (a day that changes to or from summer time is 23 or
    25 hours long; never a fixed offset). Where the clock jumps past midnight itself, the
    day begins at the jump."""
    return datetime.combine(day, time(), tzinfo=tz)


def day_or_time(
    name: str, text: str | None, *, end_of_day: bool = False, tz: ZoneInfo | None = None
) -> datetime | None:
    """A query's date (exactly YYYY-MM-DD, :func:`iso_day`; its :func:`midnight` in ``tz``,
    with ``end_of_day`` the next day's, so the day is included) or ISO 8601 time on such a
    day (a wall-clock time of ``tz`` if it names no offset), in UTC; without ``tz`` the
    days and clock are UTC's. A 422 that names the parameter and the range for anything
    else: a day (a time's, as written) outside the range, or a time whose offset moves it
    out (:func:`utc_time`)."""
    if text is None or text == "":
        return None
    day = iso_day(text)
    if day is not None:
        if not FIRST_DAY <= day <= LAST_DAY:
            raise _outside(name, text)
        begins = midnight(day + timedelta(days=1) if end_of_day else day, tz or ZoneInfo("UTC"))
        return begins.astimezone(UTC)
    if _DAY.fullmatch(text) is None:  # a time's day is written YYYY-MM-DD too
        raise _outside(name, text)
    try:
        when = datetime.fromisoformat(text)
    except ValueError:
        raise _outside(name, text) from None
    if when.tzinfo is None and tz is not None:
        # The zone's clock, on a day of the range: no offset of its moves it past year 9999.
        if not FIRST_DAY <= when.date() <= LAST_DAY:
            raise _outside(name, text)
        return when.replace(tzinfo=tz).astimezone(UTC)
    return utc_time(name, when, text)
