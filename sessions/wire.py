"""WebSocket messages between home station, server and live viewers: the one master copy.

Station and server never import each other, so the models they share live here, below both.
Every message is JSON with a ``type`` tag; each direction of each link is one discriminated
union, validated on receipt. The server publishes the JSON Schemas of these unions (WebSocket
routes do not appear in OpenAPI) at ``/api/v1/schemas/ws``.

Links and their handshake (``PROTOCOL`` is the version; a station speaking one outside
``PROTOCOL_OLDEST`` to ``PROTOCOL`` is closed with :data:`CLOSE_VERSION` and a reason naming
both versions):
- ``/ws/station``: the station authenticates with its bearer token (``Authorization``
  header) and sends :class:`StationHello`; the server answers :class:`Welcome`, then pushes
  :class:`Prescriptions` and :class:`Command`\\ s; the station streams :class:`TelemetryBatch`,
  :class:`EventMsg`, :class:`StatusMsg` and :class:`CommandResult`.
- ``/ws/live/{station_id}``: a therapist authenticates with the subprotocol pair
  ``["ankle.v1", "bearer.<token>"]`` (browsers cannot set headers) or the header; receives
  :class:`Welcome`, then every telemetry batch while it keeps up (the newest batch when it
  falls behind), events, status, presence and the results of commands; sends :class:`Command`.

Both sides send :class:`Heartbeat` every ``HEARTBEAT_S`` and drop a link silent for
``HEARTBEAT_TIMEOUT_S``: the WebSocket library's 20 s keepalive is far too slow to tell a
therapist that the live view is stale.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Annotated, Any, Literal, cast

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    TypeAdapter,
    create_model,
    model_validator,
)
from pydantic_core import PydanticCustomError

from sessions.prescription import (
    DAMPING_MAX,
    STIFFNESS_MAX,
    Axis,
    PrescriptionBody,
    plus_zero,
)
from sessions.recording import ID_MAX, DeviceInfo, SessionEvent
from sessions.text import Line, Lines

PROTOCOL = 5
"""2: telemetry travels in batches (:class:`TelemetryBatch`), no longer one sample a message.
3: a K/B change's result carries the change the station made (:class:`ImpedanceChange`).
4: the station's status names the sessions the server refused for good (``refused_uploads``).
5: the hello names the station's run (``instance``) and how often its link was taken by
another connection with its token (``displaced``). A station of protocol 4 still connects
(both fields have defaults); a protocol-5 station is told by a protocol-4 server that the
versions differ, rather than that its hello has fields it does not know."""
PROTOCOL_OLDEST = 4
"""The oldest station protocol the server still accepts."""
REFUSED_NAMED = 10
"""Refused sessions a status names (all are counted)."""
SUBPROTOCOL = "ankle.v1"
BEARER_PREFIX = "bearer."
HEARTBEAT_S = 1.0
HEARTBEAT_TIMEOUT_S = 5.0
BATCH_HZ = 25.0
"""Telemetry messages a second by default (``ankle station --batch-hz``): 4 samples of
the device's 100 Hz in each."""
BATCH_HZ_MAX = 50.0
"""Most telemetry messages a second (``--batch-hz``): each message costs the server and
every viewer about as much as a whole batch, so fewer, fuller ones are cheaper."""
MAX_MESSAGE_BYTES = 64 * 1024
"""Largest message either side accepts; a longer one closes the link with 1009."""

