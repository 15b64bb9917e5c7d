"""Resumable, idempotent session uploads from home stations (see ``station/uploader.py``).

Bytes are appended to ``data_dir/uploads/<session uuid>.part`` and reach the disk (fsync)
before the answer leaves, so an acknowledged byte is never lost and never asked for again; a
chunk is written whole or not at all (:func:`_append`: a full disk is a 507 and the upload
resumes where it was).
The first chunk must start with the recording's header, naming this station's patient and
this station (:func:`_check_recorder`). ``complete`` checks size, SHA-256 and the recording
itself (its header must name this station's patient, it must end with an end record, every
record's CRC must hold, its times must be those of one session, its summary must come out in
finite numbers), files the session under ``data_dir/sessions/`` with its summary, and
answers the same way if asked again, whatever step a crash stopped it at (see
:func:`upload_complete`). A recording refused there is discarded (:class:`Refused`); bytes
that are not the station's (a checksum mismatch: a fault of the transport or of the
server's storage, not of the recording) are discarded too, answered 409 ``upload_corrupted``
so that the station sends the same file again (:class:`Corrupted`). An upload no chunk has
reached for ``upload_expire_s`` is removed (:func:`expire_uploads`).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import fcntl
import logging
import os
import time
import uuid
import zlib
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Header, HTTPException, Request, Response, status
from fastapi.responses import JSONResponse
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError
from sqlalchemy import select
from sqlalchemy.ext.asyncio import AsyncSession

from server import audit, metrics
from server.deps import CurrentStation, Db
from server.models import Prescription, Session, Station, Upload, utcnow
from server.routes.common import UNAUTHORIZED, ErrorPublic, Responses, file_sha256
from server.routes.sessions import SessionPublic, session_public
from sessions.private import fsync_dir
from sessions.recording import (
    MAGIC,
    Recording,
    RecordingError,
    RecordType,
    check_prescription,
    check_session,
    decode,
    iter_records,
)
from sessions.recording import Header as RecordingHeader
from sessions.sentences import SHA256_HEX
from sessions.summary import Summary, summarize
from sessions.wire import error_text

log = logging.getLogger("ankle.server")
router = APIRouter(tags=["uploads"], responses=UNAUTHORIZED)
CHUNK_MAX = 1024 * 1024 + 64 * 1024
"""Largest PATCH body (bytes): the station's 1 MiB chunk and a margin. ``server.guard``
refuses a longer one before it is read."""


class UploadRefused(BaseModel):
    detail: str | list[dict[str, Any]] = Field(
        description="Why, in words; or, for a malformed request, the list of invalid fields."
    )


UNKNOWN: Responses = {
    404: {"model": ErrorPublic, "description": "No such upload (or another station's)."}
}
INVALID: Responses = {
    422: {
        "model": UploadRefused,
        "description": "A malformed request, or bytes that are not this station's recording "
        "(no header, another patient's, a checksum that does not match).",
    }
}


CORRUPTED_CODE = "upload_corrupted"
"""The ``code`` of a 409 to ``complete`` whose bytes on the server are not the station's
file (or are gone): the server discarded them; the station starts a new upload of the same
file (``Upload-Offset: 0``). Not a refusal of the recording: that is a 422."""
STORAGE_FULL_CODE = "storage_full"
"""The ``code`` of a 507 to a chunk: the server's storage is full; the upload is kept."""


class UploadAnswer(Exception):
    """An answer with a ``code`` for programs besides its sentence (:func:`upload_answer`)."""

    def __init__(
        self, status_code: int, detail: str, code: str, headers: dict[str, str] | None = None
    ) -> None:
        super().__init__(detail)
        self.status_code, self.detail, self.code = status_code, detail, code
        self.headers = headers or {}


async def upload_answer(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, UploadAnswer)
    return JSONResponse(
        {"detail": exc.detail, "code": exc.code}, status_code=exc.status_code, headers=exc.headers
    )


class CodedError(BaseModel):
    detail: str = Field(description="What happened and what to do, in a sentence.")
    code: str = Field(description="For programs: what the station does next.")


class UploadConflict(BaseModel):
    detail: str = Field(description="What happened and what to do, in a sentence.")
    code: str | None = Field(
        default=None, description=f"``{CORRUPTED_CODE}`` when the server discarded its bytes."
    )


STORAGE_FULL: Responses = {
    507: {
        "model": CodedError,
        "description": f"``{STORAGE_FULL_CODE}``: the server's storage is full; this chunk was "
        "not stored, what was acknowledged before it is kept, and the upload resumes from "
        "``Upload-Offset`` once space is freed.",
    }
}


