"""Faults injected into the plant simulation at a given simulated time.

Plain Python on purpose (no numba): this is the vocabulary of the command line and the wire.
The compiled plant (``device.plant.model``) reads a fixed-size table of float rows built by
:func:`fault_row`; it imports only the integer kinds from here.

Channels are 0-based everywhere, the same numbers as the arrays of :mod:`device.signals`
and :mod:`device.plant.model`:

- pressure transducers 0..12: chamber ``2 i`` is the cap side of leg ``i``, ``2 i + 1`` its
  rod side; 12 is the supply transducer;
- legs 0..5 (leg length sensors);
- force/torque channels 0..5 = Fx Fy Fz Tx Ty Tz (sensor frame), or -1 for all six;
- valves 0..23: ``2 c`` is the intake and ``2 c + 1`` the exhaust of chamber ``c``;
- chambers 0..11 (for a leak).

The supply faults have no channel (-1).

Command-line form (:func:`parse_fault`)::

    KIND@TIME[+DURATION][:CHANNEL][=VALUE]

``TIME`` and ``DURATION`` in seconds of simulated (plant) time; the fault acts from TIME
for DURATION (default: for ever). Kind names are case-insensitive, ``-`` or ``_``.
Examples: ``supply_loss@0.5``, ``pressure_open@0.5:3``, ``leg_stuck@1.2:2``,
``ft_offset@1:2=15``, ``leg-noise@2+0.3:4=0.5``, ``chamber_leak@1:6=0.2``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

from device.signals import chamber

MAX_FAULTS = 16
"""Rows of the plant's fault table."""

FAULT_COLUMNS = 6
"""Columns of a table row: kind, t0, channel, value (SI), t_end, held reading (NaN)."""


class FaultKind(IntEnum):
    """What breaks. 0 is reserved for an empty row of the plant's table."""

    SUPPLY_LOSS = 1
    """Hose off at the regulator: the supply manifold vents to atmosphere through the line."""
    SUPPLY_DROOP = 2
    """The regulator's output droops to ``value`` bar gauge."""
    PRESSURE_OPEN = 3
    """A transducer's signal wire is open: it reads 0 Pa absolute (0 V)."""
    PRESSURE_SHORT = 4
    """A transducer's signal is shorted to its supply: it reads the ADC's top code."""
    PRESSURE_STUCK = 5
    """A transducer's reading freezes at its first sample from ``time`` on."""
    PRESSURE_OFFSET = 6
    """A transducer reads ``value`` bar too high (clipped to its range)."""
    LEG_STUCK = 7
    """A leg length sensor freezes at its first sample from ``time`` on."""
    LEG_OFFSET = 8
    """A leg length sensor reads ``value`` mm too long (clipped to the stroke)."""
    LEG_NOISE = 9
    """A leg length sensor gets ``value`` mm rms of extra noise (a burst: give a duration)."""
    FT_DEAD = 10
    """The force/torque sensor (or one channel) reads zero: power or cable lost."""
    FT_SATURATED = 11
    """The force/torque sensor (or one channel) reads its positive full scale."""
    FT_OFFSET = 12
    """A force/torque channel (or all) reads ``value`` N (forces) or N m (torques) too high."""
    VALVE_STUCK_OPEN = 13
    """A valve's armature sticks fully open, whatever its coil."""
    VALVE_STUCK_CLOSED = 14
    """A valve's armature sticks closed, whatever its coil."""
    CHAMBER_LEAK = 15
    """A leak from a chamber to atmosphere; ``value`` = its conductance / one valve's C."""


_CHANNEL_RANGE: dict[FaultKind, tuple[int, int, str]] = {}
"""Per kind: lowest and highest channel, and what the channel names."""
for _k in (FaultKind.SUPPLY_LOSS, FaultKind.SUPPLY_DROOP):
    _CHANNEL_RANGE[_k] = (-1, -1, "no channel")
