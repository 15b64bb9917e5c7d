"""A controller on its hardware: the Python face of the device, with validated commands.

Every command is checked here (finite, inside the device's own limits) and refused with
:class:`CommandError` saying what was wrong, leaving the controller untouched. The compiled
controller checks again on its side (``device.safety``); the limits live in both places.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from device import controller as ctl
from device import tickloop
from device.controller import ControllerConfig, Mode, Waveform
from device.geometry import AXES, DEFAULT_GEOMETRY, Geometry
from device.hardware import Hardware, SimulatedHardware
from device.plant.params import TICK_HZ, PlantConfig
from device.safety import SafetyLimits, Trip

Vector = Sequence[float] | NDArray[np.float64]
"""Six numbers, one per leg or axis."""


_NO_LOG = np.zeros((0, tickloop.N_LOG))


class CommandError(ValueError):
    """A command the device refuses; nothing was changed."""


@dataclass(frozen=True)
class AxisTarget:
    """Target waveform of one task-space axis, relative to the home pose (m or rad)."""

    kind: Waveform = Waveform.HOLD
    center: float = 0.0
    amplitude: float = 0.0
    """Sine amplitude, or ramp rate per second."""
    frequency: float = 0.0
    """Sine frequency (Hz), or the ramp's end value."""


def _finite(name: str, values: Vector | Sequence[float]) -> NDArray[np.float64]:
    arr = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise CommandError(f"{name} must be finite numbers, got {np.asarray(values).tolist()}")
    return arr