class UploadComplete(BaseModel):
    model_config = ConfigDict(extra="forbid")
    size: int = Field(ge=len(MAGIC), description="Bytes in the whole file.")
    sha256: Annotated[str, AfterValidator(str.lower)] = Field(
        pattern=SHA256_HEX, title="SHA-256", description="SHA-256 of the file, hex (either case)."
    )


def _dirs(app: Any) -> tuple[Path, Path]:
    data = Path(app.state.settings.data_dir)
    uploads, sessions = data / "uploads", data / "sessions"
    uploads.mkdir(mode=0o700, parents=True, exist_ok=True)
    sessions.mkdir(mode=0o700, parents=True, exist_ok=True)
    return uploads, sessions


LOCK_STRIPES = 64
"""Lock files shared by all uploads (an upload takes the one its id hashes to), so that no
lock file is left behind per upload."""
LOCK_POLL_S = 0.01


class _Held:
    """One upload's asyncio lock and how many requests hold it or wait for it."""

    __slots__ = ("lock", "users")

    def __init__(self) -> None:
        self.lock = asyncio.Lock()
        self.users = 0


@asynccontextmanager
async def _lock(app: Any, key: str) -> AsyncIterator[None]:
    """One upload's appends, completion and expiry, one at a time: among this process's
    requests (an asyncio lock) and among every server process sharing the data directory (an
    exclusive flock on a stripe file in uploads/). The flock is polled, never waited for
    in a thread: the holder needs the thread pool to write its bytes. The asyncio lock is
    dropped from ``app.state.upload_locks`` when the last request holding or waiting for it
    is done, so that the map holds only the uploads being worked on now, not every id a
    station ever sent."""
    locks: dict[str, _Held] = app.state.__dict__.setdefault("upload_locks", {})
    held = locks.get(key)
    if held is None:
        held = locks[key] = _Held()
    held.users += 1
    try:
        async with held.lock:
            uploads, _ = _dirs(app)
            stripe = uploads / f".lock-{zlib.crc32(key.encode()) % LOCK_STRIPES:02d}"
            fd = os.open(stripe, os.O_RDWR | os.O_CREAT, 0o600)
            try:
                while True:
                    try:
                        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                        break
                    except BlockingIOError:
                        await asyncio.sleep(LOCK_POLL_S)
                yield
            finally:
                os.close(fd)  # releases the flock
    finally:
        held.users -= 1
        if held.users == 0:
            del locks[key]


class _Lost(Exception):
    """The ``.part`` file holds fewer bytes than its upload acknowledged (``size``)."""

    def __init__(self, size: int) -> None:
        super().__init__(size)
        self.size = size


