"""Request dependencies: the database session, who is calling, and what they may see.

Authorization is decided here and only here. Two rules shape it:

- A role that may never do something gets 403 before any id is looked at.
- A therapist asking for another therapist's patient (or anything of theirs) gets the same
  404 as for an id that does not exist: the API never confirms that someone else's record is
  there.

``authenticate_user`` and ``authenticate_station`` are plain functions so that WebSocket
handlers, which have no HTTP dependencies of this kind, check tokens the same way.
"""

from __future__ import annotations

import re
from collections.abc import AsyncIterator
from datetime import datetime, timedelta
from typing import Annotated, Literal, NamedTuple, Protocol, TypeVar

from annotated_types import Ge, Le
from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from pydantic import BeforeValidator
from pydantic_core import PydanticCustomError
from sqlalchemy import select, text
from sqlalchemy.exc import DBAPIError
from sqlalchemy.ext.asyncio import AsyncSession, async_sessionmaker

from server.db import COMMIT_SENT
from server.errors import CommitUnknown, database_unavailable
from server.models import ID_MAX, AuthToken, Patient, Station, User, utcnow
from server.security import same_secret, token_hash

# Writing last_seen_at on every request of a polling station would be a write per poll.
LAST_SEEN_RESOLUTION = timedelta(seconds=30)

_DIGITS = re.compile(r"-?[0-9]+")


def _whole_number(value: object) -> object:
    """A path or query id as written: digits only. Read as any integer, "1.0", "+1", " 1"
    and "1_0" named records 1 and 10 (``/users/1.0``, ``/ws/live/1.0``)."""
    if isinstance(value, str) and not _DIGITS.fullmatch(value):
        raise PydanticCustomError(
            "int_parsing", "Input should be a valid integer, unable to parse string as an integer"
        )
    return value


Id = Annotated[int, BeforeValidator(_whole_number), Ge(1), Le(ID_MAX)]
"""The type of every id a request names (path or query): anything but digits, or outside
1..2**63-1, names no record and is a 422 naming the parameter, before the database is asked
(where the driver would overflow). ``tests/server/test_ids.py`` checks every route uses
it."""

Offset = Annotated[int, Ge(0), Le(ID_MAX)]
"""The type of every page's offset: rows to skip, 0..2**63-1. Past it a 422 naming the
parameter, as an id's, where PostgreSQL's driver refused the 64-bit overflow (a 500) and
SQLite's the same number differently."""

_user_bearer = HTTPBearer(
    auto_error=False,
    scheme_name="UserToken",
    description="A therapist's or admin's token from POST /api/v1/auth/login.",
)
_station_bearer = HTTPBearer(
    auto_error=False,
    scheme_name="StationToken",
    description="A home station's token, given once when the station was provisioned.",
)


async def get_db(request: Request) -> AsyncIterator[AsyncSession]:
    """The request's session. The database going away after its commit was sent
    (``server.db.COMMIT_SENT``) is :class:`server.errors.CommitUnknown`, whatever the
    driver raised: only before that does its 503 say that nothing was done."""
    sessionmaker: async_sessionmaker[AsyncSession] = request.app.state.sessionmaker
    async with sessionmaker() as session:
        try:
            yield session
        except (DBAPIError, OSError) as exc:
            if session.info.get(COMMIT_SENT) and database_unavailable(exc):
                raise CommitUnknown(str(exc)) from exc
            raise


Db = Annotated[AsyncSession, Depends(get_db)]


def unauthorized(detail: str = "not authenticated") -> HTTPException:
    return HTTPException(
        status.HTTP_401_UNAUTHORIZED, detail=detail, headers={"WWW-Authenticate": "Bearer"}
    )


def forbidden(detail: str) -> HTTPException:
    return HTTPException(status.HTTP_403_FORBIDDEN, detail=detail)


def not_found(what: str) -> HTTPException:
    return HTTPException(status.HTTP_404_NOT_FOUND, detail=f"{what} not found")


LoginFailure = Literal["unknown", "expired", "inactive", "must_change"]
"""Why a token does not sign anyone in: no such login (never issued, logged out, or ended by
a password change or reset), past its expiry, its user deactivated, or its user holding a
printed or reset password they must change first (such a login may change that password,
ask who it is and log out: ``SignedInUser``, nothing else)."""

FOR_USERS = (
    "this route is for therapists and admins: a home station's token is valid, but cannot use it"
)
FOR_STATIONS = (
    "this route is for home stations: a therapist's or admin's token is valid, but cannot use it"
)
"""A valid token on a route for the other kind of caller: 403, since it is who is asking
that is refused, not the token (a 401 would say the token is invalid or expired)."""

