"""Accounts of therapists and administrators (admins only)."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request, status
from sqlalchemy import select
from sqlalchemy.exc import IntegrityError

from server import audit
from server.deps import Admin, Db
from server.models import User
from server.routes.common import CONFLICT, FORBIDDEN, UNAUTHORIZED
from server.schemas import UserCreate, UserPublic
from server.security import HashingSlots, hash_password

router = APIRouter(prefix="/users", tags=["users"])

EMAIL_TAKEN = "a user with this email exists"


@router.post(
    "",
    response_model=UserPublic,
    status_code=status.HTTP_201_CREATED,
    summary="Create a therapist or admin account",
    responses={**UNAUTHORIZED, **FORBIDDEN, **CONFLICT},
)
async def create_user(body: UserCreate, admin: Admin, db: Db, request: Request) -> UserPublic:
    """Admins only. 409 if the email is taken."""
    if (await db.execute(select(User.id).where(User.email == body.email))).first():
        raise HTTPException(status.HTTP_409_CONFLICT, detail=EMAIL_TAKEN)
    hashing: HashingSlots = request.app.state.hashing
    password_hash = await hashing.run(hash_password, body.password)
    user = User(email=body.email, name=body.name, role=body.role, password_hash=password_hash)
    db.add(user)
    try:
        await db.flush()
    except IntegrityError:  # created by a concurrent request since the check above
        await db.rollback()
        raise HTTPException(status.HTTP_409_CONFLICT, detail=EMAIL_TAKEN) from None
    audit.record(
        db,
        audit.user_actor(admin),
        "user.create",
        "user",
        user.id,
        None,
        None,
        {"email": user.email, "name": user.name, "role": user.role},
    )
    await db.commit()
    return UserPublic.model_validate(user)


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
