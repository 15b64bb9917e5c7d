"""The messages of the serial link: one typed dataclass each, the single master copy.

Every message is a frozen dataclass whose fields carry their wire format, count, unit and
meaning (:func:`wire`). From that one description come the fixed little-endian layout,
:func:`pack` / :func:`unpack`, the checks on the way in and the protocol table of the README
(:func:`markdown_table`; a test keeps the README equal to it).

Type numbers are per direction: the device sends 1-15, the host sends 1 and 16 and up.
Type 1 is the handshake in both directions (see ``framing.HANDSHAKE_TYPE``).

Units are SI throughout: metres, radians, newtons, newton metres, pascals (gauge unless
stated), seconds. Poses and ranges of motion are relative to the home pose.
"""

from __future__ import annotations

import dataclasses
import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from enum import IntEnum, IntFlag
from typing import Any, ClassVar, Literal, dataclass_transform

from device.axes import AXES
from device.protocol.framing import HANDSHAKE_TYPE, MAX_BODY, Frame, encode_frame
from device.trips import Trip
from device.waveforms import Waveform

Sender = Literal["host", "device"]

SIX_F: tuple[float, ...] = (0.0,) * 6


class DeviceMode(IntEnum):
    """The device service's mode. Valves are closed in every mode but HOMING and ACTIVE."""

    IDLE = 0
    """Not homed; valves closed. Leaves only on arm/home."""
    HOMING = 1
    """Moving slowly to the home pose."""
    READY = 2
    """At home, valves closed, waiting for an exercise segment."""
    ACTIVE = 3
    """An exercise segment is running."""
    HOLD = 4
    """Segment paused (hold command or watchdog); valves closed; resumes only on command."""
    ESTOP = 5
    """Emergency stop, latched until re-armed."""
    FAULT = 6
    """A safety limit tripped, latched until re-armed; the trip code says which."""


class TelemetryFlags(IntFlag):
    NONE = 0
    HOMED = 1
    """The platform has been homed since the last stop."""
    VENTING = 2
    """Release in progress: exhaust valves pulse, the platform sinks slowly."""
    SEGMENT = 4
    """A segment is loaded (running in ACTIVE, paused in HOLD)."""
    SUPPLY_LOW = 8
    """The air supply is below its low mark: homing, a segment and a resume are refused until
    it has stayed above its resume mark for a while (the SUPPLY_LOW event says when it fell)."""


class Capability(IntFlag):
    NONE = 0
    SIMULATED = 1
    """The plant is a simulation, not a platform."""
    TASK_SPACE = 2
    IMPEDANCE = 4
    RELEASE = 8
    EVENT_REPLAY = 16
    CALIBRATED = 32
    """The controller subtracts this unit's identified zeros from its readings
    (``ankle device --calibration FILE``, made by ``ankle device --identify FILE``); without
    it a leg sensor's zero error (up to 1 mm on a build) is a steady error of the platform."""


class EventKind(IntEnum):
    MODE_CHANGE = 1
    WATCHDOG = 2
    """No valid frame from the host for the watchdog time, or a HELLO from a new connection
    (a restarted host) while moving: ACTIVE went to HOLD."""
    LIMIT = 3
    """A safety limit tripped (code = trip code); the device is in FAULT."""
    FAULT = 4
    """A fault other than a limit (sensor, kinematics, command); the device is in FAULT."""
    SEGMENT_DONE = 5
    """The segment ran its full duration; the device is READY."""
    HOMED = 6
    ESTOP = 7
    SUPPLY_LOW = 8
    """The air supply fell below its low mark (value: supply, Pa gauge): ACTIVE went to HOLD
    (HOMING to IDLE); at rest the mode stays. Motion is refused until it recovers (the
    telemetry's SUPPLY_LOW flag clears). Once each time it falls."""
    SERVICE = 9
    """A chamber's air does not add up (code AIR_BALANCE, a leak or a stuck valve): the
    running segment (or homing) finishes under control, nothing new starts until a re-arm.
    When it ends and the valves shut, the chamber is named by a VALVE fault at once and
    held by its own valves; after an e-stop or any other trip too."""
    DAMPING_RAISED = 10
    """A compliant axis rang with the foot on it and the ring guard raised the damping the
    law renders there (code: the axis 0-5; value: the factor now on its damping); it holds
    until that axis's stiffness or damping changes or the device homes again (device.ring)."""


