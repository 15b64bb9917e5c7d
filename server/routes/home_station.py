"""What a home station asks with its own token: who it is, and what to run."""

from __future__ import annotations

from fastapi import APIRouter
from sqlalchemy import select

from server.deps import CurrentStation, Db
from server.models import Patient, Prescription, Session, utcnow
from server.routes.common import UNAUTHORIZED
from server.schemas import PrescriptionPublic, StationSelf
from sessions.home_progress import HomeProgress, home_progress

router = APIRouter(prefix="/station", tags=["station"])


@router.get(
    "/me",
    response_model=StationSelf,
    summary="The calling station and its patient",
    responses=UNAUTHORIZED,
)
async def station_me(station: CurrentStation, db: Db) -> StationSelf:
    """Station token only; user tokens are refused."""
    patient = await db.get(Patient, station.patient_id)
    assert patient is not None  # the foreign key guarantees it
    return StationSelf(
        id=station.id,
        name=station.name,
        patient_id=patient.id,
        patient_display_name=patient.display_name,
    )


@router.get(
    "/prescriptions",
    response_model=list[PrescriptionPublic],
    summary="The active prescriptions of the station's patient",
    responses=UNAUTHORIZED,
)
async def station_prescriptions(station: CurrentStation, db: Db) -> list[PrescriptionPublic]:
    """Station token only. Oldest first: the order the therapist prescribed them in."""
    query = (
        select(Prescription)
        .where(Prescription.patient_id == station.patient_id, Prescription.status == "active")
        .order_by(Prescription.id)
    )
    return [PrescriptionPublic.from_row(p) for p in (await db.execute(query)).scalars()]


@router.get(
    "/progress",
    response_model=HomeProgress,
    summary="The station's patient's own progress, for their page at home",
    responses=UNAUTHORIZED,
)
async def station_progress(station: CurrentStation, db: Db) -> HomeProgress:
    """Station token only. Sessions in the last 7 days, and how far the foot moves lately
    against the first week, from the stored summaries of the patient's uploaded sessions."""
    patient = await db.get(Patient, station.patient_id)
    assert patient is not None  # the foreign key guarantees it
    query = select(Session.started_at, Session.summary).where(
        Session.patient_id == station.patient_id, Session.upload_complete.is_(True)
    )
    rows = [(started, summary) for started, summary in (await db.execute(query)).all()]
    return home_progress(rows, patient.affected_side, utcnow())