CLOSE_NORMAL = 1000
CLOSE_MALFORMED = 1007
"""Not JSON, or not one of the link's messages: the reason says which field."""
CLOSE_POLICY = 1008
"""Wrong token or Origin (a browser sees the handshake refused with 403)."""
CLOSE_TOO_BIG = 1009
CLOSE_VERSION = 4000
"""The peers speak different protocol versions."""
CLOSE_TIMEOUT = 4001
"""No message for ``HEARTBEAT_TIMEOUT_S``."""
CLOSE_REPLACED = 4002
"""A newer connection with the same station token replaced this link; the newest wins (a
station reconnecting over its own half-open link must get in at once). A station whose live
link is closed with it knows the newer connection was not its own, and steps back for
minutes rather than take the link straight back."""
CLOSE_REVOKED = 4003
"""The station's token was revoked (a station link), or the watched station was (a view)."""
CLOSE_SIGNED_OUT = 4004
"""The viewer's sign-in ended: logged out, or its password was changed or reset."""
CLOSE_EXPIRED = 4005
"""The viewer's sign-in expired (``token_ttl_s`` after it began)."""
CLOSE_DEACTIVATED = 4006
"""The viewer's account was deactivated."""
CLOSE_NO_ACCESS = 4007
"""The viewer may no longer see this station's patient."""
CLOSE_MUST_CHANGE = 4008
"""The viewer's password was printed or reset: it must be changed before anything else."""
CLOSE_TOO_SLOW = 4009
"""The viewer fell too far behind the events, status and results sent to it (the server's
``CONTROL_QUEUE_MAX``): it reconnects and is sent the station's state afresh."""
CLOSE_TOO_FAST = 4010
"""The viewer sent commands faster than its link's budget (the server's ``COMMAND_BURST``
at once, ``COMMANDS_PER_S`` after): no person at a dashboard does."""

_STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)

Vec6 = Annotated[list[float], Field(min_length=6, max_length=6)]


def _id(value: int) -> int:
    """The bounds said as the REST API says them (``Session id must be at most ...``), the
    largest as the integer it is."""
    if value < 1:
        raise PydanticCustomError("id", "must be at least 1")
    if value > ID_MAX:
        raise PydanticCustomError("id", f"must be at most {ID_MAX}")
    return value


Id = Annotated[
    int,
    Field(strict=True, json_schema_extra={"minimum": 1, "maximum": ID_MAX}),
    AfterValidator(_id),
]
"""Every id a message names: a JSON integer from 1 to 2**63-1, as the REST API takes them
(``server.deps.Id``). A larger one names nothing the database can hold: a Start of
prescription 2**70 reached the database, whose driver could not send it, and was refused as
if the database were away (``AUDIT``, logged at ERROR); ``true`` was taken as 1."""


class Heartbeat(BaseModel):
    model_config = _STRICT
    type: Literal["heartbeat"] = "heartbeat"
    sent: float = Field(description="Sender's wall clock, Unix s.")


class StationHello(BaseModel):
    model_config = _STRICT
    type: Literal["hello"] = "hello"
    protocol: int
    software: str
    device: DeviceInfo | None = Field(default=None, description="None while not connected.")
    instance: str = Field(
        default="",
        max_length=64,
        pattern=r"^[A-Za-z0-9_-]*$",
        description="Names this run of the station program, the same on each of its "
        "reconnections (protocol 5; empty from an older station). A link that replaces a "
        "live one of another instance is a second station using the same token.",
    )
    displaced: int = Field(
        default=0,
        strict=True,
        ge=0,
        le=1_000_000,
        description="How many times in a row this station's live link was closed because "
        "another connection with its token replaced it (CLOSE_REPLACED), since its last link "
        "that ended otherwise (protocol 5; 0 from an older station).",
    )


class Welcome(BaseModel):
    model_config = _STRICT
    type: Literal["welcome"] = "welcome"
    protocol: int = PROTOCOL
    station_id: Id
    patient_id: int = Field(
        strict=True, ge=0, le=ID_MAX, description="0 for a viewer: the station is offline."
    )
    online: bool = Field(default=True, description="For a viewer: is the station connected.")
    status: StatusMsg | None = None
    server_time: float = Field(description="Unix s.")


