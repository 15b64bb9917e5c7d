"""The life of an account: created, its password changed or reset, deactivated, reactivated.

The API (``server.routes.users``, ``server.routes.auth``) and the command line
(``ankle admin``) both change accounts through these functions, so each rule is written once.
Each works in the caller's transaction and adds its audit row there; the caller commits and
then, in the server, calls the live hub's ``recheck`` so that links whose login just ended
close at once. Audit rows never hold a password or a hash: only whether one must be
changed and how many logins ended.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import delete, func, or_, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.ext.asyncio import AsyncSession

from server import audit
from server.deps import hold
from server.models import AuthToken, User
from server.schemas import UserCreate
from server.security import HashingSlots, hash_password, new_password

EMAIL_TAKEN = "a user with this email exists"
NOT_YOURSELF = "you cannot deactivate your own account: another admin must"
LAST_ADMIN = (
    "this is the last active admin: create or reactivate another admin before deactivating it"
)
RESET_YOURSELF = "reset another user's password; change your own with POST /api/v1/auth/password"


class AccountRefused(Exception):
    """A change the rules of accounts refuse; the message is the sentence to show (the API
    answers 409, the command line exits 2)."""


async def create_user(
    db: AsyncSession, hashing: HashingSlots, actor: str, body: UserCreate
) -> tuple[User, str | None]:
    """Add the account and its audit row (user.create). Without ``body.password`` the
    server makes one, returned here to be shown once, and the account must change it at the
    first sign-in; a password the owner chose themselves is kept as it is. Raises
    AccountRefused if the email is taken."""
    if (await db.execute(select(User.id).where(User.email == body.email))).first():
        raise AccountRefused(EMAIL_TAKEN)
    one_time = None if body.password is not None else new_password()
    password = body.password if body.password is not None else one_time
    assert password is not None
    user = User(
        email=body.email,
        name=body.name,
        role=body.role,
        password_hash=await hashing.run(hash_password, password),
        must_change_password=one_time is not None,
    )
    db.add(user)
    try:
        await db.flush()
    except IntegrityError:  # created by a concurrent request since the check above
        await db.rollback()
        raise AccountRefused(EMAIL_TAKEN) from None
    new: dict[str, Any] = {"email": user.email, "name": user.name, "role": user.role}
    if user.must_change_password:
        new["must_change_password"] = True
    audit.record(db, actor, "user.create", "user", user.id, None, None, new)
    return user, one_time


async def end_logins(db: AsyncSession, user_id: int, keep_token_hash: str | None = None) -> int:
    """Delete the user's logins (but the one whose token hash is ``keep_token_hash``); how
    many ended. Their live views close at the hub's next re-check (code 4004)."""
    stmt = delete(AuthToken).where(AuthToken.user_id == user_id)
    if keep_token_hash is not None:
        stmt = stmt.where(AuthToken.token_hash != keep_token_hash)
    result = await db.execute(stmt)
    return int(getattr(result, "rowcount", 0) or 0)


async def change_password(
    db: AsyncSession,
    hashing: HashingSlots,
    user: User,
    password: str,
    keep_token_hash: str,
) -> None:
    """The user's own new password (already checked: they gave the current one). Clears
    the must-change mark and ends every other login of theirs, keeping this one. Audited
    as user.password_change."""
    before = user.must_change_password
    user.password_hash = await hashing.run(hash_password, password)
    user.must_change_password = False
    ended = await end_logins(db, user.id, keep_token_hash)
    audit.record(
        db,
        audit.user_actor(user),
        "user.password_change",
        "user",
        user.id,
        None,
        {"must_change_password": before},
        {"must_change_password": False, "other_logins_ended": ended},
    )


async def reset_password(
    db: AsyncSession, hashing: HashingSlots, actor: str, user: User, by: User | None = None
) -> str:
    """A new one-time password for ``user``, returned to be shown once: it must be changed
    at the next sign-in, and every login of the account ends now. ``by``, the admin asking
    (None on the command line), may not reset their own. Audited as user.password_reset.
    The account is held for the change (``server.deps.hold``)."""
    if by is not None and by.id == user.id:
        raise AccountRefused(RESET_YOURSELF)
    password = new_password()
    password_hash = await hashing.run(hash_password, password)  # slow: before the hold
    await hold(db, user)
    before = user.must_change_password
    user.password_hash = password_hash
    user.must_change_password = True
    ended = await end_logins(db, user.id)
    audit.record(
        db,
        actor,
        "user.password_reset",
        "user",
        user.id,
        None,
        {"must_change_password": before},
        {"must_change_password": True, "logins_ended": ended},
    )
    return password


async def set_active(db: AsyncSession, by: User, user: User, active: bool) -> bool:
    """Deactivate or reactivate ``user`` at the request of the admin ``by``; False if it
    was so already (nothing changes, no audit row).

    Deactivation keeps the logins (so that the live views close saying why, code 4006) but
    none of them signs in any more; an admin cannot deactivate themself, nor the last active
    admin (the active admins' rows are locked, then counted in the statement that
    deactivates, so two admins deactivating each other at once cannot leave none).
    Reactivation ends the logins from before, so a token from then does not come back to
    life. Audited as user.deactivate / user.reactivate. The account is held for the change
    (``server.deps.hold``): two requests at once take turns, and the second finds the
    change made (one audit row, not two).
    """
    if not active and user.role == "admin":  # a role never changes: no need to hold first
        # Lock the active admins' rows first, in one order, before holding the account
        # (holding it first, two admins deactivating each other would each hold one row
        # and wait for the other's). On PostgreSQL (read committed) the statement below
        # alone is not enough: two admins deactivating each other each saw the other still
        # active and both went through. The second now waits for the first to commit, and
        # its statement then counts afresh. SQLite takes its one write lock anyway (FOR
        # UPDATE is not rendered there).
        await db.execute(
            select(User.id)
            .where(User.role == "admin", User.active.is_(True))
            .order_by(User.id)
            .with_for_update()
        )
    await hold(db, user)
    if user.active == active:
        return False
    if not active:
        if user.id == by.id:
            raise AccountRefused(NOT_YOURSELF)
        other_admins = (
            select(func.count())
            .select_from(User)
            .where(User.role == "admin", User.active.is_(True), User.id != user.id)
            .scalar_subquery()
        )
        result = await db.execute(
            update(User)
            .where(User.id == user.id, or_(User.role != "admin", other_admins > 0))
            .values(active=False)
            .execution_options(synchronize_session=False)
        )
        if not getattr(result, "rowcount", 0):
            raise AccountRefused(LAST_ADMIN)
        await db.refresh(user)
    else:
        user.active = True
        await end_logins(db, user.id)
    audit.record(
        db,
        audit.user_actor(by),
        "user.reactivate" if active else "user.deactivate",
        "user",
        user.id,
        None,
        {"active": not active},
        {"active": active},
    )
    return True
