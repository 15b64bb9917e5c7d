"""Every check of every command, in one place, against the limits the device publishes.

The device service answers each command ACK or NACK after :func:`check`; the rig (the
controller's Python face, used by experiments) calls the same functions. A command that
passes is turned into a *checked* value the mode machine and the rig apply without checking
again, so an acknowledged command can never be refused later, inside the running loop, for
its own targets. The limits are the published ones (``SafetyLimits.published``, the float32
values ``DeviceHello`` carries), so a host asking for exactly a published limit is accepted
and the controller enforces exactly what was accepted.

Plain Python and numpy: no compiled code, no I/O.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from device.axes import AXES, unit
from device.limits import LEG_HEADROOM, SafetyLimits, implausible_legs, to_float32
from device.protocol import messages as msg
from device.protocol.messages import DeviceMode, NackCode
from device.trips import Trip
from device.waveforms import SINE_HZ_MAX, AxisTarget, Waveform

SEGMENT_DURATION_MAX = 3600.0
"""Longest segment (s)."""
FORCE_LIMIT_MIN = 60.0
"""Least force limit a segment may set (N). A foot at rest puts the shank's weight on the
plate: a 5 s hold-only segment read up to 44.4 N on the force sensor with a relaxed or a
resisting foot (three seeds each; 1.8 N of sensor noise with no foot), so 1, 5 and 20 N
tripped WRENCH_LIMIT with nothing moving. 60 N is 1.35 times the most a foot at rest gave."""
TORQUE_LIMIT_MIN = 2.0
"""Least torque limit a segment may set (N m). The same holds read up to 0.8 N m about any
axis with a relaxed or a resisting foot (0.06 N m of noise with none): 0.1 N m tripped a
motionless segment. 2 N m is 2.5 times that (a moving exercise puts more on the plate, 3.2 N m
for a relaxed foot at 0.2 rad and 0.5 Hz in pitch, which its own limit is there to stop)."""
WATCHDOG_MS_MIN, WATCHDOG_MS_MAX = 100, 2000
"""The watchdogs the device accepts (published in HELLO). The least leaves a host room for
several heartbeats (the client sends four per watchdog, 25 ms apart at the least), and the
client counts any stall of more than half the watchdog (``device.client.stall_threshold``),
so every hold a host's own standing still causes shows in its stall count."""
COMPLIANT_AXES = (False, False, False, True, True, True)
"""The axes that may be compliant: the device renders impedance about the ankle's rotations
only. The translations' stable damping was never measured (no exercise renders them; the
prescriptions are rotations only): a compliant z at K 500 N/m, B 50 N s/m tripped LEG_SPEED
or FOLLOWING, and at K 0, B 1 FOLLOWING within 0.3 s. So none is offered."""
LEG_SPEED_SHARE = 0.64
"""Share of the leg speed limit a segment's targets may plan for a leg
(:func:`check_planned_leg_speed`); the rest is room for the sine's fade-in and tracking
error. Measured on the rig (relaxed, resisting and no foot, sines of one to six axes at 1-10
Hz, ramps end to end): the legs peaked at up to 1.52 times the planned bound, the most at 1
Hz, where a sine's raised-cosine fade-in makes its command up to 1.6 times its steady peak
speed. At 0.64 (0.256 m/s) the fastest of those scaled to the bound peaked at 0.388 m/s,
under the 0.40 m/s trip; the largest single-axis plan at the axis speed limit (pitch end to
end at 2 rad/s, 0.253 m/s; it peaks at 0.32 m/s) fits. Searched further (about 700 accepted
segments at the bound: grids of one to six axes, random and hill-climbed, the nominal unit
and drawn builds 15, 18, 19 and 50 with each foot): no trip, the fastest leg 0.970 of the
trip (build 19, no foot, roll and yaw in phase at 1 Hz). The margin is the fade-in's: any fade
from zero amplitude that is short against the period commands more than the sine's steady
speed, as the sine starts at its zero crossing; a sine started at a turning point (zero
speed, the approach taking the platform there) would leave room for a larger share."""