class TelemetryMsg(BaseModel):
    """One device sample as the station received it (SI units: m, rad, N, N·m, Pa).

    Not a message of its own on the links (since protocol 2): samples travel in a
    :class:`TelemetryBatch`, whose :meth:`~TelemetryBatchBase.newest` gives one back."""

    model_config = _STRICT
    type: Literal["telemetry"] = "telemetry"
    sent: float = Field(description="Station wall clock when sent (its batch's), Unix s.")
    t: float = Field(description="Device time, s.")
    mode: str = Field(description="Device mode name: IDLE, HOMING, READY, ACTIVE, HOLD, ...")
    trip: int = Field(description="Latched trip code, 0 if none.")
    segment_id: int
    set: int = Field(description="1-based set of the running exercise, 0 if none.")
    rep: int = Field(description="1-based repetition in the set, 0 if none.")
    pose: Vec6 = Field(description="Measured pose relative to home: m, m, m, rad, rad, rad.")
    pose_cmd: Vec6 = Field(description="Commanded pose relative to home.")
    legs: Vec6 = Field(description="Piston displacements, m.")
    pressures: Annotated[list[float], Field(min_length=12, max_length=12)] = Field(
        description="Chamber gauge pressures, Pa; legs 1..6, cap then rod side."
    )
    wrench: Vec6 = Field(description="Patient's wrench on the foot plate: N, N·m.")
    stiffness: Vec6 = Field(description="K in force: N/m, N·m/rad.")
    damping: Vec6 = Field(description="B in force: N·s/m, N·m·s/rad.")
    lag_ms: float = Field(description="Device pacing lag, ms.")
    overruns: int
    frames_dropped: int = Field(description="Frames the device dropped (CRC, length, ...).")


BATCH_MAX = 50
"""Most samples in one :class:`TelemetryBatch` (50 samples are about 25 KB of JSON)."""
SAMPLE_COLUMNS: tuple[str, ...] = tuple(
    name for name in TelemetryMsg.model_fields if name not in ("type", "sent")
)
"""The columns of a batch, one per field of :class:`TelemetryMsg` but its ``sent``."""


class TelemetryBatchBase(BaseModel):
    """Several device samples in one message, as columns: each field of
    :class:`TelemetryMsg` (but ``type`` and ``sent``) is a list with one item per sample,
    oldest first. Key names travel once per batch instead of once per sample, and the link
    carries a few messages a second instead of one per sample.

    ``{"type": "telemetry", "sent": 1700000000.04, "t": [12.00, 12.01, 12.02, 12.03],
    "mode": ["ACTIVE", ...], "pose": [[x, y, z, roll, pitch, yaw], ...], ...}``
    """

    model_config = _STRICT
    type: Literal["telemetry"] = "telemetry"
    sent: float = Field(description="Station wall clock when the batch was sent, Unix s.")

    @model_validator(mode="after")
    def _same_length(self) -> TelemetryBatchBase:
        n = len(self.column("t"))
        for name in SAMPLE_COLUMNS:
            if len(self.column(name)) != n:
                raise ValueError(f"{name} has {len(self.column(name))} samples, t has {n}")
        return self

    def column(self, name: str) -> list[Any]:
        return cast(list[Any], getattr(self, name))

    def __len__(self) -> int:
        return len(self.column("t"))

    def sample(self, i: int) -> TelemetryMsg:
        """Sample ``i`` (negative from the newest) as a :class:`TelemetryMsg`."""
        values = {name: self.column(name)[i] for name in SAMPLE_COLUMNS}
        return TelemetryMsg.model_construct(sent=self.sent, **values)

    def samples(self) -> list[TelemetryMsg]:
        return [self.sample(i) for i in range(len(self))]

    def newest(self) -> TelemetryMsg:
        """The newest sample: what the server's readers (3D view, K/B in force) look at."""
        return self.sample(-1)

    @staticmethod
    def of(rows: Sequence[Mapping[str, Any]], sent: float) -> TelemetryBatchBase:
        """A batch (validated) of ``rows``, each a sample's fields by name (a
        ``TelemetryMsg.model_dump()`` or the station's dict), oldest first."""
        return TelemetryBatch.model_validate(
            {"sent": sent} | {n: [row[n] for row in rows] for n in SAMPLE_COLUMNS}
        )


