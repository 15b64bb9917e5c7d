"""Recorded sessions: list, detail with the clinician's summary, downloads in open formats,
and the whole time series decimated for charts.

Downloads are made from the stored recording on first request and kept, under the SHA-256
of the recording they were made from; a recording that is no longer the file the station
uploaded (its size and SHA-256 at the upload's completion) is refused with a 500. Each
answer carries the file's SHA-256 (``X-Content-SHA256`` and the ``ETag``), so a clinician or
a script can check what they got. Files are served with HTTP Range support, so a large
download resumes. Each download is audited as ``patient.export`` (entity ``session``, with
its format) and sent with ``Cache-Control: no-store``, as the patient's report is.

The chart series is computed from the recording on every request and kept nowhere: a 3 min
session at 100 Hz reads and decimates in milliseconds, and nothing can go stale.
"""

from __future__ import annotations

import asyncio
import logging
import os
import re
from datetime import datetime
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import FileResponse, PlainTextResponse, Response
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy import select
from starlette.responses import MalformedRangeHeader, RangeNotSatisfiable

from device.protocol.messages import DeviceMode
from server import audit
from server.deps import Db, Id, Offset, TherapistOrAdmin, record_for
from server.models import Patient, Session
from server.routes.common import NOT_FOUND, UNAUTHORIZED, ErrorPublic, attachment, file_sha256
from server.routes.dates import Tz, day_or_time, refuse, zone
from sessions.export import FILE_SUFFIX, FORMATS, MEDIA_TYPES
from sessions.prescription import AXIS_INDEX, ROTATION_AXES
from sessions.recording import Recording, read
from sessions.summary import Summary, prescribed_axes, summarize

log = logging.getLogger(__name__)

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
        description="ROM, torque, work, repetitions, tracking error and time in target, and "
        "the metrics that fit the exercise (see sessions.summary.Summary)."
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
    return await record_for(db, user, Session, session_id, "session")


@router.get("/sessions", response_model=list[SessionPublic], summary="List recorded sessions")
async def list_sessions(
    db: Db,
    user: TherapistOrAdmin,
    patient_id: Id | None = None,
    station_id: Id | None = None,
    prescription_id: Id | None = None,
    since: Annotated[
        str | None,
        Query(
            description="Started on or after this day (YYYY-MM-DD, of tz) or at or after this "
            "time (ISO 8601; tz's clock, UTC without tz, if it names no offset)."
        ),
    ] = None,
    until: Annotated[
        str | None,
        Query(
            description="Started up to and including this day (YYYY-MM-DD, of tz), or before "
            "this time; days from 1900-01-01 to 9998-12-31."
        ),
    ] = None,
    tz: Tz = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 100,
    offset: Annotated[Offset, Query()] = 0,
) -> list[SessionPublic]:
    """Newest first. A therapist sees their own patients' sessions; an admin sees all.
    ``since`` and ``until`` are read as the progress page, the report and the FHIR bundle
    read them (``server.routes.dates.day_or_time``): a day ``until`` names is included, and
    the days are those of ``tz`` if the caller names it."""
    where = zone(tz)
    start = day_or_time("since", since, tz=where)
    end = day_or_time("until", until, end_of_day=True, tz=where)
    if start is not None and end is not None and start >= end:
        raise refuse("since", f"since ({since}) must be before until ({until})")
    q = select(Session).join(Patient, Patient.id == Session.patient_id)
    if user.role != "admin":
        q = q.where(Patient.therapist_id == user.id)
    if patient_id is not None:
        q = q.where(Session.patient_id == patient_id)
    if station_id is not None:
        q = q.where(Session.station_id == station_id)
    if prescription_id is not None:
        q = q.where(Session.prescription_id == prescription_id)
    if start is not None:
        q = q.where(Session.started_at >= start)
    if end is not None:
        q = q.where(Session.started_at < end)
    rows = await db.scalars(q.order_by(Session.started_at.desc()).limit(limit).offset(offset))
    return [session_public(r) for r in rows]


async def with_metrics(request: Request, db: Db, rows: list[Session]) -> list[Session]:
    """``rows``, each summary holding the metrics that fit its exercise (sessions.metrics).

    A summary stored before the metrics existed is computed again from the session's
    recording and stored, once; a session whose file is gone keeps the summary it has."""
    stale = [r for r in rows if r.summary is not None and r.summary.get("metrics") is None]
    for row in stale:
        try:
            source, _ = await intact_recording(request, row)
        except HTTPException:
            continue
        summary = await asyncio.to_thread(_summarize_file, source)
        row.summary = summary.model_dump(mode="json")
    if stale:
        await db.commit()
    return rows