class CommandError(ValueError):
    """A command the device refuses; nothing was changed. The service answers it as a NACK
    with this code, the field at fault and the sentence."""

    def __init__(
        self,
        text: str,
        field: str = "",
        code: NackCode = NackCode.OUT_OF_RANGE,
        axis: int | None = None,
        amount: tuple[float, float] | None = None,
    ) -> None:
        super().__init__(text)
        self.code = code
        self.field = field
        self.axis = axis
        """The axis (index into ``AXES``) the refused value belongs to, where there is one:
        for a host that maps the refusal back onto its own field (not sent in the NACK)."""
        self.amount = amount
        """What the refused targets need and the bound it passes, where the sentence is
        about a quantity no field holds (a leg's length or speed, :func:`check_reachable`,
        :func:`check_planned_leg_speed`): for a host that says it in its own words."""


class Geometry(Protocol):
    """What the checks need of the platform's geometry: a :class:`device.geometry.Geometry`,
    or what a ``DeviceHello`` publishes of it (:class:`PublishedGeometry`)."""

    @property
    def stroke(self) -> float: ...
    @property
    def min_length(self) -> float: ...
    @property
    def home_pose(self) -> NDArray[np.float64]: ...
    @property
    def base_joints(self) -> NDArray[np.float64]: ...
    @property
    def platform_joints(self) -> NDArray[np.float64]: ...


@dataclass(frozen=True)
class CheckedSegment:
    """A ``StartSegment`` that passed every check: what the mode machine runs."""

    segment_id: int
    duration: float
    targets: tuple[AxisTarget, ...]
    """Six targets relative to home, in axis order."""
    stiffness: tuple[float, ...]
    damping: tuple[float, ...]
    compliant: tuple[bool, ...]
    rom_low: tuple[float, ...]
    rom_high: tuple[float, ...]
    force_limit: float
    torque_limit: float


@dataclass(frozen=True)
class CheckedImpedance:
    stiffness: tuple[float, ...]
    damping: tuple[float, ...]
    compliant: tuple[bool, ...]


@dataclass(frozen=True)
class Context:
    """What a command is checked against: the device's published limits and its state."""

    limits: SafetyLimits
    geometry: Geometry
    mode: DeviceMode
    trip: Trip = Trip.NONE
    telemetry_hz_max: int = 250
    compliant: tuple[bool, ...] | None = None
    """The loaded segment's compliant axes (for a live impedance change)."""
    legs: tuple[float, ...] | None = None
    """Measured piston displacements (m), for homing."""
    supply_low: bool = False
    """The air supply is below its low mark: motion commands wait until it recovers."""
    service: bool = False
    """The device needs service (a SERVICE event): nothing new moves until a re-arm."""


Checked = msg.Message | CheckedSegment | CheckedImpedance


def figures(value: float, *bounds: float, digits: int = 6) -> tuple[str, ...]:
    """``value`` (six significant digits at least, as ``:g``) and ``bounds`` (``digits`` at
    least) as text, with the fewest digits at which each printed bound lies on the same side
    of the printed value as the numbers do: a refusal never reads "stiffness 500 outside
    0..500" for 500.0001, nor "at least 0.24, got 0.24" for a bound of 0.244."""

    def side(a: float, b: float) -> int:
        return int(a > b) - int(a < b)

    value, bounds = float(value), tuple(float(b) for b in bounds)
    for d in range(digits, 18):
        texts = (f"{value:.{max(d, 6)}g}", *(f"{x:.{d}g}" for x in bounds))
        shown = float(texts[0])
        if all(
            side(float(t), shown) == side(b, value) for t, b in zip(texts[1:], bounds, strict=True)
        ):
            return texts
    return tuple(repr(float(x)) for x in (value, *bounds))


# -- the one entry point of the device service -------------------------------------------


