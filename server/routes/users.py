"""Accounts of therapists and administrators (admins only): create, list, reset a password,
deactivate and reactivate. The rules live in ``server.accounts``."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from fastapi import APIRouter, Request, status
from sqlalchemy import select

from server import accounts, audit
from server.deps import Admin, Db, Id, conflict, not_found
from server.idempotency import Idempotent
from server.models import User
from server.routes.common import CONFLICT, FORBIDDEN, NOT_FOUND, UNAUTHORIZED
from server.schemas import PasswordReset, UserCreate, UserCreated, UserPublic
from server.security import HashingSlots

router = APIRouter(prefix="/users", tags=["users"])

_ONE_USER = {**UNAUTHORIZED, **FORBIDDEN, **NOT_FOUND, **CONFLICT}


@contextmanager
def _refused_as_conflict() -> Iterator[None]:
    try:
        yield
    except accounts.AccountRefused as exc:
        raise conflict(str(exc)) from None


def _hashing(request: Request) -> HashingSlots:
    hashing: HashingSlots = request.app.state.hashing
    return hashing


async def _user(db: Db, user_id: int) -> User:
    user = await db.get(User, user_id)
    if user is None:
        raise not_found("user")
    return user


@router.post(
    "",
    response_model=UserCreated,
    status_code=status.HTTP_201_CREATED,
    summary="Create a therapist or admin account",
    responses={**UNAUTHORIZED, **FORBIDDEN, **CONFLICT},
)
async def create_user(
    body: UserCreate, admin: Admin, db: Db, request: Request, once: Idempotent
) -> UserCreated:
    """Admins only. Without a password in the request the answer carries a one-time
    password, shown this once, that its owner must change at the first sign-in. 409 if the
    email is taken. Audited as user.create."""
    await once.check(admin, body, secrets=("password",))
    with _refused_as_conflict():
        user, one_time = await accounts.create_user(
            db, _hashing(request), audit.user_actor(admin), body
        )
    answer = UserCreated(**UserPublic.model_validate(user).model_dump(), one_time_password=one_time)
    await once.keep(
        answer, secret="one_time_password", if_lost=f"reset account {user.id}'s password"
    )
    await db.commit()
    return answer


@router.get(
    "",
    response_model=list[UserPublic],
    summary="List accounts",
    responses={**UNAUTHORIZED, **FORBIDDEN},
)
async def list_users(admin: Admin, db: Db) -> list[UserPublic]:
    """Admins only."""
    users = (await db.execute(select(User).order_by(User.id))).scalars()
    return [UserPublic.model_validate(u) for u in users]


@router.post(
    "/{user_id}/reset-password",
    response_model=PasswordReset,
    summary="Reset a user's password",
    responses=_ONE_USER,
)
async def reset_password(user_id: Id, admin: Admin, db: Db, request: Request) -> PasswordReset:
    """Admins only, for another user (409 for your own: change it instead). The answer
    carries a new one-time password, shown this once; the user must change it at the next
    sign-in. Every login of the user ends now and their live views close (code 4004).
    Audited as user.password_reset."""
    user = await _user(db, user_id)
    with _refused_as_conflict():
        password = await accounts.reset_password(
            db, _hashing(request), audit.user_actor(admin), user, by=admin
        )
    await db.commit()
    await request.app.state.hub.recheck()
    return PasswordReset(user=UserPublic.model_validate(user), one_time_password=password)


async def _set_active(
    user_id: int, admin: User, db: Db, request: Request, active: bool
) -> UserPublic:
    user = await _user(db, user_id)
    with _refused_as_conflict():
        changed = await accounts.set_active(db, admin, user, active)
    if changed:
        await db.commit()
        await request.app.state.hub.recheck()
    return UserPublic.model_validate(user)


@router.post(
    "/{user_id}/deactivate",
    response_model=UserPublic,
    summary="Deactivate a user",
    responses=_ONE_USER,
)
async def deactivate_user(user_id: Id, admin: Admin, db: Db, request: Request) -> UserPublic:
    """Admins only. The user can no longer sign in, their tokens are refused and their live
    views close (code 4006); their patients and records stay. 409 for your own account or
    the last active admin. Deactivating twice changes nothing. Audited as user.deactivate."""
    return await _set_active(user_id, admin, db, request, active=False)


@router.post(
    "/{user_id}/reactivate",
    response_model=UserPublic,
    summary="Reactivate a user",
    responses=_ONE_USER,
)
async def reactivate_user(user_id: Id, admin: Admin, db: Db, request: Request) -> UserPublic:
    """Admins only. The user can sign in again with their password; logins from before the
    deactivation stay ended. Audited as user.reactivate."""
    return await _set_active(user_id, admin, db, request, active=True)
