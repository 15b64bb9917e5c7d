"""Experiments a researcher runs on the simulated device, all in simulated time.

Each function builds a fresh :class:`~device.rig.Rig` on the plant simulation, runs one
experiment of the paper (Figures 7, 9, 10, 12) and returns its numbers together with the
traces, so the CLI, the benchmark, the plots and the tests share one implementation.

Every result says whether its numbers can be trusted (:class:`Health`): whether the device
tripped (its trip code), and which limits it ran into:

- ``range_of_motion``: in a task-space experiment the commanded pose was clamped at the
  device's range of motion (``pose_cmd`` equal to a bound of ``rig.limits``; the controller
  clamps to exactly that value), or the device tripped on RANGE_OF_MOTION. The platform then
  did not follow the experiment's own reference: this invalidates sine, sweep and impedance
  numbers.
- ``valve_duty``: a chamber's valve was driven at the largest duty the controller can
  command (its pressure loop's output at +-100 %: ``slots`` at +-28, the whole 4 ms PWM
  period, without dead-band compensation; +-21 with it, whose largest duty is
  ``100 - d_dead`` = 75 %) for at least :data:`VALVE_SATURATION_S` without a break. The response was
  then limited by the valves' flow, not by the loop. This is the device's real large-signal
  behaviour (a 10 mm step's rise is flow-limited by design), so it is reported but does not
  by itself invalidate a number.
- ``leg_speed``: the leg speed limit tripped (a LEG_SPEED trip).

A tripped experiment is always invalid: its valves closed mid-run and what follows is the
held platform, not a response.

Requests that cannot measure anything (below what the sensors resolve, zero, outside the
device's limits) are refused with :class:`~device.rig.CommandError` before any simulation.
"""

from __future__ import annotations

import contextlib
import math
import weakref
from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from device import pwm, ring, trips
from device.calibration import Calibration
from device.commands import figures
from device.controller import ControllerConfig, Mode, Waveform
from device.geometry import AXES, AXIS_INDEX, DEFAULT_GEOMETRY
from device.hardware import SimulatedHardware
from device.identify import identify_simulated
from device.limits import LEG_HEADROOM
from device.plant.faults import Fault, FaultKind, describe, format_fault
from device.plant.model import SCRIPT_RAMP, SCRIPT_SINE
from device.plant.params import TICK_HZ, PlantConfig, build_params, draw_plant
from device.rig import AxisTarget, CommandError, Rig, leg_index
from device.safety import SafetyLimits, Trip
from device.tickloop import COL
from device.waveforms import SINE_HZ_MAX
from lab.metrics import (
    SETTLE_BAND_M,
    SETTLE_HOLD_S,
    StepMetrics,
    impedance_fit,
    impedance_fit_inertia,
    sine_response,
    step_metrics,
    stiffness_slope,
)

SETTLE_S = 0.5
"""Time the platform is held at home under control before an experiment starts."""

VALVE_SATURATION_S = 0.012
"""A valve held at the controller's largest duty this long without a break (three 4 ms PWM
periods) counts as saturated: longer than any step transient needs (the largest step a leg
can take, 45 mm, holds its valves there for 8 ms), so the loop was not in control of the
flow."""
ROM_TOLERANCE = 1e-9
"""How close (m or rad) the commanded pose must be to a range-of-motion bound to count as
clamped there; the controller clamps to the bound exactly."""

LEG_SENSOR_M = DEFAULT_GEOMETRY.stroke / 2.0**12
"""One count of the 12-bit leg position sensor: 0.024 mm (device/plant/params.py)."""
STEP_DURATION_MAX_S = 60.0
"""Longest step record (s)."""
MIN_STEP_COUNTS = 10
"""A step's 10 % point must be at least one sensor count for a 10-90 % rise time."""
MIN_SINE_COUNTS = 10
"""A sine must move its most-moved leg at least this many counts, so the +-0.5 count
quantisation is under 5 % of the amplitude (0.4 dB)."""
MIN_STAIR_COUNTS = 1
"""A staircase step smaller than one count cannot be told from the previous level."""
STAIR_STEPS = 8
"""Steps up (and back down) of the staircase."""
TORQUE_MIN_NM = 0.1
"""Smallest patient torque: 75 counts of the torque sensor, 30 times its noise."""
TORQUE_MAX_NM = 40.0
"""Largest patient torque: below the 60 N m wrench trip of the force plate."""
RING_MARGIN = 0.8
"""The patient's torque stays this share of the ring guard's lowest frequency below it."""
_LIMITS = SafetyLimits().published()
"""The device's limits exactly as it publishes them (float32, ``DeviceHello``): every check
here compares against these, as the device's own does, so a request this lab accepts the
device accepts too."""
IMPEDANCE_HZ_RANGE = (0.1, RING_MARGIN * ControllerConfig().ring_band[0])
"""Frequencies of the patient's sinusoidal torque (0.1-4 Hz): below 0.1 Hz a few cycles
would take minutes. The top stays a fifth below the ring guard's band
(``ControllerConfig.ring_band``, from 5 Hz; device.ring): a torque sine moves the admittance
law at its own frequency, and at the band's edge the guard took it for a ring (pitch at
K = 50, B = 1 against 5 Hz: "rang at 5 Hz and raised its damping 1.50 times", on a healthy
unit, every time), since it counts half-cycles in whole control periods and the loop's noise
shortens some. Voluntary ankle torque is below 4 Hz."""
INERTIA_SHARE_MAX = 0.05
"""At one frequency alone the fit cannot tell the device's virtual inertia from a lower
stiffness (it measures ``K - J w^2``): the inertia's term may be at most this share of K,
the 5 % the stiffness target allows."""


@dataclass(frozen=True)
class Health:
    """Whether a run's numbers can be trusted, and why not."""

    tripped: bool
    trip: str | None
    """Name of the trip code (``LEG_SPEED``, ...), None if the device did not trip."""
    trip_time_s: float | None
    """When it tripped, seconds from the start of the measured window (None if before it or
    not tripped)."""
    saturated: tuple[str, ...]
    """Which of ``range_of_motion``, ``valve_duty``, ``leg_speed`` occurred."""
    valid: bool
    reason: str | None
    """Why the measurement is invalid, in words (None when valid)."""
    warning: str | None = None
    """What the device warned of without tripping, in words: it asked for service (a
    chamber's air did not add up with its valves) or held on a low supply. The loop ran on,
    but on a device that is not the one the experiment means to measure (an injected fault,
    or a false alarm): invalid as a trip is."""
    part: str | None = None
    """The part the trip names, in a technician's words ("supply transducer", "force along
    z"; device.trips.where), None if it names none or the device did not trip."""
    faults: tuple[FaultOutcome, ...] = ()
    """What became of each fault injected into the run (``--fault``): struck or not, and
    what the device did about it."""

    def words(self) -> str:
        """What happened, for a person: empty when nothing did."""
        parts = []
        if self.warning:
            parts.append(self.warning)
        if self.tripped:
            at = (
                f" {self.trip_time_s:.3f} s into the measurement"
                if self.trip_time_s is not None
                else " before the measurement started"
            )
            named = f" ({self.part})" if self.part else ""
            parts.append(f"tripped {self.trip}{named}{at}")
        notes = {
            "range_of_motion": "range of motion reached",
            "valve_duty": f"valves at largest duty for >= {VALVE_SATURATION_S * 1e3:.0f} ms",
            "leg_speed": "leg speed limit",
        }
        sat = [notes[k] for k in self.saturated if k in notes]
        if sat:
            parts.append("saturated: " + ", ".join(sat))
        if not parts and self.reason:
            parts.append(self.reason)  # invalid for a reason of the experiment's own
        return "; ".join(parts)


