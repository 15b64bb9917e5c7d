"""``Idempotency-Key``: a create that is safe to send again.

A create whose answer never came (a timeout, a dropped connection, a 503 saying the outcome
is unknown) may or may not have been stored; sent again, it would make a second patient or
prescription. A client that sends ``Idempotency-Key: <key>`` with it, and the same key with
the same request when it tries again, is answered the first answer instead, and nothing
more is made.

The key's row (:class:`server.models.IdempotencyKey`: the user, the key, the request's
SHA-256 and what a repeat is answered) is written in the create's own transaction, just
before its commit: it is stored if and only if the record is, so no crash between the two
can leave a key that claims a record that is not there, nor one stuck "in progress". The
key is the row's primary key with its user, so two requests with one key at the same moment
cannot both commit: the second waits on the first's row (PostgreSQL: the unique index;
SQLite: its one writer), finds it stored, rolls back what it made and is answered the first
answer. Keys are the caller's own (another user's same key is another key) and last
``TTL``; the same key with another request is a 422, never the other request's answer.

Answers that hold a secret shown only once (a station's token, a one-time password) are not
kept: the server keeps no such secret. A repeat of such a create is a 409 naming the record
the first request made and what to do if its secret was lost.

The middleware packages for FastAPI keep the answer in a store of their own, written after
the route's commit: a crash between the two is a record without its key (made again on a
retry), and they would keep the secrets above. Hence these few lines, in the route's
transaction.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from datetime import timedelta
from typing import Annotated

from fastapi import Depends, Header, Request, status
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from sqlalchemy import delete, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.ext.asyncio import AsyncSession

from server.deps import Db
from server.models import IdempotencyKey, User, utcnow

HEADER = "Idempotency-Key"
REPLAYED = "Idempotent-Replayed"
"""The header on an answer given again from a key's row (``true``)."""
KEY_MAX = 128
TTL = timedelta(hours=24)
"""How long a key's answer is kept and given again."""
_KEY = re.compile(rf"[\x21-\x7e]{{1,{KEY_MAX}}}")
KEY_RULE = (
    f"the {HEADER} header must be 1 to {KEY_MAX} printable ASCII characters (letters, digits "
    "and punctuation, no spaces): a fresh random one, such as a UUID, for each new request"
)
OTHER_REQUEST = (
    f"this {HEADER} was used for a different request in the last 24 hours: send a new key "
    "with a new request, and the same key only with the same request sent again"
)


class Replay(Exception):
    """A repeat of a request already done: ``response`` is what it is answered."""

    def __init__(self, response: JSONResponse) -> None:
        super().__init__("a repeated request")
        self.response = response


async def replayed(_request: Request, exc: Exception) -> JSONResponse:
    """The exception handler answering a :class:`Replay`."""
    assert isinstance(exc, Replay)
    return exc.response


def _digest(request: Request, body: BaseModel, secrets: tuple[str, ...]) -> str:
    """The request's SHA-256; of each field in ``secrets`` (a password), only whether it was
    given: a fast hash of a password kept in the database would let it be guessed."""
    fields = body.model_dump(mode="json")
    for name in secrets:
        fields[name] = fields.get(name) is not None
    text = json.dumps(
        [request.method, request.url.path, fields],
        sort_keys=True,
        ensure_ascii=True,
    )
    return hashlib.sha256(text.encode()).hexdigest()


@dataclass
class Once:
    """A create's key (None: sent without one, and nothing here does anything). A route
    calls :meth:`check` before it makes anything and :meth:`keep` just before it commits;
    either raises :class:`Replay` for a request already done."""

    db: AsyncSession
    request: Request
    key: str | None
    _user_id: int = 0
    _sha256: str = ""

    async def check(self, user: User, body: BaseModel, secrets: tuple[str, ...] = ()) -> None:
        """Raise :class:`Replay` if ``user`` sent this key within ``TTL`` (its answer, or a
        422 for another request with it). ``secrets``: fields of ``body`` not to hash."""
        if self.key is None:
            return
        self._user_id, self._sha256 = user.id, _digest(self.request, body, secrets)
        found = await self._found()
        if found is not None:
            raise Replay(self._answer(found))

    async def keep(self, answer: BaseModel, secret: str | None = None, if_lost: str = "") -> None:
        """Store in the transaction what a repeat is answered: ``answer`` with 201, or, if
        it holds ``secret`` (a field shown once), a 409 naming the record and ``if_lost``.
        Raises :class:`Replay` when a request with the same key was stored meanwhile (this
        one's changes are rolled back)."""
        if self.key is None:
            return
        body = answer.model_dump(mode="json")
        code = status.HTTP_201_CREATED
        if secret is not None and body.get(secret) is not None:
            code = status.HTTP_409_CONFLICT
            body = {
                "detail": f"this request was done already (id {body.get('id')}) by an "
                f"earlier one with the same {HEADER}; its {secret.replace('_', ' ')} was "
                f"shown only in that answer and is not kept: {if_lost}"
            }
        cutoff = utcnow() - TTL
        await self.db.execute(
            delete(IdempotencyKey).where(
                IdempotencyKey.user_id == self._user_id, IdempotencyKey.created_at < cutoff
            )
        )
        self.db.add(
            IdempotencyKey(
                user_id=self._user_id,
                key=self.key,
                request_sha256=self._sha256,
                status=code,
                answer=body,
            )
        )
        try:
            await self.db.flush()
        except IntegrityError:
            await self.db.rollback()
            found = await self._found()
            if found is None:
                raise
            raise Replay(self._answer(found)) from None

    async def _found(self) -> IdempotencyKey | None:
        row: IdempotencyKey | None = (
            await self.db.execute(
                select(IdempotencyKey).where(
                    IdempotencyKey.user_id == self._user_id,
                    IdempotencyKey.key == self.key,
                    IdempotencyKey.created_at >= utcnow() - TTL,
                )
            )
        ).scalar_one_or_none()
        return row

    def _answer(self, row: IdempotencyKey) -> JSONResponse:
        if row.request_sha256 != self._sha256:
            # The shape of every other 422 (the documented one), on the header.
            raise RequestValidationError(
                [{"type": "value_error", "loc": ("header", HEADER), "msg": OTHER_REQUEST}]
            )
        return JSONResponse(row.answer, status_code=row.status, headers={REPLAYED: "true"})


async def once(
    request: Request,
    db: Db,
    key: Annotated[
        str | None,
        Header(
            alias=HEADER,
            description="Makes the create safe to send again: the same request with the same "
            f"key within 24 hours is answered the first answer (with `{REPLAYED}: true`) "
            "and makes nothing; the same key with another request is a 422. "
            f"1 to {KEY_MAX} printable ASCII characters; a fresh random one (a UUID) per new "
            "request.",
        ),
    ] = None,
) -> Once:
    if key is not None and _KEY.fullmatch(key) is None:
        raise RequestValidationError(
            [{"type": "value_error", "loc": ("header", HEADER), "msg": KEY_RULE, "input": key}]
        )
    return Once(db, request, key)


Idempotent = Annotated[Once, Depends(once)]
