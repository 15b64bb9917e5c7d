"""A patient's record over a period, for the medical record: a PDF report a clinician signs
and a FHIR R4 bundle. Both are made from one ``sessions.record.PatientRecord`` and both are
audited as data leaving the system (``patient.export``, with the format, period and counts).

Who may: the patient's therapist, or an admin (read-only, as for sessions); anyone else
gets the 404 of a patient that does not exist. The period is whole days of one time zone
(``tz``, an IANA name; UTC if not given; read as the session list and the progress page read
it, ``server.routes.dates.zone`` and ``midnight``), both ends included, ending today at the latest
(:data:`AHEAD_OF_UTC`); it defaults to the :data:`DEFAULT_DAYS` days up to today. The PDF
prints every time on that zone's clock, and names it.
"""

from __future__ import annotations

import asyncio
import json
from datetime import date, timedelta
from typing import Annotated, Any
from zoneinfo import ZoneInfo

from fastapi import APIRouter, Query, Request, Response
from sqlalchemy import select

from server import audit
from server.deps import Db, Id, TherapistOrAdmin, patient_for
from server.facts import prescription_facts
from server.models import Patient, Prescription, Session, utcnow
from server.report import pdf
from server.routes.common import NOT_FOUND, UNAUTHORIZED, ascii_name, attachment, name_part
from server.routes.dates import (
    FIRST_DAY,
    LAST_DAY,
    TZ_EXAMPLE,
    iso_day,
    midnight,
    refuse,
    shown,
    zone,
)
from server.routes.progress import load_progress, session_rows
from sessions import fhir, record

router = APIRouter(prefix="/patients", tags=["reports"])

DEFAULT_DAYS = 90
"""The period a report covers when not told: this many days up to today, inclusive."""
AHEAD_OF_UTC = timedelta(hours=14)
"""How far a clock anywhere runs ahead of UTC (UTC+14, the Line Islands). A report ends on
today at the latest, and today is the therapist's own day: their page sends their local
date, which is UTC's or the next day; the latest day begun anywhere is never refused."""
_WORDS = {"since": "the first day (since)", "until": "the last day (until)"}
"""How a refusal names each parameter: as the patient page labels it, and as the API does."""

_DATE_DOC = "A date, YYYY-MM-DD (in the time zone tz), included in the period."
Since = Annotated[
    str | None,
    Query(
        description=f"First day of the period. {_DATE_DOC} Default: the {DEFAULT_DAYS} days "
        "that end on until.",
        examples=["2026-01-01"],
    ),
]
Until = Annotated[
    str | None,
    Query(
        description=f"Last day of the period. {_DATE_DOC} Today at the latest (the "
        "latest date anywhere: up to UTC+14; with tz, that zone's today). Default: today in tz.",
        examples=["2026-03-31"],
    ),
]
Tz = Annotated[
    str | None,
    Query(
        description="The IANA time zone whose calendar days since and until are, and whose "
        "clock the PDF prints times on, naming it (the patient's page sends the browser's "
        f"own). Default: UTC. Such as {TZ_EXAMPLE}, America/New_York or UTC.",
        examples=[TZ_EXAMPLE],
    ),
]


def _day(field: str, text: str | None) -> date | None:
    if text is None:
        return None
    day = iso_day(text)
    if day is None or not FIRST_DAY <= day <= LAST_DAY:
        raise refuse(
            field,
            f"{_WORDS[field]} must be a date written YYYY-MM-DD between {FIRST_DAY} and "
            f"{LAST_DAY}, such as 2026-01-31; got {shown(text)!r}",
        )
    return day


def period(since: str | None, until: str | None, tz: ZoneInfo | None = None) -> tuple[date, date]:
    """The first and last day of the period asked for, days of ``tz`` (a zone the client
    named) or, if it named none, of UTC; 422 with a sentence if it is not one."""
    first, last = _day("since", since), _day("until", until)
    now = utcnow()
    # With its zone named, a client's today is known; without, it may be any day begun.
    latest = now.astimezone(tz).date() if tz is not None else (now + AHEAD_OF_UTC).date()
    if last is not None and last > latest:
        # A signed report is a record of what happened: it never covers days still to come.
        raise refuse(
            "until",
            f"{_WORDS['until']}, {last}, is still to come: a report covers days that have "
            f"begun, up to today ({latest} at the latest)",
        )
    last = last or now.astimezone(tz or ZoneInfo("UTC")).date()
    first = first or last - timedelta(days=DEFAULT_DAYS - 1)
    if first > last:
        raise refuse(
            "since",
            f"{_WORDS['since']}, {first}, is after {_WORDS['until']}, {last}: the period "
            "must start on or before the day it ends",
        )
    return first, last


