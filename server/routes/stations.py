"""Home stations, as therapists and admins manage them: provision, list, revoke."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request, status
from sqlalchemy import select
from sqlalchemy.ext.asyncio import AsyncSession

from server import audit
from server.deps import (
    Db,
    Id,
    TherapistOrAdmin,
    hold,
    may_manage_stations,
    not_found,
    require_current,
)
from server.idempotency import Idempotent
from server.models import Patient, Station, User
from server.routes.common import CONFLICT, NOT_FOUND, UNAUTHORIZED
from server.schemas import StationCreate, StationProvisioned, StationPublic
from server.security import new_token, token_hash

router = APIRouter(tags=["stations"])


async def _online(request: Request, station: Station) -> bool:
    """Whether ``station`` is linked now. A revoked station never is: its token is refused
    and the revocation closes its link (``Hub.recheck``), though another process's lease
    on it may not have run out yet."""
    return not station.revoked and bool(await request.app.state.hub.online(station.id))


async def _manageable(db: AsyncSession, user: User, patient_id: int) -> Patient | None:
    """The patient whose stations ``user`` may provision and revoke, held for the change
    (``server.deps.hold``); None if there is none such."""
    patient = await db.get(Patient, patient_id)
    if patient is None or not may_manage_stations(user, patient):
        return None
    await hold(db, patient)
    return patient


def revoke(db: AsyncSession, actor: str, station: Station, because: str = "") -> bool:
    """Revoke ``station`` in ``db``'s transaction, with its audit row; False if it was
    revoked already (nothing changes). ``because``: the action that caused it, if any. The
    caller commits, then calls the hub's ``recheck`` so that its open link closes."""
    if station.revoked:
        return False
    station.revoked = True
    new: dict[str, Any] = {"revoked": True}
    if because:
        new["because"] = because
    audit.record(
        db,
        actor,
        "station.revoke",
        "station",
        station.id,
        station.patient_id,
        {"revoked": False},
        new,
    )
    return True


@router.post(
    "/patients/{patient_id}/stations",
    response_model=StationProvisioned,
    status_code=status.HTTP_201_CREATED,
    summary="Provision a home station for a patient",
    responses={**UNAUTHORIZED, **NOT_FOUND, **CONFLICT},
)
async def provision_station(
    patient_id: Id,
    body: StationCreate,
    user: TherapistOrAdmin,
    db: Db,
    request: Request,
    once: Idempotent,
) -> StationProvisioned:
    """The patient's therapist or an admin. The answer carries the station's token; it is
    shown this once and only its hash is stored. 409 for an archived patient. Audited as
    station.provision. Sent again with its ``Idempotency-Key``: a 409 naming the station
    (the token is not kept to be shown again)."""
    await once.check(user, body)
    patient = await _manageable(db, user, patient_id)
    if patient is None:
        raise not_found("patient")
    require_current(patient)
    token = new_token()
    station = Station(patient_id=patient_id, name=body.name, token_hash=token_hash(token))
    db.add(station)
    await db.flush()
    audit.record(
        db,
        audit.user_actor(user),
        "station.provision",
        "station",
        station.id,
        patient_id,
        None,
        {"name": station.name, "patient_id": patient_id},
    )
    # A new station has never been linked: it is offline.
    answer = StationProvisioned(**StationPublic.from_row(station, False).model_dump(), token=token)
    await once.keep(
        answer, secret="token", if_lost=f"revoke station {station.id} and provision another"
    )
    await db.commit()
    return answer


@router.get(
    "/stations",
    response_model=list[StationPublic],
    summary="List home stations",
    responses=UNAUTHORIZED,
)
async def list_stations(
    user: TherapistOrAdmin, db: Db, request: Request, patient_id: Id | None = None
) -> list[StationPublic]:
    """A therapist sees their patients' stations, an admin all; with ``online`` (connected
    now) and ``last_seen_at``. Optionally one patient's."""
    query = select(Station).order_by(Station.id)
    if user.role != "admin":
        query = query.join(Patient, Patient.id == Station.patient_id).where(
            Patient.therapist_id == user.id
        )
    if patient_id is not None:
        query = query.where(Station.patient_id == patient_id)
    stations = list((await db.execute(query)).scalars())
    online = await request.app.state.hub.online_of([s.id for s in stations])
    return [StationPublic.from_row(s, s.id in online and not s.revoked) for s in stations]


@router.post(
    "/stations/{station_id}/revoke",
    response_model=StationPublic,
    summary="Revoke a station's token",
    responses={**UNAUTHORIZED, **NOT_FOUND},
)
async def revoke_station(
    station_id: Id, user: TherapistOrAdmin, db: Db, request: Request
) -> StationPublic:
    """The patient's therapist or an admin. The station's token is refused from now on
    (a lost or returned device); revoking twice changes nothing. Audited as station.revoke."""
    station = await db.get(Station, station_id)
    if station is None or not await _manageable(db, user, station.patient_id):
        raise not_found("station")
    await db.refresh(station)  # as it is now that its patient is held
    if revoke(db, audit.user_actor(user), station):
        await db.commit()
        await request.app.state.hub.recheck()  # its open link goes too
    return StationPublic.from_row(station, await _online(request, station))