for _k in (
    FaultKind.PRESSURE_OPEN,
    FaultKind.PRESSURE_SHORT,
    FaultKind.PRESSURE_STUCK,
    FaultKind.PRESSURE_OFFSET,
):
    _CHANNEL_RANGE[_k] = (0, 12, "pressure transducer 0..11 (chambers) or 12 (supply)")
for _k in (FaultKind.LEG_STUCK, FaultKind.LEG_OFFSET, FaultKind.LEG_NOISE):
    _CHANNEL_RANGE[_k] = (0, 5, "leg 0..5")
for _k in (FaultKind.FT_DEAD, FaultKind.FT_SATURATED, FaultKind.FT_OFFSET):
    _CHANNEL_RANGE[_k] = (-1, 5, "force/torque channel 0..5 (Fx Fy Fz Tx Ty Tz) or -1 (all)")
for _k in (FaultKind.VALVE_STUCK_OPEN, FaultKind.VALVE_STUCK_CLOSED):
    _CHANNEL_RANGE[_k] = (0, 23, "valve 0..23 (2c intake, 2c+1 exhaust of chamber c)")
_CHANNEL_RANGE[FaultKind.CHAMBER_LEAK] = (0, 11, "chamber 0..11")

_DEFAULT_CHANNEL: dict[FaultKind, int] = {
    FaultKind.SUPPLY_LOSS: -1,
    FaultKind.SUPPLY_DROOP: -1,
    FaultKind.FT_DEAD: -1,
    FaultKind.FT_SATURATED: -1,
    FaultKind.FT_OFFSET: -1,
}
"""Kinds whose channel may be left out; every other kind needs one."""

_DEFAULT_VALUE: dict[FaultKind, float] = {
    FaultKind.SUPPLY_DROOP: 3.5,  # bar gauge: a regulator set to 6 bar sagging by 2.5 bar
    FaultKind.CHAMBER_LEAK: 0.1,  # a cracked fitting: a tenth of a valve's conductance
}
"""Kinds whose value may be left out; the others that use a value need one."""

_UNIT: dict[FaultKind, str] = {
    FaultKind.SUPPLY_DROOP: "bar gauge",
    FaultKind.PRESSURE_OFFSET: "bar",
    FaultKind.LEG_OFFSET: "mm",
    FaultKind.LEG_NOISE: "mm rms",
    FaultKind.FT_OFFSET: "N or N m",
    FaultKind.CHAMBER_LEAK: "x valve C",
}
"""Kinds that take a value, and its unit."""

_TO_SI: dict[FaultKind, float] = {
    FaultKind.SUPPLY_DROOP: 1e5,
    FaultKind.PRESSURE_OFFSET: 1e5,
    FaultKind.LEG_OFFSET: 1e-3,
    FaultKind.LEG_NOISE: 1e-3,
}

_FT_NAMES = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")


def kind_names() -> str:
    """The kinds as the command line spells them, comma-separated."""
    return ", ".join(k.name.lower() for k in FaultKind)


