"""Answers for requests the routes cannot serve: invalid input, numbers past the store's
range, a full disk and a database that is away. Each is a 4xx, 503 or 507 with a sentence,
never a 500.

The validation answer keeps FastAPI's shape (``detail``: a list of ``type``, ``loc``,
``msg``, ``input``) for programs, but ``msg`` is a sentence a clinician understands, naming
the field as the form labels it (:mod:`sessions.sentences`), and ``loc`` goes down to the
field a model-wide check is about. It quotes at most ``EXCERPT`` characters of the input:
FastAPI's own handler echoes the whole of it, so one large invalid body would be serialised
again, on the event loop, to be sent back.
"""

from __future__ import annotations

import errno
import json
import logging
import math
import socket
import sqlite3
from typing import Any

from fastapi import Request, status
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from sqlalchemy.exc import DBAPIError

from sessions.sentences import FieldError, Loc, sentence

log = logging.getLogger("ankle.server")

EXCERPT = 100
"""Characters of an invalid input quoted back."""
ERRORS_MAX = 20
"""Validation errors listed; a body with more gets one closing entry that counts them."""
DISK_FULL = (
    "the server's disk is full: nothing of this request was stored; "
    "try again once an administrator has freed space"
)
DATABASE_AWAY = (
    "the database is unavailable (restarting, unreachable or busy): nothing of this request "
    "was done; try again in a few seconds"
)
OUTCOME_UNKNOWN = (
    "the database stopped answering while this request was being saved: it may have been "
    "saved; check before trying again (or send it again with the same Idempotency-Key)"
)
"""A failure once the commit was sent: the database may have stored it all (PostgreSQL
commits locally, then waits for a standby) or nothing, and only it knows which."""
AWAY_CODE = "database_away"
UNKNOWN_CODE = "outcome_unknown"
"""The ``code`` of the two 503s, for programs: ``database_away`` may be sent again as it
is; ``outcome_unknown`` only with the ``Idempotency-Key`` it was sent with, or after
checking what was stored."""
RETRY_AFTER_S = 5
"""What a 503 for a database that is away tells a client to wait, seconds."""
_SQLITE_AWAY = {sqlite3.SQLITE_BUSY, sqlite3.SQLITE_LOCKED, sqlite3.SQLITE_CANTOPEN}
# SQLSTATEs of a database that is not there or busy: class 08 connection exception, 57P
# operator intervention (shutting down, crashed, still starting up), 55P03 a lock held past
# the lock timeout and 57014 a statement cancelled (by the driver, past its wait:
# server.db.DATABASE_WAIT_S), SQLite's busy timeout on PostgreSQL.
_SQLSTATE_AWAY = ("08", "57P", "55P03", "57014")


class _Full(Exception):
    pass


def _scalar(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)  # strict JSON has no NaN: rendering one would be a 500
    if isinstance(value, str):
        # backslashreplace: a lone surrogate quoted back must not make the answer unencodable
        text = value[:EXCERPT].encode("utf-8", "backslashreplace").decode("utf-8")
        return text + ("…" if len(value) > EXCERPT else "")
    if value is None or isinstance(value, bool | int | float):
        return value
    if isinstance(value, bytes | bytearray):  # a body FastAPI did not parse: cut, then decode
        text = bytes(value[:EXCERPT]).decode("utf-8", "backslashreplace")
        return text + ("…" if len(value) > EXCERPT else "")
    return str(value)[:EXCERPT]


def _bounded(value: Any, budget: int) -> str:
    """JSON-like text of ``value``, cut after ``budget`` characters without walking the
    rest of it."""
    out: list[str] = []
    used = 0

    def emit(text: str) -> None:
        nonlocal used
        out.append(text)
        used += len(text)
        if used > budget:
            raise _Full

    def walk(v: Any) -> None:
        if isinstance(v, dict):
            emit("{")
            for i, (k, x) in enumerate(v.items()):
                emit(", " if i else "")
                emit(json.dumps(_scalar(str(k))) + ": ")
                walk(x)
            emit("}")
        elif isinstance(v, list | tuple):
            emit("[")
            for i, x in enumerate(v):
                emit(", " if i else "")
                walk(x)
            emit("]")
        else:
            emit(json.dumps(_scalar(v)))

    try:
        walk(value)
    except _Full:
        return "".join(out)[:budget] + "…"
    return "".join(out)


def excerpt(value: Any) -> Any:
    """``value`` as it can be quoted back: scalars as they are (long text cut), a small
    object or list as it is, a large one as the first ``EXCERPT`` characters of its JSON."""
    if not isinstance(value, dict | list | tuple):
        return _scalar(value)
    text = _bounded(value, EXCERPT)
    if text.endswith("…"):
        return text
    return json.loads(text)


_ABSENT = object()


def _at(value: Any, loc: Loc) -> Any:
    """What ``loc`` names inside ``value`` (a parsed JSON body), or ``_ABSENT``."""
    for part in loc:
        if isinstance(value, dict) and isinstance(part, str) and part in value:
            value = value[part]
            continue
        if not (isinstance(value, list) and isinstance(part, int)):
            return _ABSENT
        if not -len(value) <= part < len(value):
            return _ABSENT
        value = value[part]
    return value