def check(command: msg.Message, ctx: Context) -> Checked:
    """Check one host command; returns what to apply, or raises :class:`CommandError`."""
    bad = msg.non_finite_field(command)
    if bad is not None:
        raise CommandError(f"{bad} must be finite numbers", bad, NackCode.NOT_FINITE)
    if isinstance(command, msg.Heartbeat | msg.EStop | msg.ReplayEvents | msg.HoldCmd):
        return command
    if isinstance(command, msg.Configure):
        check_configure(command.telemetry_hz, command.watchdog_ms, ctx.telemetry_hz_max)
        return command
    if isinstance(command, msg.Rearm):
        if ctx.service and ctx.mode not in (DeviceMode.ESTOP, DeviceMode.FAULT):
            # Clearing a need for service: only while nothing moves.
            require_mode(ctx.mode, (DeviceMode.IDLE, DeviceMode.READY), "stop first")
        else:
            require_mode(ctx.mode, (DeviceMode.ESTOP, DeviceMode.FAULT), "nothing to re-arm")
        return command
    if isinstance(command, msg.Release):
        require_mode(
            ctx.mode,
            (
                DeviceMode.IDLE,
                DeviceMode.READY,
                DeviceMode.HOLD,
                DeviceMode.ESTOP,
                DeviceMode.FAULT,
            ),
            "hold first",
        )
        return command
    check_not_latched(ctx.mode, ctx.trip)
    if ctx.supply_low and isinstance(command, msg.ArmHome | msg.StartSegment | msg.Resume):
        raise CommandError(
            "the air supply is low: nothing moves until it is back (check the compressor)",
            code=NackCode.SUPPLY_LOW,
        )
    if ctx.service and isinstance(command, msg.ArmHome | msg.StartSegment | msg.Resume):
        raise CommandError(
            "the device needs service (see its SERVICE event): a technician re-arms it",
            code=NackCode.SERVICE_NEEDED,
        )
    if isinstance(command, msg.ArmHome):
        require_mode(ctx.mode, (DeviceMode.IDLE, DeviceMode.READY, DeviceMode.HOLD))
        if ctx.legs is not None:
            check_homing_start(ctx.legs, ctx.geometry, ctx.limits)
        return command
    if isinstance(command, msg.StartSegment):
        if ctx.mode == DeviceMode.IDLE:
            raise CommandError("home the platform first (ArmHome)", code=NackCode.NOT_HOMED)
        require_mode(ctx.mode, (DeviceMode.READY, DeviceMode.ACTIVE))
        return check_segment(command, ctx.limits, ctx.geometry)
    if isinstance(command, msg.SetImpedance):
        require_mode(ctx.mode, (DeviceMode.ACTIVE, DeviceMode.HOLD), "no segment is loaded")
        compliant = ctx.compliant if ctx.compliant is not None else COMPLIANT_AXES
        check_impedance(command.stiffness, command.damping, compliant, ctx.limits)
        return CheckedImpedance(command.stiffness, command.damping, compliant)
    if isinstance(command, msg.Resume):
        require_mode(ctx.mode, (DeviceMode.HOLD,))
        return command
    raise CommandError(f"{type(command).__name__} is not a command", code=NackCode.UNKNOWN_COMMAND)


# -- a host checking before it sends ---------------------------------------------------


@dataclass(frozen=True)
class PublishedGeometry:
    """The geometry a ``DeviceHello`` publishes."""

    stroke: float
    min_length: float
    home_pose: NDArray[np.float64]
    base_joints: NDArray[np.float64]
    platform_joints: NDArray[np.float64]


def published(hello: msg.DeviceHello) -> tuple[SafetyLimits, PublishedGeometry]:
    """The limits and the geometry a device publishes in its HELLO, for a host that checks a
    command with these same functions before it sends it. The stroke margin and the trip
    margins are not published: they are this software's own (the device's are the same)."""
    limits = dataclasses.replace(
        SafetyLimits().published(),
        rom_low=tuple(hello.rom_low),
        rom_high=tuple(hello.rom_high),
        force_limit=hello.force_limit,
        torque_limit=hello.torque_limit,
        leg_speed_limit=hello.leg_speed_limit,
        stiffness_max=tuple(hello.stiffness_max),
        damping_max=tuple(hello.damping_max),
        stiffness_slew=tuple(hello.stiffness_slew),
        damping_slew=tuple(hello.damping_slew),
        axis_speed_max=tuple(hello.axis_speed_max),
        envelope_stiffness=tuple(hello.envelope_stiffness),
        damping_min=tuple(hello.damping_min),
    )
    geometry = PublishedGeometry(
        stroke=hello.stroke,
        min_length=hello.min_length,
        home_pose=np.asarray(hello.home_pose, dtype=np.float64),
        base_joints=np.asarray(hello.base_joints, dtype=np.float64).reshape(6, 3),
        platform_joints=np.asarray(hello.platform_joints, dtype=np.float64).reshape(6, 3),
    )
    return limits, geometry


M = TypeVar("M", bound=msg.Message)


def as_received(command: M) -> M:
    """``command`` as the device decodes it: every number through its wire type (float32), so
    a host checks what the device will check (1e-300 N m arrives as 0)."""
    try:
        body = msg.pack(command)
    except (struct.error, OverflowError) as exc:
        raise CommandError(
            f"{type(command).__name__} does not fit its wire types: {exc}",
            code=NackCode.MALFORMED,
        ) from None
    received = msg.unpack(type(command), body)
    assert isinstance(received, type(command))
    return received