async def patient_record(
    request: Request, db: Db, patient: Patient, first: date, last: date, tz: ZoneInfo
) -> record.PatientRecord:
    """The patient's prescriptions in force and sessions started within the days of ``tz``,
    and their progress over those days (the same as the patient's page shows)."""
    since, until = midnight(first, tz), midnight(last + timedelta(days=1), tz)
    progress = await load_progress(request, db, patient, since=since, until=until)
    prescriptions = (
        await db.scalars(
            select(Prescription)
            .where(Prescription.patient_id == patient.id, Prescription.created_at < until)
            .order_by(Prescription.created_at, Prescription.id)
        )
    ).all()
    # A prescription withdrawn or completed before the period began is not in it.
    facts = {p.id: prescription_facts(p) for p in prescriptions}
    prescriptions = [p for p in prescriptions if (facts[p.id].ended_at or until) >= since]
    rows = await session_rows(
        request,
        db,
        [Session.patient_id == patient.id, Session.started_at >= since, Session.started_at < until],
        ordered=True,
    )
    kinds = {p.id: facts[p.id].exercise.value for p in prescriptions}
    rxs = [
        record.Prescription(
            id=p.id,
            title=facts[p.id].title or facts[p.id].exercise.value,
            exercise=facts[p.id].exercise.value,
            status=p.status,
            created_at=p.created_at,
            sessions_per_week=facts[p.id].sessions_per_week,
        )
        for p in prescriptions
    ]
    sessions = [
        record.Session(
            id=s.id,
            uuid=s.session_uuid,
            started_at=s.started_at,
            ended_at=s.ended_at,
            end_reason=s.end_reason,
            prescription_id=s.prescription_id,
            exercise=kinds.get(s.prescription_id or 0),
            summary=s.summary,
        )
        for s in rows
    ]
    return record.PatientRecord(
        patient=record.Patient(
            id=patient.id,
            display_name=patient.display_name,
            reference=patient.reference,
            birth_year=patient.birth_year,
            affected_side=patient.affected_side,
        ),
        since=since,
        until=until,
        zone=tz,
        generated_at=utcnow(),
        prescriptions=rxs,
        sessions=sessions,
        progress=progress,
    )


def disposition(patient: Patient, first: date, last: date, suffix: str) -> str:
    """``Content-Disposition`` for ``report-<reference or patient-id>-<first>-<last><suffix>``,
    safe in any file system: the reference in its own script (``Řehoř-12``), and for a
    client that reads only ``filename=``, in ASCII (``Rehor-12``; ``patient-<id>`` if none of
    it is)."""

    def name(who: str) -> str:
        return f"report-{who or f'patient-{patient.id}'}-{first:%Y%m%d}-{last:%Y%m%d}{suffix}"

    reference = patient.reference or ""
    return attachment(name(name_part(reference)), name(ascii_name(reference)))


async def _exported(
    db: Db, user: Any, patient: Patient, fmt: str, data: record.PatientRecord, **counts: int
) -> None:
    first, last = data.days
    what = {"format": fmt, "since": str(first), "until": str(last), "tz": data.zone.key, **counts}
    await audit.export(db, audit.user_actor(user), "patient", patient.id, patient.id, what)


def _attachment(body: bytes, media_type: str, disposition: str) -> Response:
    return Response(
        body,
        media_type=media_type,
        # A patient's record: kept by no cache on the way.
        headers={
            "Content-Disposition": disposition,
            "Cache-Control": "no-store",
        },
    )


@router.get(
    "/{patient_id}/report.pdf",
    response_class=Response,
    summary="The patient's report over a period (PDF, for the medical record)",
    responses={
        **UNAUTHORIZED,
        **NOT_FOUND,
        200: {"content": {"application/pdf": {}}, "description": "The report, to sign."},
    },
)
async def report_pdf(
    patient_id: Id,
    request: Request,
    db: Db,
    user: TherapistOrAdmin,
    since: Since = None,
    until: Until = None,
    tz: Tz = None,
) -> Response:
    """Patient, period, prescriptions, sessions done against prescribed, each session's
    range of motion per direction, torque and work, their trend, notable events (faults,
    holds, early ends) and a signature block. Audited as ``patient.export`` (format pdf)."""
    patient = await patient_for(db, user, patient_id)
    where = zone(tz)
    first, last = period(since, until, where if tz is not None else None)
    data = await patient_record(request, db, patient, first, last, where)
    body = await asyncio.to_thread(pdf, data)
    await _exported(db, user, patient, "pdf", data, sessions=len(data.sessions))
    return _attachment(body, "application/pdf", disposition(patient, first, last, ".pdf"))


@router.get(
    "/{patient_id}/fhir",
    response_class=Response,
    summary="The patient's sessions over a period as a FHIR R4 Bundle",
    responses={
        **UNAUTHORIZED,
        **NOT_FOUND,
        200: {
            "content": {fhir.MEDIA_TYPE: {}},
            "description": "A collection Bundle: the Patient and an Observation per measure "
            "per session (UCUM units, ankle body site with laterality).",
        },
    },
)
async def report_fhir(
    patient_id: Id,
    request: Request,
    db: Db,
    user: TherapistOrAdmin,
    since: Since = None,
    until: Until = None,
    tz: Tz = None,
) -> Response:
    """Codes: the project's session-measures code system (docs/measures.md; served at
    ``{fhir_base}/CodeSystem/session-measures``), SNOMED CT for
    the body site, laterality and a passive range-of-motion assessment. Audited as
    ``patient.export`` (format fhir)."""
    patient = await patient_for(db, user, patient_id)
    where = zone(tz)
    first, last = period(since, until, where if tz is not None else None)
    data = await patient_record(request, db, patient, first, last, where)
    base = request.app.state.settings.fhir_base

    def make() -> tuple[int, bytes]:
        bundle = fhir.bundle(base, data)
        return len(bundle["entry"]) - 1, json.dumps(bundle, ensure_ascii=False).encode()

    # In a thread, as the PDF is: a year of sessions (1,000) is a 9 MB bundle, over a second
    # of pure Python in which the event loop would otherwise answer nobody else.
    observations, body = await asyncio.to_thread(make)
    await _exported(
        db,
        user,
        patient,
        "fhir",
        data,
        sessions=len(data.sessions),
        observations=observations,
    )
    return _attachment(body, fhir.MEDIA_TYPE, disposition(patient, first, last, ".fhir.json"))
