"""Recorded sessions: list, detail with the clinician's summary, downloads in open formats.

Downloads are made from the stored recording on first request and kept beside it; each
answer carries the file's SHA-256 (``X-Content-SHA256`` and the ``ETag``), so a clinician or
a script can check what they got. Files are served with HTTP Range support, so a large
download resumes.
"""

from __future__ import annotations

import asyncio
from datetime import datetime
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import FileResponse
from pydantic import BaseModel, Field
from sqlalchemy import select

from server.deps import Db, TherapistOrAdmin, patient_for
from server.models import Patient, Session
from server.routes.common import NOT_FOUND, UNAUTHORIZED
from sessions.export import FILE_SUFFIX, FORMATS, MEDIA_TYPES, write_export
from sessions.recording import read

router = APIRouter(tags=["sessions"], responses=UNAUTHORIZED)

Format = Literal["csv", "parquet", "mcap", "json", "rec"]
DOWNLOAD_FORMATS: tuple[str, ...] = (*FORMATS, "rec")
"""``rec`` is the recording exactly as the station wrote and uploaded it."""


class SessionPublic(BaseModel):
    id: int
    session_uuid: str = Field(description="Chosen by the station; the upload's key.")
    station_id: int
    patient_id: int
    prescription_id: int | None
    started_at: datetime
    ended_at: datetime | None
    end_reason: str | None = Field(description="completed, stopped, fault or interrupted.")
    size_bytes: int = Field(description="Size of the uploaded recording, bytes.")
    sha256: str | None = Field(description="SHA-256 of the uploaded recording.")
    summary: dict[str, Any] | None = Field(
        description="ROM, torque, work, repetitions, tracking error and time in target "
        "(see sessions.summary.Summary)."
    )
    downloads: dict[str, str] = Field(description="Download URL per format.")


def session_public(row: Session) -> SessionPublic:
    return SessionPublic(
        id=row.id,
        session_uuid=row.session_uuid,
        station_id=row.station_id,
        patient_id=row.patient_id,
        prescription_id=row.prescription_id,
        started_at=row.started_at,
        ended_at=row.ended_at,
        end_reason=row.end_reason,
        size_bytes=row.size_bytes,
        sha256=row.sha256,
        summary=row.summary,
        downloads={f: f"/api/v1/sessions/{row.id}/download/{f}" for f in DOWNLOAD_FORMATS},
    )


async def _session_for(db: Db, user: TherapistOrAdmin, session_id: int) -> Session:
    row = await db.get(Session, session_id)
    if row is None:
        raise HTTPException(404, "session not found")
    try:
        await patient_for(db, user, row.patient_id)
    except HTTPException:
        raise HTTPException(404, "session not found") from None
    return row


@router.get("/sessions", response_model=list[SessionPublic], summary="List recorded sessions")
async def list_sessions(
    db: Db,
    user: TherapistOrAdmin,
    patient_id: int | None = None,
    station_id: int | None = None,
    prescription_id: int | None = None,
    since: Annotated[datetime | None, Query(description="Started at or after (ISO 8601).")] = None,
    until: Annotated[datetime | None, Query(description="Started before (ISO 8601).")] = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 100,
    offset: Annotated[int, Query(ge=0)] = 0,
) -> list[SessionPublic]:
    """Newest first. A therapist sees their own patients' sessions; an admin sees all."""
    q = select(Session).join(Patient, Patient.id == Session.patient_id)
    if user.role != "admin":
        q = q.where(Patient.therapist_id == user.id)
    if patient_id is not None:
        q = q.where(Session.patient_id == patient_id)
    if station_id is not None:
        q = q.where(Session.station_id == station_id)
    if prescription_id is not None:
        q = q.where(Session.prescription_id == prescription_id)
    if since is not None:
        q = q.where(Session.started_at >= since)
    if until is not None:
        q = q.where(Session.started_at < until)
    rows = await db.scalars(q.order_by(Session.started_at.desc()).limit(limit).offset(offset))
    return [session_public(r) for r in rows]


@router.get(
    "/sessions/{session_id}",
    response_model=SessionPublic,
    responses=NOT_FOUND,
    summary="One session with its summary",
)
async def get_session(session_id: int, db: Db, user: TherapistOrAdmin) -> SessionPublic:
    return session_public(await _session_for(db, user, session_id))


@router.get(
    "/sessions/{session_id}/download/{fmt}",
    response_class=FileResponse,
    responses={
        **NOT_FOUND,
        200: {
            "description": "csv (clinicians), parquet (analysis), mcap (Foxglove), json "
            "(summary and events) or rec (the recording as uploaded). The SHA-256 of the "
            "body is in X-Content-SHA256."
        },
    },
    summary="Download a session",
)
async def download(
    session_id: int, fmt: Format, request: Request, db: Db, user: TherapistOrAdmin
) -> FileResponse:
    row = await _session_for(db, user, session_id)
    if row.file_path is None:
        raise HTTPException(404, "session file not found")
    source = Path(row.file_path)
    name = f"session-{row.id}-{row.started_at:%Y%m%d-%H%M%S}"
    if fmt == "rec":
        path, digest, media = source, row.sha256 or "", "application/octet-stream"
        filename = f"{name}.rec"
    else:
        exports = Path(request.app.state.settings.data_dir) / "exports"
        exports.mkdir(parents=True, exist_ok=True)
        path = exports / f"{row.session_uuid}{FILE_SUFFIX[fmt]}"
        sidecar = path.with_name(path.name + ".sha256")
        if not (path.exists() and sidecar.exists()):
            digest = await asyncio.to_thread(_export, source, fmt, path)
            sidecar.write_text(digest)
        digest = sidecar.read_text().strip()
        media, filename = MEDIA_TYPES[fmt], f"{name}{FILE_SUFFIX[fmt]}"
    return FileResponse(
        path,
        media_type=media,
        filename=filename,
        headers={"X-Content-SHA256": digest, "ETag": f'"{digest}"'},
    )


def _export(source: Path, fmt: str, path: Path) -> str:
    return write_export(read(source), fmt, path)