def check_segment_as_received(
    c: msg.StartSegment, limits: SafetyLimits, geometry: Geometry
) -> CheckedSegment:
    """:func:`check_segment` of ``c`` as the device will receive it: what a host runs before
    it sends (or stores) a segment, so the device's refusal is known in advance."""
    return check_segment(as_received(c), limits, geometry)


# -- modes ---------------------------------------------------------------------------------


def check_not_latched(mode: DeviceMode, trip: Trip) -> None:
    if mode in (DeviceMode.ESTOP, DeviceMode.FAULT):
        raise CommandError(f"{mode.name} ({trip.name}) is latched: re-arm", code=NackCode.LATCHED)


def require_mode(mode: DeviceMode, allowed: Sequence[DeviceMode], why: str = "") -> None:
    if mode not in allowed:
        names = " or ".join(m.name for m in allowed)
        text = f"not in {mode.name}: needs {names}"
        raise CommandError(f"{text} ({why})" if why else text, code=NackCode.WRONG_MODE)


# -- values --------------------------------------------------------------------------------


def check_configure(telemetry_hz: int, watchdog_ms: int, telemetry_hz_max: int) -> None:
    if not 1 <= telemetry_hz <= telemetry_hz_max:
        raise CommandError(
            f"telemetry_hz {telemetry_hz} outside 1..{telemetry_hz_max}", "telemetry_hz"
        )
    if not WATCHDOG_MS_MIN <= watchdog_ms <= WATCHDOG_MS_MAX:
        raise CommandError(
            f"watchdog_ms {watchdog_ms} outside {WATCHDOG_MS_MIN}..{WATCHDOG_MS_MAX}",
            "watchdog_ms",
        )


def _finite(name: str, values: Sequence[float] | NDArray[np.float64]) -> NDArray[np.float64]:
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != (6,):
        raise CommandError(f"{name} needs 6 values, got {arr.size}", name, NackCode.MALFORMED)
    if not np.all(np.isfinite(arr)):
        raise CommandError(f"{name} must be finite numbers", name, NackCode.NOT_FINITE)
    return arr


def check_impedance(
    stiffness: Sequence[float] | NDArray[np.float64],
    damping: Sequence[float] | NDArray[np.float64],
    compliant: Sequence[bool],
    limits: SafetyLimits,
) -> None:
    """K and B per axis within the device's maxima; only a rotation may be compliant
    (:data:`COMPLIANT_AXES`), and a compliant axis needs K or B, and B at least the least
    damping of its K's band."""
    K = _finite("stiffness", stiffness)
    B = _finite("damping", damping)
    for k, axis in enumerate(AXES):
        if compliant[k] and not COMPLIANT_AXES[k]:
            raise CommandError(
                f"{axis} cannot be compliant: the device renders impedance about the ankle's "
                "rotations only",
                "compliant",
                axis=k,
            )
        if not 0.0 <= K[k] <= limits.stiffness_max[k]:
            v, lo, hi = figures(K[k], 0.0, limits.stiffness_max[k])
            raise CommandError(
                f"{axis} stiffness {v} outside {lo}..{hi}",
                "stiffness",
                axis=k,
            )
        if not 0.0 <= B[k] <= limits.damping_max[k]:
            v, lo, hi = figures(B[k], 0.0, limits.damping_max[k])
            raise CommandError(
                f"{axis} damping {v} outside {lo}..{hi}",
                "damping",
                axis=k,
            )
        if compliant[k] and K[k] == 0.0 and B[k] == 0.0:
            raise CommandError(
                f"{axis} is compliant: stiffness and damping cannot both be zero",
                "stiffness",
                axis=k,
            )
        stiff = to_float32(K[k])  # the band and the damping as the wire carries them
        least = limits.damping_min_at(k, stiff)
        if compliant[k] and to_float32(B[k]) < least:
            v, low = figures(to_float32(B[k]), least)
            # K with the digits that put it on its side of the band edges (49.999996 is
            # below the 50 that needs less damping).
            at = figures(stiff, *limits.envelope_stiffness)[0]
            raise CommandError(
                f"{axis} damping {v} is below {low}, the least that renders stably at "
                f"stiffness {at}",
                "damping",
                axis=k,
            )