class Rig:
    """Controller + hardware + tick loop, in simulated time when the hardware is the plant."""

    def __init__(
        self,
        hardware: Hardware | None = None,
        config: ControllerConfig = ControllerConfig(),
        geometry: Geometry = DEFAULT_GEOMETRY,
        limits: SafetyLimits = SafetyLimits(),
    ) -> None:
        self.hardware = hardware if hardware is not None else SimulatedHardware(PlantConfig())
        self.geometry = geometry
        self.limits = limits
        self.config = config
        self.params, self.schedule = ctl.build_params(config, geometry, limits)
        self.state = ctl.new_state(geometry)
        self._log: list[NDArray[np.float64]] = []

    # -- running -------------------------------------------------------------------------
    @property
    def time(self) -> float:
        """Controller time (s): ticks since start / 7000."""
        return int(self.state.istate[ctl.I_TICK]) / TICK_HZ

    def run(self, seconds: float, log_hz: float = 1000.0) -> NDArray[np.float64]:
        """Advance by ``seconds``; returns the log rows taken (also kept in :attr:`log`)."""
        n = round(seconds * TICK_HZ)
        decimation = max(1, round(TICK_HZ / log_hz)) if log_hz > 0 else 0
        rows = np.zeros((n // decimation + 1 if decimation else 0, tickloop.N_LOG))
        if isinstance(self.hardware, SimulatedHardware):
            hw = self.hardware
            k = tickloop.run_sim(self.state, self.params, hw.state, hw.params, n, decimation, rows)
            rows = rows[:k]
        else:
            tickloop.run_hardware(self.state, self.params, self.hardware, n)
            rows = rows[:0]
        self._log.append(rows)
        return rows

    def advance(self, ticks: int) -> None:
        """Advance ``ticks`` interrupts without logging (the device service's pacing step)."""
        if isinstance(self.hardware, SimulatedHardware):
            hw = self.hardware
            tickloop.run_sim(self.state, self.params, hw.state, hw.params, ticks, 0, _NO_LOG)
        else:
            tickloop.run_hardware(self.state, self.params, self.hardware, ticks)

    @property
    def log(self) -> NDArray[np.float64]:
        return np.concatenate(self._log) if self._log else np.zeros((0, tickloop.N_LOG))

    def clear_log(self) -> None:
        self._log.clear()

    # -- status --------------------------------------------------------------------------
    @property
    def mode(self) -> Mode:
        return Mode(int(self.state.istate[ctl.I_MODE]))

    @property
    def trip(self) -> Trip:
        return Trip(int(self.state.istate[ctl.I_TRIP]))

    # -- commands ------------------------------------------------------------------------
    def _start_motion(self) -> None:
        if self.mode == Mode.FAULT:
            raise CommandError(f"the device is tripped ({self.trip.name}); re-arm first")
        s = self.state
        if self.mode == Mode.IDLE:
            s.integral[:] = 0.0
            s.x_m[:] = 0.0
            s.v_m[:] = 0.0
            s.leg_target[:] = s.leg_x
            s.leg_target_rate[:] = 0.0

    def move_legs(self, displacement: Vector) -> None:
        """Independent joint control: hold each piston at ``displacement`` (m, 0..stroke)."""
        x = _finite("leg displacement", displacement)
        if x.shape != (6,):
            raise CommandError("leg displacement needs 6 values")
        m = self.limits.stroke_margin
        bad = [i for i in range(6) if not m < x[i] < self.geometry.stroke - m]
        if bad:
            raise CommandError(
                f"leg(s) {', '.join(str(i + 1) for i in bad)} outside "
                f"{m * 1e3:.0f}..{(self.geometry.stroke - m) * 1e3:.0f} mm"
            )
        self._start_motion()
        self.state.leg_target[:] = x
        self.state.leg_target_rate[:] = 0.0
        self.state.istate[ctl.I_MODE] = Mode.JOINT

    def track(self, targets: dict[str, AxisTarget]) -> None:
        """Task-space exercise: each named axis follows its waveform, the others hold home."""
        unknown = set(targets) - set(AXES)
        if unknown:
            raise CommandError(f"unknown axis {sorted(unknown)}; axes are {', '.join(AXES)}")
        traj = np.zeros((6, 5))
        t0 = self.time
        for k, axis in enumerate(AXES):
            tgt = targets.get(axis, AxisTarget())
            vals = _finite(f"{axis} target", [tgt.center, tgt.amplitude, tgt.frequency])
            lo, hi = self.limits.rom_low[k], self.limits.rom_high[k]
            if tgt.kind == Waveform.SINE:
                extent = (tgt.center - abs(tgt.amplitude), tgt.center + abs(tgt.amplitude))
                if not 0.0 <= tgt.frequency <= 20.0:
                    raise CommandError(f"{axis} frequency must be 0..20 Hz")
            elif tgt.kind == Waveform.RAMP:
                extent = (min(tgt.center, tgt.frequency), max(tgt.center, tgt.frequency))
            else:
                extent = (tgt.center, tgt.center)
            if extent[0] < lo or extent[1] > hi:
                raise CommandError(
                    f"{axis} target {extent[0]:.4g}..{extent[1]:.4g} leaves the range of "
                    f"motion {lo:.4g}..{hi:.4g}"
                )
            home = self.geometry.home_pose[k]
            traj[k] = (
                int(tgt.kind),
                home + vals[0],
                vals[1],
                home + vals[2] if tgt.kind == Waveform.RAMP else vals[2],
                t0,
            )
        self._start_motion()
        self.state.trajectory[:] = traj
        if self.mode != Mode.TASK:
            # A new exercise starts from the foot's resting wrench (its weight, the shank's
            # preload) whether the platform was idle or holding legs: only what the patient
            # adds beyond that drives the impedance.
            self.state.tare[:] = self.state.wrench
            self.state.x_m[:] = 0.0
            self.state.v_m[:] = 0.0
        self.state.istate[ctl.I_MODE] = Mode.TASK

    def set_impedance(
        self,
        stiffness: Vector,
        damping: Vector,
        compliant: Sequence[bool] | None = None,
    ) -> None:
        """K and B per axis (N/m, N m/rad; N s/m, N m s/rad); slewed by the device."""
        K = _finite("stiffness", stiffness)
        B = _finite("damping", damping)
        if K.shape != (6,) or B.shape != (6,):
            raise CommandError("stiffness and damping need 6 values each")
        on = np.ones(6) if compliant is None else np.asarray(compliant, dtype=np.float64)
        for k, axis in enumerate(AXES):
            if not 0.0 <= K[k] <= self.limits.stiffness_max[k]:
                raise CommandError(
                    f"{axis} stiffness {K[k]:g} outside 0..{self.limits.stiffness_max[k]:g}"
                )
            if not 0.0 <= B[k] <= self.limits.damping_max[k]:
                raise CommandError(
                    f"{axis} damping {B[k]:g} outside 0..{self.limits.damping_max[k]:g}"
                )
            if on[k] and K[k] == 0.0 and B[k] == 0.0:
                raise CommandError(f"{axis}: stiffness and damping cannot both be zero")
        s = self.state
        first = not np.any(s.compliant) and self.mode != Mode.TASK
        s.stiffness_target[:] = K
        s.damping_target[:] = B
        s.compliant[:] = on
        if first:
            # Nothing is being rendered yet: start at the requested values, no slew from 0.
            s.stiffness[:] = K
            s.damping[:] = B

    def hold(self) -> None:
        """Close every valve and hold; leaves FAULT untouched."""
        if self.mode != Mode.FAULT:
            self.state.istate[ctl.I_MODE] = Mode.IDLE
            self.state.valves[:] = 0

    def estop(self) -> None:
        ctl.trip(self.state, int(Trip.ESTOP))

    def rearm(self) -> None:
        """Clear a latched fault into IDLE; motion needs a new command."""
        s = self.state
        s.istate[ctl.I_TRIP] = 0
        s.istate[ctl.I_MODE] = Mode.IDLE
        s.integral[:] = 0.0
        s.slots[:] = 0


def leg_index(leg: int) -> int:
    """0-based index of a 1-based leg number, refusing anything but 1..6."""
    if isinstance(leg, bool) or not isinstance(leg, int) or not 1 <= leg <= 6:
        raise CommandError(f"leg must be 1..6, got {leg!r}")
    return leg - 1
