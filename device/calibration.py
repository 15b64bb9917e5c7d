"""A unit's calibration: the zeros its start-up identification measured (device.identify).

Plain Python (no numba): the service, the protocol and the station read it. Saved as JSON,
loaded by the device (``ankle device --calibration FILE``), applied by the controller to
every reading (``ControllerConfig.calibration``) and reported in ``DeviceHello``.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from device import signals
from device.signals import chamber

FT_CHANNELS = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
"""The force/torque sensor's channels as its cable and amplifier label them."""
LEG_ZERO_MAX = 3.0e-3
"""A leg zero beyond this (m) is not an offset but a fault (a bent rod, a slipped sensor):
the identification refuses it rather than let the controller trust it."""
PRESSURE_ZERO_MAX = 0.3e5
"""A chamber transducer more than this (Pa) off the atmosphere while vented is faulty."""
VALVE_GAIN_RANGE = (0.5, 1.6)
"""A valve passing outside this share of the observer's model per pulse is not a build's
spread (conductance -20/+23 % and 10 % per valve, the fill's and the discharge's polytropic
index against the observer's 1.2: 0.83-1.17) but a blocked, leaking or miswired valve."""
DEAD_VOLUME_RANGE = (1.0e-6, 30.0e-6)
"""A chamber's volume beyond its piston (m3) outside this is not a build's tube (4-15 cm3
for 0.3-1 m of 4 mm tube with its port) but a kinked, blocked or wrongly fitted one."""
VALVE_EXTRA_MAX = 1.0e-3
"""A valve whose pulse passes more than this (s) beyond or short of its length is not a
build's spread of delays (closing less opening: -0.6 to +0.8 ms at the extremes)."""
PULSE_OPENS_MAX = 1.75e-3
"""A valve that some pulse of this length (s) still did not open is not a build's spread of
opening delays (0.47-1.21 ms, and 0.3 ms for three times the jitter) but a weak coil, a low
driver voltage or a sticking armature."""
MOVING_MASS_RANGE = (2.5, 7.0)
"""What the legs of an empty platform may move (kg; device.identify.moving_mass): the
builds' platforms (2.0-3.5 kg) with their pistons (1-1.7 kg along the legs) weigh 3.0-5.2
kg, and the sway weighs up to 1.1 kg more. Far outside, something is on the plate or
holding it, or a leg or its sensor is faulty, and the derivative gain it would set is not
one the loop was measured with."""
LEG_FRICTION_MAX = 15.0
"""A leg whose seals hold back more than this (N) moving slowly is not a build's spread
(glass/graphite pistons about 1 N, light elastomer seals up to 5 N, breakaway 2 times that)
but a bent rod, a misaligned joint or a seal run dry."""

LOAD_BIAS_MAX = 20.0
"""A leg whose chambers push more than this (N) beyond its share of the empty platform's
modelled load is not a build's spread (a plate a kilogram off its model is about 2 N a leg,
transducer spans 2 % off at the working pressures up to about 8 N) but a transducer far off
its span, something on the plate, or a leg that binds."""

STILL_READS_RANGE = (10, 400)
"""A transducer whose noise lets its reading stand still, healthy, for fewer reads than the
first is not one the type's noise (1 mbar rms, 1-3 counts) makes; one that would need more
than the second is too quiet to be judged by its flicker at all (stored as 0)."""


class IdentificationError(RuntimeError):
    """The unit could not be identified; the sentence says why and what to check."""