def check_axis_targets(
    targets: Sequence[AxisTarget],
    rom_low: Sequence[float],
    rom_high: Sequence[float],
    limits: SafetyLimits,
    where: str = "the range of motion",
) -> None:
    """Six waveforms: finite, inside ``rom_low..rom_high``, no faster than the device allows."""
    if len(targets) != 6:
        raise CommandError(f"targets need 6 axes, got {len(targets)}", "waveform")
    for k, (axis, t) in enumerate(zip(AXES, targets, strict=True)):
        values = (t.center, t.amplitude, t.frequency)
        if not all(math.isfinite(v) for v in values):
            raise CommandError(
                f"{axis} target must be finite numbers", "center", NackCode.NOT_FINITE, k
            )
        if t.kind == Waveform.SINE and not 0.0 <= t.frequency <= SINE_HZ_MAX:
            got, low, high = figures(t.frequency, 0.0, SINE_HZ_MAX)
            raise CommandError(
                f"{axis} frequency {got} outside {low}..{high} Hz",
                "frequency",
                axis=k,
            )
        lo, hi = t.extent()
        if lo < rom_low[k] or hi > rom_high[k]:
            lo_text, low = figures(lo, rom_low[k], digits=4)
            hi_text, high = figures(hi, rom_high[k], digits=4)
            raise CommandError(
                f"{axis} waveform spans {lo_text}..{hi_text}, outside {where} {low}..{high}",
                "center",
                axis=k,
            )
        speed = t.peak_speed()
        if speed > limits.axis_speed_max[k]:
            v, top = figures(speed, limits.axis_speed_max[k], digits=3)
            per = f"{unit(axis)}/s"
            raise CommandError(
                f"{axis} waveform peaks at {v} {per}, above {top} {per}",
                "frequency" if t.kind == Waveform.SINE else "ramp_rate",
                axis=k,
            )


def sample_poses(targets: Sequence[AxisTarget]) -> NDArray[np.float64]:
    """(n, 6) poses relative to home that stand for every pose the targets can combine (and
    home, where each segment starts from): the corners and edge midpoints of the box of the
    targets' extents."""
    axes = []
    for t in targets:
        lo, hi = t.extent()
        lo, hi = min(lo, 0.0), max(hi, 0.0)
        axes.append(sorted({lo, 0.5 * (lo + hi), hi}))
    return np.array(list(itertools.product(*axes)), dtype=np.float64)


def check_reachable(
    targets: Sequence[AxisTarget], geometry: Geometry, limits: SafetyLimits
) -> None:
    """Every pose the targets can combine keeps every piston ``LEG_HEADROOM`` inside its
    stroke-end band (checked at :func:`sample_poses`).

    Single axes fit in the stroke over their whole range, but extremes of several axes at
    once may not (full roll and full pitch together need about 109 mm of a 100 mm stroke):
    such a target is refused here rather than tripping STROKE_END when it is reached.
    """
    x = piston_displacements(sample_poses(targets) + geometry.home_pose, geometry) * 1e3
    lo, hi = (v * 1e3 for v in usable_stroke(geometry, limits))
    worst_low, worst_high = x.min(axis=0), x.max(axis=0)
    for leg in range(6):
        if worst_low[leg] < lo or worst_high[leg] > hi:
            # Each end with the digits that put it on its side of its bound: never "50.0..
            # 95.0 mm, beyond 5..95 mm" for 95.00001.
            low_text, low = figures(worst_low[leg], lo, digits=3)
            high_text, high = figures(worst_high[leg], hi, digits=3)
            past = (worst_low[leg], lo) if worst_low[leg] < lo else (worst_high[leg], hi)
            raise CommandError(
                f"these targets together need leg {leg + 1} at {low_text}..{high_text} mm, "
                f"beyond its usable {low}..{high} mm",
                "center",
                amount=(float(past[0]), float(past[1])),
            )


