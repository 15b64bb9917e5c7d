"""Whose part a trip names, when ``ankle sim`` had several faults (lab.experiments)."""

from device.plant.faults import Fault, FaultKind
from device.trips import SUPPLY_BY_AIR, Trip
from lab.experiments import fault_parts, trip_part

OWN: dict[FaultKind, Trip] = {
    FaultKind.PRESSURE_OPEN: Trip.PRESSURE_SENSOR,
    FaultKind.PRESSURE_SHORT: Trip.PRESSURE_SENSOR,
    FaultKind.PRESSURE_STUCK: Trip.PRESSURE_SENSOR,
    FaultKind.PRESSURE_OFFSET: Trip.PRESSURE_SENSOR,
    FaultKind.LEG_STUCK: Trip.LEG_SENSOR,
    FaultKind.LEG_OFFSET: Trip.LEG_SENSOR,
    FaultKind.LEG_NOISE: Trip.LEG_SENSOR,
    FaultKind.FT_DEAD: Trip.FORCE_SENSOR,
    FaultKind.FT_SATURATED: Trip.FORCE_SENSOR,
    FaultKind.FT_OFFSET: Trip.FORCE_SENSOR,
    FaultKind.VALVE_STUCK_OPEN: Trip.VALVE,
    FaultKind.VALVE_STUCK_CLOSED: Trip.VALVE,
    FaultKind.CHAMBER_LEAK: Trip.VALVE,
    FaultKind.SUPPLY_LOSS: Trip.SUPPLY_LOSS,
    FaultKind.SUPPLY_DROOP: Trip.SUPPLY_LOSS,
}
"""The trip that names a fault of each kind by its own part."""

CHANNELS = {Trip.PRESSURE_SENSOR: 13, Trip.LEG_SENSOR: 6, Trip.FORCE_SENSOR: 6, Trip.VALVE: 12}
"""Channels (from 0) of the faults each trip of OWN answers; valves: 24, one chamber's two."""


def _fault(kind: FaultKind, channel: int) -> Fault:
    value = {FaultKind.SUPPLY_DROOP: 3.5, FaultKind.CHAMBER_LEAK: 0.1}.get(kind, 0.0)
    value = {FaultKind.PRESSURE_OFFSET: 1.0, FaultKind.LEG_OFFSET: 2.0}.get(kind, value)
    value = {FaultKind.LEG_NOISE: 0.5, FaultKind.FT_OFFSET: 10.0}.get(kind, value)
    return Fault(kind, 0.5, channel, value)


def test_a_trip_names_the_part_of_the_fault_it_answers_and_not_another_s() -> None:
    for kind, trip in OWN.items():
        count = CHANNELS.get(trip, 0) * (2 if kind.name.startswith("VALVE") else 1)
        first = -1 if trip in (Trip.FORCE_SENSOR, Trip.SUPPLY_LOSS) else 0
        for channel in range(first, count):
            fault = _fault(kind, channel)
            own = channel // 2 if trip == Trip.VALVE and kind != FaultKind.CHAMBER_LEAK else channel
            if trip == Trip.FORCE_SENSOR and channel < 0:
                own = 2  # all six channels: any of them is its part
            assert trip_part(trip, own) in fault_parts(fault), (kind.name, channel)
            if channel >= 0 and trip in (Trip.LEG_SENSOR, Trip.VALVE):
                other = (own + 1) % (6 if trip == Trip.LEG_SENSOR else 12)
                assert trip_part(trip, other) not in fault_parts(fault), (kind.name, channel)


def test_a_leg_sensor_fault_is_answered_by_its_leg_s_chambers_too_and_an_axis_by_no_part() -> None:
    stuck = _fault(FaultKind.LEG_STUCK, 2)  # leg 3: chambers 5 and 6
    assert {trip_part(Trip.AIR_BALANCE, 4), trip_part(Trip.AIR_BALANCE, 5)} <= fault_parts(stuck)
    assert trip_part(Trip.AIR_BALANCE, 6) not in fault_parts(stuck)
    assert trip_part(Trip.FOLLOWING, 4) == ""  # pitch: an axis of the pose, not a part
    assert trip_part(Trip.FOLLOWING, 6 + 2) in fault_parts(stuck)  # joint mode: leg 3
    assert trip_part(Trip.RANGE_OF_MOTION, 4) == ""  # so is a range of motion's
    assert trip_part(Trip.STROKE_END, 2) in fault_parts(stuck)  # its leg at its stroke's end
    # The supply, whether its transducer or the legs' air found it.
    supply = fault_parts(_fault(FaultKind.SUPPLY_LOSS, -1))
    assert trip_part(Trip.SUPPLY_LOSS, 12) in supply
    assert trip_part(Trip.SUPPLY_LOSS, SUPPLY_BY_AIR) in supply