class NackCode(IntEnum):
    MALFORMED = 1
    """The body does not match the message's layout, or an enum value is unknown."""
    UNKNOWN_COMMAND = 2
    NOT_FINITE = 3
    """A number is NaN or infinite."""
    OUT_OF_RANGE = 4
    """A value, or a limit, is outside what the device allows; its own limits always win."""
    WRONG_MODE = 5
    """The command does not apply in the current mode."""
    LATCHED = 6
    """ESTOP or FAULT is latched: re-arm first."""
    NOT_HOMED = 7
    """Arm/home first."""
    DEVICE_FAULT = 8
    """The device failed while applying the command and is now in FAULT (trip SOFTWARE)."""
    SUPPLY_LOW = 9
    """The air supply is below its low mark: nothing moves until it recovers."""
    SERVICE_NEEDED = 10
    """The device found a fault that needs a technician (a SERVICE event): re-arm after."""


_STRUCT_KIND = {
    "d": float,
    "f": float,
    "B": int,
    "b": int,
    "H": int,
    "h": int,
    "I": int,
    "?": bool,
}


def wire(
    fmt: str,
    count: int = 1,
    *,
    unit: str = "",
    doc: str = "",
    enum: type[IntEnum] | type[IntFlag] | None = None,
    default: Any = None,
) -> Any:
    """A message field: struct format (``d f B b H h I ?`` or ``Ns`` text), count, unit, doc."""
    if default is None:
        if fmt.endswith("s"):
            default = ""
        elif enum is not None:
            first = enum(0) if issubclass(enum, IntFlag) else next(iter(enum))
            default = (first,) * count if count > 1 else first
        else:
            zero = _STRUCT_KIND[fmt]()
            default = (zero,) * count if count > 1 else zero
    meta = {"fmt": fmt, "count": count, "unit": unit, "doc": doc, "enum": enum}
    return dataclasses.field(default=default, metadata=meta)


class MessageError(ValueError):
    """A body that does not decode into its message; ``code`` is the NACK code to answer,
    ``field`` the field at fault and ``axis`` its axis (index into ``AXES``), where known."""

    def __init__(self, code: NackCode, text: str, field: str = "", axis: int | None = None) -> None:
        super().__init__(text)
        self.code = code
        self.field = field
        self.axis = axis


@dataclass(frozen=True)
class _FieldSpec:
    name: str
    fmt: str
    count: int
    unit: str
    doc: str
    enum: type[IntEnum] | type[IntFlag] | None

    @property
    def is_text(self) -> bool:
        return self.fmt.endswith("s")

    @property
    def wire_type(self) -> str:
        names = {"d": "f64", "f": "f32", "B": "u8", "b": "i8", "H": "u16", "h": "i16"}
        names |= {"I": "u32", "?": "bool"}
        if self.is_text:
            return f"utf-8[{self.fmt[:-1]}]"
        base = names[self.fmt]
        return f"{base}[{self.count}]" if self.count > 1 else base


