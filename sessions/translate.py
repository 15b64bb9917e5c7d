"""The device's words in a session's: its identity, its telemetry samples and its events.

The home station hears the device (:mod:`device.protocol.messages`) and speaks sessions (the
recording's header and events, :mod:`sessions.wire`'s telemetry); these are the one place
where the first becomes the second.
"""

from __future__ import annotations

from typing import Any, Final

from device.protocol import messages as msg
from device.protocol.messages import EventKind
from sessions.recording import DeviceInfo, SessionEvent

EVENT_KINDS: Final[dict[EventKind, str]] = {
    EventKind.MODE_CHANGE: "mode",
    EventKind.WATCHDOG: "watchdog",
    EventKind.LIMIT: "limit",
    EventKind.FAULT: "fault",
    EventKind.SEGMENT_DONE: "segment_done",
    EventKind.HOMED: "homed",
    EventKind.ESTOP: "estop",
}
"""A device event's kind as a session names it; any other kind by its own name, lowercase."""


def device_info(hello: msg.DeviceHello) -> DeviceInfo:
    """What a session records of the device it ran on."""
    return DeviceInfo(
        firmware=hello.firmware,
        hardware=hello.hardware,
        telemetry_hz=hello.telemetry_hz,
        home_pose=list(hello.home_pose),
        calibrated=bool(hello.capabilities & msg.Capability.CALIBRATED),
    )


def device_event(event: msg.Event, wall: float) -> SessionEvent:
    """A device's event as the session records it; ``wall``: when it happened (station clock)."""
    return SessionEvent(
        wall=wall,
        t=event.time,
        kind=EVENT_KINDS.get(event.kind, event.kind.name.lower()),
        by="device",
        detail={
            "from": event.mode_from.name,
            "to": event.mode_to.name,
            "code": event.code,
            "value": event.value,
            "text": event.text,
        },
    )


def telemetry_sample(t: msg.Telemetry, set_: int, rep: int) -> dict[str, Any]:
    """One sample's fields as :class:`~sessions.wire.TelemetryMsg` names them (its batch
    gives the ``sent``); validated when its batch is made. ``set_`` and ``rep``: where in the
    exercise it was taken (0 outside one)."""
    return {
        "t": t.time,
        "mode": t.mode.name,
        "trip": int(t.trip),
        "segment_id": t.segment_id,
        "set": set_,
        "rep": rep,
        "pose": list(t.pose),
        "pose_cmd": list(t.pose_cmd),
        "legs": list(t.legs),
        "pressures": list(t.pressures),
        "wrench": list(t.wrench),
        "stiffness": list(t.stiffness),
        "damping": list(t.damping),
        "lag_ms": t.pacing_lag_ms,
        "overruns": t.overruns,
        "frames_dropped": t.frames_dropped,
    }