def _append(path: Path, offset: int, data: bytes) -> None:
    """Write ``data`` at ``offset`` whole, or leave the file as it was at ``offset``.

    ``os.pwrite`` may write part of a chunk (a disk nearly full): it is called again for
    the rest, and any error (ENOSPC, EDQUOT) cuts the file back to ``offset``, so that the
    upload's offset, which only a whole chunk advances, is always what the file holds. A
    file shorter than ``offset`` is :class:`_Lost`: extending it would make up bytes."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o600)
    try:
        size = os.fstat(fd).st_size
        if size < offset:
            raise _Lost(size)
        os.ftruncate(fd, offset)  # drop bytes a crash left past the acknowledged length
        try:
            view, done = memoryview(data), 0
            while done < len(data):
                wrote = os.pwrite(fd, view[done:], offset + done)
                if wrote <= 0:  # no error and no progress: no room
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                done += wrote
            os.fsync(fd)
        except BaseException:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, offset)
                os.fsync(fd)
            raise
    finally:
        os.close(fd)


def _restore(part: Path, final: Path, size: int) -> None:
    """Put an upload's bytes back where ``complete`` and ``PATCH`` read them: a server of
    an earlier version moved ``part`` to ``final`` before writing the session's row, and a
    crash between the two left the bytes there; and cut ``part`` to the ``size`` bytes
    acknowledged (what a crash between writing a chunk and its row left past them)."""
    if not part.exists() and final.exists():
        os.replace(final, part)
        fsync_dir(part.parent)
    with contextlib.suppress(FileNotFoundError), part.open("r+b") as f:
        if os.fstat(f.fileno()).st_size > size:
            f.truncate(size)
            os.fsync(f.fileno())


def _file(part: Path, final: Path) -> None:
    """``final`` becomes another name of ``part``'s bytes, on disk before the session's row
    names it. A link, not a move: until that row is committed the upload's bytes stay
    where a retried ``complete`` reads them."""
    final.unlink(missing_ok=True)  # a link a crash left before the row was written
    os.link(part, final)
    fsync_dir(final.parent)


def _discard(*paths: Path) -> None:
    for path in paths:
        path.unlink(missing_ok=True)


@router.head(
    "/uploads/{session_id}",
    summary="How much of an upload the server holds",
    responses={**UNKNOWN, **INVALID},
)
async def upload_state(session_id: uuid.UUID, station: CurrentStation, db: Db) -> Response:
    """``Upload-Offset``: bytes held; ``Upload-Complete: 1`` once the session is filed."""
    sid = str(session_id)
    done = await db.scalar(select(Session).where(Session.session_uuid == sid))
    if done is not None:
        if not await _sends_for(db, done.station_id, station):
            raise HTTPException(404, "no such upload")
        return Response(headers={"Upload-Offset": str(done.size_bytes), "Upload-Complete": "1"})
    up = await db.get(Upload, sid)
    if up is None or not await _sends_for(db, up.station_id, station):
        raise HTTPException(404, "no such upload")
    return Response(headers={"Upload-Offset": str(up.received_bytes), "Upload-Complete": "0"})


@router.patch(
    "/uploads/{session_id}",
    status_code=204,
    summary="Append bytes to an upload",
    responses={
        409: {"description": "Wrong Upload-Offset; the header has the right one."},
        413: {"model": ErrorPublic, "description": "The chunk or the session is too large."},
        **UNKNOWN,
        **INVALID,
        **STORAGE_FULL,
    },
)
async def upload_append(
    session_id: uuid.UUID,
    request: Request,
    station: CurrentStation,
    db: Db,
    upload_offset: Annotated[int, Header(ge=0, description="Where these bytes go.")],
) -> Response:
    sid = str(session_id)
    data = await request.body()  # at most CHUNK_MAX: server.guard refused anything longer
    if len(data) > CHUNK_MAX:
        raise HTTPException(413, f"a chunk may be at most {CHUNK_MAX} bytes")
    uploads, sessions_dir = _dirs(request.app)
    part = uploads / f"{sid}.part"
    async with _lock(request.app, sid):
        done = await db.scalar(select(Session).where(Session.session_uuid == sid))
        if done is not None:
            # Another patient's station is told what HEAD tells it: nothing of this upload.
            if not await _sends_for(db, done.station_id, station):
                raise HTTPException(404, "no such upload")
            raise HTTPException(409, "this session is already complete")
        up = await db.get(Upload, sid)
        if up is not None and not await _take_over(db, up, station):
            raise HTTPException(404, "no such upload")
        held = up.received_bytes if up else 0
        if upload_offset != held:
            raise HTTPException(
                409, f"the server holds {held} bytes", headers={"Upload-Offset": str(held)}
            )
        if held == 0:
            header = _check_start(data, station.patient_id, sid)
            await _check_recorder(db, header.station_id, station)
        limit = request.app.state.settings.upload_max_bytes
        if held + len(data) > limit:
            raise HTTPException(413, f"a session may be at most {limit} bytes")
        try:
            if up is not None:
                await asyncio.to_thread(_restore, part, sessions_dir / f"{sid}.rec", held)
            await asyncio.to_thread(_append, part, held, data)
        except _Lost as lost:
            assert up is not None  # with no row, nothing was acknowledged: held is 0
            metrics.upload_fault("lost")
            log.error(
                "upload %s: the server holds %d of the %d bytes it acknowledged; the upload "
                "resumes from there",
                sid,
                lost.size,
                held,
            )
            up.received_bytes = lost.size
            await db.commit()
            raise HTTPException(
                409,
                f"the server holds {lost.size} bytes",
                headers={"Upload-Offset": str(lost.size)},
            ) from None
        except OSError as exc:
            if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
                raise
            metrics.upload_fault("storage_full")
            log.error(
                "upload %s: the server's storage is full (%s): the chunk of %d bytes at %d "
                "was not stored; the upload is kept at %d bytes",
                sid,
                exc.strerror,
                len(data),
                held,
                held,
            )
            raise UploadAnswer(
                507,
                f"the server's storage is full: this chunk was not stored; the {held} bytes "
                "received before it are kept, and the upload resumes from there once an "
                "administrator has freed space",
                STORAGE_FULL_CODE,
                {"Upload-Offset": str(held)},
            ) from None
        if up is None:
            up = Upload(session_uuid=sid, station_id=station.id, received_bytes=0)
            db.add(up)
        up.received_bytes = held + len(data)
        await db.commit()
        return Response(status_code=204, headers={"Upload-Offset": str(up.received_bytes)})


def _check_start(data: bytes, patient_id: int, sid: str) -> RecordingHeader:
    """The first chunk must hold the header: a station uploads only its own patient's."""
    try:
        records, _, _ = iter_records(data)
    except RecordingError as exc:
        raise HTTPException(422, f"not a session recording: {exc}") from None
    if not records or records[0][0] != RecordType.HEADER:
        raise HTTPException(422, "the first chunk must contain the recording's header record")
    try:
        header = RecordingHeader.model_validate_json(records[0][1])
        check_prescription(header)
    except ValueError as exc:
        raise HTTPException(422, f"the header record is not valid: {error_text(exc)}") from None
    if header.session_id != sid:
        raise HTTPException(422, "the header's session_id differs from the upload's")
    if header.patient_id != patient_id:
        raise HTTPException(422, "the recording is for another patient than this station's")
    return header