@dataclass_transform(frozen_default=True)
class Message:
    """Base of every message: a subclass names its type and sender and becomes a frozen
    dataclass with a compiled layout, registered for decoding::

        class Ack(Message, type_=4, sender="device"):
            ack_seq: int = wire("H")
    """

    TYPE: ClassVar[int]
    SENDER: ClassVar[Sender]
    _fields: ClassVar[tuple[_FieldSpec, ...]]
    _struct: ClassVar[struct.Struct]
    _bytes: ClassVar[struct.Struct]
    """The same layout with each bool as its byte, which :func:`unpack` reads: a bool
    field's byte is checked to be 0 or 1 (``struct`` reads any other byte as true)."""

    def __init_subclass__(cls, type_: int, sender: Sender, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        dataclass(frozen=True)(cls)
        specs = []
        fmt = "<"
        for f in dataclasses.fields(cls):  # type: ignore[arg-type]
            m = f.metadata
            specs.append(_FieldSpec(f.name, m["fmt"], m["count"], m["unit"], m["doc"], m["enum"]))
            fmt += m["fmt"] if m["fmt"].endswith("s") else m["fmt"] * m["count"]
        cls.TYPE = type_
        cls.SENDER = sender
        cls._fields = tuple(specs)
        cls._struct = struct.Struct(fmt)
        cls._bytes = struct.Struct(fmt.replace("?", "B"))
        if cls._struct.size > MAX_BODY:
            raise TypeError(f"{cls.__name__} is {cls._struct.size} bytes, above {MAX_BODY}")
        registry = HOST_MESSAGES if sender == "host" else DEVICE_MESSAGES
        if type_ in registry:
            raise TypeError(f"message type {type_} from the {sender} is taken")
        registry[type_] = cls

    @classmethod
    def layout(cls) -> tuple[_FieldSpec, ...]:
        return cls._fields

    @classmethod
    def size(cls) -> int:
        return cls._struct.size


HOST_MESSAGES: dict[int, type[Message]] = {}
DEVICE_MESSAGES: dict[int, type[Message]] = {}


# -- device -> host ----------------------------------------------------------------------


class DeviceHello(Message, type_=HANDSHAKE_TYPE, sender="device"):
    """The device's answer to :class:`Hello`: who it is, its geometry and its own limits."""

    firmware: str = wire("24s", doc="Software version of the device service.")
    hardware: str = wire("8s", doc="`sim` or `board`.")
    capabilities: Capability = wire("I", enum=Capability, doc="What the device can do.")
    tick_hz: int = wire("H", unit="Hz", doc="Controller interrupt rate.")
    pwm_hz: int = wire("H", unit="Hz", doc="Valve PWM and control rate.")
    telemetry_hz: int = wire("H", unit="Hz", doc="Telemetry rate now.")
    telemetry_hz_max: int = wire("H", unit="Hz", doc="Highest telemetry rate this link allows.")
    watchdog_ms: int = wire("H", unit="ms", doc="Watchdog time now.")
    watchdog_ms_min: int = wire("H", unit="ms")
    watchdog_ms_max: int = wire("H", unit="ms")
    stroke: float = wire("f", unit="m", doc="Cylinder stroke.")
    min_length: float = wire("f", unit="m", doc="Leg length at zero piston displacement.")
    home_pose: tuple[float, ...] = wire(
        "f", 6, unit="m, rad", doc="Home pose of the ankle frame in the base frame."
    )
    base_joints: tuple[float, ...] = wire("f", 18, unit="m", doc="6 base joint centres, xyz.")
    platform_joints: tuple[float, ...] = wire(
        "f", 18, unit="m", doc="6 platform joint centres in the platform frame, xyz."
    )
    rom_low: tuple[float, ...] = wire("f", 6, unit="m, rad", doc="Range of motion, low end.")
    rom_high: tuple[float, ...] = wire("f", 6, unit="m, rad", doc="Range of motion, high end.")
    stiffness_max: tuple[float, ...] = wire("f", 6, unit="N/m, N m/rad")
    damping_max: tuple[float, ...] = wire("f", 6, unit="N s/m, N m s/rad")
    stiffness_slew: tuple[float, ...] = wire(
        "f", 6, unit="(N/m, N m/rad)/s", doc="Fastest change of K in force."
    )
    damping_slew: tuple[float, ...] = wire("f", 6, unit="(N s/m, N m s/rad)/s")
    axis_speed_max: tuple[float, ...] = wire(
        "f", 6, unit="m/s, rad/s", doc="Fastest target waveform per axis."
    )
    force_limit: float = wire("f", unit="N", doc="Largest force on the foot plate.")
    torque_limit: float = wire("f", unit="N m", doc="Largest torque on the foot plate.")
    leg_speed_limit: float = wire("f", unit="m/s")
    segment_duration_max: float = wire("f", unit="s")
    envelope_stiffness: tuple[float, ...] = wire(
        "f",
        3,
        unit="N/m, N m/rad",
        doc="Stable stiffness-damping envelope: the lower edges of its three bands of K.",
    )
    damping_min: tuple[float, ...] = wire(
        "f",
        18,
        unit="N s/m, N m s/rad",
        doc="Least B per axis (axis-major) in each band of K; a compliant axis needs B >= it.",
    )


class Telemetry(Message, type_=2, sender="device"):
    """One sample of the device's state, sent at the configured rate."""

    time: float = wire("d", unit="s", doc="Device time since the service started.")
    mode: DeviceMode = wire("B", enum=DeviceMode)
    trip: Trip = wire("B", enum=Trip, doc="Latched trip code, 0 if none.")
    flags: TelemetryFlags = wire("B", enum=TelemetryFlags)
    segment_id: int = wire("I", doc="Segment loaded, 0 if none.")
    segment_time: float = wire("f", unit="s", doc="Time into the segment, pauses excluded.")
    pose: tuple[float, ...] = wire("f", 6, unit="m, rad", doc="Measured pose.")
    pose_cmd: tuple[float, ...] = wire("f", 6, unit="m, rad", doc="Commanded pose.")
    legs: tuple[float, ...] = wire("f", 6, unit="m", doc="Piston displacements, 0..stroke.")
    pressures: tuple[float, ...] = wire(
        "f", 12, unit="Pa", doc="Chambers; 2i cap side, 2i+1 rod side of leg i+1."
    )
    supply: float = wire("f", unit="Pa", doc="Supply pressure.")
    wrench: tuple[float, ...] = wire(
        "f",
        6,
        unit="N, N m",
        doc="The patient's wrench at the ankle: measured minus the resting wrench at the "
        "segment's start.",
    )
    stiffness: tuple[float, ...] = wire("f", 6, unit="N/m, N m/rad", doc="K in force.")
    damping: tuple[float, ...] = wire("f", 6, unit="N s/m, N m s/rad", doc="B in force.")
    duty: tuple[int, ...] = wire(
        "b", 12, unit="slots of 28", doc="Valve duty per chamber; + intake, - exhaust."
    )
    frames_ok: int = wire("I", doc="Valid frames received.")
    frames_dropped: int = wire("I", doc="Frames dropped (CRC, length, COBS, version).")
    commands_refused: int = wire("I", doc="Commands answered with NACK.")
    overruns: int = wire("I", doc="Times the loop fell over a control period behind.")
    clock_resets: int = wire(
        "I", doc="Times the loop fell over 1 s behind and skipped the time lost."
    )
    pacing_lag_ms: float = wire("f", unit="ms", doc="How far device time trails wall time.")
    last_event_id: int = wire("I", doc="Id of the latest event (to notice a lost one).")


class Event(Message, type_=3, sender="device"):
    """Something happened; ids count up from 1 so the host can ask for lost ones again."""

    event_id: int = wire("I")
    time: float = wire("d", unit="s")
    kind: EventKind = wire("B", enum=EventKind)
    mode_from: DeviceMode = wire("B", enum=DeviceMode)
    mode_to: DeviceMode = wire("B", enum=DeviceMode)
    code: int = wire("B", doc="Trip code for LIMIT/FAULT/ESTOP; the axis (0-5) for DAMPING_RAISED.")
    value: float = wire(
        "f",
        doc="WATCHDOG: ms since the last valid frame; DAMPING_RAISED: the factor on the "
        "axis's damping.",
    )
    text: str = wire("120s", doc="For people: what happened, and for a fault why.")


class Ack(Message, type_=4, sender="device"):
    """The command with this sequence number was accepted and applied."""

    ack_seq: int = wire("H")
    command: int = wire("B", doc="Message type of the command.")
    mode: DeviceMode = wire("B", enum=DeviceMode, doc="Mode after the command.")


class Nack(Message, type_=5, sender="device"):
    """The command with this sequence number was refused; nothing was changed."""

    ack_seq: int = wire("H")
    command: int = wire("B")
    mode: DeviceMode = wire("B", enum=DeviceMode)
    code: NackCode = wire("B", enum=NackCode)
    field: str = wire("16s", doc="Field at fault, if one.")
    text: str = wire("96s", doc="What was wrong, for people.")


# -- host -> device ----------------------------------------------------------------------


class Hello(Message, type_=HANDSHAKE_TYPE, sender="host"):
    """Opens a session; the device answers with :class:`DeviceHello`."""

    host: str = wire("24s", doc="Name and version of the host software.")
    nonce: int = wire("I", doc="Random per connection; a new one forgets old sequence numbers.")


class Heartbeat(Message, type_=16, sender="host"):
    """Keeps the watchdog fed; any valid frame does, this one when there is nothing else."""


class Configure(Message, type_=17, sender="host"):
    """Telemetry rate and watchdog time, each within the device's bounds (any mode)."""

    telemetry_hz: int = wire("H", unit="Hz", doc="1 .. telemetry_hz_max.")
    watchdog_ms: int = wire("H", unit="ms", doc="watchdog_ms_min .. watchdog_ms_max.")


class ArmHome(Message, type_=18, sender="host"):
    """IDLE, READY or HOLD -> HOMING: move slowly to the home pose, then READY."""


class StartSegment(Message, type_=19, sender="host"):
    """READY or ACTIVE -> ACTIVE: run one exercise segment.

    Each axis follows its waveform relative to home: HOLD stays at ``center``; SINE is
    ``center + amplitude sin(2 pi frequency t)``; RAMP goes from ``center`` to ``ramp_end``
    at ``ramp_rate``. The platform first moves from where it is to the waveform's start at a
    gentle speed. Compliant axes render K and B around the waveform.
    """

    segment_id: int = wire("I", doc="Chosen by the host, echoed in telemetry; not 0.")
    duration: float = wire("f", unit="s", doc="After it, READY and a SEGMENT_DONE event.")
    waveform: tuple[Waveform, ...] = wire("B", 6, enum=Waveform, doc="Per axis.")
    center: tuple[float, ...] = wire("f", 6, unit="m, rad")
    amplitude: tuple[float, ...] = wire("f", 6, unit="m, rad")
    frequency: tuple[float, ...] = wire("f", 6, unit="Hz")
    ramp_end: tuple[float, ...] = wire("f", 6, unit="m, rad")
    ramp_rate: tuple[float, ...] = wire("f", 6, unit="m/s, rad/s")
    stiffness: tuple[float, ...] = wire("f", 6, unit="N/m, N m/rad")
    damping: tuple[float, ...] = wire("f", 6, unit="N s/m, N m s/rad")
    compliant: tuple[bool, ...] = wire("?", 6, doc="Render K, B on this axis.")
    rom_low: tuple[float, ...] = wire("f", 6, unit="m, rad", doc="Within the device's.")
    rom_high: tuple[float, ...] = wire("f", 6, unit="m, rad", doc="Within the device's.")
    force_limit: float = wire("f", unit="N", doc="At most the device's.")
    torque_limit: float = wire("f", unit="N m", doc="At most the device's.")


class SetImpedance(Message, type_=20, sender="host"):
    """Live K and B for the running segment (ACTIVE or HOLD); slewed by the device."""

    stiffness: tuple[float, ...] = wire("f", 6, unit="N/m, N m/rad")
    damping: tuple[float, ...] = wire("f", 6, unit="N s/m, N m s/rad")


class HoldCmd(Message, type_=21, sender="host"):
    """ACTIVE -> HOLD (HOMING -> IDLE): close the valves where the platform is."""


class Resume(Message, type_=22, sender="host"):
    """HOLD -> ACTIVE: continue the segment where it paused."""


class EStop(Message, type_=23, sender="host"):
    """Any mode -> ESTOP, latched; valves closed (a chamber named for service, or whose air
    moves afterwards, is held by its own valves)."""


class Rearm(Message, type_=24, sender="host"):
    """ESTOP or FAULT -> IDLE, or clears a need for service; homing is needed before motion."""


class Release(Message, type_=25, sender="host"):
    """Vent slowly to free the foot (not in HOMING or ACTIVE); the platform sinks."""


class ReplayEvents(Message, type_=26, sender="host"):
    """Send again every kept event with an id above ``after_id`` (the last 64 are kept)."""

    after_id: int = wire("I")


# -- codec -------------------------------------------------------------------------------


def _flatten(msg: Message) -> Iterator[Any]:
    for spec in msg.layout():
        value = getattr(msg, spec.name)
        if spec.is_text:
            yield str(value).encode("utf-8")[: int(spec.fmt[:-1])]
        elif spec.count > 1:
            if len(value) != spec.count:
                raise ValueError(f"{type(msg).__name__}.{spec.name} needs {spec.count} values")
            yield from (int(v) if spec.enum else v for v in value)
        else:
            yield int(value) if spec.enum else value


def pack(msg: Message) -> bytes:
    """The body of ``msg`` (fixed layout, little-endian)."""
    return msg._struct.pack(*_flatten(msg))


def _where(spec: _FieldSpec, index: int | None) -> tuple[str, int | None]:
    """How a refusal names one value of a field: the field, and its axis where the field
    holds one value per axis."""
    if index is not None and spec.count == len(AXES):
        return f"{spec.name} of {AXES[index]}", index
    return spec.name, None


def _enum(spec: _FieldSpec, value: int, index: int | None = None) -> Any:
    assert spec.enum is not None
    try:
        return spec.enum(value)
    except ValueError:
        name, axis = _where(spec, index)
        raise MessageError(
            NackCode.MALFORMED,
            f"{name}: {value} is not a known {spec.enum.__name__}",
            spec.name,
            axis,
        ) from None


def _value(spec: _FieldSpec, value: Any, index: int | None = None) -> Any:
    """One decoded value of a field: an enum member, a bool from a byte that is 0 or 1 (any
    other is a corrupt or foreign body, not true: ``struct`` reads it as true), or as read."""
    if spec.enum is not None:
        return _enum(spec, value, index)
    if spec.fmt == "?":
        if value not in (0, 1):
            name, axis = _where(spec, index)
            text = f"{name}: {value} is not 0 or 1"
            raise MessageError(NackCode.MALFORMED, text, spec.name, axis)
        return bool(value)
    return value


def unpack(cls: type[Message], body: bytes) -> Message:
    """Decode a body of message class ``cls``; :class:`MessageError` if it does not fit."""
    if len(body) != cls.size():
        raise MessageError(
            NackCode.MALFORMED,
            f"{cls.__name__} body is {len(body)} bytes, expected {cls.size()}",
        )
    values = cls._bytes.unpack(body)
    kwargs: dict[str, Any] = {}
    i = 0
    for spec in cls.layout():
        if spec.is_text:
            raw: bytes = values[i]
            kwargs[spec.name] = raw.rstrip(b"\0").decode("utf-8", "replace")
            i += 1
        elif spec.count > 1:
            chunk = values[i : i + spec.count]
            if spec.enum is not None or spec.fmt == "?":
                chunk = tuple(_value(spec, v, j) for j, v in enumerate(chunk))
            kwargs[spec.name] = chunk
            i += spec.count
        else:
            kwargs[spec.name] = _value(spec, values[i])
            i += 1
    return cls(**kwargs)


def encode(msg: Message, seq: int) -> bytes:
    """Wire bytes of ``msg`` as frame number ``seq``."""
    return encode_frame(Frame(msg.TYPE, seq & 0xFFFF, pack(msg)))


def decode(frame: Frame, sender: Sender) -> Message:
    """The message in a checked frame sent by ``sender``; :class:`MessageError` if unknown."""
    registry = HOST_MESSAGES if sender == "host" else DEVICE_MESSAGES
    cls = registry.get(frame.type)
    if cls is None:
        raise MessageError(NackCode.UNKNOWN_COMMAND, f"unknown message type {frame.type}")
    return unpack(cls, frame.body)


def non_finite_field(msg: Message) -> str | None:
    """Name of the first float field holding NaN or infinity, if any."""
    for spec in msg.layout():
        if spec.fmt not in ("f", "d"):
            continue
        value = getattr(msg, spec.name)
        values = value if spec.count > 1 else (value,)
        if not all(math.isfinite(v) for v in values):
            return spec.name
    return None


def markdown_table() -> str:
    """The protocol as Markdown: one table of messages, then each message's fields."""
    lines = [
        "| type | from | message | body bytes | meaning |",
        "|---|---|---|---|---|",
    ]
    everything = [*DEVICE_MESSAGES.values(), *HOST_MESSAGES.values()]
    for cls in everything:
        doc = " ".join((cls.__doc__ or "").strip().split("\n\n")[0].split())
        doc = doc.replace(":class:", "")
        lines.append(f"| {cls.TYPE} | {cls.SENDER} | `{cls.__name__}` | {cls.size()} | {doc} |")
    for cls in everything:
        if not cls.layout():
            continue
        lines += ["", f"`{cls.__name__}` ({cls.SENDER}, type {cls.TYPE}):", ""]
        lines += ["| field | type | unit | meaning |", "|---|---|---|---|"]
        for spec in cls.layout():
            doc = spec.doc
            if spec.enum is not None:
                names = ", ".join(f"{m.value} {m.name}" for m in spec.enum if m.name)
                doc = f"{doc} {spec.enum.__name__}: {names}.".strip()
            lines.append(f"| `{spec.name}` | {spec.wire_type} | {spec.unit} | {doc} |")
    return "\n".join(lines) + "\n"