MUST_CHANGE_PASSWORD = (
    "you must change your password before anything else: it was printed or reset, so "
    "someone else has seen it (POST /api/v1/auth/password)"
)


class LoginStanding(NamedTuple):
    user: User | None
    failure: LoginFailure | None
    """None when the token signs ``user`` in now."""
    expires_at: datetime | None


async def login_standing(db: AsyncSession, token: str) -> LoginStanding:
    """Who holds the login ``token``, until when, and, if it does not sign them in now, why.

    The one place a user's token is judged: HTTP requests (``current_user``,
    ``signed_in_user``), the live view's handshake and the live links' re-checks all ask
    here.
    """
    digest = token_hash(token)
    row = (
        await db.execute(
            select(AuthToken, User)
            .join(User, User.id == AuthToken.user_id)
            .where(AuthToken.token_hash == digest)
        )
    ).first()
    if row is None:
        return LoginStanding(None, "unknown", None)
    login, user = row
    if not same_secret(login.token_hash, digest):
        return LoginStanding(None, "unknown", None)
    if login.expires_at <= utcnow():
        return LoginStanding(user, "expired", login.expires_at)
    if not user.active:
        return LoginStanding(user, "inactive", login.expires_at)
    if user.must_change_password:
        return LoginStanding(user, "must_change", login.expires_at)
    return LoginStanding(user, None, login.expires_at)


async def authenticate_user(db: AsyncSession, token: str) -> User | None:
    """The active user holding an unexpired login ``token``, or None."""
    standing = await login_standing(db, token)
    return standing.user if standing.failure is None else None


async def authenticate_station(db: AsyncSession, token: str) -> Station | None:
    """The unrevoked station provisioned with ``token``, or None. Does not commit."""
    digest = token_hash(token)
    station = (
        await db.execute(select(Station).where(Station.token_hash == digest))
    ).scalar_one_or_none()
    if station is None or station.revoked or not same_secret(station.token_hash, digest):
        return None
    return station


async def _signed_in(
    db: AsyncSession, credentials: HTTPAuthorizationCredentials | None
) -> LoginStanding:
    """The standing of a request's login; 401 unless it signs someone in (perhaps only to
    change their password)."""
    if credentials is None:
        raise unauthorized()
    standing = await login_standing(db, credentials.credentials)
    if standing.user is None or standing.failure not in (None, "must_change"):
        if standing.user is None and await authenticate_station(db, credentials.credentials):
            raise forbidden(FOR_USERS)
        raise unauthorized("invalid or expired token")
    return standing


async def signed_in_user(
    db: Db,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_user_bearer)],
) -> User:
    """The logged-in user, even one who must change their password first: only changing
    it, ``/auth/me`` and logging out take this one. 401 as ``current_user``."""
    standing = await _signed_in(db, credentials)
    assert standing.user is not None
    return standing.user


async def current_user(
    db: Db,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_user_bearer)],
) -> User:
    """The logged-in therapist or admin; 401 if the token is missing, unknown or expired,
    403 if they must change a printed or reset password first. (Demo accounts are created
    without that mark, so the demo's printed password works as it is.)"""
    standing = await _signed_in(db, credentials)
    if standing.failure == "must_change":
        raise forbidden(MUST_CHANGE_PASSWORD)
    assert standing.user is not None
    return standing.user


SignedInUser = Annotated[User, Depends(signed_in_user)]
CurrentUser = Annotated[User, Depends(current_user)]


async def current_therapist_or_admin(user: CurrentUser) -> User:
    # Today these are the only roles; the check keeps a future role (say, read-only
    # auditor) out of clinical routes until someone decides otherwise.
    if user.role not in ("therapist", "admin"):
        raise forbidden("therapists and admins only")
    return user


async def require_therapist(user: CurrentUser) -> User:
    """Clinical changes are made by the patient's therapist; an admin's view is read-only."""
    if user.role != "therapist":
        raise forbidden("only a therapist may change clinical records")
    return user


async def require_admin(user: CurrentUser) -> User:
    if user.role != "admin":
        raise forbidden("admins only")
    return user


TherapistOrAdmin = Annotated[User, Depends(current_therapist_or_admin)]
Therapist = Annotated[User, Depends(require_therapist)]
Admin = Annotated[User, Depends(require_admin)]