async def _sends_for(db: AsyncSession, other: int, station: Station) -> bool:
    """Whether ``station`` may send what station ``other`` recorded or began to upload: it is
    that station, or ``other`` is a revoked station of the same patient (this one's
    predecessor: a station provisioned again sends, under its new token, what it recorded
    and began to upload under its old one, which nothing else can send any more). The one
    rule for a recording's header (:func:`_check_recorder`), an upload under way
    (:func:`_take_over`) and a session already filed."""
    if other == station.id:
        return True
    before = await db.get(Station, other)
    return before is not None and before.revoked and before.patient_id == station.patient_id


async def _take_over(db: AsyncSession, up: Upload, station: Station) -> bool:
    """Whether ``station`` may go on with upload ``up``: its own, or its revoked
    predecessor's (:func:`_sends_for`), which becomes this station's (saved with the
    request's change). Another station of the same patient, not revoked, keeps its own."""
    if up.station_id == station.id:
        return True
    if not await _sends_for(db, up.station_id, station):
        return False
    log.info(
        "upload %s of revoked station %d taken over by station %d",
        up.session_uuid,
        up.station_id,
        station.id,
    )
    up.station_id = station.id
    return True


async def _check_recorder(db: AsyncSession, named: int, station: Station) -> None:
    """A station uploads only what it recorded: the header names this station, or 0 (it
    recorded before it first connected and learnt its id), or its revoked predecessor
    (:func:`_sends_for`). The session is filed under the uploading station; a header naming
    another would contradict it in every download."""
    if named == 0 or await _sends_for(db, named, station):
        return
    raise HTTPException(
        422,
        f"the recording names station {named}, but this upload comes from station "
        f"{station.id}: a station uploads only the sessions it recorded",
    )


