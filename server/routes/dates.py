"""The days and times a query may name (``since``, ``until``), and how a query is refused.

One range for every route that takes a period (the session list, the progress page, the
report and the FHIR bundle), one check (:func:`utc_time`) and one shape of refusal. The
range holds any day a record can hold, with room to count the day after the last (a
period's end is the next midnight), so no date a client sends reaches an overflow.
"""

from __future__ import annotations

import re
from datetime import UTC, date, datetime, time, timedelta

from fastapi import HTTPException

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


def day_or_time(name: str, text: str | None, *, end_of_day: bool = False) -> datetime | None:
    """A query's date (exactly YYYY-MM-DD, :func:`iso_day`; midnight UTC, with
    ``end_of_day`` the next midnight, so the day is included) or ISO 8601 time on such a
    day (UTC if it names no offset), checked by :func:`utc_time`; a 422 that names the
    parameter and the range for anything else."""
    if text is None or text == "":
        return None
    day = iso_day(text)
    if day is not None:
        midnight = utc_time(name, datetime.combine(day, time()), text)
        return midnight + timedelta(days=1) if end_of_day else midnight
    if _DAY.fullmatch(text) is None:  # a time's day is written YYYY-MM-DD too
        raise _outside(name, text)
    try:
        when = datetime.fromisoformat(text)
    except ValueError:
        raise _outside(name, text) from None
    return utc_time(name, when, text)
