"""One recording model for a session, shared by the home station and the server.

A session is a header, a time series and events, closed by an end record. On disk and on
the wire it is one append-only file of checksummed records, so that the station can write it
as the session runs (durable after each flush), upload it by byte ranges while or after it
runs, and the server can check and read exactly the bytes the station wrote:

    b"ANKLREC1" then records: type u8 | length u32 | payload | crc32(type, length, payload) u32

Record types: HEADER (JSON, first), SAMPLES (a block of rows of :data:`SAMPLE_DTYPE`, little
endian, packed), EVENT (JSON), END (JSON, last). A reader stops at the first record that is
truncated or fails its CRC: what a killed writer left behind is the valid prefix.
"""

from __future__ import annotations

import enum
import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, StrictInt, StrictStr, ValidationError

from device.protocol.messages import Telemetry
from sessions.prescription import REPETITIONS_MAX, SETS_MAX, Axis
from sessions.private import PRIVATE_FILE, fsync_dir

MAGIC = b"ANKLREC1"
FORMAT_VERSION = 1
_RECORD = struct.Struct("<BI")
_CRC = struct.Struct("<I")
MAX_RECORD = 16 * 1024 * 1024
"""Largest payload of one record (bytes); a longer length field means a corrupt file."""


UNIX_TIME_MAX = 253_402_300_800.0
"""Year 10000 in Unix seconds: a start or end time a date can hold."""
ID_MAX = 2**63 - 1
"""The largest id a database holds: a header naming a larger one names nothing."""
CLOCK_SLACK_S = 3600.0
"""Seconds a sample's times may reach past the session's start and end: a clock set while
the session ran. Beyond that a recording is not of the session it says it is."""


class RecordType(enum.IntEnum):
    HEADER = 1
    SAMPLES = 2
    EVENT = 3
    END = 4


SAMPLE_DTYPE = np.dtype(
    [
        ("t", "<f8"),  # device time, s
        ("wall", "<f8"),  # station wall clock when received, Unix s
        ("mode", "u1"),  # DeviceMode
        ("trip", "u1"),  # Trip code, 0 if none
        ("segment_id", "<u4"),
        ("set", "<u2"),  # 1-based set of the timeline, 0 outside a repetition
        ("rep", "<u2"),  # 1-based repetition within the set, 0 outside one
        ("pose", "<f4", (6,)),  # m, rad, relative to home
        ("pose_cmd", "<f4", (6,)),
        ("legs", "<f4", (6,)),  # piston displacement, m
        ("pressures", "<f4", (12,)),  # gauge, Pa
        ("supply", "<f4"),  # Pa
        ("wrench", "<f4", (6,)),  # N, N m: the foot on the plate, minus the resting wrench
        ("stiffness", "<f4", (6,)),
        ("damping", "<f4", (6,)),
        ("duty", "i1", (12,)),  # signed valve duty in slots of 28
    ]
)
"""One row of the time series: what the device reported, and where in the timeline."""


def sample_row(t: Telemetry, wall: float, set_: int = 0, rep: int = 0) -> tuple[Any, ...]:
    """A row of :data:`SAMPLE_DTYPE` from one telemetry message."""
    return (
        t.time,
        wall,
        int(t.mode),
        int(t.trip),
        t.segment_id,
        set_,
        rep,
        t.pose,
        t.pose_cmd,
        t.legs,
        t.pressures,
        t.supply,
        t.wrench,
        t.stiffness,
        t.damping,
        t.duty,
    )


class DeviceInfo(BaseModel):
    firmware: str
    hardware: str
    telemetry_hz: int
    home_pose: list[float] = Field(description="m, rad")
    calibrated: bool = Field(
        default=False,
        description="The device subtracted its unit's identified sensor zeros (its HELLO "
        "said CALIBRATED). False also in sessions recorded before this was kept.",
    )


class Header(BaseModel):
    """Who, what and with which software: the first record of every session."""

    model_config = ConfigDict(extra="forbid")

    format_version: int = FORMAT_VERSION
    session_id: str = Field(description="UUID chosen by the station; the upload's key.")
    station_id: int = Field(ge=0, le=ID_MAX)
    patient_id: int = Field(ge=0, le=ID_MAX)
    prescription_id: int = Field(ge=0, le=ID_MAX)
    prescription: dict[str, Any] = Field(description="The prescription as it was run.")
    device: DeviceInfo
    software: str
    started_at: float = Field(
        ge=0.0, lt=UNIX_TIME_MAX, allow_inf_nan=False, description="Unix time, s."
    )