@dataclass(frozen=True)
class Calibration:
    """This unit's zeros, subtracted from its readings by the controller."""

    leg_zero: tuple[float, ...] = (0.0,) * 6
    """What each leg sensor reads at its lower end stop (m)."""
    pressure_zero: tuple[float, ...] = (0.0,) * 12
    """What each chamber transducer reads above the atmosphere when vented (Pa)."""
    ft_zero: tuple[float, ...] = (0.0,) * 6
    """What the force/torque sensor reads with nothing on the plate (N, N m)."""
    valve_gain: tuple[float, ...] = ()
    """Per valve (``2c`` intake, ``2c + 1`` exhaust of chamber ``c``): the air a pulse passes
    against the air observer's ISO 6358 model (device.supervision.valve_flow). Empty: not
    identified, and the observer forgives the whole type's range."""
    valve_extra: tuple[float, ...] = ()
    """Per valve: the time (s) of full flow a pulse passes beyond its length (closing
    delay less opening delay)."""
    pulse_shut: tuple[float, ...] = ()
    """Per valve: the longest test pulse (s) that never opened it. A coil released before
    its armature starts to move leaves the valve shut: a pulse shorter than the valve's
    opening delay passes nothing, one just longer passes its whole closing delay's worth.
    Empty: not identified (the observer reads every pulse by ``valve_extra``)."""
    pulse_opens: tuple[float, ...] = ()
    """Per valve: the shortest test pulse (s) from which on every one opened it. Between the
    two, the delay's jitter decides."""
    dead_volume: tuple[float, ...] = ()
    """Per chamber: its volume with the piston at that chamber's end, tube included (m3),
    from the same test pulses. Empty: the design's."""
    leg_friction: tuple[float, ...] = ()
    """Per leg: the force (N) its seals hold back at a slow, steady speed, from a slow heave
    of the empty platform up and down (device.identify.identify_friction). Empty: not
    identified, and the controller feeds no friction forward."""
    pressure_still_reads: tuple[int, ...] = ()
    """Per pressure channel (12 chambers, then the supply): how many reads in a row (1 kHz)
    its reading may stay bit for bit the same, healthy, from the noise it showed at rest at
    start-up (device.identify.pressure_still_reads); 0 where the transducer is too quiet for
    that to tell a frozen one. Empty: not identified, and nothing is judged so."""
    ft_still_reads: tuple[int, ...] = ()
    """Per force/torque channel (Fx, Fy, Fz, Tx, Ty, Tz), the same from the noise it showed
    with nobody on the plate: a channel that reads bit for bit the same for longer is dead
    or frozen on its own (the checks of the whole sensor want all six so). Empty: not
    identified, and no channel is judged so alone."""
    load_bias: tuple[float, ...] = ()
    """Per leg: what its chambers push (N) at mid-stroke beyond the force the controller
    figures holds the empty platform (device.identify.load_bias): the plate's true weight and
    centre of mass against the model's, and the transducers' spans. The force checks take it
    out of each leg's residual. Empty: not identified, and they take nothing out."""
    moving_mass: float = 0.0
    """The mass (kg) the legs move in a heave of the empty platform, pistons included
    (device.identify.moving_mass): the position loop's derivative gain grows with it
    (``ControllerConfig.moving_mass_reference``). 0: not identified, and the gain is the
    configured one."""
    identified_at: str = ""
    """When (ISO 8601, UTC); empty for the uncalibrated default."""
    notes: tuple[str, ...] = field(default=())

    def sensor_zero(self) -> NDArray[np.float64]:
        """Per channel of :mod:`device.signals`: what to subtract from each reading."""
        z = np.zeros(signals.N_SENSORS)
        z[signals.SENSOR_PRESSURE : signals.SENSOR_PRESSURE + 12] = self.pressure_zero
        z[signals.SENSOR_LEG : signals.SENSOR_LEG + 6] = self.leg_zero
        z[signals.SENSOR_FORCE : signals.SENSOR_FORCE + 6] = self.ft_zero
        return z

    @property
    def zeros_read(self) -> bool:
        """The sensors' zeros were read at start-up (device.identify dates them as it reads
        them): the controller subtracts them. Without, the force checks allow for what a
        transducer's zero may leave (``SupervisionConfig.pressure_zero_unidentified``)."""
        return bool(self.identified_at)

    @property
    def valves_identified(self) -> bool:
        """Every valve's pulse measured: its gain, extra time and where it starts to open. A
        file with only the first two (older) reads a pulse near a slow valve's opening delay
        as passing its line's worth, which it may not: the observer keeps the type's range."""
        return all(
            len(figures) == 24
            for figures in (self.valve_gain, self.valve_extra, self.pulse_shut, self.pulse_opens)
        )

    def valve_figures(self) -> NDArray[np.float64]:
        """For the controller's air checks (device.supervision, rows ``V_GAIN`` ...): each
        valve's gain, extra time (s), longest pulse that left it shut and shortest that
        opened it every time (s); 1, 0, 0 and 0 where not identified."""
        if not self.valves_identified:
            return np.vstack([np.ones(24), np.zeros((3, 24))])
        return np.array([self.valve_gain, self.valve_extra, self.pulse_shut, self.pulse_opens])

    def dead_volumes(self, design: float) -> NDArray[np.float64]:
        """Per chamber (m3), for the controller: the design's where not identified."""
        if len(self.dead_volume) == 12:
            return np.array(self.dead_volume)
        return np.full(12, design)

    def still_reads(self) -> NDArray[np.int64]:
        """Per pressure channel (13), then per force/torque channel (6), for the controller:
        0 where not judged by its flicker."""
        out = np.zeros(19, dtype=np.int64)
        if len(self.pressure_still_reads) == 13:
            out[:13] = self.pressure_still_reads
        if len(self.ft_still_reads) == 6:
            out[13:] = self.ft_still_reads
        return out

    def load_biases(self) -> NDArray[np.float64]:
        """Per leg (N), for the controller's force checks: 0 where not identified."""
        return np.array(self.load_bias) if len(self.load_bias) == 6 else np.zeros(6)

    def leg_frictions(self) -> NDArray[np.float64]:
        """Per leg (N), for the controller: 0 where not identified."""
        return np.array(self.leg_friction) if len(self.leg_friction) == 6 else np.zeros(6)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2)

    @classmethod
    def from_json(cls, text: str) -> Calibration:
        try:
            data = json.loads(text)
            cal = cls(
                leg_zero=_floats(data["leg_zero"], 6, "leg_zero"),
                pressure_zero=_floats(data["pressure_zero"], 12, "pressure_zero"),
                ft_zero=_floats(data["ft_zero"], 6, "ft_zero"),
                valve_gain=_floats(data.get("valve_gain", []), 24, "valve_gain", True),
                valve_extra=_floats(data.get("valve_extra", []), 24, "valve_extra", True),
                pulse_shut=_floats(data.get("pulse_shut", []), 24, "pulse_shut", True),
                pulse_opens=_floats(data.get("pulse_opens", []), 24, "pulse_opens", True),
                dead_volume=_floats(data.get("dead_volume", []), 12, "dead_volume", True),
                leg_friction=_floats(data.get("leg_friction", []), 6, "leg_friction", True),
                load_bias=_floats(data.get("load_bias", []), 6, "load_bias", True),
                pressure_still_reads=_ints(
                    data.get("pressure_still_reads", []), 13, "pressure_still_reads"
                ),
                ft_still_reads=_ints(data.get("ft_still_reads", []), 6, "ft_still_reads"),
                moving_mass=float(data.get("moving_mass", 0.0)),
                identified_at=str(data.get("identified_at", "")),
                notes=tuple(str(n) for n in data.get("notes", ())),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise IdentificationError(f"not a calibration file: {exc}") from None
        cal.check()
        return cal

    def save(self, path: Path) -> None:
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(self.to_json())
        tmp.replace(path)

    @classmethod
    def load(cls, path: Path) -> Calibration:
        try:
            text = path.read_text()
        except OSError as exc:
            raise IdentificationError(f"cannot read the calibration {path}: {exc}") from None
        return cls.from_json(text)

    def check(self) -> None:
        """Refuse zeros no healthy unit has (IdentificationError names the channel)."""
        for i, z in enumerate(self.leg_zero):
            if abs(z) > LEG_ZERO_MAX:
                raise IdentificationError(
                    f"leg {i + 1} sensor reads {z * 1e3:+.2f} mm at its end stop (more than "
                    f"{LEG_ZERO_MAX * 1e3:g} mm): check the sensor's mounting"
                )
        for c, z in enumerate(self.pressure_zero):
            if abs(z) > PRESSURE_ZERO_MAX:
                raise IdentificationError(
                    f"the transducer of {chamber(c)} reads {z / 1e5:+.2f} bar vented (more than "
                    f"{PRESSURE_ZERO_MAX / 1e5:g} bar): check the transducer and its valves"
                )
        self.check_valves()
        self.check_friction()
        self.check_mass()
        self.check_load_bias()
        self.check_still_reads()

    def check_still_reads(self) -> None:
        """Refuse still-read counts no healthy transducer's noise gives."""
        if len(self.pressure_still_reads) not in (0, 13):
            raise IdentificationError("pressure_still_reads needs 13 numbers, or none")
        low, high = STILL_READS_RANGE
        for c, n in enumerate(self.pressure_still_reads):
            if n != 0 and not low <= n <= high:
                name = "the supply transducer" if c == 12 else f"the transducer of {chamber(c)}"
                raise IdentificationError(
                    f"{name} may stand still {n} reads (healthy: 0 or {low}-{high}): "
                    "check the calibration file"
                )
        if len(self.ft_still_reads) not in (0, 6):
            raise IdentificationError("ft_still_reads needs 6 numbers, or none")
        for k, n in enumerate(self.ft_still_reads):
            if n != 0 and not low <= n <= high:
                raise IdentificationError(
                    f"force/torque channel {FT_CHANNELS[k]} may stand still {n} reads "
                    f"(healthy: 0 or {low}-{high}): check the calibration file"
                )

    def check_load_bias(self) -> None:
        """Refuse a load bias no healthy, empty unit has."""
        if len(self.load_bias) not in (0, 6):
            raise IdentificationError("load_bias needs 6 numbers, or none")
        for i, b in enumerate(self.load_bias):
            if not abs(b) <= LOAD_BIAS_MAX:
                raise IdentificationError(
                    f"leg {i + 1} pushes {b:+.1f} N beyond its share of the empty platform "
                    f"(healthy: within {LOAD_BIAS_MAX:g} N): check that nothing is on the "
                    "plate, the leg's pressure transducers and its joints"
                )

    def check_mass(self) -> None:
        """Refuse a moving mass no healthy, empty unit has (0: not identified)."""
        low, high = MOVING_MASS_RANGE
        if self.moving_mass != 0.0 and not low <= self.moving_mass <= high:
            raise IdentificationError(
                f"the legs move {self.moving_mass:.2f} kg heaving the empty platform (healthy: "
                f"{low:g}-{high:g} kg): check that nothing is on the plate or holding it, "
                "and the legs' sensors"
            )

    def check_friction(self) -> None:
        """Refuse leg frictions no healthy unit has."""
        if len(self.leg_friction) not in (0, 6):
            raise IdentificationError("leg_friction needs 6 numbers, or none")
        for i, f in enumerate(self.leg_friction):
            if not 0.0 <= f <= LEG_FRICTION_MAX:
                raise IdentificationError(
                    f"leg {i + 1} holds back {f:.1f} N moving slowly (healthy: 0-"
                    f"{LEG_FRICTION_MAX:g} N): check its rod, its joints and its seals"
                )

    def check_valves(self) -> None:
        """Refuse valve figures and dead volumes no healthy unit has."""
        if len(self.valve_gain) != len(self.valve_extra) or len(self.valve_gain) not in (0, 24):
            raise IdentificationError("valve_gain and valve_extra need 24 numbers each, or none")
        if len(self.pulse_shut) != len(self.pulse_opens) or len(self.pulse_shut) not in (0, 24):
            raise IdentificationError("pulse_shut and pulse_opens need 24 numbers each, or none")
        for v, (shut, opens) in enumerate(zip(self.pulse_shut, self.pulse_opens, strict=True)):
            if not 0.0 <= shut < opens <= PULSE_OPENS_MAX:
                which = "intake" if v % 2 == 0 else "exhaust"
                raise IdentificationError(
                    f"the {which} of {chamber(v // 2)} stayed shut up to a {shut * 1e3:.2f} ms "
                    f"pulse and opened on every one from {opens * 1e3:.2f} ms (healthy: opened "
                    f"by {PULSE_OPENS_MAX * 1e3:g} ms): check the valve, its coil and its driver"
                )
        low, high = DEAD_VOLUME_RANGE
        for c, vol in enumerate(self.dead_volume):
            if not low <= vol <= high:
                raise IdentificationError(
                    f"{chamber(c)} holds {vol * 1e6:.1f} cm3 beyond its piston (healthy: "
                    f"{low * 1e6:g}-{high * 1e6:g} cm3): check its tube for a leak or a kink"
                )
        low, high = VALVE_GAIN_RANGE
        for v, (g, e) in enumerate(zip(self.valve_gain, self.valve_extra, strict=True)):
            if not low <= g <= high or abs(e) > VALVE_EXTRA_MAX:
                which = "intake" if v % 2 == 0 else "exhaust"
                raise IdentificationError(
                    f"the {which} of {chamber(v // 2)} passes {g:.2f} times the model's air "
                    f"and {e * 1e3:+.2f} ms beyond its pulse (healthy: {low:g}-{high:g} and "
                    f"within {VALVE_EXTRA_MAX * 1e3:g} ms): check the valve and its tube"
                )


def _ints(values: object, n: int, name: str) -> tuple[int, ...]:
    """An optional list of ``n`` whole numbers (empty: none)."""
    if isinstance(values, list | tuple) and not values:
        return ()
    if not isinstance(values, list | tuple) or len(values) != n:
        raise ValueError(f"{name} needs {n} numbers")
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in values):
        raise ValueError(f"{name} must be whole numbers")
    return tuple(int(v) for v in values)


def _floats(values: object, n: int, name: str, optional: bool = False) -> tuple[float, ...]:
    if optional and isinstance(values, list | tuple) and not values:
        return ()
    if not isinstance(values, list | tuple) or len(values) != n:
        raise ValueError(f"{name} needs {n} numbers")
    out = tuple(float(v) for v in values)
    if not all(math.isfinite(v) for v in out):
        raise ValueError(f"{name} must be finite")
    return out
