"""Reading the audit log. There is deliberately no route that changes it."""

from __future__ import annotations

import json
from typing import Annotated

from fastapi import APIRouter, Query
from sqlalchemy import ColumnElement, Text, cast, select
from sqlalchemy.ext.asyncio import AsyncSession

from server.deps import Db, Id, Offset, TherapistOrAdmin
from server.models import AuditEntry, Patient
from server.routes.common import UNAUTHORIZED
from server.schemas import AuditPublic
from sessions.text import Line

router = APIRouter(prefix="/audit", tags=["audit"])


@router.get(
    "",
    response_model=list[AuditPublic],
    summary="Audit log, newest first",
    responses=UNAUTHORIZED,
)
async def list_audit(
    user: TherapistOrAdmin,
    db: Db,
    patient_id: Annotated[Id | None, Query(description="Only this patient's rows.")] = None,
    action: Annotated[
        Line | None, Query(max_length=64, description="Only this action, e.g. patient.update.")
    ] = None,
    station_id: Annotated[
        Id | None,
        Query(description="Only rows about this station: its live commands, provisioning."),
    ] = None,
    request_id: Annotated[
        Line | None,
        Query(
            max_length=64,
            description="Only the rows of one live command: its request and its outcome.",
        ),
    ] = None,
    limit: Annotated[int, Query(ge=1, le=500, description="Rows per page.")] = 100,
    offset: Annotated[Offset, Query(description="Rows to skip (newest first).")] = 0,
) -> list[AuditPublic]:
    """An admin reads every row; a therapist the rows about their own patients (rows about
    accounts or other therapists' patients are not shown).

    A live command leaves two rows with the same ``request_id`` in ``new``: ``<kind>.request``
    when it is sent and its outcome, ``<kind>.accepted`` (a K/B change: ``impedance.change``),
    ``<kind>.refused`` or ``<kind>.unanswered``, with ``code``, ``field`` and ``text``;
    ``kind`` is ``impedance``, ``hold``, ``resume``, ``stop`` or ``start``."""
    query = select(AuditEntry).order_by(AuditEntry.id.desc()).limit(limit).offset(offset)
    if user.role != "admin":
        own = select(Patient.id).where(Patient.therapist_id == user.id)
        query = query.where(AuditEntry.patient_id.in_(own))
    if patient_id is not None:
        query = query.where(AuditEntry.patient_id == patient_id)
    if action is not None:
        query = query.where(AuditEntry.action == action)
    if station_id is not None:
        query = query.where(AuditEntry.entity == "station", AuditEntry.entity_id == str(station_id))
    if request_id is not None:
        query = query.where(_request_id_is(db, request_id))
    return [AuditPublic.model_validate(e) for e in (await db.execute(query)).scalars()]


def _request_id_is(db: AsyncSession, request_id: str) -> ColumnElement[bool]:
    """Rows whose ``new`` holds this ``request_id``.

    On PostgreSQL the row's JSON is searched as the text it is stored as, for the pair
    ``"request_id": "<id>"`` as the serializer (``json.dumps``) wrote it, and never parsed:
    any JSON operator (``->>``, ``->``, a cast to jsonb) unescapes every string of the row,
    and a single row holding ``\u0000`` anywhere, which PostgreSQL's text cannot hold, made
    every look-up a 500 for good (the log is append-only). Such rows were written before
    request_ids and a station's answers were held to ``sessions.wire``'s rules. The quotes
    make the match exact: inside a string value they would be escaped (``\"``)."""
    if db.get_bind().dialect.name == "postgresql":
        pair = f'"request_id": {json.dumps(request_id)}'
        return cast(AuditEntry.new, Text).contains(pair, autoescape=True)
    stored: ColumnElement[bool] = AuditEntry.new["request_id"].as_string() == request_id
    return stored
