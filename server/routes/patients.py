"""Patients: each belongs to one therapist, who alone changes them."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, status
from sqlalchemy import select

from server import audit
from server.deps import Db, Therapist, TherapistOrAdmin, patient_for
from server.models import Patient
from server.routes.common import FORBIDDEN, NOT_FOUND, UNAUTHORIZED
from server.schemas import PatientCreate, PatientPublic, PatientUpdate

router = APIRouter(prefix="/patients", tags=["patients"])

_CLINICAL_FIELDS = ("display_name", "reference", "birth_year", "affected_side", "notes")


def clinical_fields(patient: Patient) -> dict[str, Any]:
    return {name: getattr(patient, name) for name in _CLINICAL_FIELDS}


@router.get(
    "",
    response_model=list[PatientPublic],
    summary="List patients",
    responses=UNAUTHORIZED,
)
async def list_patients(user: TherapistOrAdmin, db: Db) -> list[PatientPublic]:
    """A therapist sees their own patients; an admin sees all of them, read-only."""
    query = select(Patient).order_by(Patient.id)
    if user.role != "admin":
        query = query.where(Patient.therapist_id == user.id)
    return [PatientPublic.model_validate(p) for p in (await db.execute(query)).scalars()]


@router.post(
    "",
    response_model=PatientPublic,
    status_code=status.HTTP_201_CREATED,
    summary="Add a patient",
    responses={**UNAUTHORIZED, **FORBIDDEN},
)
async def create_patient(body: PatientCreate, user: Therapist, db: Db) -> PatientPublic:
    """Therapists only: the new patient is the caller's. Audited as patient.create."""
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
    await db.commit()
    return PatientPublic.model_validate(patient)


@router.get(
    "/{patient_id}",
    response_model=PatientPublic,
    summary="One patient",
    responses={**UNAUTHORIZED, **NOT_FOUND},
)
async def get_patient(patient_id: int, user: TherapistOrAdmin, db: Db) -> PatientPublic:
    """The patient's therapist, or any admin (read-only). Someone else's patient is a 404."""
    return PatientPublic.model_validate(await patient_for(db, user, patient_id))


@router.patch(
    "/{patient_id}",
    response_model=PatientPublic,
    summary="Change a patient's details",
    responses={**UNAUTHORIZED, **FORBIDDEN, **NOT_FOUND},
)
async def update_patient(
    patient_id: int, body: PatientUpdate, user: Therapist, db: Db
) -> PatientPublic:
    """The patient's own therapist only. Fields left out keep their value. Audited as
    patient.update with the old and new value of each changed field."""
    patient = await patient_for(db, user, patient_id, write=True)
    before = clinical_fields(patient)
    for name, value in body.model_dump(exclude_unset=True).items():
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