class RecordedAxis(BaseModel):
    """One axis of a :class:`RecordedPrescription`: what is read of it."""

    model_config = ConfigDict(extra="allow")

    axis: Axis
    waveform: StrictStr = "hold"


class RecordedPrescription(BaseModel):
    """The prescription a header holds, as it must be for the summaries to read it
    (``sessions.summary``, ``sessions.metrics``, the session's series): the exercise named
    in text, its axes a list of objects each naming a rotation, its counts whole numbers no
    larger than a prescription asks. Anything else may be there (what an older or newer
    station wrote), and nothing is held to today's limits: a session recorded under a
    prescription happened, whatever the rules are now. Checked by :func:`check_prescription`
    (the header record itself keeps a plain object, so that a session filed before still
    reads)."""

    model_config = ConfigDict(extra="allow")

    exercise: StrictStr
    axes: list[RecordedAxis] = Field(min_length=1)
    sets: StrictInt | None = Field(default=None, ge=1, le=SETS_MAX)
    repetitions: StrictInt | None = Field(default=None, ge=1, le=REPETITIONS_MAX)


def check_prescription(header: Header) -> None:
    """The header's prescription has the shape :class:`RecordedPrescription` says, or
    :class:`RecordingError` names the first field that does not ("prescription.axes.0.axis:
    Input should be 'roll', 'pitch' or 'yaw'")."""
    try:
        RecordedPrescription.model_validate(header.prescription)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(p) for p in ("prescription", *err["loc"]))
        raise RecordingError(f"{loc}: {err['msg']}") from None


class SessionEvent(BaseModel):
    """Something that happened: a repetition done, a limit hit, a change by a therapist."""

    model_config = ConfigDict(extra="forbid")

    wall: float = Field(description="Unix time, s.")
    t: float | None = Field(default=None, description="Device time, s, when known.")
    kind: str = Field(
        description="rep_done, set_done, rest, mode, limit, fault, watchdog, estop, "
        "supply_low, damping_raised (an axis rang with the foot on it and the device raised "
        "its damping), impedance, hold, resume, stop, interrupted (held too long, or the "
        "device's link lost), refused "
        "(the device refused the exercise's segment), game_score, note."
    )
    by: str = Field(default="station", description="device, station, patient or therapist:<id>.")
    detail: dict[str, Any] = Field(default_factory=dict)


EndReason = Literal["completed", "stopped", "fault", "interrupted"]


class End(BaseModel):
    model_config = ConfigDict(extra="forbid")

    ended_at: float = Field(
        ge=0.0, lt=UNIX_TIME_MAX, allow_inf_nan=False, description="Unix time, s."
    )
    reason: EndReason
    # Bounded at upload (check_session), not here: a session filed earlier still reads.
    sets_completed: int
    repetitions_completed: int = Field(description="All sets.")
    text: str = Field(
        default="", description="Why it ended, in words, when not simply completed or stopped."
    )


@dataclass
class Recording:
    """A whole session read back from its file."""

    header: Header
    samples: NDArray[np.void]
    events: list[SessionEvent] = field(default_factory=list)
    end: End | None = None
    valid_bytes: int = 0
    """Bytes of the file that form whole, checked records."""
    damaged: bool = False
    """Bytes after ``valid_bytes`` were truncated or failed their CRC."""


class RecordingError(ValueError):
    """The bytes are not a recording (wrong magic, or no header)."""


def _record(kind: RecordType, payload: bytes) -> bytes:
    head = _RECORD.pack(kind, len(payload))
    return head + payload + _CRC.pack(zlib.crc32(payload, zlib.crc32(head)))


def encode_json(kind: RecordType, model: BaseModel) -> bytes:
    return _record(kind, model.model_dump_json().encode())


def encode_samples(rows: NDArray[np.void]) -> bytes:
    return _record(RecordType.SAMPLES, np.ascontiguousarray(rows, SAMPLE_DTYPE).tobytes())


