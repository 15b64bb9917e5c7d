"""Prescriptions: what a patient's station will run, written and changed by their therapist.

Every change is audited with the old and new values and then announced to the patient's
connected stations, which fetch their active prescriptions again.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query, Request, status
from sqlalchemy import select
from sqlalchemy.ext.asyncio import AsyncSession

from server import audit
from server.deps import (
    Db,
    Id,
    Therapist,
    TherapistOrAdmin,
    hold,
    may_read,
    may_write,
    not_found,
    patient_for,
    require_current,
)
from server.idempotency import Idempotent
from server.models import Patient, Prescription, PrescriptionStatus, Station, User
from server.routes.common import CONFLICT, FORBIDDEN, NOT_FOUND, UNAUTHORIZED
from server.schemas import PrescriptionCreate, PrescriptionPublic, PrescriptionUpdate
from sessions.prescription import PrescriptionBody

log = logging.getLogger(__name__)

router = APIRouter(tags=["prescriptions"])

_ERRORS = {**UNAUTHORIZED, **FORBIDDEN, **NOT_FOUND}


def body_json(body: PrescriptionBody) -> dict[str, Any]:
    return body.model_dump(mode="json")


async def prescription_for(
    db: AsyncSession, user: User, prescription_id: int, *, write: bool = False
) -> Prescription:
    """Like ``patient_for``: someone else's prescription is the same 404 as a missing one.
    With ``write`` its patient is held for the change (``server.deps.hold``) and the
    prescription read again as it is then."""
    prescription = await db.get(Prescription, prescription_id)
    patient = None if prescription is None else await db.get(Patient, prescription.patient_id)
    allowed = may_write if write else may_read
    if prescription is None or patient is None or not allowed(user, patient):
        raise not_found("prescription")
    if write:
        await hold(db, patient)
        await db.refresh(prescription)
        require_current(patient)
    return prescription


async def notify_stations(request: Request, db: AsyncSession, patient_id: int) -> None:
    """Tell the patient's live stations to fetch their prescriptions again.

    All at once, and with the request's database connection given back first: a station
    held by another process is found through the relay, which a hanging Redis keeps waiting
    up to its 5 s timeout (one station after another, 10 s for two, the connection held
    all along). While the relay is known to be away those are skipped (the hub's
    ``prescriptions_changed``): the change is committed, and a station is sent its
    prescriptions whenever it connects."""
    station_ids = list(
        (
            await db.execute(
                select(Station.id).where(
                    Station.patient_id == patient_id, Station.revoked.is_(False)
                )
            )
        ).scalars()
    )
    await db.commit()  # ends the read's transaction: the connection goes back to the pool
    hub = request.app.state.hub

    async def notify(station_id: int) -> None:
        try:
            await hub.prescriptions_changed(station_id)
        except Exception:
            # The change is committed; a station that missed the nudge fetches on reconnect.
            log.exception("could not notify station %d of new prescriptions", station_id)

    await asyncio.gather(*(notify(s) for s in station_ids))


@router.get(
    "/patients/{patient_id}/prescriptions",
    response_model=list[PrescriptionPublic],
    summary="A patient's prescriptions",
    responses={**UNAUTHORIZED, **NOT_FOUND},
)
async def list_prescriptions(
    patient_id: Id,
    user: TherapistOrAdmin,
    db: Db,
    status_filter: Annotated[
        PrescriptionStatus | None, Query(alias="status", description="Only this status.")
    ] = None,
) -> list[PrescriptionPublic]:
    """The patient's therapist, or an admin (read-only). Newest first; optionally only one
    status."""
    await patient_for(db, user, patient_id)
    query = (
        select(Prescription)
        .where(Prescription.patient_id == patient_id)
        .order_by(Prescription.id.desc())
    )
    if status_filter is not None:
        query = query.where(Prescription.status == status_filter)
    return [PrescriptionPublic.from_row(p) for p in (await db.execute(query)).scalars()]


@router.post(
    "/patients/{patient_id}/prescriptions",
    response_model=PrescriptionPublic,
    status_code=status.HTTP_201_CREATED,
    summary="Prescribe an exercise",
    responses={**_ERRORS, **CONFLICT},
)
async def create_prescription(
    patient_id: Id,
    body: PrescriptionCreate,
    user: Therapist,
    db: Db,
    request: Request,
    once: Idempotent,
) -> PrescriptionPublic:
    """The patient's own therapist only. Values outside anatomical ranges or the device's
    limits are a 422 naming the field and the bound. Audited as prescription.create."""
    await once.check(user, body)
    await patient_for(db, user, patient_id, write=True)
    stored = body_json(body)
    prescription = Prescription(patient_id=patient_id, created_by=user.id, body=stored)
    db.add(prescription)
    await db.flush()
    audit.record(
        db,
        audit.user_actor(user),
        "prescription.create",
        "prescription",
        prescription.id,
        patient_id,
        None,
        {"status": prescription.status, "version": prescription.version, "body": stored},
    )
    answer = PrescriptionPublic.from_row(prescription)
    await once.keep(answer)
    await db.commit()
    await notify_stations(request, db, patient_id)
    return answer


@router.get(
    "/prescriptions/{prescription_id}",
    response_model=PrescriptionPublic,
    summary="One prescription",
    responses={**UNAUTHORIZED, **NOT_FOUND},
)
async def get_prescription(
    prescription_id: Id, user: TherapistOrAdmin, db: Db
) -> PrescriptionPublic:
    """The patient's therapist, or an admin (read-only)."""
    return PrescriptionPublic.from_row(await prescription_for(db, user, prescription_id))