def _column(name: str) -> Any:
    info = TelemetryMsg.model_fields[name]
    item = Annotated[(info.annotation, *info.metadata)] if info.metadata else info.annotation
    return (
        Annotated[list[item], Field(min_length=1, max_length=BATCH_MAX)],  # type: ignore[valid-type]
        Field(description=f"Per sample: {info.description or name}"),
    )


TelemetryBatch: type[TelemetryBatchBase] = create_model(
    "TelemetryBatch",
    __base__=TelemetryBatchBase,
    __module__=__name__,
    **{name: _column(name) for name in SAMPLE_COLUMNS},
)
"""The telemetry message (:class:`TelemetryBatchBase` with one column per sample field)."""


class EventMsg(BaseModel):
    model_config = _STRICT
    type: Literal["event"] = "event"
    session_id: str | None = None
    event: SessionEvent


Phase = Literal[
    "idle", "homing", "running", "rest", "paused", "done", "stopped", "fault", "interrupted"
]
"""``interrupted``: the station ended the exercise early: it was held longer than the
station's limit, or the device's link was lost (the status's message says which)."""

HoldCode = Literal["pause", "therapist", "station", "watchdog", "supply_low", "device"]
"""Who or what holds the exercise: the patient's pause, the therapist's HOLD, the station
itself, the device's watchdog (its link went silent), the device's air supply, or the device
for a reason the station did not hear."""


class HoldInfo(BaseModel):
    """Why the device (or the exercise, between repetitions) is held, and since when."""

    model_config = _STRICT
    code: HoldCode
    text: str = Field(description="What happened, in a sentence for the therapist.")
    by: str = Field(description="device, station, patient or therapist:<id>.")
    since: float = Field(description="When the hold began, Unix s.")
    patient_may_resume: bool = Field(
        description="Only the patient's own pause may be continued from the patient's page."
    )
    ends_at: float | None = Field(
        default=None,
        description="When the exercise ends if still held (the station's limit), Unix s; "
        "null when no exercise is running.",
    )


class StatusMsg(BaseModel):
    """What the station is doing: sent on every change and once a second."""

    model_config = _STRICT
    type: Literal["status"] = "status"
    sent: float
    device_link: Literal["connected", "lost"] = "lost"
    device_mode: str = "UNKNOWN"
    trip: int = 0
    phase: Phase = "idle"
    session_id: str | None = None
    prescription_id: Id | None = None
    exercise: str | None = None
    set: int = 0
    rep: int = 0
    sets: int = 0
    repetitions: int = 0
    rest_remaining_s: float = 0.0
    pending_uploads: int = 0
    refused_uploads: int = Field(
        default=0,
        description="Sessions the server refused for good (not a valid recording, too "
        "large): kept aside at the station, in its spool's refused/ folder, and not sent again.",
    )
    refused_sessions: list[str] = Field(
        default_factory=list,
        max_length=REFUSED_NAMED,
        description="The ids of the first of them, with the server's reason: '<id>: <reason>'.",
    )
    overruns: int = 0
    frames_lost: int = Field(default=0, description="Serial frames lost on the host side.")
    message: str = Field(default="", description="Last error or notice, plain words.")
    hold: HoldInfo | None = Field(default=None, description="Why it is held; null if not.")
    fault: str = Field(
        default="", description="The device's own words for its latched fault or e-stop."
    )


REQUEST_ID_PATTERN = r"^[A-Za-z0-9._:-]{1,64}$"
"""What a command's ``request_id`` may be: up to 64 letters, digits and ``. _ : -`` (the
dashboard sends ``<time>-<counter>-<random>`` in base 36; a UUID fits). It goes into the
audit log, which is append-only and looked up by it: a control character there (PostgreSQL
cannot turn a NUL back into text) broke every look-up for good."""
_REQUEST_ID = re.compile(REQUEST_ID_PATTERN)