def iter_records(data: bytes | memoryview) -> tuple[list[tuple[RecordType, bytes]], int, bool]:
    """Whole, checked records of ``data``; the bytes they span; whether anything followed."""
    buf = memoryview(data)
    if bytes(buf[: len(MAGIC)]) != MAGIC:
        raise RecordingError("not a session recording (bad magic)")
    pos = len(MAGIC)
    out: list[tuple[RecordType, bytes]] = []
    while pos + _RECORD.size <= len(buf):
        kind, length = _RECORD.unpack_from(buf, pos)
        end = pos + _RECORD.size + length + _CRC.size
        if length > MAX_RECORD or end > len(buf) or kind not in RecordType._value2member_map_:
            break
        head = bytes(buf[pos : pos + _RECORD.size])
        payload = bytes(buf[pos + _RECORD.size : end - _CRC.size])
        (crc,) = _CRC.unpack_from(buf, end - _CRC.size)
        if crc != zlib.crc32(payload, zlib.crc32(head)):
            break
        out.append((RecordType(kind), payload))
        pos = end
    return out, pos, pos != len(buf)


def decode(data: bytes | memoryview) -> Recording:
    """Read a recording; a damaged tail is dropped and flagged, never guessed at."""
    records, valid, damaged = iter_records(data)
    if not records or records[0][0] != RecordType.HEADER:
        raise RecordingError("a recording starts with its header record")
    header = Header.model_validate_json(records[0][1])
    blocks: list[NDArray[np.void]] = []
    events: list[SessionEvent] = []
    end: End | None = None
    for kind, payload in records[1:]:
        if end is not None:
            damaged = True  # nothing may follow the end record
            break
        if kind == RecordType.SAMPLES:
            if len(payload) % SAMPLE_DTYPE.itemsize:
                raise RecordingError("a samples record is not a whole number of rows")
            blocks.append(np.frombuffer(payload, SAMPLE_DTYPE))
        elif kind == RecordType.EVENT:
            events.append(SessionEvent.model_validate_json(payload))
        elif kind == RecordType.END:
            end = End.model_validate_json(payload)
        else:
            raise RecordingError("a second header record")
    samples = np.concatenate(blocks) if blocks else np.zeros(0, SAMPLE_DTYPE)
    return Recording(header, samples, events, end, valid, damaged)