@dataclass(frozen=True)
class FaultOutcome:
    """One injected fault and what the device did about it (:func:`fault_outcomes`)."""

    fault: Fault
    struck: bool
    """Its time came before the run ended."""
    noticed: str | None
    """What the device did once it struck, in words ("tripped LEG_SENSOR (leg 3)", "asked
    for service: ..."); None if nothing, or only before it struck."""
    noticed_ms: float | None
    """How long after it struck the device tripped (ms); None when not known (a warning, or
    a trip the run's log does not cover) or when nothing was noticed."""
    before: bool = False
    """The device had tripped before the fault struck: nothing after it can be told."""
    run_end_s: float = 0.0
    """When the run ended (s of simulated time, the settle at home included)."""
    names_it: bool | None = None
    """The device's trip after it struck names a part this fault acts on (its sensor, its
    chamber, its leg: :func:`fault_parts`); None when the trip names no part, or nothing
    tripped after it struck. With several faults, which one the device answered."""
    others: bool = False
    """Another fault struck before the trip as well: the words then say whose part the trip
    names."""
    warned_ms: float | None = None
    """The device's warning (:func:`device_warning`) was first seen this long after the fault
    struck (ms, within :data:`WARNING_WATCH_S` of when it was raised); None when the warning
    is not credited to this fault, or its time is not known."""
    warning_names_it: bool | None = None
    """The warning credited to this fault names a part this fault acts on (the chamber whose
    air did not add up, or the supply); None when it names none (a ring names an axis) or
    no warning is credited to it."""
    warned_before: bool = False
    """The device had already warned before this fault struck: the warning is another's."""
    warning_credited: bool = False
    """``noticed`` begins with the device's warning: it was raised after this fault struck."""

    def words(self) -> str:
        """One line for a person: the fault in the device's own numbering, then its fate."""
        said = describe(self.fault)
        if not self.struck:
            return f"{said}: never struck (the run ended at {self.run_end_s:.2f} s)"
        if self.before:
            return f"{said}: struck after the device had already tripped"
        struck = "struck after the device had already warned" if self.warned_before else "struck"
        if self.noticed is None:
            more = " more" if self.warned_before else ""
            return f"{said}: {struck}; the device noticed nothing{more}"

        def whose(names: bool | None) -> str:
            if not self.others or names is None:
                return ""
            return ", which names this fault's part" if names else ", naming another part"

        # ``noticed`` is the warning credited to it (if any), then the trip (if any).
        parts = self.noticed.split("; then ")
        warned = parts.pop(0) if self.warning_credited else None
        text = []
        if warned is not None:
            ms = self.warned_ms
            by = f" (by {ms:.0f} ms after it struck)" if ms is not None else ""
            text.append(f"{warned}{by}{whose(self.warning_names_it)}")
        if parts:
            ms = self.noticed_ms
            after = f" ({ms:.0f} ms after it struck)" if ms is not None else ""
            text.append(f"{parts[0]}{after}{whose(self.names_it)}")
        return f"{said}: {struck}; the device then " + "; then ".join(text)

    def as_json(self) -> dict[str, object]:
        return {
            "fault": format_fault(self.fault),
            "words": describe(self.fault),
            "struck": self.struck,
            "noticed": self.noticed,
            "noticed_ms": self.noticed_ms,
            "after_trip": self.before,
            "names_its_part": self.names_it,
            "warned_ms": self.warned_ms,
            "warning_names_its_part": self.warning_names_it,
            "after_warning": self.warned_before,
        }


_PRESSURE_KINDS = (
    FaultKind.PRESSURE_OPEN,
    FaultKind.PRESSURE_SHORT,
    FaultKind.PRESSURE_STUCK,
    FaultKind.PRESSURE_OFFSET,
)
_LEG_KINDS = (FaultKind.LEG_STUCK, FaultKind.LEG_OFFSET, FaultKind.LEG_NOISE)
_FT_KINDS = (FaultKind.FT_DEAD, FaultKind.FT_SATURATED, FaultKind.FT_OFFSET)
_SUPPLY = "the supply"


