"""Patients: each belongs to one therapist, who alone changes them, and archives them when
the treatment ends.

An archived patient's record is kept whole and read-only (``server.deps.require_current``:
409 for any change but unarchiving) and left out of the default list. Archiving also
withdraws their active prescriptions and revokes their stations (each audited), so no
device keeps exercising or streaming for them: the devices go back to the clinic.
Unarchiving brings none of that back; the therapist prescribes and provisions anew.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Request, status
from sqlalchemy import select
from sqlalchemy.ext.asyncio import AsyncSession

from server import audit
from server.attention import AttentionItem, attention
from server.deps import Db, Id, Therapist, TherapistOrAdmin, conflict, hold, patient_for
from server.idempotency import Idempotent
from server.models import Patient, Prescription, Station, User, utcnow
from server.routes.common import CONFLICT, FORBIDDEN, NOT_FOUND, UNAUTHORIZED
from server.routes.prescriptions import cancel
from server.routes.stations import revoke
from server.schemas import PatientArchived, PatientCreate, PatientPublic, PatientUpdate

router = APIRouter(prefix="/patients", tags=["patients"])

_CLINICAL_FIELDS = (
    "display_name",
    "reference",
    "birth_year",
    "affected_side",
    "weight_kg",
    "notes",
)


def clinical_fields(patient: Patient) -> dict[str, Any]:
    return {name: getattr(patient, name) for name in _CLINICAL_FIELDS}


async def require_free_reference(
    db: AsyncSession, therapist: User, reference: str | None, patient_id: int | None = None
) -> None:
    """409 if another of ``therapist``'s patients, current or archived, has ``reference``
    (the clinic's identifier names one patient). Per therapist, not per server: another
    therapist's patients are not theirs to know of. The therapist's account is held
    (``server.deps.hold``) until the commit, so two saves of one reference take turns and
    the second finds the first. Patients stored with one reference before this rule keep
    it; only a reference given now is checked."""
    if reference is None:
        return
    await hold(db, therapist)
    query = select(Patient).where(
        Patient.therapist_id == therapist.id, Patient.reference == reference
    )
    if patient_id is not None:
        query = query.where(Patient.id != patient_id)
    other = (await db.execute(query.order_by(Patient.id).limit(1))).scalar_one_or_none()
    if other is not None:
        archived = other.archived_at is not None
        raise conflict(
            f"your {'archived ' if archived else ''}patient {other.display_name} "
            f"(id {other.id}) already has the reference {reference}: a reference names one "
            f"patient; {'unarchive and ' if archived else ''}open that patient instead, or "
            "correct the reference"
        )


@router.get(
    "",
    response_model=list[PatientPublic],
    summary="List patients",
    responses=UNAUTHORIZED,
)
async def list_patients(
    user: TherapistOrAdmin,
    db: Db,
    archived: Annotated[
        bool,
        Query(description="false: current patients (the default); true: archived ones only."),
    ] = False,
) -> list[PatientPublic]:
    """A therapist sees their own patients; an admin sees all of them, read-only."""
    query = select(Patient).order_by(Patient.id)
    if archived:
        query = query.where(Patient.archived_at.is_not(None))
    else:
        query = query.where(Patient.archived_at.is_(None))
    if user.role != "admin":
        query = query.where(Patient.therapist_id == user.id)
    return [PatientPublic.model_validate(p) for p in (await db.execute(query)).scalars()]


@router.get(
    "/attention",
    response_model=list[AttentionItem],
    summary="What needs attention",
    responses=UNAUTHORIZED,
)
async def needs_attention(user: TherapistOrAdmin, db: Db, request: Request) -> list[AttentionItem]:
    """Across the caller's current patients (an admin: all of them), from the last
    seven days: faults, exercises held, sessions ended early, prescribed sessions missed in a
    prescribed week that ended in those days (as the progress page's adherence counts them)
    and stations not seen for two days, each with a sentence and the page where it
    happened."""
    return await attention(db, user, utcnow(), request.app.state.hub.online_of)


@router.post(
    "",
    response_model=PatientPublic,
    status_code=status.HTTP_201_CREATED,
    summary="Add a patient",
    responses={**UNAUTHORIZED, **FORBIDDEN, **CONFLICT},
)
async def create_patient(
    body: PatientCreate, user: Therapist, db: Db, once: Idempotent
) -> PatientPublic:
    """Therapists only: the new patient is the caller's. 409 if another of the caller's
    patients has the same ``reference``. Audited as patient.create."""
    await once.check(user, body)
    await require_free_reference(db, user, body.reference)
    patient = Patient(therapist_id=user.id, **body.model_dump())
    db.add(patient)
    await db.flush()
    audit.record(
        db,
        audit.user_actor(user),
        "patient.create",
        "patient",
        patient.id,
        patient.id,
        None,
        {"therapist_id": user.id, **clinical_fields(patient)},
    )
    answer = PatientPublic.model_validate(patient)
    await once.keep(answer)
    await db.commit()
    return answer


@router.get(
    "/{patient_id}",
    response_model=PatientPublic,
    summary="One patient",
    responses={**UNAUTHORIZED, **NOT_FOUND},
)
async def get_patient(patient_id: Id, user: TherapistOrAdmin, db: Db) -> PatientPublic:
    """The patient's therapist, or any admin (read-only). Someone else's patient is a 404."""
    return PatientPublic.model_validate(await patient_for(db, user, patient_id))


@router.patch(
    "/{patient_id}",
    response_model=PatientPublic,
    summary="Change a patient's details",
    responses={**UNAUTHORIZED, **FORBIDDEN, **NOT_FOUND, **CONFLICT},
)
async def update_patient(
    patient_id: Id, body: PatientUpdate, user: Therapist, db: Db
) -> PatientPublic:
    """The patient's own therapist only; 409 if the patient is archived, or if another of
    the caller's patients has the ``reference`` given. Fields left out keep their value.
    Audited as patient.update with the old and new value of each changed field."""
    patient = await patient_for(db, user, patient_id, write=True)
    changes = body.model_dump(exclude_unset=True)
    if changes.get("reference") not in (None, patient.reference):
        await require_free_reference(db, user, changes["reference"], patient.id)
    before = clinical_fields(patient)
    for name, value in changes.items():
        setattr(patient, name, value)
    old, new = audit.changes(before, clinical_fields(patient))
    if new:
        audit.record(
            db,
            audit.user_actor(user),
            "patient.update",
            "patient",
            patient.id,
            patient.id,
            old,
            new,
        )
        await db.commit()
    return PatientPublic.model_validate(patient)


@router.post(
    "/{patient_id}/archive",
    response_model=PatientArchived,
    summary="Archive a patient (treatment ended)",
    responses={**UNAUTHORIZED, **FORBIDDEN, **NOT_FOUND},
)
async def archive_patient(
    patient_id: Id, user: Therapist, db: Db, request: Request
) -> PatientArchived:
    """The patient's own therapist only. The record becomes read-only and leaves the
    default patient list (``GET /patients?archived=true`` lists it); their active
    prescriptions are withdrawn and their stations revoked at once: a connected station is
    cut off (code 4003) and its device stops streaming. Sessions a station has not uploaded
    yet stay on it. Archiving twice changes nothing. Audited as patient.archive, with a
    prescription.cancel and a station.revoke row for each (``because``: patient.archive)."""
    patient = await patient_for(db, user, patient_id, write=True, even_archived=True)
    if patient.archived_at is not None:
        return PatientArchived(
            **PatientPublic.model_validate(patient).model_dump(),
            stations_revoked=[],
            prescriptions_cancelled=[],
        )
    actor = audit.user_actor(user)
    patient.archived_at = utcnow()
    audit.record(
        db,
        actor,
        "patient.archive",
        "patient",
        patient.id,
        patient.id,
        {"archived": False},
        {"archived": True},
    )
    active = (
        (
            await db.execute(
                select(Prescription)
                .where(Prescription.patient_id == patient.id, Prescription.status == "active")
                .order_by(Prescription.id)
            )
        )
        .scalars()
        .all()
    )
    for prescription in active:
        cancel(db, user, prescription, because="patient.archive")
    stations = (
        (
            await db.execute(
                select(Station)
                .where(Station.patient_id == patient.id, Station.revoked.is_(False))
                .order_by(Station.id)
            )
        )
        .scalars()
        .all()
    )
    for station in stations:
        revoke(db, actor, station, because="patient.archive")
    await db.commit()
    await request.app.state.hub.recheck()
    return PatientArchived(
        **PatientPublic.model_validate(patient).model_dump(),
        stations_revoked=[s.id for s in stations],
        prescriptions_cancelled=[p.id for p in active],
    )


@router.post(
    "/{patient_id}/unarchive",
    response_model=PatientPublic,
    summary="Bring an archived patient back",
    responses={**UNAUTHORIZED, **FORBIDDEN, **NOT_FOUND},
)
async def unarchive_patient(patient_id: Id, user: Therapist, db: Db) -> PatientPublic:
    """The patient's own therapist only. The record can be changed again and is back in
    the default list; withdrawn prescriptions and revoked stations stay so (prescribe and
    provision anew). Unarchiving a current patient changes nothing. Audited as
    patient.unarchive."""
    patient = await patient_for(db, user, patient_id, write=True, even_archived=True)
    if patient.archived_at is not None:
        patient.archived_at = None
        audit.record(
            db,
            audit.user_actor(user),
            "patient.unarchive",
            "patient",
            patient.id,
            patient.id,
            {"archived": True},
            {"archived": False},
        )
        await db.commit()
    return PatientPublic.model_validate(patient)