@router.post(
    "/uploads/{session_id}/complete",
    response_model=SessionPublic,
    summary="Finish an upload: check it and file the session",
    responses={
        201: {"model": SessionPublic, "description": "Filed now (200: filed before, the same)."},
        409: {
            "model": UploadConflict,
            "description": "Not all bytes are there yet (``Upload-Offset`` says how many "
            f"are); or ``{CORRUPTED_CODE}``: the server's bytes are not the file whose size "
            "and SHA-256 were sent (or are gone), so it discarded them: start a new upload of "
            "the same file (``Upload-Offset: 0``); or this session was filed with other "
            "content (no ``Upload-Offset``).",
        },
        **UNKNOWN,
        **INVALID,
    },
)
async def upload_complete(
    session_id: uuid.UUID,
    body: UploadComplete,
    request: Request,
    response: Response,
    station: CurrentStation,
    db: Db,
) -> SessionPublic:
    """Each step leaves what a crash there needs to be done again, and each is done again
    safely: the checks only read the ``.part`` file; it is linked (not moved) to
    ``sessions/``, on disk before the row names it; the row is committed (the upload's row
    deleted in the same transaction); only then is the ``.part`` name dropped. A retry
    finds either no session row (the bytes still in ``.part``: checked and linked again)
    or the session filed (answered 200, a ``.part`` left behind removed)."""
    sid = str(session_id)
    uploads, sessions_dir = _dirs(request.app)
    part, final = uploads / f"{sid}.part", sessions_dir / f"{sid}.rec"
    async with _lock(request.app, sid):
        done = await db.scalar(select(Session).where(Session.session_uuid == sid))
        if done is not None:
            if not await _sends_for(db, done.station_id, station):
                raise HTTPException(404, "no such upload")
            if done.sha256 != body.sha256 or done.size_bytes != body.size:
                raise HTTPException(409, "this session was filed with other content")
            part.unlink(missing_ok=True)  # a crash after the commit left the upload's name
            return session_public(done)
        up = await db.get(Upload, sid)
        if up is None or not await _take_over(db, up, station):
            raise HTTPException(404, "no such upload")
        if up.received_bytes != body.size:
            raise HTTPException(
                409,
                f"the server holds {up.received_bytes} of {body.size} bytes",
                headers={"Upload-Offset": str(up.received_bytes)},
            )
        try:
            await asyncio.to_thread(_restore, part, final, body.size)
            rec, summary, digest = await asyncio.to_thread(_checked, part, body.sha256)
        except (Refused, Corrupted, FileNotFoundError) as exc:
            # The station's whole file is wrong, or the server's copy is not the station's
            # file: keeping it helps nobody, and the station can only send a file from the
            # start. Row first: a crash before the files go leaves them to the expiry.
            await db.delete(up)
            await db.commit()
            await asyncio.to_thread(_discard, part, final)
            if isinstance(exc, Refused):
                raise HTTPException(422, str(exc)) from None
            raise _corrupted(sid, exc) from None
        end = rec.end
        assert end is not None  # _checked refuses a recording without one
        prescription = await db.get(Prescription, rec.header.prescription_id)
        row = Session(
            session_uuid=sid,
            station_id=station.id,
            patient_id=station.patient_id,
            prescription_id=(
                prescription.id
                if prescription is not None and prescription.patient_id == station.patient_id
                else None
            ),
            started_at=datetime.fromtimestamp(rec.header.started_at, UTC),
            ended_at=datetime.fromtimestamp(end.ended_at, UTC),
            end_reason=end.reason,
            size_bytes=body.size,
            sha256=digest,
            summary=summary.model_dump(mode="json"),
            file_path=str(final.relative_to(request.app.state.settings.data_dir)),
            upload_complete=True,
        )
        # Filed only now that every check has passed. If the row cannot be written (a full
        # disk, the database away), both names stay: a retry links again and writes it.
        await asyncio.to_thread(_file, part, final)
        db.add(row)
        await db.delete(up)
        await db.flush()
        audit.record(
            db,
            audit.station_actor(station),
            "session.upload",
            "session",
            row.id,
            station.patient_id,
            None,
            {"session_uuid": sid, "size_bytes": body.size, "sha256": digest},
        )
        await db.commit()
        part.unlink(missing_ok=True)
        response.status_code = status.HTTP_201_CREATED
        return session_public(row)


class Refused(Exception):
    """A recording refused at ``complete``, in words: the upload is discarded."""


class Corrupted(Exception):
    """The server's bytes do not hash to the station's SHA-256 (their digest): the upload
    is discarded and the station sends its file again (:data:`CORRUPTED_CODE`)."""


def _corrupted(sid: str, exc: Exception) -> UploadAnswer:
    """The 409 for bytes that are not the station's file, or are gone, logged as the
    server's error: every byte was acknowledged as stored, so the transport or the storage
    failed."""
    if isinstance(exc, Corrupted):
        metrics.upload_fault("corrupted")
        log.error(
            "upload %s: the bytes received hash to %s, not to the station's SHA-256; "
            "discarded, the station sends the session again",
            sid,
            exc,
        )
        said = (
            f"the bytes the server received hash to {exc}, not to the SHA-256 sent: they "
            "were damaged on the way or on the server's storage, not in the recording"
        )
    else:
        metrics.upload_fault("lost")
        log.error("upload %s: its bytes are gone from the server's storage", sid)
        said = "the server no longer has the bytes it received (its storage lost them)"
    return UploadAnswer(
        409,
        f"{said}; the server discarded its copy: upload the same file again from its first byte",
        CORRUPTED_CODE,
        {"Upload-Offset": "0"},
    )