def check_session(rec: Recording) -> None:
    """A finished recording must describe one session a station ran: its header's
    prescription can be read (:func:`check_prescription`); its end's counts are
    no more than a prescription can ask (and not negative); it ends no earlier than it
    starts, its samples were received within it (station clock, ``wall``), and the device's
    clock covers no more time than the session lasted (the sum of its forward steps ``t``,
    so that a device restarted mid-session, its clock back at 0, still counts right). Each
    allows :data:`CLOCK_SLACK_S`. No sample goes back in time on both clocks at once: the
    station writes each sample once, in the order received, so a device time ``t`` that
    does not move forward while the station's ``wall`` does not either is a sample repeated
    or replayed (a device restarted has its ``t`` back at 0, but received later). Times that
    are not finite are unmeasured, not wrong (the summary leaves them out). Raises
    :class:`RecordingError` naming the field and, for a sample, where it is.

    Samples missing (a gap in ``t``: the device's link stalled for under the 2 s that end a
    session, the station stood still, frames lost on the wire) are no reason to refuse a
    session that happened: the summary counts them (``telemetry_gaps``,
    ``telemetry_missing_s``) and leaves their time out of the exercise.

    The server asks it of every upload before filing it (``server.routes.uploads``);
    :func:`decode` does not, so that the station's recovery never takes a session whose
    clock was set while it ran for a file to delete, and a session filed earlier still
    reads."""
    if rec.end is None:
        raise RecordingError("it is cut off: it has no end record")
    check_prescription(rec.header)
    for name, count, most in (
        ("sets_completed", rec.end.sets_completed, SETS_MAX),
        ("repetitions_completed", rec.end.repetitions_completed, SETS_MAX * REPETITIONS_MAX),
    ):
        if not 0 <= count <= most:
            raise RecordingError(
                f"the end record's {name} ({count}) is outside 0 to {most}, what a "
                "prescription can ask"
            )
    samples = rec.samples
    start, stop = rec.header.started_at, rec.end.ended_at
    if stop < start:
        raise RecordingError(
            f"the end record's ended_at ({stop:.3f}) is before the header's started_at "
            f"({start:.3f}): a session ends after it starts"
        )
    wall = samples["wall"].astype(np.float64)
    wall = wall[np.isfinite(wall)]
    if len(wall) and (wall.min() < start - CLOCK_SLACK_S or wall.max() > stop + CLOCK_SLACK_S):
        raise RecordingError(
            f"a sample's wall time ({_outlier(wall, start, stop):.6g}) lies outside the "
            f"session (started_at {start:.3f} to ended_at {stop:.3f}, give or take "
            f"{CLOCK_SLACK_S:g} s)"
        )
    with np.errstate(over="ignore", invalid="ignore"):
        t = samples["t"].astype(np.float64)
        dt = np.diff(t)
        dwall = np.diff(samples["wall"].astype(np.float64))
        replayed = np.isfinite(dt) & np.isfinite(dwall) & (dt <= 0) & (dwall <= 0)
        forward = dt[np.isfinite(dt) & (dt > 0)]
        covered = float(forward.sum()) if len(forward) else 0.0
    if replayed.any():
        i = int(np.argmax(replayed))
        raise RecordingError(
            f"sample {i + 1} (of {len(samples)}, counted from 0) goes back in time: its "
            f"device time t ({t[i + 1]:.6g} s) and wall time are not after those of the "
            f"sample before it (t {t[i]:.6g} s): samples repeated or replayed, not a "
            "recording the station writes"
        )
    if covered > stop - start + CLOCK_SLACK_S:
        raise RecordingError(
            f"the samples' device time t covers {covered:.6g} s, more than the session lasted "
            f"(ended_at - started_at = {stop - start:.6g} s): not a recording of this session"
        )


def _outlier(wall: NDArray[np.float64], start: float, stop: float) -> float:
    low, high = float(wall.min()), float(wall.max())
    return low if low < start - CLOCK_SLACK_S else high


def read(path: Path) -> Recording:
    return decode(path.read_bytes())


class RecordingWriter:
    """Appends a session to its file; :meth:`flush` makes what was written durable.

    Samples are buffered and written as one record per flush; events and the end record are
    written at once. After a crash, :func:`recover` truncates the damaged tail and the writer
    can be reopened to append the end record.
    """

    def __init__(self, path: Path, header: Header | None = None) -> None:
        self.path = path
        self._rows: list[tuple[Any, ...]] = []
        existing = path.exists() and path.stat().st_size > 0
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, PRIVATE_FILE)
        if not existing:
            if header is None:
                raise RecordingError(f"{path} is new: a header is needed")
            os.write(self._fd, MAGIC + encode_json(RecordType.HEADER, header))
            self.flush()
            fsync_dir(path.parent)
        self.samples_written = 0

    def add(self, row: tuple[Any, ...]) -> None:
        self._rows.append(row)

    def event(self, event: SessionEvent) -> None:
        self._write_rows()
        os.write(self._fd, encode_json(RecordType.EVENT, event))

    def end(self, end: End) -> None:
        self._write_rows()
        os.write(self._fd, encode_json(RecordType.END, end))
        self.flush()

    def _write_rows(self) -> None:
        if self._rows:
            rows = np.array(self._rows, dtype=SAMPLE_DTYPE)
            os.write(self._fd, encode_samples(rows))
            self.samples_written += len(rows)
            self._rows.clear()

    def flush(self) -> None:
        """Write buffered samples and wait until the disk has them."""
        self._write_rows()
        os.fsync(self._fd)

    def close(self) -> None:
        if self._fd >= 0:
            self.flush()
            os.close(self._fd)
            self._fd = -1

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def recover(path: Path) -> Recording:
    """Cut a crashed session's file back to its whole records and read it."""
    rec = decode(path.read_bytes())
    if rec.damaged:
        with path.open("r+b") as f:
            f.truncate(rec.valid_bytes)
            f.flush()
            os.fsync(f.fileno())
        rec.damaged = False
    return rec