@router.get(
    "/sessions/{session_id}",
    response_model=SessionPublic,
    responses=NOT_FOUND,
    summary="One session with its summary",
)
async def get_session(
    session_id: Id, request: Request, db: Db, user: TherapistOrAdmin
) -> SessionPublic:
    """The summary holds the metrics that fit the exercise; for a session stored before
    they existed, they are computed from its recording on first request."""
    (row,) = await with_metrics(request, db, [await _session_for(db, user, session_id)])
    return session_public(row)


_RANGE_TEXT = {"text/plain": {"schema": {"type": "string"}}}
_DOWNLOAD: dict[str, Any] = {
    "response_class": FileResponse,
    "responses": {
        **NOT_FOUND,
        200: {
            "description": "csv (clinicians), parquet (analysis), mcap (Foxglove), json "
            "(summary and events) or rec (the recording as uploaded). The SHA-256 of the "
            "body is in X-Content-SHA256. HEAD: the same headers, no body."
        },
        206: {
            "description": "The part a `Range: bytes=…` header asked for (one range, or "
            "several as multipart/byteranges), with Content-Range; X-Content-SHA256 is the "
            "whole file's."
        },
        400: {
            "description": "A Range header that is not one (not bytes, or any part of it "
            "not first-last, first- or -suffix), in plain text. A range that ends before it "
            "starts (bytes=5-2) is not refused: the header is ignored and the whole file "
            "sent (200), as RFC 9110 allows.",
            "content": _RANGE_TEXT,
        },
        416: {
            "description": "A Range that starts past the end of the file, or asks for more "
            "than 16 ranges, with Content-Range: bytes */<size>.",
            "content": _RANGE_TEXT,
        },
        500: {
            "model": ErrorPublic,
            "description": "The stored recording is damaged (not the file the station "
            "uploaded): the server's operator must restore it from backup.",
        },
    },
}


@router.get("/sessions/{session_id}/download/{fmt}", summary="Download a session", **_DOWNLOAD)
@router.head(
    "/sessions/{session_id}/download/{fmt}",
    summary="A session's download, headers only",
    **_DOWNLOAD,
)
async def download(
    session_id: Id, fmt: Format, request: Request, db: Db, user: TherapistOrAdmin
) -> Response:
    """Audited as data leaving the system (``patient.export``, entity ``session``, with the
    format), as the patient's report is, and kept by no cache on the way."""
    row = await _session_for(db, user, session_id)
    source, source_digest = await intact_recording(request, row)
    name = f"session-{row.id}-{row.started_at:%Y%m%d-%H%M%S}"
    if fmt == "rec":
        path, digest, media = source, source_digest, "application/octet-stream"
        filename = f"{name}.rec"
    else:
        path, digest = await _cached_export(request, row, fmt, source, source_digest)
        media, filename = MEDIA_TYPES[fmt], f"{name}{FILE_SUFFIX[fmt]}"
    response = _Download(
        path,
        media_type=media,
        headers={
            "Content-Disposition": attachment(filename),
            "X-Content-SHA256": digest,
            "ETag": f'"{digest}"',
            "Cache-Control": "no-store",
        },
        stat_result=await asyncio.to_thread(os.stat, path),
    )
    refused = _range_refused(request, response)
    if refused is not None:
        return refused
    if _sends_data(request, response):
        await exported(db, user, row, fmt)
    return response


RANGES_MAX = 16
"""Ranges one request may ask for. A resumed download asks for one, a reader of parts a few;
each is a part of its own in a multipart answer. Starlette serves up to 100 and, past that,
ignores the header and sends the whole file (200): 300 one-byte ranges were a full
download. Past this many the request is refused (416, as RFC 9110 has it for an excessive
request of small ranges), and nothing is sent."""
_RANGE_SPEC = re.compile(r"\d{1,30}-\d{0,30}|-\d{1,30}")
"""One part of a byte Range (RFC 9110, 14.1.2): first-last, first- (to the end) or -suffix
(the last so many bytes). A position has at most 30 digits: a larger one is past any file
all the same, and Python reads no integer of more than 4,300 digits."""
NOT_A_RANGE = (
    "Range header: {part!r} is not a byte range; each part of bytes=... must be first-last, "
    "first- or -suffix, separated by commas"
)


