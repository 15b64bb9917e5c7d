"""Layout of the sensor and valve vectors exchanged with the hardware.

One flat float64 vector of sensor readings and one uint8 vector of valve coils: the same for
the plant simulation and an I/O board, so the controller never knows which it talks to.
"""

N_CHAMBERS = 12
N_VALVES = 24

SENSOR_PRESSURE = 0
"""12 chamber pressures (Pa abs): chamber 2i is leg i's cap side, 2i+1 its rod side."""
SENSOR_SUPPLY = 12
"""Supply pressure (Pa abs)."""
SENSOR_LEG = 13
"""6 piston displacements (m, 0..stroke)."""
SENSOR_FORCE = 19
"""Force on the foot plate (N), sensor frame."""
SENSOR_TORQUE = 22
"""Torque on the foot plate about the sensor origin (N m), sensor frame."""
N_SENSORS = 25


def chamber(c: int) -> str:
    """Chamber ``c`` (0-11; 12: the supply) as a technician finds it on the unit, counted
    from 1 as the legs are: ``chamber 1 (leg 1, cap side)``. Every sentence that names a
    chamber (trip events, calibration checks, the simulator's faults) says it so."""
    if c == N_CHAMBERS:
        return "supply transducer"
    side = "cap" if c % 2 == 0 else "rod"
    return f"chamber {c + 1} (leg {c // 2 + 1}, {side} side)"
