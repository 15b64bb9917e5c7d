"""A controller on its hardware: the Python face of the device.

The only code that writes the controller's state. Its public commands (``move_legs``,
``track``, ``set_impedance``) check their arguments with :mod:`device.commands`, the same
checks the device service answers its host with, and raise :class:`CommandError` leaving
the controller untouched. The ``apply_*`` methods and the mode helpers take values that were
already checked (or that the mode machine built to be valid) and never refuse. The compiled
controller still enforces its limits on the measured motion (``device.safety``).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from device import commands, ring, safety, supervision, tickloop
from device import controller as ctl
from device.axes import AXES
from device.commands import CommandError as CommandError
from device.controller import ControllerConfig, Mode
from device.geometry import DEFAULT_GEOMETRY, Geometry
from device.hardware import Hardware, SimulatedHardware
from device.plant.params import TICK_HZ, PlantConfig
from device.safety import SafetyLimits, Trip
from device.waveforms import AxisTarget as AxisTarget
from device.waveforms import Waveform

Vector = Sequence[float] | NDArray[np.float64]
"""Six numbers, one per leg or axis."""


_NO_LOG = np.zeros((0, tickloop.N_LOG))


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
        self.limits = limits.published()
        """The device's own limits, exactly as ``DeviceHello`` publishes them."""
        self.config = config
        self.params, self.schedule = ctl.build_params(config, geometry, self.limits)
        self._limits = self.params.limits.copy()
        self.state = ctl.new_state(geometry)
        self._log: list[NDArray[np.float64]] = []
        self._hardware_loop: tickloop.HardwareLoop | None = None
        self.tripped_at: float | None = None
        """When the latched trip struck (s, the log's simulated clock): the first logged row
        that shows it, in a run that began untripped; None if none, or not logged then."""

    def _on_hardware(self) -> tickloop.HardwareLoop:
        """The Python loop for hardware that is not the simulation, resolved once."""
        if self._hardware_loop is None:
            self._hardware_loop = tickloop.HardwareLoop(self.state, self.params)
        return self._hardware_loop

    # -- running -------------------------------------------------------------------------
    @property
    def time(self) -> float:
        """Controller time (s): ticks since start / 7000."""
        return int(self.state.istate[ctl.I_TICK]) / TICK_HZ

    def run(self, seconds: float, log_hz: float = 1000.0) -> NDArray[np.float64]:
        """Advance by ``seconds``; returns the log rows taken (also kept in :attr:`log`)."""
        n = round(seconds * TICK_HZ)
        untripped = self.trip == Trip.NONE
        decimation = max(1, round(TICK_HZ / log_hz)) if log_hz > 0 else 0
        rows = np.zeros((n // decimation + 1 if decimation else 0, tickloop.N_LOG))
        if isinstance(self.hardware, SimulatedHardware):
            hw = self.hardware
            k = tickloop.run_sim(self.state, self.params, hw.state, hw.params, n, decimation, rows)
            rows = rows[:k]
        else:
            self._on_hardware().run(self.hardware, n)
            rows = rows[:0]
        self._log.append(rows)
        if untripped and rows.shape[0]:
            hit = np.flatnonzero(rows[:, tickloop.COL["trip"]])
            if hit.size:
                self.tripped_at = float(rows[hit[0], tickloop.COL["t"]])
        return rows

    def compile(self) -> None:
        """Load, or compile, every compiled function this rig's loop and mode changes call,
        on scratch copies of the state: nothing compiles later, inside the loop.

        Numba compiles each at its first call. Where that call was in a pass of the
        service, the loop (telemetry, watchdog and all) stood still while it compiled:
        under a second from a warm cache, tens of seconds where other processes had just
        rewritten the cache (a test run's parallel workers)."""
        s = copy.deepcopy(self.state)
        supervision.reset_motion(s.monitor, s.counters)
        g = self.geometry
        safety.outside_at_start(s.sensors[13:19], s.pose, g.home_pose, g.stroke, self.params.limits)
        supervision.disarm_following(s.counters)
        supervision.settle_side(s.counters)
        ctl.halt(s)
        ctl.trip(s, int(Trip.NONE))
        if isinstance(self.hardware, SimulatedHardware):
            hw = self.hardware
            plant = copy.deepcopy(hw.state)
            tickloop.run_sim(s, self.params, plant, hw.params, 0, 0, _NO_LOG)
        else:  # the hardware loop is Python: what it calls, resolved without running
            self._on_hardware()

    def advance(self, ticks: int) -> None:
        """Advance ``ticks`` interrupts without logging (the device service's pacing step)."""
        if isinstance(self.hardware, SimulatedHardware):
            hw = self.hardware
            tickloop.run_sim(self.state, self.params, hw.state, hw.params, ticks, 0, _NO_LOG)
        else:
            self._on_hardware().run(self.hardware, ticks)

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

    # -- checked commands (experiments and tools) ----------------------------------------
    def _check_not_tripped(self) -> None:
        if self.mode == Mode.FAULT:
            raise CommandError(f"the device is tripped ({self.trip.name}); re-arm first")

    def move_legs(self, displacement: Vector) -> None:
        """Independent joint control: hold each piston at ``displacement`` (m, 0..stroke)."""
        x = commands.check_leg_targets(displacement, self.geometry, self.limits)
        self._check_not_tripped()
        self.apply_leg_targets(x)

    def track(self, targets: Mapping[str, AxisTarget]) -> None:
        """Task-space exercise: each named axis follows its waveform, the others hold home."""
        unknown = set(targets) - set(AXES)
        if unknown:
            raise CommandError(f"unknown axis {sorted(unknown)}; axes are {', '.join(AXES)}")
        six = [targets.get(axis, AxisTarget()) for axis in AXES]
        lim = self.limits
        commands.check_targets(six, lim.rom_low, lim.rom_high, lim, self.geometry)
        self._check_not_tripped()
        self.apply_track(six)

    def set_impedance(
        self,
        stiffness: Vector,
        damping: Vector,
        compliant: Sequence[bool] | None = None,
    ) -> None:
        """K and B per axis (N/m, N m/rad; N s/m, N m s/rad); slewed by the device. The
        compliant axes are the rotations unless named (only those may be:
        :data:`device.commands.COMPLIANT_AXES`)."""
        on = commands.COMPLIANT_AXES if compliant is None else tuple(bool(c) for c in compliant)
        commands.check_impedance(stiffness, damping, on, self.limits)
        self.apply_impedance(stiffness, damping, on)

    # -- applying checked values (never refuses) -----------------------------------------
    def _start_motion(self, joint: bool) -> None:
        s = self.state
        if self.mode == Mode.IDLE:
            supervision.reset_motion(s.monitor, s.counters)
            s.istate[ctl.I_OUTSIDE] = (
                safety.outside_at_start(
                    s.sensors[13:19],
                    s.pose,
                    self.geometry.home_pose,
                    self.geometry.stroke,
                    self.params.limits,
                )
                if joint
                else 0
            )
            s.integral[:] = 0.0
            s.x_m[:] = 0.0
            s.v_m[:] = 0.0
            s.catch_up[:] = 0.0
            s.v_low[:] = 0.0
            s.leg_target[:] = s.leg_x
            s.leg_target_rate[:] = 0.0

    def apply_leg_targets(self, x: Vector, rate: Vector | None = None) -> None:
        """Joint mode at piston targets ``x`` (m) moving at ``rate`` (m/s); no-op if tripped."""
        if self.mode == Mode.FAULT:
            return
        self._start_motion(joint=True)
        s = self.state
        bound = self.params.sup.following_translation
        if self.mode != Mode.JOINT or np.max(np.abs(np.asarray(x) - s.leg_x)) > bound:
            # A step the legs must first travel (an experiment's), or joint mode starting:
            # the following check waits until they have arrived.
            supervision.disarm_following(s.counters)
        s.leg_target[:] = x
        s.leg_target_rate[:] = 0.0 if rate is None else rate
        s.istate[ctl.I_MODE] = Mode.JOINT

    def apply_track(self, targets: Sequence[AxisTarget]) -> None:
        """Task mode on six checked waveforms (relative to home); no-op if tripped."""
        if self.mode == Mode.FAULT:
            return
        traj = np.zeros((6, 5))
        t0 = self.time
        home = self.geometry.home_pose
        for k, tgt in enumerate(targets):
            ramp = tgt.kind == Waveform.RAMP
            traj[k] = (
                int(tgt.kind),
                home[k] + tgt.center,
                tgt.amplitude,
                home[k] + tgt.frequency if ramp else tgt.frequency,
                t0,
            )
        self._start_motion(joint=False)
        supervision.settle_side(self.state.counters)
        self.state.istate[ctl.I_OUTSIDE] = 0  # an exercise is judged whole, from any mode
        self.state.trajectory[:] = traj
        if self.mode != Mode.TASK:
            # A new exercise starts from the foot's resting wrench (its weight, the shank's
            # preload) whether the platform was idle or holding legs: only what the patient
            # adds beyond that drives the impedance.
            self.state.tare[:] = self.state.wrench
            self.state.x_m[:] = 0.0
            self.state.v_m[:] = 0.0
            self.state.catch_up[:] = 0.0
            self.state.v_low[:] = 0.0
            supervision.disarm_following(self.state.counters)
        self.state.istate[ctl.I_MODE] = Mode.TASK

    def apply_impedance(
        self, stiffness: Vector, damping: Vector, compliant: Sequence[bool]
    ) -> None:
        """K and B per axis, slewed by the device from what it renders; an axis that starts
        rendering starts at its own (there is nothing to slew from). The same values again
        change nothing.

        No check waits for a change: unlike a new target, K and B slew, and what they move
        is the foot's to move. Measured with the moment, sideways and vertical cross-checks
        judging throughout, K and B stepped to either end of their ranges on a compliant
        pitch or roll under a relaxed and a resisting foot (the nominal unit and drawn builds
        1, 15, 18, 19, 27 and 47): at most 0.33, 0.44 and 0.27 of their limits in the 0.5 s
        after, against 0.32, 0.48 and 0.24 with no change. When each change held them off
        for 40 ms (``supervision.settle_side``), a 3 N m offset on the pitch torque landing
        with one was named in 46-56 ms instead of 20 and turned the platform 2.4-3.0 deg,
        and a host that re-sent its K and B every 30 ms kept them off for good.

        An axis that starts rendering while the foot pushes it meets the whole push at once
        (its offset starts at 0): a pitch held stiff against 8 N m, made compliant at K 20 by
        the next segment, was commanded at 4.1 rad/s. It catches up with the foot at the
        approach speed instead (``ControllerState.catch_up``; a new exercise, which tares
        the foot's wrench, clears it)."""
        s = self.state
        K = np.asarray(stiffness, dtype=np.float64)
        B = np.asarray(damping, dtype=np.float64)
        on = np.asarray(compliant, dtype=np.float64)
        if (
            np.array_equal(K, s.stiffness_target)
            and np.array_equal(B, s.damping_target)
            and np.array_equal(on, s.compliant)
        ):
            return
        starting = s.compliant <= 0.5
        s.stiffness_target[:] = K
        s.damping_target[:] = B
        s.compliant[:] = on
        s.stiffness[starting] = K[starting]
        s.damping[starting] = B[starting]
        s.catch_up[starting & (on > 0.5)] = 1.0

    def release_impedance(self) -> None:
        """Render nothing: the next segment's K and B start where it asks, not slewed."""
        self.state.compliant[:] = 0.0

    def shift_trajectory(self, seconds: float) -> None:
        """Delay every waveform by ``seconds`` (a resumed segment continues where it paused)."""
        self.state.trajectory[:, 4] += seconds

    def resume_task(self) -> None:
        """Back to task mode on the loaded waveforms, from a hold; no-op if tripped.

        The compliance stood still through the hold while the foot did not (its push
        kept changing, often reversing): each compliant axis catches up with it at no
        more than the approach speed (``ControllerState.catch_up``), not at once. Taring
        again instead would move the foot's neutral."""
        if self.mode != Mode.FAULT:
            supervision.disarm_following(self.state.counters)
            supervision.settle_side(self.state.counters)
            s = self.state
            s.catch_up[:] = np.where(s.compliant > 0.5, 1.0, 0.0)
            s.istate[ctl.I_MODE] = Mode.TASK

    def set_vent(self, on: bool) -> None:
        """Release: vent the chambers slowly while idle or tripped (see device.controller).
        A new release forgets what stopped the last (``release_stopped``)."""
        if on and not self.venting:
            self.state.istate[ctl.I_RELEASE_STOP] = 0
        self.state.istate[ctl.I_VENT] = 1 if on else 0

    @property
    def release_stopped(self) -> tuple[int, str]:
        """(chamber, why) that stopped the last release (ctl.watch_release): why is
        "gained" (its air rose: an intake stuck open), "kept" (it kept its air: its exhaust
        stuck shut) or "lost" (it emptied ahead of the others: its exhaust stuck open or a
        leak); (-1, "") if none did."""
        code = int(self.state.istate[ctl.I_RELEASE_STOP])
        if code == 0:
            return -1, ""
        return (code - 1) % 12, ("gained", "kept", "lost")[(code - 1) // 12]

    @property
    def held_chamber(self) -> int:
        """The chamber a valve of its own holds after a trip or an e-stop (ctl.bleed: its air
        moved with every valve shut, or the air checks had named it), -1 if none."""
        c = int(self.state.istate[ctl.I_BLEED])
        if c < 0:
            return -1
        for base in (ctl.HOLD_BOTH, ctl.HOLD_BALANCE, ctl.HOLD_FEED):
            if c >= base:
                return c - base
        return c

    @property
    def held_chambers(self) -> list[int]:
        """Every chamber a valve of its own holds after a trip or an e-stop (ctl.bleed):
        ``held_chamber`` first, then any found after it, in chamber order."""
        first = self.held_chamber
        more = int(self.state.istate[ctl.I_HELD_MORE])
        found = [c for c in range(12) if c != first and (more >> c | more >> (12 + c)) & 1]
        return ([first] if first >= 0 else []) + found

    def held_feeding(self, chamber: int) -> bool | None:
        """How ``chamber`` of ``held_chambers`` is held (ctl.bleed): True fed by its intake
        (its air was lost), False bled by its exhaust (gained), None either as it moves (the
        chamber the air checks named while the loop ran, ``HOLD_BOTH``)."""
        c = int(self.state.istate[ctl.I_BLEED])
        if c >= 0 and self.held_chamber == chamber:
            if c >= ctl.HOLD_BOTH:
                return None
            return ctl.HOLD_FEED <= c < ctl.HOLD_BALANCE
        return bool((int(self.state.istate[ctl.I_HELD_MORE]) >> (12 + chamber)) & 1)

    @property
    def venting(self) -> bool:
        return bool(self.state.istate[ctl.I_VENT])

    def narrow_limits(
        self,
        rom_low: Sequence[float],
        rom_high: Sequence[float],
        force_limit: float,
        torque_limit: float,
    ) -> None:
        """The controller enforces a segment's (checked, narrower) range and wrench limits."""
        lim = self.params.limits
        lim[safety.ROW_ROM_LOW] = rom_low
        lim[safety.ROW_ROM_HIGH] = rom_high
        lim[safety.ROW_SCALARS, 0] = force_limit
        lim[safety.ROW_SCALARS, 1] = torque_limit

    def narrow_range(self, low: Vector, high: Vector) -> None:
        """The controller enforces ``low..high`` (relative to home, within the device's own)
        as the range of motion, its wrench limits as they are."""
        lim = self.params.limits
        lim[safety.ROW_ROM_LOW] = low
        lim[safety.ROW_ROM_HIGH] = high

    def restore_limits(self) -> None:
        """The device's own limits again."""
        self.params.limits[:] = self._limits

    def hold(self) -> None:
        """Close every valve and hold, every leg at rest now (``ctl.halt``); leaves FAULT
        untouched."""
        ctl.halt(self.state)

    def forget_rings(self) -> None:
        """A new exercise: the ring guard's factors (device.ring) start again at 1."""
        self.state.ring[:] = ring.new_ring()

    def latch_trip(self, code: Trip) -> None:
        """Latch a fault now: valves close, nothing moves until a re-arm."""
        ctl.trip(self.state, int(code))

    def estop(self) -> None:
        self.latch_trip(Trip.ESTOP)

    def close_valves_now(self) -> None:
        """De-energise every coil at the hardware at once (the safe state), whatever the loop
        does next: for when the loop itself failed."""
        self.state.valves[:] = 0
        self.hardware.write_valves(self.state.valves)

    @property
    def trip_channel(self) -> int:
        """The sensor, chamber or leg the latched trip names, -1 if none."""
        return int(self.state.istate[ctl.I_TRIP_CHANNEL])

    @property
    def service_chamber(self) -> int:
        """The chamber whose air did not add up with its valves (-1: none): needs service."""
        return int(self.state.counters[supervision.C_SERVICE]) - 1

    @property
    def supply_low(self) -> bool:
        """The air supply is below its low mark: hold, and start nothing, until it recovers."""
        return bool(self.state.counters[supervision.C_LOW_FLAG])

    def rearm(self) -> None:
        """Clear a latched fault into IDLE; motion needs a new command."""
        s = self.state
        s.istate[ctl.I_TRIP] = 0
        s.istate[ctl.I_TRIP_CHANNEL] = -1
        self.tripped_at = None
        s.istate[ctl.I_BLEED] = -1
        s.istate[ctl.I_HELD_MORE] = 0
        s.istate[ctl.I_BAD_SENSORS] = 0
        s.istate[ctl.I_RELEASE_STOP] = 0
        s.trip_air[:] = np.nan
        s.counters[supervision.C_SERVICE] = 0
        s.counters[supervision.C_SERVICE_LEGS] = 0
        s.istate[ctl.I_MODE] = Mode.IDLE
        s.integral[:] = 0.0
        s.slots[:] = 0


def leg_index(leg: int) -> int:
    """0-based index of a 1-based leg number, refusing anything but 1..6."""
    if isinstance(leg, bool) or not isinstance(leg, int) or not 1 <= leg <= 6:
        raise CommandError(f"leg must be 1..6, got {leg!r}")
    return leg - 1
