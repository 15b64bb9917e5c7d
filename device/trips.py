"""Why the device stopped: trip codes and the sentence a technician reads for each.

Plain Python (the protocol, the station and the server import it without the compiled
controller). The numbers are stable: they travel in telemetry and events and are stored in
recordings, so a code is never renumbered or reused.
"""

from __future__ import annotations

from enum import IntEnum


class Trip(IntEnum):
    """Why the controller stopped. 0 means no trip."""

    NONE = 0
    SENSOR_INVALID = 1
    """A sensor read NaN or infinity."""
    PRESSURE_RANGE = 2
    """A chamber or the supply read outside its physical range."""
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


TRIP_TEXT: dict[Trip, str] = {
    Trip.NONE: "no fault",
    Trip.SENSOR_INVALID: "a sensor gave no number (NaN or infinity): check its wiring and ADC",
    Trip.PRESSURE_RANGE: "a pressure reading is outside what the air can do: check transducers",
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
}
"""For the technician: what tripped and where to look. Events carry the code; hosts show this."""


def describe(code: int) -> str:
    """The sentence for a trip code, also for a code this software does not know."""
    try:
        return TRIP_TEXT[Trip(code)]
    except ValueError:
        return f"unknown trip code {code}"