_INT_RANGE = re.compile(r"\s*(\d{1,30})-(\d{1,30})\s*")


class _Download(FileResponse):
    """A file whose Range is ignored, and the whole file sent (200), when one of its parts
    ends before it starts (``bytes=5-2``): RFC 9110 (14.1.1, 14.2) makes such a
    ranges-specifier invalid and lets the server ignore it. Starlette answered it 400,
    "start must be less than end", the sentence it also has for a range it cannot read."""

    @classmethod
    def _parse_range_header(cls, http_range: str, file_size: int) -> list[tuple[int, int]]:
        unit, _, ranges = http_range.partition("=")
        if unit.strip().lower() == "bytes":
            for part in ranges.split(","):
                spec = _INT_RANGE.fullmatch(part)
                if spec is not None and int(spec[2]) < int(spec[1]):
                    return []  # Starlette's "no range": the whole file
        ranges_asked: list[tuple[int, int]] = super()._parse_range_header(http_range, file_size)
        return ranges_asked


def _range_refused(request: Request, response: FileResponse) -> Response | None:
    """The answer to a Range header that Starlette would read leniently, or None.

    Starlette skips a part of a Range it cannot read (``bytes=0-1,abc`` is ``bytes=0-1``),
    and ignores a header of more than 100 parts, sending the whole file; the answer then
    was not what was asked. A part that is not a byte range is a 400, as a header that is
    not one at all is (``bytes=abc``), and more than ``RANGES_MAX`` ranges a 416. Empty
    parts are allowed, as in any HTTP list (RFC 9110, 5.6.1). Only a Range that would be
    used is judged: one whose If-Range no longer matches asks for the whole file."""
    http_range = request.headers.get("range")
    if http_range is None or response.stat_result is None:
        return None
    if_range = request.headers.get("if-range")
    should_use = getattr(response, "_should_use_range", None)
    if if_range is not None and should_use is not None and not should_use(if_range):
        return None
    unit, _, ranges = http_range.partition("=")
    if unit.strip().lower() != "bytes":
        return None  # Starlette's own 400
    parts = [part.strip() for part in ranges.split(",")]
    for part in parts:
        if part and not _RANGE_SPEC.fullmatch(part):
            return PlainTextResponse(NOT_A_RANGE.format(part=part[:40]), status_code=400)
    asked = sum(1 for part in parts if part)
    if asked > RANGES_MAX:
        return PlainTextResponse(
            f"Range header: {asked} ranges; at most {RANGES_MAX} may be asked at once",
            status_code=416,
            headers={"Content-Range": f"bytes */{response.stat_result.st_size}"},
        )
    return None


def _sends_data(request: Request, response: FileResponse) -> bool:
    """Whether ``response`` will send any of its file: a Range it cannot serve is answered
    400 (malformed) or 416 (past the end) with none, and is not an export. Asks Starlette's
    own Range reading, so that the answer and the audit cannot disagree."""
    if request.method == "HEAD":
        return False  # the headers alone
    http_range = request.headers.get("range")
    if_range = request.headers.get("if-range")
    # Starlette's own (private) Range reading; a Starlette without it: count it as sent,
    # an audit row too many rather than an export unaudited (tests/server/test_report.py
    # then fails on the 416 case and says so).
    should_use = getattr(response, "_should_use_range", None)
    parse = getattr(response, "_parse_range_header", None)
    if http_range is None or should_use is None or parse is None:
        return True
    if if_range is not None and not should_use(if_range):
        return True  # the whole file
    assert response.stat_result is not None
    try:
        parse(http_range, response.stat_result.st_size)
    except (MalformedRangeHeader, RangeNotSatisfiable):
        return False
    return True


async def exported(db: Db, user: Any, row: Session, fmt: str) -> None:
    """Audit a session leaving the system as a file (``patient.export``, entity session)."""
    what = {"format": fmt, "session_id": row.id}
    await audit.export(db, audit.user_actor(user), "session", row.id, row.patient_id, what)