def _require_active(prescription: Prescription) -> None:
    if prescription.status != "active":
        raise HTTPException(
            status.HTTP_409_CONFLICT,
            detail=f"the prescription is {prescription.status}; write a new one instead",
        )


@router.patch(
    "/prescriptions/{prescription_id}",
    response_model=PrescriptionPublic,
    summary="Replace an active prescription's settings",
    responses={**_ERRORS, **CONFLICT},
)
async def update_prescription(
    prescription_id: Id, body: PrescriptionUpdate, user: Therapist, db: Db, request: Request
) -> PrescriptionPublic:
    """The patient's own therapist only; the body is replaced whole and the version goes up
    by one. 409 if the prescription is no longer active. Audited as prescription.update with
    the old and new value of each changed top-level field."""
    prescription = await prescription_for(db, user, prescription_id, write=True)
    _require_active(prescription)
    stored = body_json(body)
    old_body, new_body = audit.changes(prescription.body, stored)
    if not new_body:
        return PrescriptionPublic.from_row(prescription)
    old_version = prescription.version
    prescription.body = stored
    prescription.version = old_version + 1
    audit.record(
        db,
        audit.user_actor(user),
        "prescription.update",
        "prescription",
        prescription.id,
        prescription.patient_id,
        {"version": old_version, "body": old_body},
        {"version": prescription.version, "body": new_body},
    )
    await db.commit()
    await notify_stations(request, db, prescription.patient_id)
    return PrescriptionPublic.from_row(prescription)


@router.post(
    "/prescriptions/{prescription_id}/cancel",
    response_model=PrescriptionPublic,
    summary="Withdraw an active prescription",
    responses={**_ERRORS, **CONFLICT},
)
async def cancel_prescription(
    prescription_id: Id, user: Therapist, db: Db, request: Request
) -> PrescriptionPublic:
    """The patient's own therapist only; the station stops offering it. 409 if it is not
    active. Audited as prescription.cancel."""
    prescription = await prescription_for(db, user, prescription_id, write=True)
    _require_active(prescription)
    cancel(db, user, prescription)
    await db.commit()
    await notify_stations(request, db, prescription.patient_id)
    return PrescriptionPublic.from_row(prescription)


def cancel(db: AsyncSession, user: User, prescription: Prescription, because: str = "") -> None:
    """Withdraw an active prescription in ``db``'s transaction, with its audit row
    (``because``: the action that caused it, when it was not asked for by itself)."""
    prescription.status = "cancelled"
    new: dict[str, Any] = {"status": "cancelled"}
    if because:
        new["because"] = because
    audit.record(
        db,
        audit.user_actor(user),
        "prescription.cancel",
        "prescription",
        prescription.id,
        prescription.patient_id,
        {"status": "active"},
        new,
    )
