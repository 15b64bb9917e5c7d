"""Why the device stopped: trip codes and the sentence a technician reads for each.

Plain Python (the protocol, the station and the server import it without the compiled
controller). The numbers are stable: they travel in telemetry and events and are stored in
recordings, so a code is never renumbered or reused.
"""

from __future__ import annotations

from enum import IntEnum

from device.axes import AXES
from device.signals import chamber


class Trip(IntEnum):
    """Why the controller stopped. 0 means no trip."""

    NONE = 0
    SENSOR_INVALID = 1
    """A sensor read NaN or infinity."""
    PRESSURE_SENSOR = 2
    """A pressure transducer (chamber or supply) reads what air cannot do: open or short."""
    RANGE_OF_MOTION = 3
    """The measured pose left the range of motion (plus margin)."""
    WRENCH_LIMIT = 4
    """The foot's force or torque exceeded its limit."""
    LEG_SPEED = 5
    """A leg moved faster than the speed limit."""
    KINEMATICS = 6
    """Forward kinematics did not converge on the measured leg lengths."""
    COMMAND_INVALID = 7
    """A command reached the controller with NaN/inf or out of its limits."""
    STROKE_END = 8
    """A piston reached the end of its stroke."""
    ESTOP = 9
    """Emergency stop."""
    HOMING = 10
    """Homing did not reach the home pose in time."""
    SOFTWARE = 11
    """The device software raised an error inside a pass of its loop."""
    SUPPLY_LOSS = 12
    """The air supply fell below its loss mark while the platform moved."""
    SUPPLY_HIGH = 13
    """The air supply rose above its high mark while the platform moved."""
    LEG_SENSOR = 14
    """A leg length sensor jumped, or froze while its leg was driven."""
    FORCE_SENSOR = 15
    """The foot's force/torque sensor is saturated, dead (all zeros) or frozen, or disagrees
    with the load the six legs carry together (the channel names the component)."""
    FORCE_BALANCE = 16
    """A leg's chamber forces disagree with the platform's load."""
    VALVE = 17
    """A chamber's pressure did not answer its valves."""
    AIR_BALANCE = 18
    """A chamber's air did not add up with what its valves moved over 0.2 s (reported in a
    SERVICE event, not latched as a trip: see device.supervision.C_SERVICE)."""
    FOLLOWING = 19
    """The platform stayed further from its commanded pose than the following bound (task
    mode; the channel names the axis, 0-5) or a leg from its target (joint mode; 6 + leg)."""


SUPPLY_BY_AIR = 13
"""The channel of a SUPPLY_LOSS trip that the chambers' air found, not the supply transducer
(device.supervision.supply_by_air); the transducer's own trip names channel 12."""


TRIP_TEXT: dict[Trip, str] = {
    Trip.NONE: "no fault",
    Trip.SENSOR_INVALID: "a sensor gave no number (NaN or infinity): check its wiring and ADC",
    Trip.PRESSURE_SENSOR: "a pressure transducer reads what air cannot do (open wire, short, "
    "a jump, or a reading frozen without its noise): check that transducer and its cable",
    Trip.RANGE_OF_MOTION: "the platform left its range of motion",
    Trip.WRENCH_LIMIT: "the force or torque on the foot plate went over its limit",
    Trip.LEG_SPEED: "a leg moved faster than the speed limit",
    Trip.KINEMATICS: "the leg lengths fit no platform pose: check the leg length sensors",
    Trip.COMMAND_INVALID: "a command reached the controller outside its limits",
    Trip.STROKE_END: "a piston reached the end of its stroke",
    Trip.ESTOP: "emergency stop",
    Trip.HOMING: "homing did not reach the home pose in time: check air supply and legs",
    Trip.SOFTWARE: "the device software failed inside its control loop: valves closed; "
    "report the event text to the maintainer",
    Trip.SUPPLY_LOSS: "the air supply was lost while moving: check the compressor, its hose "
    "and the regulator",
    Trip.SUPPLY_HIGH: "the air supply is above its high mark: check the regulator",
    Trip.LEG_SENSOR: "a leg length sensor jumped or stopped changing while its leg was "
    "driven: check that sensor and its cable, then the force/torque sensor's zero and that "
    "leg's two pressure transducers' (a load read 10-20 N off makes the loop push a leg that "
    "then does not move)",
    Trip.FORCE_SENSOR: "the foot's force/torque sensor is saturated, dead, frozen or reads "
    "a load the legs do not carry: check its cable, power, amplifier and zero",
    Trip.FORCE_BALANCE: "a leg's chamber forces disagree with the load on the platform: "
    "check that leg's pressure transducers, valves and tubes for a leak",
    Trip.VALVE: "a chamber's pressure did not follow its valves: a valve stuck open or "
    "closed, a leak, a blocked tube, or its transducer frozen or jumped (if it held its "
    "pressure against its open exhaust, that exhaust stays open to bleed a stuck intake "
    "until re-armed)",
    Trip.AIR_BALANCE: "a chamber's air does not add up with what its valves moved: a leak "
    "in its tube, fitting or seal, a valve stuck, its transducer's zero off, or its leg's "
    "length sensor stuck or off",
    Trip.FOLLOWING: "the platform left the pose it was commanded to: check the foot's "
    "force/torque sensor zero, then the valves and tubes for a leak",
}
"""For the technician: what tripped and where to look. Events carry the code; hosts show this."""


def describe(code: int) -> str:
    """The sentence for a trip code, also for a code this software does not know."""
    try:
        return TRIP_TEXT[Trip(code)]
    except ValueError:
        return f"unknown trip code {code}"


def where(trip: int, channel: int) -> str:
    """The part a trip names, in a technician's words ('' when it names none)."""
    if channel < 0:
        return ""
    if trip in (Trip.PRESSURE_SENSOR, Trip.VALVE, Trip.AIR_BALANCE):
        return chamber(channel)
    if trip in (Trip.LEG_SENSOR, Trip.FORCE_BALANCE, Trip.STROKE_END, Trip.LEG_SPEED):
        return f"leg {channel + 1}"
    if trip in (Trip.FORCE_SENSOR, Trip.WRENCH_LIMIT) and channel < len(_WRENCH_PARTS):
        return _WRENCH_PARTS[channel]
    if trip == Trip.RANGE_OF_MOTION and channel < len(AXES):
        return AXES[channel]
    if trip == Trip.SUPPLY_LOSS and channel == SUPPLY_BY_AIR:
        return (
            "the air of two legs or more (a supply its transducer missed, or a fault on each: "
            "see SERVICE)"
        )
    if trip == Trip.FOLLOWING:
        if channel < len(AXES):
            return AXES[channel]
        return f"leg {channel - len(AXES) + 1}"
    return ""


_WRENCH_PARTS = (
    "force along x",
    "force along y",
    "force along z",
    "torque about roll",
    "torque about pitch",
    "torque about yaw",
)
"""The component of the wrench at the ankle a FORCE_SENSOR trip names (base frame)."""


def event_text(trip: int, channel: int, limit: int = 120) -> str:
    """What a FAULT event says: the code, the part, and the sentence when it fits."""
    part = where(trip, channel)
    head = f"{Trip(trip).name}" + (f" on {part}" if part else "")
    full = f"{head}: {describe(trip)}"
    return full if len(full.encode()) <= limit else head