def _request_id(text: str) -> str:
    if not _REQUEST_ID.fullmatch(text):
        raise PydanticCustomError(
            "request_id", "must be 1 to 64 letters, digits, dots, underscores, colons or hyphens"
        )
    return text


RequestId = Annotated[
    str,
    Field(
        json_schema_extra={"pattern": REQUEST_ID_PATTERN, "minLength": 1, "maxLength": 64},
        description="1-64 letters, digits and . _ : - chosen by the viewer; links the command, "
        "its result and its audit rows.",
    ),
    AfterValidator(_request_id),
]

Action = Literal["set_impedance", "hold", "resume", "stop", "start"]
# Strict: a live K or B must be a JSON number, never true or "40" (see sessions.prescription).
# -0.0 is 0.0, as in a prescription (sessions.prescription.plus_zero).
LiveStiffness = Annotated[
    float, Field(strict=True, ge=0.0, le=STIFFNESS_MAX), AfterValidator(plus_zero)
]
LiveDamping = Annotated[
    float, Field(strict=True, ge=0.0, le=DAMPING_MAX), AfterValidator(plus_zero)
]


class Command(BaseModel):
    """A therapist's live change, relayed by the server to the station and the device."""

    model_config = _STRICT
    type: Literal["command"] = "command"
    request_id: RequestId
    action: Action
    stiffness: dict[Axis, LiveStiffness] | None = Field(
        default=None, description="set_impedance: new K per ankle axis, N·m/rad."
    )
    damping: dict[Axis, LiveDamping] | None = Field(
        default=None, description="set_impedance: new B per ankle axis, N·m·s/rad."
    )
    prescription_id: Id | None = Field(default=None, description="start: which exercise.")
    by: str = Field(default="", description="Set by the server: therapist:<id>.")


START_NEEDS_PRESCRIPTION = (
    "start needs a prescription_id: which of the patient's active prescriptions to run"
)
"""A Start that names no prescription (the server's refusal, and the station's)."""


def not_prescribed(prescription_id: int) -> str:
    """A Start of a prescription the station's patient has not (active), as refused."""
    return f"prescription {prescription_id} is not an active prescription of this patient"


Applies = Literal["now", "on_resume", "next_repetition"]


class Impedance(BaseModel):
    """K and B on some ankle axes."""

    model_config = _STRICT
    stiffness: dict[Axis, float] = Field(default_factory=dict, description="K, N·m/rad.")
    damping: dict[Axis, float] = Field(default_factory=dict, description="B, N·m·s/rad.")


class ImpedanceChange(BaseModel):
    """A live K/B change as the station made it, on the axes it asked for that the exercise
    uses. ``old`` is what was set before (by the prescription or the last change, whether or
    not the device has reached it yet), ``new`` what is set now. The session's event log and
    the server's audit log both record this one object, so they never disagree."""

    model_config = _STRICT
    old: Impedance
    new: Impedance
    applies: Applies = Field(
        description="now: the device slews to it at once; on_resume: the platform is held and "
        "the device renders it from Resume; next_repetition: nothing is rendered now (rest)."
    )

    @classmethod
    def between(
        cls,
        before: tuple[Mapping[str, float], Mapping[str, float]],
        after: tuple[Mapping[str, float], Mapping[str, float]],
        asked: Command,
        applies: Applies,
    ) -> ImpedanceChange:
        """The change from ``before`` to ``after`` (each K and B per axis of the exercise),
        on the axes ``asked`` names."""

        def pick(values: Mapping[str, float], names: Mapping[Axis, float] | None) -> Any:
            return {a: values[a] for a in (names or {}) if a in values}

        return cls(
            old=Impedance(
                stiffness=pick(before[0], asked.stiffness), damping=pick(before[1], asked.damping)
            ),
            new=Impedance(
                stiffness=pick(after[0], asked.stiffness), damping=pick(after[1], asked.damping)
            ),
            applies=applies,
        )