async def _cached_export(
    request: Request, row: Session, fmt: str, source: Path, source_digest: str
) -> tuple[Path, str]:
    """The export of ``source`` in ``fmt`` and its SHA-256, made on first request and kept.

    Its name holds the SHA-256 of the recording it was made from, so an export is served
    only for the very bytes it was made from: one made before the recording changed (a
    damaged file since restored, or the other way round) is never found again. An export
    is kept only if the recording stayed as checked while it was made. It is made in a
    process of its own (:mod:`server.export_workers`), never on the event loop."""
    exports = Path(request.app.state.settings.data_dir) / "exports"
    exports.mkdir(mode=0o700, parents=True, exist_ok=True)
    path = exports / f"{row.session_uuid}.{source_digest}{FILE_SUFFIX[fmt]}"
    sidecar = path.with_name(path.name + ".sha256")
    if not (path.exists() and sidecar.exists()):
        before = await asyncio.to_thread(_identity, source)
        digest = await request.app.state.exports.make(source, fmt, path)
        if await asyncio.to_thread(_identity, source) != before:
            path.unlink(missing_ok=True)
            raise HTTPException(503, RECORDING_CHANGED, headers={"Retry-After": "1"})
        fd = os.open(sidecar, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as f:
            f.write(digest)
    return path, sidecar.read_text().strip()


DAMAGED = (
    "the stored recording of this session is damaged: it is not the file the station "
    "uploaded, so nothing of it was sent; the server's operator must restore it from backup"
)
RECORDING_CHANGED = "the stored recording changed while it was read: try again"

_checked: dict[Path, tuple[tuple[int, int, int], str | None]] = {}
"""Stored recording -> (its size, mtime and inode when last checked, its SHA-256 if it was
intact then, else None): each state of a file is hashed once per process, and a damaged
one logged once."""


def _identity(path: Path) -> tuple[int, int, int]:
    st = path.stat()
    return st.st_size, st.st_mtime_ns, st.st_ino


async def intact_recording(request: Request, row: Session) -> tuple[Path, str]:
    """The stored recording of a session and its SHA-256, checked against the size and
    SHA-256 the upload completed with; a 500 saying it is damaged if it is not.

    A recording cut short on disk used to be served as complete: the ``rec`` download with
    the original ``X-Content-SHA256``, a JSON export with no end and a third of the
    samples, kept in the export cache after the file was restored. Hashing costs about
    1 ms per MB, off the event loop (a 30 min session at 100 Hz: 42 MB hashed in 43 ms,
    against 0.13 s to make its JSON export and 0.9 s its CSV); it is done once per state of
    the file (its size, mtime and inode) in each process."""
    source = recording_path(request, row)
    identity = await asyncio.to_thread(_identity, source)
    known = _checked.get(source)
    if known is not None and known[0] == identity:
        digest = known[1]
    else:
        digest = None
        if not row.size_bytes or identity[0] == row.size_bytes:
            found = await asyncio.to_thread(file_sha256, source)
            if row.sha256 is None or found == row.sha256:
                digest = found
        if digest is None:
            log.error(
                "session %s: the stored recording %s is damaged: %d bytes now, uploaded "
                "with %d bytes and SHA-256 %s; restore it from backup",
                row.id,
                source,
                identity[0],
                row.size_bytes,
                row.sha256,
            )
        _checked[source] = (identity, digest)
    if digest is None:
        raise HTTPException(500, DAMAGED)
    return source, digest


def _summarize_file(source: Path) -> Summary:
    return summarize(read(source))


def recording_path(request: Request, row: Session) -> Path:
    """The stored recording of a session; 404 if the server holds no file for it.

    ``file_path`` is relative to the data directory (older rows hold an absolute path,
    which the join leaves as it is), so every server process, whatever its working
    directory or the mount point of the shared data directory, finds the file another
    process filed."""
    if row.file_path is not None:
        path = Path(request.app.state.settings.data_dir) / row.file_path
        if path.is_file():
            return path
    raise HTTPException(404, "session file not found")


# ---- the whole session for charts -------------------------------------------------------

SERIES_POINTS = 2000
"""Rows of a chart series by default: two per pixel column of a wide chart."""
SERIES_POINTS_MIN, SERIES_POINTS_MAX = 10, 20000

_PA_PER_BAR = 1e5
_MODE_NAMES = {int(m): m.name for m in DeviceMode}

Column = list[float | None]


class ModeSpan(BaseModel):
    """A stretch of the session in one device mode, at full resolution (never decimated)."""

    mode: str = Field(description="IDLE, HOMING, READY, ACTIVE, HOLD, ESTOP or FAULT.")
    start_s: float = Field(description="Time of the first sample in this mode, s (as time_s).")
    end_s: float = Field(
        description="Time of the first sample after it, or of the last sample, s (as time_s)."
    )


class SessionSeries(BaseModel):
    """The whole session as columns for charts, decimated so that no peak is lost.

    Up to ``points`` rows. A longer session is cut into ``rows / 2`` buckets of consecutive
    samples and each bucket gives two rows: for every column separately, its lowest and its
    highest value in the bucket, in the order they happened. So every minimum and maximum of
    the session is in the answer exactly (a line through the rows covers what the full data
    covers), and the two rows of a bucket carry the times of its first and last sample: a
    value is placed at most one bucket (``bucket_s``) from when it happened. A shorter
    session comes whole. Values the device could not measure are null. The per-axis
    columns are keyed ``roll``, ``pitch`` and ``yaw``.
    """

    model_config = ConfigDict(allow_inf_nan=False)

    session_id: int
    samples: int = Field(description="Samples in the recording.")
    rows: int = Field(description="Rows in each column here.")
    decimated: bool = Field(description="True if the rows are bucket minima and maxima.")
    bucket_s: float | None = Field(
        description="Mean time one bucket spans, s; null when not decimated."
    )
    axes: list[str] = Field(description="The axes the prescription exercises, in its order.")
    time_s: list[float] = Field(
        description="Device clock, s since the first sample. Non-decreasing: should the clock "
        "jump back (a restarted device), the jump counts as no time."
    )
    pose_deg: dict[str, Column] = Field(description="Measured angle, degrees from home.")
    pose_cmd_deg: dict[str, Column] = Field(description="Commanded angle, degrees from home.")
    torque_nm: dict[str, Column] = Field(
        description="The patient's torque on the foot plate (wrench[3:6]), N·m."
    )
    force_z_n: Column = Field(description="The patient's vertical force on the foot plate, N.")
    pressures_bar: list[Column] = Field(
        description="12 chamber pressures, gauge, bar: p(2i-1) cap side and p(2i) rod side "
        "of leg i, in that order."
    )
    supply_bar: Column = Field(description="Supply pressure, gauge, bar.")
    stiffness_nm_per_rad: dict[str, Column] = Field(description="Stiffness in force, N·m/rad.")
    damping_nms_per_rad: dict[str, Column] = Field(description="Damping in force, N·m·s/rad.")
    modes: list[ModeSpan] = Field(description="Device modes over the session, in order.")


def session_time(t: NDArray[Any]) -> NDArray[np.float64]:
    """Seconds since the first sample on the device clock, never running backwards: an
    interval in which the clock does not advance (or is not a number) counts as zero."""
    t = np.asarray(t, dtype=np.float64)
    if len(t) == 0:
        return np.zeros(0)
    dt = np.diff(t)
    dt = np.where(np.isfinite(dt) & (dt > 0), dt, 0.0)
    return np.concatenate(([0.0], np.cumsum(dt)))


def minmax_buckets(
    values: NDArray[np.float64], buckets: int
) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64]]:
    """Cut ``values`` (samples × columns) into ``buckets`` runs of consecutive samples; per
    bucket and column, the lowest and highest finite value in the order they came.

    Returns each bucket's first and last sample index and the (2 × buckets, columns) values;
    a bucket with no finite value of a column gives NaN for it.
    """
    n = len(values)
    edges = np.linspace(0, n, buckets + 1).astype(np.intp)
    starts, ends = edges[:-1], edges[1:] - 1
    width = int((ends - starts).max()) + 1
    # A bucket shorter than the widest is padded with its own last sample: a repeat changes
    # neither its minimum nor its maximum.
    index = np.minimum(starts[:, None] + np.arange(width)[None, :], ends[:, None])
    # Columns first, so that each bucket's samples are contiguous for argmin and argmax.
    block = np.ascontiguousarray(values.T)[:, index]  # columns × buckets × width
    finite = np.isfinite(block)
    low = np.argmin(np.where(finite, block, np.inf), axis=2)
    high = np.argmax(np.where(finite, block, -np.inf), axis=2)
    c = np.arange(values.shape[1])[:, None]
    b = np.arange(buckets)[None, :]
    out = np.empty((2 * buckets, values.shape[1]))
    out[0::2] = block[c, b, np.minimum(low, high)].T
    out[1::2] = block[c, b, np.maximum(low, high)].T
    return starts, ends, out