def fault_parts(fault: Fault) -> frozenset[str]:
    """The parts a trip may name for ``fault``, in the words of :func:`device.trips.where`:
    its own sensor, chamber or force/torque channel, and the leg (or chambers) a fault of a
    leg's sensor, valves or air shows in."""
    k, ch = fault.kind, fault.channel
    chamber, leg = Trip.VALVE, Trip.LEG_SENSOR
    if k in (FaultKind.SUPPLY_LOSS, FaultKind.SUPPLY_DROOP):
        return frozenset({_SUPPLY})
    if k in _PRESSURE_KINDS and ch == 12:
        return frozenset({trips.where(Trip.PRESSURE_SENSOR, 12), _SUPPLY})
    if k in _FT_KINDS:
        channels = range(6) if ch < 0 else (ch,)
        return frozenset(trips.where(Trip.FORCE_SENSOR, c) for c in channels)
    if k in _LEG_KINDS:
        sides = (trips.where(chamber, 2 * ch + side) for side in (0, 1))
        return frozenset({trips.where(leg, ch), *sides})
    c = ch // 2 if k in (FaultKind.VALVE_STUCK_OPEN, FaultKind.VALVE_STUCK_CLOSED) else ch
    return frozenset({trips.where(chamber, c), trips.where(leg, c // 2)})


def trip_part(trip: Trip, channel: int) -> str:
    """The part a trip names, as :func:`fault_parts` says it ('' for none, and for an axis:
    a FOLLOWING or RANGE_OF_MOTION trip of the platform's pose names no part)."""
    if trip in (Trip.SUPPLY_LOSS, Trip.SUPPLY_HIGH):
        return _SUPPLY
    if trip in (Trip.FOLLOWING, Trip.RANGE_OF_MOTION) and channel < len(AXES):
        return ""
    return trips.where(trip, channel)


def fault_outcomes(rig: Rig) -> tuple[FaultOutcome, ...]:
    """What became of each injected fault (:func:`injected`) in ``rig``'s run: whether it
    struck, and what the device then did: its warning, credited to a fault only if the fault
    struck before the device raised it (:func:`run` times it), then its trip, timed from
    the fault where the run's log shows when it tripped (:attr:`Rig.tripped_at`). Each says
    whether the part it names is the fault's."""
    trip, end, trip_at_s = rig.trip, rig.time, rig.tripped_at
    warning = device_warning(rig)
    warned = _WARNED.get(rig)
    warned_part = warning_part(rig) if warning is not None else ""
    tripped = ""
    if trip != Trip.NONE:
        named = trips.where(trip, rig.trip_channel)
        tripped = f"tripped {trip.name}" + (f" ({named})" if named else "")
    part = trip_part(trip, rig.trip_channel) if trip != Trip.NONE else ""
    out = []
    for f in _FAULTS:
        struck = f.time <= end
        before = trip != Trip.NONE and trip_at_s is not None and trip_at_s < f.time
        after = None
        if trip != Trip.NONE and trip_at_s is not None and not before:
            after = (trip_at_s - f.time) * 1e3
        names_it = part in fault_parts(f) if part and struck and not before else None
        others = any(
            g is not f and g.time <= end and (trip_at_s is None or g.time <= trip_at_s)
            for g in _FAULTS
        )
        # The warning is this fault's to answer only if the fault struck before it was
        # raised; where the run was not timed (:func:`run`), only if it struck at all.
        credited = (
            warning is not None
            and struck
            and (warned is None or _strike_tick(f) <= round(warned[0] * TICK_HZ))
        )
        said = []
        if credited:
            assert warning is not None
            said.append(warning.removeprefix("the device "))
        if tripped:
            said.append(tripped)
        notice = "; then ".join(said) or None
        out.append(
            FaultOutcome(
                f, struck, notice if struck and not before else None, after, before, end,
                names_it, others,
                (warned[1] - f.time) * 1e3 if credited and warned is not None else None,
                (warned_part in fault_parts(f)) if credited and warned_part else None,
                warning is not None and struck and not credited,
                credited and not before,
            )
        )  # fmt: skip
    return tuple(out)


WARNING_WATCH_S = 0.005
"""With faults injected, :func:`run` looks for the device's warning this often (s): the time
it gives a warning is this close, and every fault's strike is a boundary of its own, so the
order of a warning and a fault is known exactly."""

_WARNED: weakref.WeakKeyDictionary[Rig, tuple[float, float]] = weakref.WeakKeyDictionary()
"""When each rig's device first warned: between the two times (s) of the rig's clock."""


def _strike_tick(fault: Fault) -> int:
    """The controller tick at which ``fault`` strikes (its time, on the rig's clock)."""
    return math.ceil(fault.time * TICK_HZ - 1e-6)


def run(rig: Rig, seconds: float) -> NDArray[np.float64]:
    """``rig.run(seconds)``. With faults injected, run in pieces that end at each fault's
    strike and every :data:`WARNING_WATCH_S`, noting when the device first warned, so that a
    warning is credited only to a fault that struck before it (:func:`fault_outcomes`).
    A healthy run is one piece, as it always was."""
    if not _FAULTS or rig in _WARNED:
        return rig.run(seconds)
    first = round(rig.time * TICK_HZ)
    last = first + round(seconds * TICK_HZ)
    every = round(WARNING_WATCH_S * TICK_HZ)
    cuts = {*range(first + every, last, every), last}
    cuts |= {_strike_tick(f) for f in _FAULTS if first < _strike_tick(f) < last}
    rows = []
    tick = first
    for cut in sorted(cuts):
        rows.append(rig.run((cut - tick) / TICK_HZ))
        if rig not in _WARNED and device_warning(rig) is not None:
            _WARNED[rig] = (tick / TICK_HZ, cut / TICK_HZ)
        tick = cut
    return np.concatenate(rows)


class Checked:
    """A result carrying its :class:`Health`."""

    health: Health

    @property
    def tripped(self) -> bool:
        return self.health.tripped

    @property
    def trip(self) -> str | None:
        return self.health.trip

    @property
    def saturated(self) -> tuple[str, ...]:
        return self.health.saturated

    @property
    def valid(self) -> bool:
        return self.health.valid


def full_duty_slots(rig: Rig) -> int:
    """Slots of the largest duty the rig's controller commands (28, or 21 compensated)."""
    return int(pwm.duty_slots(pwm.duty(100.0, rig.params.d_dead, rig.params.compensate)))


def _full_duty_runs(t: NDArray[np.float64], slots: NDArray[np.float64], full: int) -> float:
    """Longest time any chamber's valve stayed at ``full`` slots or more without a break (s)."""
    if t.size == 0:
        return 0.0
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    longest = 0.0
    for c in range(slots.shape[1]):
        at_full = np.abs(slots[:, c]) >= full
        if not at_full.any():
            continue
        edges = np.diff(np.concatenate(([0], at_full.astype(np.int8), [0])))
        starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
        for a, b in zip(starts, ends, strict=True):
            longest = max(longest, float(t[b - 1] - t[a]) + dt)
    return longest


def never_struck(rig: Rig) -> str | None:
    """Why ``rig``'s finished run is not what was asked for when a fault injected into it
    (``--fault``) was timed after it ended: what was measured is a healthy unit."""
    late = [f for f in _FAULTS if f.time > rig.time]
    if not late:
        return None
    return (
        f"the {late[0].kind.name.lower()} fault at {late[0].time:g} s never struck: the "
        f"run ended at {rig.time:.2f} s of simulated time (the settle at home included)"
    )


def assess(
    rig: Rig,
    log: NDArray[np.float64],
    invalidating: frozenset[str] = frozenset(),
    final: bool = True,
) -> Health:
    """The :class:`Health` of a run whose measured window is ``log``.

    ``invalidating`` names the saturations that make this experiment's number meaningless;
    a trip always does. ``final``: the run has ended (False for one window of a run that
    goes on, where a fault timed later may still strike: :func:`never_struck`).
    """
    trip = rig.trip
    tripped = trip != Trip.NONE
    trip_in_window = None
    if tripped and log.shape[0]:
        hit = np.nonzero(log[:, COL["trip"]] != 0)[0]
        if hit.size and hit[0] > 0:  # a trip already latched at the first row came before
            trip_in_window = float(log[hit[0], 0] - log[0, 0])
    saturated: list[str] = []
    task = log[:, COL["mode"]] == int(Mode.TASK)
    rom = trip == Trip.RANGE_OF_MOTION
    if task.any():
        home = rig.geometry.home_pose
        for k, axis in enumerate(AXES):
            rel = log[task, COL[f"pose_cmd_{axis}"]] - home[k]
            lo, hi = rig.limits.rom_low[k], rig.limits.rom_high[k]
            if np.any(rel <= lo + ROM_TOLERANCE) or np.any(rel >= hi - ROM_TOLERANCE):
                rom = True
    if rom:
        saturated.append("range_of_motion")
    slots = log[:, [COL[f"slots{c}"] for c in range(12)]]
    if _full_duty_runs(log[:, 0], slots, full_duty_slots(rig)) >= VALVE_SATURATION_S:
        saturated.append("valve_duty")
    if trip == Trip.LEG_SPEED:
        saturated.append("leg_speed")
    warning = device_warning(rig)
    reason = None
    if tripped:
        reason = f"tripped {trip.name}"
    elif warning is not None:
        reason = warning
    else:
        bad = [k for k in saturated if k in invalidating]
        if bad:
            reason = "saturated: " + ", ".join(b.replace("_", " ") for b in bad)
    if reason is None and final:
        reason = never_struck(rig)
    return Health(
        tripped,
        trip.name if tripped else None,
        trip_in_window,
        tuple(saturated),
        reason is None,
        reason,
        warning,
        (trips.where(trip, rig.trip_channel) or None) if tripped else None,
        fault_outcomes(rig),
    )


def device_warning(rig: Rig) -> str | None:
    """What the rig's device warned of without tripping (latched until a re-arm), if any."""
    if rig.service_chamber >= 0:
        part = trips.where(Trip.AIR_BALANCE, rig.service_chamber)
        return f"the device asked for service: the air of {part} did not add up with its valves"
    if rig.supply_low:
        return "the device held: the air supply is low"
    rang = [k for k in range(6) if rig.state.ring[k, ring.G_RINGS] > 0]
    if rang:
        k = rang[0]
        factor = float(rig.state.ring[k, ring.G_FACTOR])
        hz = float(rig.state.ring[k, ring.G_HZ])
        return (
            f"{AXES[k]} rang at {hz:.0f} Hz and the ring guard raised its damping {factor:.2f} "
            "times: what was measured is the raised damping"
        )
    return None


def warning_part(rig: Rig) -> str:
    """The part the device's warning names, in the words of :func:`fault_parts` ('' for
    none: a ring names an axis)."""
    if rig.service_chamber >= 0:
        return trips.where(Trip.AIR_BALANCE, rig.service_chamber)
    if rig.supply_low:
        return _SUPPLY
    return ""


def with_warning(health: Health, warning: str | None) -> Health:
    """``health`` of a result put together from several runs, with what the device warned
    of in any of them: invalid if it did and nothing worse already made it so."""
    if warning is None or health.warning is not None:
        return health
    reason = health.reason if health.reason is not None else warning
    return replace(health, valid=False, reason=reason, warning=warning)


def _sine_min_amplitude(k: int) -> float:
    """Smallest amplitude (m or rad) on axis ``k`` that moves a leg MIN_SINE_COUNTS counts."""
    from device.kinematics import Kinematics

    g = DEFAULT_GEOMETRY
    jq = Kinematics(g).pose_jacobian(g.home_pose)
    return MIN_SINE_COUNTS * LEG_SENSOR_M / float(np.max(np.abs(jq[:, k])))


_FAULTS: list[Fault] = []


@contextlib.contextmanager
def injected(faults: tuple[Fault, ...]) -> Iterator[None]:
    """Inject ``faults`` into the plant of every experiment run inside (their times are
    simulated seconds from the rig's start, the settle at home included)."""
    before = list(_FAULTS)
    _FAULTS[:] = list(faults)
    try:
        yield
    finally:
        _FAULTS[:] = before


@dataclass(frozen=True)
class PlantChoice:
    """Which plant the experiments run on (:func:`on_plant`)."""

    draw: int | None = None
    """Plant ``draw`` of the ensemble (device.plant.params.draw_plant); None: nominal."""
    changes: tuple[tuple[str, float], ...] = ()
    """Parameter changes on top (``("unit", n)`` picks another unit)."""
    seed: int | None = None
    """Seed of the sensor noise and valve jitter; None: each experiment's own."""
    calibrate: bool = True
    """Identify the unit first (device.identify) and run the controller with its
    calibration, as the device does at start-up; False: uncalibrated, as wave 1 ran."""

    def config(self, patient: str) -> PlantConfig:
        base = PlantConfig(patient=patient) if self.draw is None else draw_plant(self.draw, patient)
        return base.changed(self.changes)

    def describe(self) -> str:
        parts = [] if self.draw is None else [f"ensemble plant {self.draw}"]
        parts += [f"{k}={v:g}" for k, v in self.changes]
        return ", ".join(parts) or "nominal plant"


_PLANT: list[PlantChoice] = [PlantChoice()]
_CALIBRATIONS: dict[tuple[object, ...], Calibration] = {}


def calibration_of(cfg: PlantConfig) -> Calibration:
    """The unit's start-up identification (device.identify), run once per unit on a twin of
    its plant with nobody on the plate, so that each experiment still starts at rest at
    home. The zeros are properties of the unit, the same on the twin."""
    key = (cfg.overrides, cfg.unit, cfg.substeps, id(cfg.geometry))
    if key not in _CALIBRATIONS:
        _CALIBRATIONS[key] = identify_simulated(cfg)
    return _CALIBRATIONS[key]


def unit_hardware(
    choice: PlantChoice,
    patient: str,
    config: ControllerConfig,
    seed: int,
    plant: PlantConfig | None = None,
) -> tuple[SimulatedHardware, ControllerConfig]:
    """``choice``'s unit with ``patient`` (or ``plant``) on its noise seed (``seed`` unless
    it names one), and ``config`` with the unit's calibration when it calibrates."""
    cfg = plant if plant is not None else choice.config(patient)
    if choice.calibrate:  # first: identifying seeds the plant's random generator itself
        config = replace(config, calibration=calibration_of(cfg))
    return SimulatedHardware(cfg, seed=seed if choice.seed is None else choice.seed), config


@contextlib.contextmanager
def on_plant(choice: PlantChoice) -> Iterator[None]:
    """Run every experiment inside on ``choice``'s plant (and noise seed)."""
    choice.config("relaxed")  # refuse a bad change before anything runs
    before = _PLANT[0]
    _PLANT[0] = choice
    try:
        yield
    finally:
        _PLANT[0] = before


def current_plant() -> PlantChoice:
    return _PLANT[0]


def _rig(
    patient: str = "absent",
    compensate: bool = True,
    seed: int = 1,
    plant: PlantConfig | None = None,
    limits: SafetyLimits | None = None,
) -> Rig:
    hw, config = unit_hardware(
        _PLANT[0], patient, ControllerConfig(deadband_compensation=compensate), seed, plant
    )
    for fault in _FAULTS:
        hw.inject(fault)
    return Rig(hw, config, limits=limits) if limits is not None else Rig(hw, config)


class TrippedBeforeMeasurement(RuntimeError):
    """The device tripped while it was being put in place for an experiment (e.g. holding
    at home): there is no measurement, and no command could have been refused for it."""

    def __init__(
        self,
        trip: str,
        where: str,
        part: str | None = None,
        faults: tuple[FaultOutcome, ...] = (),
    ) -> None:
        named = f" ({part})" if part else ""
        super().__init__(f"tripped {trip}{named} {where}, before the measurement")
        self.trip = trip
        self.part = part
        self.faults = faults


def _settle_at_home(rig: Rig) -> None:
    rig.move_legs(np.full(6, 0.5 * rig.geometry.stroke))
    run(rig, SETTLE_S)
    if rig.trip != Trip.NONE:
        part = trips.where(rig.trip, rig.trip_channel) or None
        faults = fault_outcomes(rig)
        raise TrippedBeforeMeasurement(rig.trip.name, "while settling at home", part, faults)
    rig.clear_log()


def _unit(k: int) -> tuple[float, str]:
    """(SI per user unit, user unit) of axis ``k``: deg for rotations, mm for translations."""
    return (math.radians(1.0), "deg") if k >= 3 else (1e-3, "mm")


@dataclass(frozen=True)
class StepResult(Checked):
    leg: int
    step_mm: float
    compensate: bool
    metrics: StepMetrics
    health: Health
    t: NDArray[np.float64] = field(repr=False)
    displacement_mm: NDArray[np.float64] = field(repr=False)
    """Displacement of the stepped leg relative to its start (mm)."""
    pressure_bar: NDArray[np.float64] = field(repr=False)
    """(n, 2) gauge pressures of its cap and rod chambers (bar)."""
    duty: NDArray[np.float64] = field(repr=False)
    """(n, 2) signed PWM slots of those chambers, as percent of the period."""
    unsettled: str | None = None
    """Why the metrics are not all numbers (the leg did not rise, or did not settle, within
    the record): the step is then invalid (``health``) with this reason, unless the device
    made it so first."""


def leg_step_range(leg: int) -> tuple[float, float]:
    """The lowest and highest displacement (m) leg ``leg`` (1..6) may step from home, the
    other five held there: the target within the stroke the device lets a target use
    (:func:`device.commands.usable_stroke`) and the platform, once there, within its range
    of motion (forward kinematics), which a single leg's step tilts and shifts it through
    on several axes at once: leg 1 down 45 mm moves the platform 36 mm along x, past the
    30 mm range and its 5 mm trip margin; up 45 mm, 34 mm the other way, 1 mm short of the
    trip, where any overshoot trips it."""
    from device.commands import usable_stroke
    from device.kinematics import Kinematics

    i = leg_index(leg)
    g, limits = DEFAULT_GEOMETRY, _LIMITS
    kin = Kinematics(g)
    rom_low, rom_high = np.array(limits.rom_low), np.array(limits.rom_high)

    def inside(d: float) -> bool:
        lengths = np.full(6, g.home_length)
        lengths[i] += d
        pose = kin.forward(lengths) - g.home_pose
        return bool(np.all(rom_low <= pose) and np.all(pose <= rom_high))

    def reach(end: float) -> float:  # from home (inside) toward ``end``, as far as inside
        if inside(end):
            return end
        near, far = 0.0, end
        for _ in range(40):  # to well under a micrometre
            mid = 0.5 * (near + far)
            near, far = (mid, far) if inside(mid) else (near, mid)
        return near

    low, high = usable_stroke(g, limits)
    home = 0.5 * g.stroke
    return reach(low - home), reach(high - home)


def _check_leg_travel(leg: int, mm: float, what: str, times: int = 1) -> None:
    """Refuse ``times`` steps of ``mm`` on ``leg`` beyond :func:`leg_step_range`."""
    low, high = (x * 1e3 / times for x in leg_step_range(leg))
    if not low <= mm <= high:
        got, lo_text, hi_text = figures(mm, low, high, digits=3)
        span = f"{times} steps" if times > 1 else "a step"
        raise CommandError(
            f"leg {leg} {what} must be {lo_text}..{hi_text} mm: {span} beyond would take its "
            f"piston within {LEG_HEADROOM * 1e3:g} mm of the stroke-end trip band or the "
            f"platform out of its range of motion; got {got}"
        )


def check_step(leg: int, mm: float, duration: float = 1.0) -> None:
    """Refuse a step that cannot be measured (before any simulation)."""
    leg_index(leg)
    smallest = MIN_STEP_COUNTS * LEG_SENSOR_M * 1e3
    if not math.isfinite(mm):
        raise CommandError(f"step must be a finite number of mm, got {mm!r}")
    if abs(mm) < smallest:
        got, least = figures(abs(mm), smallest, digits=3)
        raise CommandError(
            f"step must be at least {least} mm either way (a 10-90 % rise needs its 10 % "
            f"point resolved by the {LEG_SENSOR_M * 1e3:.4f} mm leg sensor), got "
            f"{'-' if mm < 0 else ''}{got}"
        )
    _check_leg_travel(leg, mm, "step")
    # The record must hold the step: the leg's travel at the fastest the device lets a leg
    # go (its leg speed limit trips beyond), then the window a settled response stays in.
    shortest = abs(mm) * 1e-3 / _LIMITS.leg_speed_limit + SETTLE_HOLD_S
    if not (math.isfinite(duration) and shortest <= duration <= STEP_DURATION_MAX_S):
        got, low, high = figures(duration, shortest, STEP_DURATION_MAX_S, digits=3)
        raise CommandError(
            f"duration of a {abs(mm):g} mm step must be {low}..{high} s (its travel at the "
            f"{_LIMITS.leg_speed_limit:g} m/s leg speed limit, then {SETTLE_HOLD_S:g} s within "
            f"{SETTLE_BAND_M * 1e3:g} mm of the target to count as settled), got {got}"
        )


def step(
    leg: int = 1,
    mm: float = 10.0,
    compensate: bool = True,
    duration: float = 1.0,
    patient: str = "absent",
    seed: int = 1,
) -> StepResult:
    """Independent joint position step of one leg (paper, Figure 9)."""
    check_step(leg, mm, duration)
    i = leg_index(leg)
    rig = _rig(patient, compensate, seed)
    _settle_at_home(rig)
    target = rig.state.leg_target.copy()
    target[i] += mm * 1e-3
    rig.move_legs(target)
    log = run(rig, duration)
    t = log[:, 0] - log[0, 0]
    y = log[:, COL[f"leg_x{i}"]]
    y_start = float(y[0])
    # Against the commanded target, so a static offset cannot hide in the difference.
    m = step_metrics(t, y, y_start, float(target[i]))
    p = log[:, [COL[f"pressure_g{2 * i}"], COL[f"pressure_g{2 * i + 1}"]]] / 1e5
    d = log[:, [COL[f"slots{2 * i}"], COL[f"slots{2 * i + 1}"]]] * (100.0 / 28.0)
    health = assess(rig, log)
    unsettled = unmeasured_step(m, duration)
    if unsettled is not None and health.valid:
        health = replace(health, valid=False, reason=unsettled)
    return StepResult(leg, mm, compensate, m, health, t, (y - y_start) * 1e3, p, d, unsettled)


def unmeasured_step(m: StepMetrics, duration: float) -> str | None:
    """Why a step's metrics are not all numbers, in words; None when they are."""
    if m.measured:
        return None
    band = f"{SETTLE_BAND_M * 1e3:g} mm"
    if not math.isfinite(m.rise_ms):
        return f"the leg did not reach 90 % of the step within the {duration:g} s recorded"
    return (
        f"the leg did not settle: it stayed within {band} of the target for no "
        f"{SETTLE_HOLD_S:g} s of the {duration:g} s recorded"
    )


@dataclass(frozen=True)
class StaircaseResult(Checked):
    leg: int
    step_mm: float
    errors_mm: tuple[float, ...]
    """Steady error after each step (mm)."""
    health: Health
    t: NDArray[np.float64] = field(repr=False)
    displacement_mm: NDArray[np.float64] = field(repr=False)
    target_mm: NDArray[np.float64] = field(repr=False)

    @property
    def resolution_mm(self) -> float:
        """The largest steady error over the staircase (NaN if no step was taken)."""
        return max(self.errors_mm) if self.errors_mm else math.nan


def check_staircase(leg: int, step_mm: float, steps: int = STAIR_STEPS) -> None:
    """Refuse a staircase that cannot be measured (before any simulation)."""
    leg_index(leg)
    smallest = MIN_STAIR_COUNTS * LEG_SENSOR_M * 1e3
    if not math.isfinite(step_mm):
        raise CommandError(f"staircase step must be a finite number of mm, got {step_mm!r}")
    if abs(step_mm) < smallest:
        got, least = figures(abs(step_mm), smallest, digits=3)
        raise CommandError(
            f"staircase step must be at least {least} mm either way (one count of the leg "
            f"sensor), got {'-' if step_mm < 0 else ''}{got}"
        )
    _check_leg_travel(leg, step_mm, "staircase step", steps)


def staircase(
    leg: int = 1, step_mm: float = 0.3, steps: int = STAIR_STEPS, dwell: float = 0.5, seed: int = 1
) -> StaircaseResult:
    """Small steps up then down: how fine can a leg be placed?"""
    check_staircase(leg, step_mm, steps)
    i = leg_index(leg)
    rig = _rig("absent", True, seed)
    _settle_at_home(rig)
    target = rig.state.leg_target.copy()
    start = float(rig.state.leg_x[i])
    base = float(target[i])
    errors: list[float] = []
    levels = list(range(1, steps + 1)) + list(range(steps - 1, -1, -1))
    ts, ys, rs = [], [], []
    for n in levels:
        target[i] = base + n * step_mm * 1e-3
        if rig.mode == Mode.FAULT:
            break  # tripped: no further step would move
        rig.move_legs(target)
        log = run(rig, dwell)
        y = log[:, COL[f"leg_x{i}"]]
        tail = log[:, 0] >= log[-1, 0] - 0.1
        errors.append(abs(float(np.mean(y[tail])) - target[i]) * 1e3)
        ts.append(log[:, 0])
        ys.append((y - start) * 1e3)
        rs.append(np.full(y.shape, (target[i] - start) * 1e3))
    health = assess(rig, rig.log)
    if not ts:  # tripped while settling at home: not one step was taken
        empty = np.zeros(0)
        return StaircaseResult(leg, step_mm, (), health, empty, empty, empty)
    t = np.concatenate(ts)
    return StaircaseResult(
        leg, step_mm, tuple(errors), health, t - t[0], np.concatenate(ys), np.concatenate(rs)
    )


def _axis(axis: str) -> int:
    if axis not in AXIS_INDEX:
        raise CommandError(f"unknown axis {axis!r}; axes are {', '.join(AXES)}")
    return AXIS_INDEX[axis]


def _angular(k: int) -> bool:
    return k >= 3


@dataclass(frozen=True)
class SineResult(Checked):
    axis: str
    amplitude: float
    """In degrees for rotations, mm for translations."""
    frequency: float
    gain_db: float
    phase_deg: float
    health: Health
    t: NDArray[np.float64] = field(repr=False)
    command: NDArray[np.float64] = field(repr=False)
    response: NDArray[np.float64] = field(repr=False)


SINE_HZ_RANGE = (0.05, SINE_HZ_MAX)
"""Sine frequencies: below 0.05 Hz six cycles take minutes; the top is the device's own
limit on a sine command."""


def check_sine(axis: str, amplitude: float, hz: float, limits: SafetyLimits | None = None) -> None:
    """Refuse a sine that cannot be measured (before any simulation)."""
    k = _axis(axis)
    scale, unit = _unit(k)
    lim = _LIMITS if limits is None else limits.published()
    smallest = _sine_min_amplitude(k) / scale
    largest = largest_amplitude(k, lim)
    if not (math.isfinite(amplitude) and smallest <= amplitude <= largest):
        # Each bound with the digits that tell it from the value (the one place those are
        # many: 30 mm along x against the published 29.999999).
        got, low = figures(amplitude, smallest, digits=3)
        got_high, high = figures(amplitude, largest, digits=3)
        got = max(got, got_high, key=len)
        raise CommandError(
            f"{axis} amplitude must be {low}..{high} {unit} (at least {MIN_SINE_COUNTS} leg "
            f"sensor counts; at most the range of motion), got {got}"
        )
    lo, hi = SINE_HZ_RANGE
    if not (math.isfinite(hz) and lo <= hz <= hi):
        got, low, high = figures(hz, lo, hi)
        raise CommandError(f"frequency must be {low}..{high} Hz, got {got}")
    fastest = speed_limit_hz(axis, amplitude, lim)
    if hz > fastest:
        got, high = figures(hz, fastest, digits=3)
        raise CommandError(
            f"{axis} {amplitude:g} {unit} at {got} Hz is faster than the device accepts "
            f"(axis speed limit {lim.axis_speed_max[k]:g} {'rad' if k >= 3 else 'm'}/s: "
            f"at most {high} Hz at this amplitude)"
        )


def largest_amplitude(k: int, limits: SafetyLimits) -> float:
    """The largest sine amplitude on axis ``k``, in the user's unit (deg or mm), that the
    device accepts about home: the one whose value in SI (``amplitude * scale``, as the
    experiment commands it) stays within the range of motion ``limits`` publish (float32, as
    ``DeviceHello`` carries them, so 30 mm along x is just beyond 0.029999999 m)."""
    scale = _unit(k)[0]
    rom = min(limits.rom_high[k], -limits.rom_low[k])
    a = rom / scale
    while a * scale > rom:  # the same comparison the device makes, one unit in the last place
        a = math.nextafter(a, 0.0)
    return a


def speed_limit_hz(axis: str, amplitude: float, limits: SafetyLimits | None = None) -> float:
    """Highest sine frequency the device accepts at ``amplitude`` (deg or mm): its axis speed
    limit (``SafetyLimits.axis_speed_max``) bounds the target's peak speed 2 pi f A."""
    k = _axis(axis)
    a = amplitude * _unit(k)[0]
    lim = _LIMITS if limits is None else limits.published()
    return lim.axis_speed_max[k] / (2.0 * math.pi * a) if a > 0 else math.inf


def _sine_lead_s(hz: float) -> float:
    """How long :func:`sine` runs its sine before it measures (s): the start-up transient."""
    return max(1.0 / hz, 0.3)


def _sweep_cycles(hz: float) -> int:
    """Cycles :func:`sweep` measures at ``hz``."""
    return max(3, min(12, int(2 * hz)))


def _sweep_run_s(hz: float) -> float:
    """How long one frequency's run of :func:`sweep` lasts, in the simulated time that
    ``--fault`` times count (s): the settle at home, the lead, the measured cycles."""
    return SETTLE_S + _sine_lead_s(hz) + _sweep_cycles(hz) / hz


def sine(
    axis: str = "pitch",
    amplitude: float = 2.0,
    hz: float = 1.0,
    cycles: int = 6,
    patient: str = "relaxed",
    seed: int = 1,
    limits: SafetyLimits | None = None,
) -> SineResult:
    """Pose tracking of a sine on one axis (paper, Figure 10). Amplitude in deg or mm."""
    check_sine(axis, amplitude, hz, limits)
    k = _axis(axis)
    scale = _unit(k)[0]
    rig = _rig(patient, True, seed, limits=limits)
    _settle_at_home(rig)
    rig.track({axis: AxisTarget(Waveform.SINE, 0.0, amplitude * scale, hz)})
    run(rig, _sine_lead_s(hz))  # let the start-up transient die
    rig.clear_log()
    log = run(rig, cycles / hz)
    home = rig.geometry.home_pose[k]
    command = (log[:, COL[f"pose_cmd_{axis}"]] - home) / scale
    response = (log[:, COL[f"pose_{axis}"]] - home) / scale
    t = log[:, 0]
    health = assess(rig, log, frozenset({"range_of_motion"}))
    if health.valid:
        reference = amplitude * np.sin(2.0 * math.pi * hz * (t - rig.state.trajectory[k, 4]))
        gain, phase = sine_response(t, reference, response, hz)
    else:
        gain = phase = math.nan  # the held platform after a trip is no response
    return SineResult(axis, amplitude, hz, gain, phase, health, t - t[0], command, response)


SWEEP_HZ: tuple[float, ...] = (0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 10.0, 12.0, 15.0)


@dataclass(frozen=True)
class SweepResult(Checked):
    axis: str
    amplitude: float
    frequencies: tuple[float, ...]
    """The frequencies measured: the sweep stops at the first invalid one (included)."""
    gains_db: tuple[float, ...]
    phases_deg: tuple[float, ...]
    bandwidth_hz: float
    """First frequency where the gain falls below -3 dB (interpolated) when measured; the
    last valid frequency when only a lower bound is known; NaN when unknown."""
    bandwidth_kind: str
    """``measured``, ``lower_bound`` (the gain stayed above -3 dB up to the top of the sweep
    or up to where it stopped) or ``unknown`` (the first frequency was already invalid)."""
    health: Health
    """Of the sweep as a whole: the first invalid frequency's, or the last one's."""
    stopped_hz: float | None
    """The frequency at which the sweep stopped because it tripped or saturated."""
    requested: tuple[float, ...] = ()
    speed_limit_hz: float = math.inf
    """Above this frequency the device refuses the sine (its axis speed limit), so the sweep
    ends below it; inf when every requested frequency was within the limit."""


def sweep(
    axis: str = "pitch",
    amplitude: float = 2.0,
    frequencies: tuple[float, ...] = SWEEP_HZ,
    seed: int = 1,
    limits: SafetyLimits | None = None,
) -> SweepResult:
    """Frequency response of one axis and its -3 dB bandwidth.

    Stops at the first frequency whose run tripped or hit the range of motion: a trip is
    not roll-off. The bandwidth is then measured only if the gain had already fallen below
    -3 dB; otherwise it is a lower bound (the last valid frequency), or unknown.
    """
    fastest = speed_limit_hz(axis, amplitude, limits)
    requested = tuple(frequencies)
    frequencies = tuple(f for f in frequencies if f <= fastest)
    for f in frequencies:
        check_sine(axis, amplitude, f, limits)
    if frequencies and _FAULTS:
        # Each frequency runs on a fresh unit, with every fault at its time in that run.
        shortest = min(frequencies, key=_sweep_run_s)
        ends = _sweep_run_s(shortest)
        late = [f for f in _FAULTS if f.time > ends]
        if late:
            raise CommandError(
                f"a sweep runs each frequency on a fresh unit, each fault at its time in every "
                f"run: the {shortest:g} Hz run ends at {ends:.2f} s, so the "
                f"{late[0].kind.name.lower()} fault at {late[0].time:g} s would strike in "
                f"some runs only; time it before {ends:.2f} s"
            )
    done: list[float] = []
    gains: list[float] = []
    phases: list[float] = []
    health: Health | None = None
    stopped: float | None = None
    for f in frequencies:
        r = sine(axis, amplitude, f, cycles=_sweep_cycles(f), seed=seed, limits=limits)
        done.append(f)
        gains.append(r.gain_db)
        phases.append(r.phase_deg)
        health = r.health
        if not r.valid:
            stopped = f
            break
    assert health is not None
    valid_f = done[:-1] if stopped is not None else done
    bw, kind = math.nan, "unknown"
    for n in range(len(valid_f)):
        if gains[n] < -3.0:
            if n == 0:
                bw = valid_f[0]
            else:
                f0, f1, g0, g1 = valid_f[n - 1], valid_f[n], gains[n - 1], gains[n]
                bw = f0 + (f1 - f0) * (-3.0 - g0) / (g1 - g0)
            kind = "measured"
            break
    else:
        if valid_f:
            bw, kind = valid_f[-1], "lower_bound"
    if kind == "measured" and stopped is not None:
        # The trip (or the warning) came after the gain had fallen: the bandwidth itself
        # was measured.
        health = replace(health, valid=True, reason=None)
    return SweepResult(
        axis,
        amplitude,
        tuple(done),
        tuple(gains),
        tuple(phases),
        bw,
        kind,
        health,
        stopped,
        requested,
        fastest if len(frequencies) < len(requested) else math.inf,
    )


@dataclass(frozen=True)
class ImpedanceResult(Checked):
    axis: str
    stiffness: float
    damping: float
    measured_stiffness: float
    error_pct: float
    health: Health
    t: NDArray[np.float64] = field(repr=False)
    angle: NDArray[np.float64] = field(repr=False)
    """Platform angle (rad) or position (m) from home."""
    torque: NDArray[np.float64] = field(repr=False)
    """Measured foot torque (N m) or force (N) on that axis, tare removed."""


def check_impedance(axis: str, k: float, b: float, torque: float) -> int:
    """Refuse an impedance experiment that cannot be measured; returns the axis index."""
    ax = _axis(axis)
    if not _angular(ax):
        raise CommandError("the patient pushes with a torque: choose roll, pitch or yaw")
    for name, v in (("stiffness", k), ("damping", b), ("torque", torque)):
        if not math.isfinite(v):
            raise CommandError(f"{name} must be a finite number")
    limits = _LIMITS
    if k <= 0.0:
        raise CommandError("stiffness must be positive to measure it")
    if k > limits.stiffness_max[ax]:
        got, top = figures(k, limits.stiffness_max[ax])
        raise CommandError(f"stiffness must be at most {top} N m/rad, got {got}")
    if b < 0.0:
        raise CommandError("damping cannot be negative")
    if b > limits.damping_max[ax]:
        got, top = figures(b, limits.damping_max[ax])
        raise CommandError(f"damping must be at most {top} N m s/rad, got {got}")
    if not TORQUE_MIN_NM <= abs(torque) <= TORQUE_MAX_NM:
        got, lo, hi = figures(abs(torque), TORQUE_MIN_NM, TORQUE_MAX_NM)
        raise CommandError(
            f"torque must be {lo}..{hi} N m either way (resolved by the force plate; below "
            f"its {limits.torque_limit:g} N m trip), got {'-' if torque < 0 else ''}{got}"
        )
    # The relaxed ankle's own stiffness takes its share of the patient's torque: the
    # platform turns by torque / (K + K_ankle), and the plate sees K times that.
    ankle = float(build_params(current_plant().config("relaxed")).patient_k[ax])
    unit = f"N m/rad (the relaxed ankle's own {ankle:.3g} N m/rad takes the rest)"
    # What the plate sees must be resolved by it: at least the smallest torque it resolves.
    if k * abs(torque) / (k + ankle) < TORQUE_MIN_NM:
        if abs(torque) <= TORQUE_MIN_NM:
            raise CommandError(
                f"torque {torque:g} N m: the plate sees only K / (K + K_ankle) of it, "
                f"under the {TORQUE_MIN_NM:g} N m it resolves whatever K; push harder"
            )
        least_k = TORQUE_MIN_NM * ankle / (abs(torque) - TORQUE_MIN_NM)
        got, low = figures(k, least_k, digits=3)
        raise CommandError(
            f"against torque {torque:g} N m the plate sees K / (K + K_ankle) of it: K must be "
            f"at least {low} {unit} for the plate to see the {TORQUE_MIN_NM:g} N m it "
            f"resolves, got {got}"
        )
    # The deflection must stay inside the range of motion, where the device clamps it.
    rom = limits.rom_high[ax] if torque > 0 else -limits.rom_low[ax]
    least_k = abs(torque) / rom - ankle
    if k < least_k:
        got, low = figures(k, least_k, digits=3)
        raise CommandError(
            f"torque {torque:g} N m would turn {axis} beyond its range of motion "
            f"({math.degrees(rom):.3g} deg): K must be at least {low} {unit}, got {got}"
        )
    # The deflection must move the legs by enough counts.
    smallest = _sine_min_amplitude(ax)
    deflection = abs(torque) / (k + ankle)
    if deflection < smallest:
        most_k = abs(torque) / smallest - ankle
        got, high = figures(k, most_k, digits=3)
        raise CommandError(
            f"torque {torque:g} N m against K = {got} and the relaxed ankle's {ankle:.3g} "
            f"N m/rad moves {axis} {math.degrees(deflection):.3g} deg, below the "
            f"{math.degrees(smallest):.3g} deg the leg sensors resolve: K must be at most "
            f"{high} N m/rad"
        )
    return ax


def _impedance_rig(ax: int, k: float, b: float, seed: int) -> Rig:
    rig = _rig("relaxed", True, seed)
    _settle_at_home(rig)
    K = np.full(6, 0.0)
    B = np.full(6, 0.0)
    K[ax], B[ax] = k, b
    on = [i == ax for i in range(6)]
    rig.set_impedance(K, B, on)
    rig.track({})
    run(rig, 0.3)
    return rig


def impedance(
    axis: str = "pitch",
    k: float = 50.0,
    b: float = 1.0,
    torque: float = 10.0,
    ramp_s: float = 4.0,
    seed: int = 1,
) -> ImpedanceResult:
    """The patient pushes with a slow torque ramp against the rendered impedance (Figure 12).

    Returns the stiffness measured as the slope of foot torque against platform angle.
    """
    ax = check_impedance(axis, k, b, torque)
    rig = _impedance_rig(ax, k, b, seed)
    t0 = rig.time
    rig.hardware.script_torque(ax, SCRIPT_RAMP, t0, torque / ramp_s, torque)  # type: ignore[attr-defined]
    rig.clear_log()
    log = run(rig, ramp_s + 0.5)
    home = rig.geometry.home_pose[ax]
    angle = log[:, COL[f"pose_meas_{AXES[ax]}"]] - home
    tq = log[:, COL[f"wrench_{AXES[ax]}"]] - rig.state.tare[ax]
    t = log[:, 0] - t0
    window = (t > 0.15 * ramp_s) & (t < ramp_s)
    health = assess(rig, log, frozenset({"range_of_motion"}))
    slope = stiffness_slope(angle[window], tq[window]) if health.valid else math.nan
    return ImpedanceResult(axis, k, b, slope, abs(slope - k) / k * 100.0, health, t, angle, tq)


IMPEDANCE_HZ: tuple[float, ...] = (0.5, 1.0, 2.0)


@dataclass(frozen=True)
class FitResult:
    """One least-squares fit of torque = K angle + B rate + c."""

    hz: float | None
    """The patient's torque frequency; None for the joint fit over all of them."""
    stiffness: float
    damping: float
    offset: float
    patient_stiffness: float
    """The same fit of the patient's own (active, scripted) torque: what the patient's
    muscles work against, the rendered impedance plus the passive ankle in parallel."""
    patient_damping: float
    law_stiffness: float
    """The same fit of the measured torque against the commanded pose: the admittance law
    alone, before the position loop has to follow it."""
    law_damping: float
    inertia: float = math.nan
    """Joint fit over two or more frequencies only: the inertia J (kg m2) fitted beside K
    and B (lab.metrics.impedance_fit_inertia); the device renders a virtual one."""


@dataclass(frozen=True)
class DynamicImpedanceResult(Checked):
    """The patient applies a sinusoidal torque at several frequencies (``--mode dynamic``).

    The fit uses the force plate's torque, which is the wrench between foot and plate: the
    patient's active torque minus what the relaxed ankle's own stiffness and damping (in
    parallel, device/plant/params.py) take up. It therefore measures the impedance the
    device renders, K and B, not the patient's. The patient's muscles feel K + K_ankle and
    B + B_ankle: the same fit of the scripted active torque (``patient_*``, known only in
    simulation) shows that sum.
    """

    axis: str
    stiffness: float
    damping: float
    torque: float
    fits: tuple[FitResult, ...]
    """One per frequency, then the joint fit (``hz`` None)."""
    health: Health

    @property
    def joint(self) -> FitResult:
        return self.fits[-1]

    @property
    def stiffness_error_pct(self) -> float:
        return abs(self.joint.stiffness - self.stiffness) / self.stiffness * 100.0

    @property
    def damping_error(self) -> float:
        """Absolute error of B (N m s/rad): B may be 0, so no percentage by default."""
        return abs(self.joint.damping - self.damping)

    @property
    def damping_error_pct(self) -> float:
        return self.damping_error / self.damping * 100.0 if self.damping > 0 else math.nan


def virtual_inertia(ax: int, k: float) -> float:
    """The virtual inertia (kg m2) the device renders on axis ``ax`` at stiffness ``k``: the
    axis's own, raised so the virtual mode stays at or below its frequency cap
    (``ControllerConfig.virtual_inertia``, ``virtual_frequency_max``)."""
    config = ControllerConfig()
    j = config.virtual_inertia[ax]
    if j > 0.0 and config.virtual_frequency_max > 0.0:
        j = max(j, k / (2.0 * math.pi * config.virtual_frequency_max) ** 2)
    return j


def check_dynamic(axis: str, k: float, b: float, torque: float, hz: tuple[float, ...]) -> int:
    """Refuse a dynamic impedance experiment that cannot be measured; returns the axis."""
    ax = check_impedance(axis, k, b, torque)
    lo, hi = IMPEDANCE_HZ_RANGE
    if not hz:
        raise CommandError("give at least one patient torque frequency")
    for f in hz:
        if not (math.isfinite(f) and lo <= f <= hi):
            got, low, high = figures(f, lo, hi)
            ring_low = ControllerConfig().ring_band[0]
            raise CommandError(
                f"patient torque frequencies must be {low}..{high} Hz (a few cycles within "
                f"minutes; below the ring guard's band from {ring_low:g} Hz, where a torque "
                f"sine is taken for the foot ringing), got {got}"
            )
    if len(set(hz)) == 1:
        # One frequency measures K - J w^2: refused where the inertia would pass for K.
        j = virtual_inertia(ax, k)
        top = math.sqrt(INERTIA_SHARE_MAX * k / j) / (2.0 * math.pi) if j > 0.0 else math.inf
        if hz[0] > top:
            got, high = figures(hz[0], top, digits=3)
            raise CommandError(
                f"at one frequency the fit cannot tell the device's virtual inertia "
                f"({j:.3g} kg m2 at K = {k:g}) from a lower stiffness: alone, the frequency "
                f"must be at most {high} Hz (J w^2 within {INERTIA_SHARE_MAX * 100:g} % of K), "
                f"got {got}; or give two or more frequencies, fitted with J"
            )
    return ax


def impedance_dynamic(
    axis: str = "pitch",
    k: float = 50.0,
    b: float = 1.0,
    torque: float = 5.0,
    hz: tuple[float, ...] = IMPEDANCE_HZ,
    seed: int = 1,
) -> DynamicImpedanceResult:
    """The patient's torque is a sine at each of ``hz`` in turn; K and B are fitted by least
    squares of the measured torque on angle and angular rate (per frequency and jointly)."""
    ax = check_dynamic(axis, k, b, torque, hz)
    rig = _impedance_rig(ax, k, b, seed)
    home = rig.geometry.home_pose[ax]
    windows = []
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    for f in hz:
        t0 = rig.time
        hw.script_torque(ax, SCRIPT_SINE, t0, torque, f)
        run(rig, max(1.0 / f, 0.5))  # the transient of the new frequency dies
        rig.clear_log()
        cycles = max(3, math.ceil(2.0 * f))
        log = run(rig, cycles / f)
        health = assess(rig, log, frozenset({"range_of_motion"}), final=False)
        if not health.valid:
            hw.script_torque(ax, 0, 0.0, 0.0, 0.0)
            return DynamicImpedanceResult(axis, k, b, torque, (), health)
        t = log[:, 0]
        angle = log[:, COL[f"pose_meas_{AXES[ax]}"]] - home
        tq = log[:, COL[f"wrench_{AXES[ax]}"]] - rig.state.tare[ax]
        active = torque * np.sin(2.0 * math.pi * f * (t - t0))
        command = log[:, COL[f"pose_cmd_{AXES[ax]}"]] - home
        windows.append((f, t, angle, tq, active, health, command))
    hw.script_torque(ax, 0, 0.0, 0.0, 0.0)
    fits = []
    for f, t, angle, tq, active, _, command in windows:
        fit = impedance_fit(t, angle, tq, f)
        pfit = impedance_fit(t, angle, active, f)
        lfit = impedance_fit(t, command, tq, f)
        fits.append(FitResult(f, fit[0], fit[1], fit[2], pfit[0], pfit[1], lfit[0], lfit[1]))
    several = len(set(hz)) >= 2

    def joint_fit(values: int) -> tuple[float, float, float, float]:
        """(K, B, c, J) over every window of ``windows[i][values]`` against the angle (or
        the command, for the law's fit): with an inertia beside K and B when the windows
        span two or more frequencies."""
        angles = [w[6] if values == 6 else w[2] for w in windows]
        torques = [w[4] if values == 4 else w[3] for w in windows]
        times = [w[1] for w in windows]
        if several:
            k_, b_, j_, c_ = impedance_fit_inertia(times, angles, torques, list(hz))
            return k_, b_, c_, j_
        k_, b_, c_ = impedance_fit(times, angles, torques, list(hz))
        return k_, b_, c_, math.nan

    k_j, b_j, c_j, j_j = joint_fit(3)
    joint = (k_j, b_j, c_j)
    pjoint = joint_fit(4)
    ljoint = joint_fit(6)
    fits.append(  # the joint fit
        FitResult(None, *joint, pjoint[0], pjoint[1], ljoint[0], ljoint[1], inertia=j_j)
    )
    saturated = sorted({s for w in windows for s in w[5].saturated})
    warned = next((w[5].warning for w in windows if w[5].warning), None)
    late = never_struck(rig)
    health = Health(
        False, None, None, tuple(saturated), late is None, late, faults=fault_outcomes(rig)
    )
    return DynamicImpedanceResult(axis, k, b, torque, tuple(fits), with_warning(health, warned))