@dataclass(frozen=True)
class Fault:
    """One fault: ``kind`` acts on ``channel`` from ``time`` for ``duration`` (s, plant time).

    ``value`` is in the unit of the kind: bar (SUPPLY_DROOP gauge, PRESSURE_OFFSET), mm
    (LEG_OFFSET, LEG_NOISE rms), N or N m (FT_OFFSET), a fraction of one valve's sonic
    conductance (CHAMBER_LEAK); other kinds ignore it and it must be 0.
    """

    kind: FaultKind
    time: float
    channel: int = -1
    value: float = 0.0
    duration: float = math.inf

    def __post_init__(self) -> None:
        if not isinstance(self.kind, FaultKind):
            raise ValueError(f"fault kind must be one of: {kind_names()}")
        name = self.kind.name.lower()
        if not (math.isfinite(self.time) and self.time >= 0.0):
            raise ValueError(f"{name}: time must be a finite number of seconds >= 0")
        if math.isnan(self.duration) or self.duration <= 0.0:
            raise ValueError(f"{name}: duration must be > 0 s (inf for ever)")
        lo, hi, what = _CHANNEL_RANGE[self.kind]
        if not (isinstance(self.channel, int) and lo <= self.channel <= hi):
            if lo == hi:  # a part of its own: the supply
                raise ValueError(f"{name} takes no channel, got channel {self.channel!r}")
            raise ValueError(f"{name}: channel {self.channel!r} is not a {what}")
        if not math.isfinite(self.value):
            raise ValueError(f"{name}: value must be a finite number")
        if self.kind not in _UNIT and self.value != 0.0:
            raise ValueError(f"{name} takes no value")
        if self.kind == FaultKind.SUPPLY_DROOP and not 0.0 <= self.value <= 9.0:
            raise ValueError("supply_droop: value is the drooped pressure, 0..9 bar gauge")
        if self.kind == FaultKind.LEG_NOISE and self.value <= 0.0:
            raise ValueError("leg_noise: value is the noise in mm rms and must be > 0")
        if self.kind == FaultKind.CHAMBER_LEAK and not 0.0 < self.value <= 10.0:
            raise ValueError("chamber_leak: value is the leak's conductance / a valve's, 0..10")

    @property
    def end(self) -> float:
        """Simulated time (s) at which the fault stops acting (inf: never)."""
        return self.time + self.duration


def fault_row(fault: Fault) -> tuple[float, float, float, float, float, float]:
    """The plant table's row for ``fault``: kind, t0, channel, value in SI, t_end, NaN.

    SI values: Pa (SUPPLY_DROOP as gauge, PRESSURE_OFFSET), m (LEG_OFFSET, LEG_NOISE rms),
    N or N m (FT_OFFSET), a fraction (CHAMBER_LEAK). The last column is where a stuck
    sensor keeps its frozen reading (NaN until it is captured).
    """
    value = fault.value * _TO_SI.get(fault.kind, 1.0)
    return (
        float(fault.kind),
        fault.time,
        float(fault.channel),
        value,
        fault.end,
        math.nan,
    )


def _number(text: str, what: str, spec: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"fault {spec!r}: {what} {text!r} is not a number") from None


def parse_kind(name: str) -> FaultKind:
    """A kind from its name, case-insensitive, ``-`` or ``_`` (``leg-stuck``, ``LEG_STUCK``)."""
    try:
        return FaultKind[name.strip().upper().replace("-", "_")]
    except KeyError:
        raise ValueError(f"unknown kind {name.strip()!r}; kinds: {kind_names()}") from None


def parse_fault(spec: str) -> Fault:
    """Parse ``KIND@TIME[+DURATION][:CHANNEL][=VALUE]`` (see the module's docstring)."""
    text = spec.strip()
    head, at, rest = text.partition("@")
    if not at:
        raise ValueError(
            f"fault {spec!r} needs the form KIND@TIME[+DURATION][:CHANNEL][=VALUE]; "
            f"kinds: {kind_names()}"
        )
    try:
        kind = parse_kind(head)
    except ValueError as exc:
        raise ValueError(f"fault {spec!r}: {exc}") from None
    rest, eq, value_text = rest.partition("=")
    rest, colon, channel_text = rest.partition(":")
    time_text, plus, duration_text = rest.partition("+")
    time = _number(time_text, "time", spec)
    duration = _number(duration_text, "duration", spec) if plus else math.inf
    if colon:
        try:
            channel = int(channel_text)
        except ValueError:
            raise ValueError(
                f"fault {spec!r}: channel {channel_text!r} is not a whole number"
            ) from None
    elif kind in _DEFAULT_CHANNEL:
        channel = _DEFAULT_CHANNEL[kind]
    else:
        raise ValueError(f"fault {spec!r}: {kind.name.lower()} needs a {_CHANNEL_RANGE[kind][2]}")
    if eq:
        value = _number(value_text, "value", spec)
    elif kind in _DEFAULT_VALUE:
        value = _DEFAULT_VALUE[kind]
    elif kind in _UNIT:
        raise ValueError(f"fault {spec!r}: {kind.name.lower()} needs =VALUE ({_UNIT[kind]})")
    else:
        value = 0.0
    try:
        return Fault(kind, time, channel, value, duration)
    except ValueError as e:
        raise ValueError(f"fault {spec!r}: {e}") from None