def _checked(part: Path, sha256: str) -> tuple[Recording, Summary, str]:
    """The recording in ``part``, its summary and its SHA-256, or :class:`Refused` saying
    why not (:class:`Corrupted`: the bytes are not the station's file). Every check
    ``complete`` makes of the bytes is here, so that every refusal discards the upload the
    same way. Reading the file may fail (an ``OSError``: the server's, retried, or
    ``FileNotFoundError``: the bytes are gone, and sent again); what follows reads only the
    bytes, so anything else that fails there is an error of this recording, refused rather
    than answered 500 to a station that would send the same bytes for a day."""
    digest = file_sha256(part)
    if digest != sha256:
        # Start over rather than keep bytes that do not match the station's file.
        raise Corrupted(digest)
    data = part.read_bytes()
    try:
        rec = decode(data)
        if rec.damaged or rec.end is None:
            raise RecordingError("it is cut off: it has no end record")
        check_session(rec)
    except ValueError as exc:  # RecordingError, or a record's ValidationError
        raise Refused(
            f"not a valid recording: {error_text(exc, 300)}; upload the session again"
        ) from None
    except MemoryError:
        raise
    except Exception as exc:
        raise _unexpected(part, "read", exc) from None
    try:
        summary = summarize(rec)
    except ValidationError as exc:  # a value past what a float holds: no clinician's number
        raise Refused(
            f"not a valid recording: its values give no finite summary ({exc.title}."
            f"{error_text(exc, 300)}); upload the session again"
        ) from None
    except MemoryError:
        raise
    except Exception as exc:
        raise _unexpected(part, "summarise", exc) from None
    return rec, summary, digest


def _unexpected(part: Path, doing: str, exc: Exception) -> Refused:
    """A recording the server failed to read or summarise for a reason no check names: a
    fault of the server's code to be fixed (logged with its traceback), but the same bytes
    would fail the same way at every retry, so the recording is refused like any other."""
    log.error("upload %s: could not %s the recording", part.stem, doing, exc_info=exc)
    return Refused(
        f"not a valid recording: the server could not {doing} it "
        f"({type(exc).__name__}: {error_text(exc, 200)}); upload the session again"
    )


EXPIRE_PASS_MAX_S = 3600.0
"""The longest time between two passes of :func:`expire_uploads`, seconds."""


async def expire_uploads(app: Any) -> int:
    """Remove the incomplete uploads no chunk has reached for ``upload_expire_s`` (row and
    bytes, and the link to them in ``sessions/`` a crash in ``complete`` left before the
    session's row), and any ``.part`` file as old that no row names (a crash between writing
    the bytes and the row). Each under its upload's lock, looked at again there: a chunk
    that arrived meanwhile keeps it. Returns how many were removed."""
    settings = app.state.settings
    uploads, sessions_dir = _dirs(app)
    cutoff = utcnow() - timedelta(seconds=settings.upload_expire_s)
    removed = 0
    async with app.state.sessionmaker() as db:
        stale = list(
            await db.scalars(select(Upload.session_uuid).where(Upload.updated_at < cutoff))
        )
        known = set(await db.scalars(select(Upload.session_uuid)))
    for sid in stale:
        async with _lock(app, sid), app.state.sessionmaker() as db:
            up = await db.get(Upload, sid)
            if up is None or up.updated_at >= cutoff:
                continue
            filed = await db.scalar(select(Session.id).where(Session.session_uuid == sid))
            await db.delete(up)
            await db.commit()
            (uploads / f"{sid}.part").unlink(missing_ok=True)
            if filed is None:
                (sessions_dir / f"{sid}.rec").unlink(missing_ok=True)
            removed += 1
            log.info("upload %s expired: no chunk for %g s", sid, settings.upload_expire_s)
    old = time.time() - settings.upload_expire_s
    for part in uploads.glob("*.part"):
        sid = part.stem
        if sid in known:
            continue
        async with _lock(app, sid), app.state.sessionmaker() as db:
            if await db.get(Upload, sid) is None and _older(part, old):
                part.unlink(missing_ok=True)
                removed += 1
    return removed


def _older(path: Path, when: float) -> bool:
    try:
        return path.stat().st_mtime < when
    except FileNotFoundError:
        return False


async def expire_uploads_forever(app: Any) -> None:
    """:func:`expire_uploads` now and every ``min(upload_expire_s / 4, 1 hour)``: every
    server process runs its own (the locks keep them apart)."""
    period = min(app.state.settings.upload_expire_s / 4, EXPIRE_PASS_MAX_S)
    while True:
        try:
            await expire_uploads(app)
        except Exception:  # the database is away: the next pass tries again
            log.exception("removing abandoned uploads failed")
        await asyncio.sleep(period)