def planned_leg_speeds(targets: Sequence[AxisTarget], geometry: Geometry) -> NDArray[np.float64]:
    """A bound on each leg's speed (m/s) the targets plan: the most, over
    :func:`sample_poses`, of the sum over the axes of ``|d x_leg / d q_k|`` times the axis's
    peak speed. Each axis at its own peak and every sign against the leg: a sine's phase
    cannot make the legs faster than that."""
    peaks = np.array([t.peak_speed() for t in targets], dtype=np.float64)
    poses = sample_poses(targets) + geometry.home_pose
    moving = np.flatnonzero(peaks)
    bound = np.zeros(6)
    if moving.size == 0:
        return bound
    step = 1e-6  # central differences of the inverse kinematics (m, rad)
    for k in moving:
        d = np.zeros(6)
        d[k] = step
        ahead = piston_displacements(poses + d, geometry)
        behind = piston_displacements(poses - d, geometry)
        bound = bound + np.abs(ahead - behind) / (2.0 * step) * peaks[k]
    result: NDArray[np.float64] = bound.max(axis=0)
    return result


def check_planned_leg_speed(
    targets: Sequence[AxisTarget], geometry: Geometry, limits: SafetyLimits
) -> None:
    """No leg plans faster than :data:`LEG_SPEED_SHARE` of the leg speed limit.

    Each axis alone within its speed limit is not enough: roll, pitch and yaw sines at 2 Hz,
    each just within its 2 rad/s, plan 0.43 m/s for leg 6 together and trip LEG_SPEED.
    """
    planned = planned_leg_speeds(targets, geometry)
    bound = LEG_SPEED_SHARE * limits.leg_speed_limit
    leg = int(np.argmax(planned))
    if planned[leg] > bound:
        v, top = figures(float(planned[leg]), bound, digits=3)
        raise CommandError(
            f"these targets together move leg {leg + 1} at up to {v} m/s, above the {top} m/s "
            "they may plan",
            "waveform",
            amount=(float(planned[leg]), float(bound)),
        )


def check_targets(
    targets: Sequence[AxisTarget],
    rom_low: Sequence[float],
    rom_high: Sequence[float],
    limits: SafetyLimits,
    geometry: Geometry,
    where: str = "the range of motion",
) -> None:
    """Every check of six axis targets, in one place for a segment and for the rig: each
    axis within ``rom_low..rom_high`` and its speed (:func:`check_axis_targets`), the legs'
    stroke for every pose they combine (:func:`check_reachable`) and the legs' combined
    speed (:func:`check_planned_leg_speed`)."""
    check_axis_targets(targets, rom_low, rom_high, limits, where)
    check_reachable(targets, geometry, limits)
    check_planned_leg_speed(targets, geometry, limits)


def usable_stroke(geometry: Geometry, limits: SafetyLimits) -> tuple[float, float]:
    """Where a target may put a piston (m): ``LEG_HEADROOM`` inside the stroke-end trip
    band at either end, so a step's overshoot or a sine's tracking error never trips it."""
    lo = limits.stroke_margin + LEG_HEADROOM
    return lo, geometry.stroke - lo


def check_leg_targets(
    displacement: Sequence[float] | NDArray[np.float64],
    geometry: Geometry,
    limits: SafetyLimits,
    what: str = "leg displacement",
) -> NDArray[np.float64]:
    """Six piston displacements (m) strictly inside the stroke-end trip band."""
    x = _finite("leg displacement", displacement)
    m = limits.stroke_margin
    bad = [i for i in range(6) if not m < x[i] < geometry.stroke - m]
    if bad:
        raise CommandError(
            f"{what}: leg(s) {', '.join(str(i + 1) for i in bad)} outside "
            f"{m * 1e3:.0f}..{(geometry.stroke - m) * 1e3:.0f} mm",
            "legs",
        )
    return x


def check_homing_start(
    legs: Sequence[float] | NDArray[np.float64], geometry: Geometry, limits: SafetyLimits
) -> None:
    """Homing starts from any leg reading a piston can give (:func:`implausible_legs`):
    from the end stops too, where a release, the start-up identification and every power-off
    leave the platform, inside the stroke-end trip band."""
    bad = implausible_legs(legs, geometry.stroke, limits)
    if bad:
        m = limits.stroke_margin
        readings = ", ".join(f"{i + 1} at {legs[i] * 1e3:.2f} mm" for i in bad)
        raise CommandError(
            f"homing cannot start from these leg readings: leg {readings}, beyond "
            f"{-m * 1e3:.0f}..{(geometry.stroke + m) * 1e3:.0f} mm (check the leg sensors)",
            "legs",
        )