def format_fault(fault: Fault) -> str:
    """The command-line spec of ``fault``; :func:`parse_fault` reads it back unchanged."""
    out = f"{fault.kind.name.lower()}@{fault.time!r}"
    if math.isfinite(fault.duration):
        out += f"+{fault.duration!r}"
    if fault.channel != -1 or fault.kind not in _DEFAULT_CHANNEL:
        out += f":{fault.channel}"
    if fault.kind in _UNIT:
        out += f"={fault.value!r}"
    return out


def _channel_words(fault: Fault) -> str:
    """The part struck: its channel as ``--fault`` counts it (from 0), then the part as the
    device's events name it (from 1, :func:`device.signals.chamber`)."""
    k, ch = fault.kind, fault.channel
    lo, hi, _ = _CHANNEL_RANGE[k]
    if lo == hi == -1:
        return "the air supply"
    if k.name.startswith("PRESSURE"):
        if ch == 12:
            return "channel 12, the supply pressure transducer"
        return f"channel {ch}, the transducer of {chamber(ch)}"
    if k.name.startswith("LEG"):
        return f"channel {ch}, the length sensor of leg {ch + 1}"
    if k.name.startswith("FT"):
        return "every force/torque channel" if ch == -1 else f"force/torque channel {_FT_NAMES[ch]}"
    if k.name.startswith("VALVE"):
        role = "intake" if ch % 2 == 0 else "exhaust"
        return f"channel {ch}, the {role} of {chamber(ch // 2)}"
    return f"channel {ch}, {chamber(ch)}"


_WHAT: dict[FaultKind, str] = {
    FaultKind.SUPPLY_LOSS: "supply lost (hose off): vents to atmosphere",
    FaultKind.SUPPLY_DROOP: "regulator droops to {v:g} bar gauge",
    FaultKind.PRESSURE_OPEN: "open wire: reads 0 Pa absolute",
    FaultKind.PRESSURE_SHORT: "shorted: reads full scale",
    FaultKind.PRESSURE_STUCK: "stuck at its reading",
    FaultKind.PRESSURE_OFFSET: "offset by {v:+g} bar",
    FaultKind.LEG_STUCK: "stuck at its reading",
    FaultKind.LEG_OFFSET: "offset by {v:+g} mm",
    FaultKind.LEG_NOISE: "{v:g} mm rms of extra noise",
    FaultKind.FT_DEAD: "dead: reads zero",
    FaultKind.FT_SATURATED: "saturated: reads full scale",
    FaultKind.FT_OFFSET: "offset by {v:+g} {unit}",
    FaultKind.VALVE_STUCK_OPEN: "armature stuck open",
    FaultKind.VALVE_STUCK_CLOSED: "armature stuck closed",
    FaultKind.CHAMBER_LEAK: "leaks to atmosphere ({v:g} of a valve's conductance)",
}


def describe(fault: Fault) -> str:
    """One sentence for a human, e.g. ``at 0.5 s, pressure transducer 3 (...): open wire...``."""
    when = f"at {fault.time:g} s"
    if math.isfinite(fault.duration):
        when = f"from {fault.time:g} s for {fault.duration:g} s"
    # An offset on every channel at once is in N on the forces and N m on the torques.
    unit = {-1: "N or N m"}.get(fault.channel, "N" if fault.channel < 3 else "N m")
    what = _WHAT[fault.kind].format(v=fault.value, unit=unit)
    return f"{when}, {_channel_words(fault)}: {what}"