async def current_station(
    db: Db,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_station_bearer)],
) -> Station:
    """The calling home station; 401 if its token is missing, unknown or revoked."""
    if credentials is None:
        raise unauthorized()
    station = await authenticate_station(db, credentials.credentials)
    if station is None:
        standing = await login_standing(db, credentials.credentials)
        if standing.failure in (None, "must_change"):
            raise forbidden(FOR_STATIONS)
        raise unauthorized("invalid or revoked station token")
    now = utcnow()
    if station.last_seen_at is None or now - station.last_seen_at > LAST_SEEN_RESOLUTION:
        station.last_seen_at = now
        await db.commit()
    return station


CurrentStation = Annotated[Station, Depends(current_station)]


def may_read(user: User, patient: Patient) -> bool:
    """Admins read every patient (a read-only clinical view); a therapist reads their own."""
    return user.role == "admin" or patient.therapist_id == user.id


def may_write(user: User, patient: Patient) -> bool:
    """Only the patient's own therapist changes clinical records."""
    return user.role == "therapist" and patient.therapist_id == user.id


def may_manage_stations(user: User, patient: Patient) -> bool:
    """Admins set up and retire hardware for any patient; therapists for their own."""
    return user.role == "admin" or patient.therapist_id == user.id


def conflict(detail: str) -> HTTPException:
    return HTTPException(status.HTTP_409_CONFLICT, detail=detail)


PATIENT_ARCHIVED = (
    "the patient is archived, so their record is read-only: unarchive them first "
    "(POST /api/v1/patients/{id}/unarchive)"
)


def require_current(patient: Patient) -> None:
    """An archived patient's record is read-only: 409 for any change but unarchiving."""
    if patient.archived_at is not None:
        raise conflict(PATIENT_ARCHIVED.replace("{id}", str(patient.id)))


async def hold(db: AsyncSession, row: Patient | User) -> None:
    """Hold ``row`` (a patient, or a user's account) for a change in ``db``'s transaction
    and read it again as it is now.

    A change is read, checked, written and audited in one transaction; two at once must
    take turns, or both would start from the same old value: one change lost, and two
    audit rows claiming the same "before". Every change of a patient's record or of
    anything of theirs (their prescriptions and stations) holds the patient first
    (``patient_for`` with ``write``, ``prescription_for``, the station routes), so an edit,
    a cancellation and an archiving of one patient take turns: whoever holds the patient
    first goes on, the other waits until that transaction ends and then reads what it
    stored. An admin's change of an account (``server.accounts``: deactivating,
    reactivating, resetting its password) holds the account the same way. PostgreSQL
    locks the row (``FOR NO KEY UPDATE``: rows naming it, a patient's sessions or a
    user's logins, may still be inserted). SQLite locks no rows, only the whole database
    for writing: a write that changes nothing takes that lock (waiting for any other
    writer up to its busy timeout) before the row is read again. The lock goes at commit
    or rollback, when the request's session ends."""
    if db.get_bind().dialect.name == "sqlite":
        table = type(row).__tablename__  # a model's name, never a request's
        await db.execute(text(f"UPDATE {table} SET id = id WHERE id = :id"), {"id": row.id})
        await db.refresh(row)
    else:
        await db.refresh(row, with_for_update={"key_share": True})


async def patient_for(
    db: AsyncSession,
    user: User,
    patient_id: int,
    *,
    write: bool = False,
    even_archived: bool = False,
) -> Patient:
    """The patient ``user`` may read (or, with ``write``, change); else 404, the same 404
    as for an id that does not exist. A change to an archived patient is a 409, unless
    ``even_archived`` (archiving and unarchiving themselves). With ``write`` the patient is
    held for the change (:func:`hold`) and checked as it is once held."""
    patient = await db.get(Patient, patient_id)
    allowed = may_write if write else may_read
    if patient is None or not allowed(user, patient):
        raise not_found("patient")
    if write:
        await hold(db, patient)
        if not even_archived:
            require_current(patient)
    return patient


class _OfPatient(Protocol):
    @property
    def patient_id(self) -> int: ...


R = TypeVar("R", bound=_OfPatient)


async def record_for(db: AsyncSession, user: User, model: type[R], record_id: int, what: str) -> R:
    """The record (a session, a station) of a patient ``user`` may read; else a 404 naming
    ``what``, the same as for an id that does not exist."""
    row = await db.get(model, record_id)
    if row is None:
        raise not_found(what)
    try:
        await patient_for(db, user, row.patient_id)
    except HTTPException:
        raise not_found(what) from None
    return row


UserCredentials = Annotated[HTTPAuthorizationCredentials | None, Depends(_user_bearer)]
"""The raw bearer credentials of a user request (to log that very token out)."""
