"""Logging in and out: email and password for a bearer token."""

from __future__ import annotations

import asyncio
from datetime import timedelta

from fastapi import APIRouter, Request, status
from sqlalchemy import delete, select

from server.config import Settings
from server.deps import CurrentUser, Db, UserCredentials, unauthorized
from server.models import AuthToken, User, utcnow
from server.routes.common import UNAUTHORIZED
from server.schemas import LoginRequest, TokenPublic, UserPublic
from server.security import (
    burn_verify,
    hash_password,
    needs_rehash,
    new_token,
    token_hash,
    verify_password,
)

router = APIRouter(prefix="/auth", tags=["auth"])

# One message for an unknown email, a wrong password and a deactivated account: the answer
# must not tell an attacker which addresses have accounts.
BAD_LOGIN = "wrong email or password"


@router.post(
    "/login",
    response_model=TokenPublic,
    summary="Log in with email and password",
    responses=UNAUTHORIZED,
)
async def login(body: LoginRequest, db: Db, request: Request) -> TokenPublic:
    """A bearer token valid for ``token_ttl_s`` (12 h by default). A wrong email and a wrong
    password get the same 401 and take the same time."""
    settings: Settings = request.app.state.settings
    email = body.email.strip().lower()
    user = (await db.execute(select(User).where(User.email == email))).scalar_one_or_none()
    # Argon2 is deliberately slow; run it off the event loop so other requests go on.
    if user is None:
        await asyncio.to_thread(burn_verify, body.password)
        raise unauthorized(BAD_LOGIN)
    ok = await asyncio.to_thread(verify_password, user.password_hash, body.password)
    if not ok or not user.active:
        raise unauthorized(BAD_LOGIN)
    if needs_rehash(user.password_hash):
        user.password_hash = await asyncio.to_thread(hash_password, body.password)
    now = utcnow()
    token = new_token()
    expires_at = now + timedelta(seconds=settings.token_ttl_s)
    # Expired logins are useless rows; each login sweeps its own user's.
    await db.execute(
        delete(AuthToken).where(AuthToken.user_id == user.id, AuthToken.expires_at <= now)
    )
    db.add(AuthToken(token_hash=token_hash(token), user_id=user.id, expires_at=expires_at))
    await db.commit()
    return TokenPublic(
        access_token=token, expires_at=expires_at, user=UserPublic.model_validate(user)
    )


@router.post(
    "/logout",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="End this login",
    responses=UNAUTHORIZED,
)
async def logout(user: CurrentUser, credentials: UserCredentials, db: Db) -> None:
    """The token used for this request stops working; other logins of the user do not."""
    assert credentials is not None  # current_user has refused a request without one
    await db.execute(
        delete(AuthToken).where(AuthToken.token_hash == token_hash(credentials.credentials))
    )
    await db.commit()


@router.get("/me", response_model=UserPublic, summary="Who am I", responses=UNAUTHORIZED)
async def me(user: CurrentUser) -> UserPublic:
    return UserPublic.model_validate(user)