class CommandResult(BaseModel):
    """The device's own answer to a command (its ACK or NACK), or why it never got there."""

    model_config = _STRICT
    type: Literal["result"] = "result"
    request_id: RequestId
    ok: bool
    # What the station says goes into the audit log as it is: no control characters.
    code: Line = Field(
        default="",
        description="The device's NACK code; the station's REFUSED, OFFLINE or TIMEOUT; or the "
        "server's FORBIDDEN, OFFLINE, DUPLICATE (request_id in use), AUDIT (not recorded, "
        "not sent), SUPERSEDED (a HOLD or Stop went out while it waited: not sent), BUSY "
        "(too many of the view's commands in hand: not sent) or TIMEOUT.",
    )
    field: Line = ""
    text: Lines = ""
    rtt_ms: float = Field(default=0.0, description="Station to device and back, ms.")
    change: ImpedanceChange | None = Field(
        default=None, description="set_impedance, when made: what changed, and when it applies."
    )


class PrescriptionItem(BaseModel):
    model_config = _STRICT
    id: Id
    version: int
    patient_id: Id
    body: PrescriptionBody


class Prescriptions(BaseModel):
    model_config = _STRICT
    type: Literal["prescriptions"] = "prescriptions"
    items: list[PrescriptionItem]


class Presence(BaseModel):
    """Whether the station is connected to the server, told to its viewers when it changes."""

    model_config = _STRICT
    type: Literal["presence"] = "presence"
    online: bool
    text: str = Field(
        default="",
        description="What happened, in a sentence: the station connected or left, its server "
        "stopped holding it, or its viewer's server cannot reach the station's (then known is "
        "false). The server never sends it empty.",
    )
    known: bool = Field(
        default=True,
        description="False when the viewer's server cannot reach the station's (the relay is "
        "down): online is then false, and whether the station is connected is not known.",
    )
    warning: bool = Field(
        default=False,
        description="The station is online but the text says what the therapist must know "
        "while it is: two stations are using its token, so the platform shown may not be "
        "the one in use.",
    )


StationUp = Annotated[
    StationHello | TelemetryBatch | EventMsg | StatusMsg | CommandResult | Heartbeat,  # type: ignore[valid-type]
    Field(discriminator="type"),
]
StationDown = Annotated[Welcome | Prescriptions | Command | Heartbeat, Field(discriminator="type")]
ViewerUp = Annotated[Command | Heartbeat, Field(discriminator="type")]
ViewerDown = Annotated[
    Welcome | TelemetryBatch | EventMsg | StatusMsg | CommandResult | Presence | Heartbeat,  # type: ignore[valid-type]
    Field(discriminator="type"),
]

STATION_UP: TypeAdapter[Any] = TypeAdapter(StationUp)
STATION_DOWN: TypeAdapter[Any] = TypeAdapter(StationDown)
VIEWER_UP: TypeAdapter[Any] = TypeAdapter(ViewerUp)
VIEWER_DOWN: TypeAdapter[Any] = TypeAdapter(ViewerDown)


def json_schemas() -> dict[str, Any]:
    """The JSON Schema of each direction of each link, for clients in other languages."""
    return {
        "protocol": PROTOCOL,
        "station_to_server": STATION_UP.json_schema(),
        "server_to_station": STATION_DOWN.json_schema(),
        "viewer_to_server": VIEWER_UP.json_schema(),
        "server_to_viewer": VIEWER_DOWN.json_schema(),
    }


def error_text(exc: Exception, limit: int = 120) -> str:
    """A close reason (at most 123 bytes on the wire) naming the first bad field."""
    from pydantic import ValidationError

    if isinstance(exc, ValidationError) and exc.errors():
        err = exc.errors()[0]
        loc = ".".join(str(p) for p in err["loc"]) or "message"
        text = f"{loc}: {err['msg']}"
    else:
        text = str(exc) or type(exc).__name__
    return text.encode()[:limit].decode(errors="ignore")