def check_segment(c: msg.StartSegment, limits: SafetyLimits, geometry: Geometry) -> CheckedSegment:
    """Every field of a segment against the device's published limits."""
    if c.segment_id == 0:
        raise CommandError("segment_id 0 means none; use 1 or more", "segment_id")
    if not 0.0 < c.duration <= SEGMENT_DURATION_MAX:
        got, low, high = figures(c.duration, 0.0, SEGMENT_DURATION_MAX)
        raise CommandError(f"duration {got} s outside ({low}, {high}]", "duration")
    for name, value, least, top, per in (
        ("force_limit", c.force_limit, FORCE_LIMIT_MIN, limits.force_limit, "N"),
        ("torque_limit", c.torque_limit, TORQUE_LIMIT_MIN, limits.torque_limit, "N m"),
    ):
        if value < least:
            got, low = figures(value, least)
            raise CommandError(
                f"{name} {got} {per} is below {low} {per}: a foot at rest would trip it", name
            )
        if value > top:
            got, low, high = figures(value, least, top)
            raise CommandError(f"{name} {got} {per} outside [{low}, {high}]", name)
    for k, axis in enumerate(AXES):
        lo, hi = c.rom_low[k], c.rom_high[k]
        if not limits.rom_low[k] <= lo <= hi <= limits.rom_high[k]:
            lo_text, low = figures(lo, limits.rom_low[k], digits=4)
            hi_text, high = figures(hi, limits.rom_high[k], digits=4)
            text = f"{axis} range {lo_text}..{hi_text} is not within the device's {low}..{high}"
            # The field that is wrong: the end outside the device's range, or, with both
            # inside, the low end above the high one.
            if lo < limits.rom_low[k] or lo > limits.rom_high[k]:
                field = "rom_low"
            elif hi < limits.rom_low[k] or hi > limits.rom_high[k]:
                field = "rom_high"
            else:
                field = "rom_low"
                lo_text, hi_text = figures(lo, hi)
                text = f"{axis} range low end {lo_text} is above its high end {hi_text}"
            raise CommandError(text, field, axis=k)
    targets = tuple(segment_targets(c))
    check_targets(targets, c.rom_low, c.rom_high, limits, geometry, "the segment's range")
    check_impedance(c.stiffness, c.damping, c.compliant, limits)
    return CheckedSegment(
        segment_id=c.segment_id,
        duration=c.duration,
        targets=targets,
        stiffness=tuple(float(v) for v in c.stiffness),
        damping=tuple(float(v) for v in c.damping),
        compliant=tuple(bool(v) for v in c.compliant),
        rom_low=tuple(float(v) for v in c.rom_low),
        rom_high=tuple(float(v) for v in c.rom_high),
        force_limit=float(c.force_limit),
        torque_limit=float(c.torque_limit),
    )


def segment_targets(c: msg.StartSegment) -> list[AxisTarget]:
    """The six waveforms a segment message describes."""
    out = []
    for k in range(6):
        kind = Waveform(c.waveform[k])
        if kind == Waveform.SINE:
            out.append(AxisTarget(kind, c.center[k], c.amplitude[k], c.frequency[k]))
        elif kind == Waveform.RAMP:
            out.append(AxisTarget.ramp(c.center[k], c.ramp_end[k], c.ramp_rate[k]))
        else:
            out.append(AxisTarget(Waveform.HOLD, c.center[k]))
    return out


# -- kinematics for the checks (numpy; the controller has its own compiled copy) ---------


def piston_displacements(poses: NDArray[np.float64], geometry: Geometry) -> NDArray[np.float64]:
    """(n, 6) piston displacements (m) of (n, 6) absolute poses by inverse kinematics."""
    poses = np.atleast_2d(poses)
    roll, pitch, yaw = poses[:, 3], poses[:, 4], poses[:, 5]
    cr, sr, cp, sp, cy, sy = (
        np.cos(roll),
        np.sin(roll),
        np.cos(pitch),
        np.sin(pitch),
        np.cos(yaw),
        np.sin(yaw),
    )
    R = np.empty((poses.shape[0], 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 0, 2] = cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr
    R[:, 1, 0], R[:, 1, 1], R[:, 1, 2] = sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr
    R[:, 2, 0], R[:, 2, 1], R[:, 2, 2] = -sp, cp * sr, cp * cr
    joints = np.einsum("nij,lj->nli", R, geometry.platform_joints) + poses[:, None, :3]
    lengths = np.linalg.norm(joints - geometry.base_joints[None, :, :], axis=2)
    result: NDArray[np.float64] = lengths - geometry.min_length
    return result