def _column(x: NDArray[np.float64], decimals: int) -> Column:
    rounded = np.round(x, decimals)
    if np.isfinite(rounded).all():
        out: Column = rounded.tolist()
        return out
    return [float(v) if np.isfinite(v) else None for v in rounded]


def _mode_spans(mode: NDArray[Any], time: NDArray[np.float64]) -> list[ModeSpan]:
    if len(mode) == 0:
        return []
    change = np.flatnonzero(np.diff(mode.astype(np.int16))) + 1
    starts = np.concatenate(([0], change))
    ends = np.concatenate((change, [len(mode) - 1]))
    return [
        ModeSpan(
            mode=_MODE_NAMES.get(int(mode[s]), str(int(mode[s]))),
            start_s=round(float(time[s]), 3),
            end_s=round(float(time[e]), 3),
        )
        for s, e in zip(starts, ends, strict=True)
    ]


def session_series(session_id: int, rec: Recording, points: int) -> SessionSeries:
    """The chart columns of a recording, at most ``points`` rows (see :class:`SessionSeries`)."""
    s = rec.samples
    time = session_time(s["t"])
    deg = float(np.degrees(1.0))
    # (name, key, recording values, scale to the column's unit, decimals kept)
    spec: list[tuple[str, str | int | None, NDArray[Any], float, int]] = []
    for axis in ROTATION_AXES:
        i = AXIS_INDEX[axis]
        spec += [
            ("pose_deg", axis, s["pose"][:, i], deg, 3),
            ("pose_cmd_deg", axis, s["pose_cmd"][:, i], deg, 3),
            ("torque_nm", axis, s["wrench"][:, i], 1.0, 3),
            ("stiffness_nm_per_rad", axis, s["stiffness"][:, i], 1.0, 2),
            ("damping_nms_per_rad", axis, s["damping"][:, i], 1.0, 3),
        ]
    spec.append(("force_z_n", None, s["wrench"][:, 2], 1.0, 2))
    spec += [("pressures_bar", j, s["pressures"][:, j], 1 / _PA_PER_BAR, 4) for j in range(12)]
    spec.append(("supply_bar", None, s["supply"], 1 / _PA_PER_BAR, 4))

    n = len(s)
    buckets = points // 2
    decimated = n > points
    # One column at a time: the 40 columns of a 6 h session at 100 Hz side by side were
    # 0.7 GB, and decimating them at once took as much again several times over (2.8 GB at
    # the peak); a column's buckets do not depend on another's.
    values = np.empty((2 * buckets if decimated else n, len(spec)))
    starts = ends = np.zeros(0, dtype=np.intp)
    for k, (_, _, x, scale, _) in enumerate(spec):
        full = np.asarray(x, dtype=np.float64) * scale
        if decimated:
            starts, ends, low_high = minmax_buckets(full[:, None], buckets)
            values[:, k] = low_high[:, 0]
        else:
            values[:, k] = full
    if decimated:
        row_time = np.empty(2 * buckets)
        row_time[0::2], row_time[1::2] = time[starts], time[ends]
    else:
        row_time = time

    out: dict[str, Any] = {
        "pose_deg": {},
        "pose_cmd_deg": {},
        "torque_nm": {},
        "stiffness_nm_per_rad": {},
        "damping_nms_per_rad": {},
        "pressures_bar": [],
    }
    for k, (name, key, _, _, decimals) in enumerate(spec):
        column = _column(values[:, k], decimals)
        if name == "pressures_bar":
            out[name].append(column)
        elif key is None:
            out[name] = column
        else:
            out[name][key] = column
    return SessionSeries(
        session_id=session_id,
        samples=n,
        rows=len(row_time),
        decimated=decimated,
        bucket_s=float(time[-1] / buckets) if decimated else None,
        axes=prescribed_axes(rec.header.prescription),
        time_s=np.round(row_time, 3).tolist(),
        modes=_mode_spans(s["mode"], time),
        **out,
    )


@router.get(
    "/sessions/{session_id}/series",
    response_model=SessionSeries,
    responses=NOT_FOUND,
    summary="The whole session for charts, decimated keeping every peak",
)
async def get_series(
    session_id: Id,
    request: Request,
    db: Db,
    user: TherapistOrAdmin,
    points: Annotated[
        int,
        Query(
            ge=SERIES_POINTS_MIN,
            le=SERIES_POINTS_MAX,
            description="Most rows to answer with; a longer session is decimated to minima "
            "and maxima per bucket.",
        ),
    ] = SERIES_POINTS,
) -> SessionSeries:
    row = await _session_for(db, user, session_id)
    source, _ = await intact_recording(request, row)

    def build() -> SessionSeries:
        return session_series(session_id, read(source), points)

    return await asyncio.to_thread(build)