def _error(e: Any, model: type[BaseModel] | None, body: Any) -> dict[str, Any]:
    """One entry of a 422. A refusal a model-wide check made about one of its fields (a
    ``FieldError``: the damping below the stable least, say) is reported as that field's:
    its location, its value as ``input`` (not the whole model's, which pydantic gives), and
    its sentence whole in ``ctx.error``, bound included (ours, and short)."""
    loc, msg = sentence(e, model, body)
    out: dict[str, Any] = {"type": e.get("type"), "loc": list(loc), "msg": msg}
    ctx = e.get("ctx")
    cause = ctx.get("error") if isinstance(ctx, dict) else None
    if "input" in e:
        value = _at(e["input"], cause.loc) if isinstance(cause, FieldError) else e["input"]
        if value is not _ABSENT:  # absent: the field took its default
            out["input"] = excerpt(value)
    if isinstance(ctx, dict):
        out["ctx"] = {
            str(k): str(v) if isinstance(v, FieldError) else _scalar(v) for k, v in ctx.items()
        }
    return out


def _body_model(request: Request) -> type[BaseModel] | None:
    """The model the route reads its body into, whose field titles label the errors."""
    dependant = getattr(request.scope.get("route"), "dependant", None)
    params = getattr(dependant, "body_params", None) or []
    if len(params) != 1:
        return None
    annotation = params[0].field_info.annotation
    return (
        annotation if isinstance(annotation, type) and issubclass(annotation, BaseModel) else None
    )


async def validation_error(request: Request, exc: Exception) -> JSONResponse:
    """FastAPI's 422 in a clinician's words, with a short excerpt of each invalid input
    instead of all of it."""
    assert isinstance(exc, RequestValidationError)
    errors = list(exc.errors())
    model = _body_model(request)
    detail = [_error(e, model, exc.body) for e in errors[:ERRORS_MAX]]
    if len(errors) > ERRORS_MAX:
        detail.append(
            {
                "type": "too_many_errors",
                "loc": ["body"],
                "msg": f"and {len(errors) - ERRORS_MAX} more invalid values",
            }
        )
    return JSONResponse({"detail": detail}, status_code=status.HTTP_422_UNPROCESSABLE_CONTENT)


async def overflow_error(request: Request, exc: Exception) -> JSONResponse:
    """An id or offset beyond what the database stores (2**63-1) cannot name anything: a
    422 in FastAPI's own shape, not a 500 from the driver."""
    detail = [
        {
            "loc": ["request"],
            "msg": "a number in the request is beyond 2**63-1, the largest the server stores",
            "type": "overflow",
        }
    ]
    return JSONResponse({"detail": detail}, status_code=status.HTTP_422_UNPROCESSABLE_CONTENT)


def _disk_full() -> JSONResponse:
    return JSONResponse({"detail": DISK_FULL}, status_code=status.HTTP_507_INSUFFICIENT_STORAGE)


def database_unavailable(exc: BaseException) -> bool:
    """Whether ``exc`` says the database cannot be reached now (as opposed to refusing
    this statement): refused or dropped connections, a server shutting down or starting
    up, an SQLite file locked past its busy timeout or that cannot be opened. The one rule
    both the 503 handlers and ``/health`` ask."""
    if isinstance(exc, DBAPIError) and exc.connection_invalidated:
        return True
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, ConnectionError | TimeoutError | socket.gaierror):
            return True
        if str(getattr(e, "sqlstate", None) or "").startswith(_SQLSTATE_AWAY):
            return True
        if getattr(e, "sqlite_errorcode", None) in _SQLITE_AWAY:
            return True
        e = e.orig if isinstance(e, DBAPIError) else (e.__cause__ or e.__context__)
    return False


class CommitUnknown(Exception):
    """The database went away (:func:`database_unavailable`) once a request's commit was
    sent: raised by ``server.deps.get_db`` in place of the driver's error."""


def _database_away(request: Request, exc: BaseException) -> JSONResponse:
    said = str(exc).strip() or f"{type(exc).__name__} (it did not answer in time)"
    log.warning("database unavailable while serving %s: %s", request.url.path, said)
    return JSONResponse(
        {"detail": DATABASE_AWAY, "code": AWAY_CODE},
        status_code=status.HTTP_503_SERVICE_UNAVAILABLE,
        headers={"Retry-After": str(RETRY_AFTER_S)},
    )


async def commit_unknown(request: Request, exc: Exception) -> JSONResponse:
    """503 without ``Retry-After``: sending the request again as it is might store it
    twice."""
    log.warning(
        "database unavailable once the commit was sent, serving %s: %s",
        request.url.path,
        exc.__cause__,
    )
    return JSONResponse(
        {"detail": OUTCOME_UNKNOWN, "code": UNKNOWN_CODE},
        status_code=status.HTTP_503_SERVICE_UNAVAILABLE,
    )


async def os_error(request: Request, exc: Exception) -> JSONResponse:
    """A write that found no space (or quota) left is the server's state, not a bug: 507.
    A connection to the database refused or lost: 503. Any other OSError is a fault and
    goes on to the 500 handler."""
    assert isinstance(exc, OSError)
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        log.error("disk full while serving %s: %s", request.url.path, exc)
        return _disk_full()
    if database_unavailable(exc):
        return _database_away(request, exc)
    raise exc


async def database_error(request: Request, exc: Exception) -> JSONResponse:
    """SQLite says SQLITE_FULL when the disk is full (507); a database that is away is a
    503 with ``Retry-After``. The transaction is rolled back either way."""
    assert isinstance(exc, DBAPIError)
    causes = [exc.orig, getattr(exc.orig, "__cause__", None)]  # the async driver wraps it
    if any(
        getattr(c, "sqlite_errorcode", None) == sqlite3.SQLITE_FULL for c in causes
    ) or "database or disk is full" in str(exc):
        log.error("database full while serving %s", request.url.path)
        return _disk_full()
    if database_unavailable(exc):
        return _database_away(request, exc)
    raise exc
