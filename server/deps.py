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

from collections.abc import AsyncIterator
from datetime import datetime, timedelta
from typing import Annotated, Literal, NamedTuple, Protocol, TypeVar

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy import select
from sqlalchemy.ext.asyncio import AsyncSession, async_sessionmaker

from server.models import AuthToken, Patient, Station, User, utcnow
from server.security import same_secret, token_hash

# Writing last_seen_at on every request of a polling station would be a write per poll.
LAST_SEEN_RESOLUTION = timedelta(seconds=30)

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
    sessionmaker: async_sessionmaker[AsyncSession] = request.app.state.sessionmaker
    async with sessionmaker() as session:
        yield session


Db = Annotated[AsyncSession, Depends(get_db)]


def unauthorized(detail: str = "not authenticated") -> HTTPException:
    return HTTPException(
        status.HTTP_401_UNAUTHORIZED, detail=detail, headers={"WWW-Authenticate": "Bearer"}
    )


def forbidden(detail: str) -> HTTPException:
    return HTTPException(status.HTTP_403_FORBIDDEN, detail=detail)


def not_found(what: str) -> HTTPException:
    return HTTPException(status.HTTP_404_NOT_FOUND, detail=f"{what} not found")


LoginFailure = Literal["unknown", "expired", "inactive"]
"""Why a token does not sign anyone in: no such login (never issued, logged out, or ended by
a password change), past its expiry, or its user is deactivated."""


class LoginStanding(NamedTuple):
    user: User | None
    failure: LoginFailure | None
    """None when the token signs ``user`` in now."""
    expires_at: datetime | None


async def login_standing(db: AsyncSession, token: str) -> LoginStanding:
    """Who holds the login ``token``, until when, and, if it does not sign them in now, why.

    The one place a user's token is judged: HTTP requests (``authenticate_user``), the live
    view's handshake and the live links' re-checks all ask here.
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


async def current_user(
    db: Db,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_user_bearer)],
) -> User:
    """The logged-in therapist or admin; 401 if the token is missing, unknown or expired."""
    if credentials is None:
        raise unauthorized()
    user = await authenticate_user(db, credentials.credentials)
    if user is None:
        raise unauthorized("invalid or expired token")
    return user


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


async def patient_for(
    db: AsyncSession, user: User, patient_id: int, *, write: bool = False
) -> Patient:
    """The patient ``user`` may read (or, with ``write``, change); else 404, the same 404
    as for an id that does not exist."""
    patient = await db.get(Patient, patient_id)
    allowed = may_write if write else may_read
    if patient is None or not allowed(user, patient):
        raise not_found("patient")
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
