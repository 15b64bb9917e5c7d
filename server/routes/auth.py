"""Logging in and out: email and password for a bearer token."""

from __future__ import annotations

import logging
from datetime import timedelta

from fastapi import APIRouter, HTTPException, Request, status
from fastapi.exceptions import RequestValidationError
from sqlalchemy import delete, select
from sqlalchemy.ext.asyncio import AsyncSession

from server import accounts, audit
from server.config import Settings
from server.deps import Db, SignedInUser, UserCredentials, unauthorized
from server.models import AuthToken, User, utcnow
from server.routes.common import UNAUTHORIZED, ErrorPublic, Responses
from server.schemas import LoginRequest, PasswordChange, TokenPublic, UserPublic
from server.security import (
    HashingSlots,
    burn_verify,
    hash_password,
    needs_rehash,
    new_token,
    password_weakness,
    token_hash,
    verify_password,
)
from server.throttle import CountsAway, LoginThrottle, Throttled

router = APIRouter(prefix="/auth", tags=["auth"])
log = logging.getLogger("ankle.server.auth")

# One message for an unknown email and a wrong password (a deactivated account's too): the
# answer must not tell an attacker which addresses have accounts.
BAD_LOGIN = "wrong email or password"
DEACTIVATED = "this account is deactivated: ask your clinic's administrator to reactivate it"
"""Said only to someone who gave the account's right password: it tells nothing to anyone
without it, and tells its owner why the password they know is refused (they were told
"wrong email or password" and could only guess)."""
WRONG_CURRENT = "current_password is not this account's password"

THROTTLED: Responses = {
    429: {
        "model": ErrorPublic,
        "description": "Too many failed sign-ins for this account or from this address, "
        "or too many at once; Retry-After says when to try again.",
    }
}


def _too_many(exc: Throttled) -> HTTPException:
    return HTTPException(
        status.HTTP_429_TOO_MANY_REQUESTS,
        detail=exc.detail,
        headers={"Retry-After": str(exc.retry_after)},
    )


def _uncounted(exc: CountsAway) -> HTTPException:
    log.warning("sign-in refused: the store of failed sign-ins does not answer (%s)", exc)
    return HTTPException(
        status.HTTP_503_SERVICE_UNAVAILABLE,
        detail=exc.detail,
        headers={"Retry-After": str(exc.retry_after)},
    )


async def _failed(db: AsyncSession, actor: str, action: str, user: User, address: str) -> None:
    """Audit a wrong password given for ``user`` (from ``address``), committed at once."""
    audit.record(db, actor, action, "user", user.id, None, None, {"client": address})
    await db.commit()


def _client(request: Request) -> str:
    return request.client.host if request.client else "unknown"


@router.post(
    "/login",
    response_model=TokenPublic,
    summary="Log in with email and password",
    responses={**UNAUTHORIZED, **THROTTLED},
)
async def login(body: LoginRequest, db: Db, request: Request) -> TokenPublic:
    """A bearer token valid for ``token_ttl_s`` (12 h by default). A wrong email and a wrong
    password get the same 401 and take the same time; a deactivated account's right
    password a 401 that says it is deactivated. Repeated failures are slowed down and
    then refused with 429 (see ``server.throttle``). If ``user.must_change_password``, the
    token serves only to change the password, read /auth/me and log out (403 elsewhere)."""
    settings: Settings = request.app.state.settings
    throttle: LoginThrottle = request.app.state.login_throttle
    hashing: HashingSlots = request.app.state.hashing
    email = body.email  # in its stored form (sessions.text.sign_in_address)
    address = _client(request)
    try:
        async with throttle.attempt(email, address) as attempt:
            user = (await db.execute(select(User).where(User.email == email))).scalar_one_or_none()
            if user is None:
                await hashing.run(burn_verify, body.password, key=address)
            ok = user is not None and await hashing.run(
                verify_password, user.password_hash, body.password, key=address
            )
            if user is None or not ok or not user.active:
                await attempt.failed()
                if user is not None:
                    # Only known accounts: the log must not collect what people mistype.
                    await _failed(db, audit.SYSTEM, "auth.login_failed", user, address)
                raise unauthorized(DEACTIVATED if ok else BAD_LOGIN)
            await attempt.succeeded()
    except Throttled as exc:
        raise _too_many(exc) from None
    except CountsAway as exc:
        raise _uncounted(exc) from None
    if needs_rehash(user.password_hash):
        user.password_hash = await hashing.run(hash_password, body.password, key=address)
    audit.record(
        db, audit.user_actor(user), "auth.login", "user", user.id, None, None, {"client": address}
    )
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
async def logout(
    user: SignedInUser, credentials: UserCredentials, db: Db, request: Request
) -> None:
    """The token used for this request stops working, and the live views opened with it
    close (code 4004); other logins of the user do not."""
    assert credentials is not None  # current_user has refused a request without one
    await db.execute(
        delete(AuthToken).where(AuthToken.token_hash == token_hash(credentials.credentials))
    )
    await db.commit()
    await request.app.state.hub.recheck()


@router.get("/me", response_model=UserPublic, summary="Who am I", responses=UNAUTHORIZED)
async def me(user: SignedInUser) -> UserPublic:
    return UserPublic.model_validate(user)


@router.post(
    "/password",
    response_model=UserPublic,
    summary="Change your own password",
    responses={
        **UNAUTHORIZED,
        400: {"model": ErrorPublic, "description": "current_password is wrong."},
        **THROTTLED,
    },
)
async def change_password(
    body: PasswordChange,
    user: SignedInUser,
    credentials: UserCredentials,
    db: Db,
    request: Request,
) -> UserPublic:
    """Any signed-in user, including one who must change a printed or reset password (this
    clears that mark). The current password is checked like a sign-in: a wrong one is a 400
    and counts against the account's and the address's failed sign-ins (then 429). Every
    other login of the user ends (their live views close, code 4004); this one stays. A new
    password easy to guess (``server.security.password_weakness``) is a 422 on
    new_password, with zxcvbn's advice.
    Audited as user.password_change (a wrong current password as
    user.password_change_failed); never the password itself."""
    assert credentials is not None  # signed_in_user has refused a request without one
    throttle: LoginThrottle = request.app.state.login_throttle
    hashing: HashingSlots = request.app.state.hashing
    address = _client(request)
    try:
        async with throttle.attempt(user.email, address) as attempt:
            if not await hashing.run(verify_password, user.password_hash, body.current_password):
                await attempt.failed()
                await _failed(
                    db, audit.user_actor(user), "user.password_change_failed", user, address
                )
                raise HTTPException(status.HTTP_400_BAD_REQUEST, detail=WRONG_CURRENT)
            await attempt.succeeded()
    except Throttled as exc:
        raise _too_many(exc) from None
    except CountsAway as exc:
        raise _uncounted(exc) from None
    weak = await hashing.run(password_weakness, body.new_password, (user.email, user.name))
    if weak is not None:  # a 422 on the field, as the body's own checks give (no input echoed)
        loc = ("body", "new_password")
        raise RequestValidationError([{"type": "value_error", "loc": loc, "msg": weak}])
    await accounts.change_password(
        db, hashing, user, body.new_password, token_hash(credentials.credentials)
    )
    await db.commit()
    await request.app.state.hub.recheck()
    return UserPublic.model_validate(user)
