"""The device's mode machine: homing, segment phases, hold and resume, e-stop, release, faults.

::

    IDLE --arm/home--> HOMING --at home--> READY --segment--> ACTIVE --done--> READY
                                                       ACTIVE <--resume-- HOLD <--hold/watchdog--
    any --e-stop--> ESTOP;  a tripped limit or a software error --> FAULT;
    ESTOP/FAULT --re-arm--> IDLE

It acts on commands that :mod:`device.commands` already checked, so it never refuses one;
it moves the controller only through the rig's methods; it reports every change through the
``on_event`` callback. The device service owns the loop, the link, the replies and the
telemetry around it. Valves are closed in every mode but HOMING and ACTIVE, and nothing
moves again after a stop until the host asks.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from device import ring
from device.axes import AXES
from device.commands import CheckedImpedance, CheckedSegment
from device.controller import Mode
from device.limits import APPROACH_SPEED
from device.protocol.messages import DeviceMode, EventKind
from device.rig import Rig
from device.trips import SUPPLY_BY_AIR, Trip, event_text, where
from device.waveforms import AxisTarget

HOMING_LEG_SPEED = 0.010
"""Piston speed while homing (m/s): 5 s across the whole stroke."""
HOMING_TOLERANCE = 0.4e-3
"""Every piston this close to mid-stroke counts as home (m)."""
HOMING_SETTLE = 0.2
"""...for this long (s)."""
HOMING_TIMEOUT_EXTRA = 5.0
"""Seconds allowed beyond the planned homing move before it is a fault."""
RETURN_SETTLE = 0.1
"""Time allowed after the move home before a segment counts as done (s)."""

FAULT_TRIPS = (
    Trip.SENSOR_INVALID,
    Trip.KINEMATICS,
    Trip.COMMAND_INVALID,
    Trip.HOMING,
    Trip.SOFTWARE,
    Trip.PRESSURE_SENSOR,
    Trip.SUPPLY_LOSS,
    Trip.SUPPLY_HIGH,
    Trip.LEG_SENSOR,
    Trip.FORCE_SENSOR,
    Trip.FORCE_BALANCE,
    Trip.VALVE,
    Trip.AIR_BALANCE,
    Trip.FOLLOWING,
)
"""Trips reported as FAULT events; the others are limits the motion reached (LIMIT)."""
_AT_REST = (DeviceMode.IDLE, DeviceMode.READY, DeviceMode.HOLD)
"""Modes in which a low supply is said without a hold (the valves are shut already; after a
stop the stop's own event is what a technician reads first)."""

EventSink = Callable[[EventKind, DeviceMode, DeviceMode, int, float, str], None]
"""``(kind, mode_from, mode_to, code, value, text)``."""


@dataclass
class Segment:
    plan: CheckedSegment
    phase: str = "approach"
    """approach (to the waveform's start), run (the exercise), return (to home)."""
    phase_end: float = 0.0
    """Device time the current approach/return move ends."""
    run_start: float = 0.0
    paused: float = 0.0
    """Time spent in HOLD since the run phase started (s)."""
    hold_start: float = 0.0
    moved_at: float = 0.0
    """Device time the approach began, later by its holds."""
    reach_low: NDArray[np.float64] = field(default_factory=lambda: np.zeros(6))
    reach_high: NDArray[np.float64] = field(default_factory=lambda: np.zeros(6))
    """Where the command stood as the approach began (relative to home): the lowest and the
    highest of its waveform's part and of the whole, the compliance's offset included."""


class ModeMachine:
    """Modes of one device, on one rig."""

    def __init__(self, rig: Rig, on_event: EventSink) -> None:
        self.rig = rig
        self.on_event = on_event
        self.mode = DeviceMode.IDLE
        self.homed = False
        self.segment: Segment | None = None
        self._service_reported = False
        self._supply_reported = False
        self._release_reported = False
        self._held: set[int] = set()
        """The chambers valves of their own hold after the stop (ctl.bleed) that are said."""
        self._rings = np.zeros(6)
        self._factors = np.ones(6)
        self._homing_start = 0.0
        self._homing_from = np.zeros(6)
        self._home_since: float | None = None

    @property
    def time(self) -> float:
        return self.rig.time

    @property
    def trip(self) -> Trip:
        return self.rig.trip

    # -- commands (checked) --------------------------------------------------------------
    def arm_home(self) -> None:
        self._end_segment()
        self.rig.set_vent(False)
        self.rig.forget_rings()  # a new exercise: what the last foot needed is not this one's
        s = self.rig.state
        self._homing_start = self.time
        self._homing_from = s.leg_x.copy()
        self._home_since = None
        self.rig.apply_leg_targets(s.leg_x.copy())
        self.homed = False
        self._set_mode(DeviceMode.HOMING, "homing")

    def start_segment(self, plan: CheckedSegment) -> None:
        """The segment's compliance from its start, and with it its range of motion: on the
        way to the waveform's start a foot pushing a compliant axis moves it, and a range
        that only narrowed as the run began found the platform past it (a foot pushing 10
        N m on pitch took it to 10.9 deg of a 3 deg range during a 0.87 s approach, and the
        run's first period tripped RANGE_OF_MOTION). The approach starts wherever the
        command is (home, or inside the last segment's range when one is started during
        another, the compliance's offset kept: a spring whose rest point jumped would throw
        the foot). So the range in force spans that start and the segment's range, and
        closes in on the latter at the approach speeds: a compliant axis outside it is
        brought in as gently as the approach moves, and the run begins inside it.

        An axis this segment leaves stiff loses its offset (the controller renders none on
        it from the next period), so its approach starts from the whole command, the offset
        folded into the ramp as at the end of a run: from the waveform's part alone, a
        pitch a foot held 13.3 deg out on K 20 was commanded to 0 in one period and
        tripped FOLLOWING 4 ms later. Both starts lie in ``reach_low..reach_high``."""
        self._end_segment()
        path, whole = self._commanded()
        self.rig.apply_impedance(plan.stiffness, plan.damping, plan.compliant)
        seg = Segment(plan, moved_at=self.time)
        seg.reach_low = np.minimum(path, whole)
        seg.reach_high = np.maximum(path, whole)
        start = np.where(np.asarray(plan.compliant, dtype=bool), path, whole)
        longest = self._move_to(start, np.array([t.center for t in plan.targets]))
        speed = np.asarray(APPROACH_SPEED)
        outside = np.maximum(
            np.asarray(plan.rom_low) - seg.reach_low, seg.reach_high - np.asarray(plan.rom_high)
        )
        closing = float(np.max(np.maximum(outside, 0.0) / speed))
        seg.phase_end = self.time + max(longest, closing)
        self._approach_range(seg)
        self.segment = seg
        self._set_mode(DeviceMode.ACTIVE, f"segment {plan.segment_id}")

    def set_impedance(self, c: CheckedImpedance) -> None:
        """Live K and B for the loaded segment; none once its run is over and it returns home
        (nothing is compliant on the way home)."""
        seg = self.segment
        if seg is not None and seg.phase == "return":
            return
        self.rig.apply_impedance(c.stiffness, c.damping, c.compliant)

    def resume(self) -> None:
        seg = self.segment
        if seg is None:  # checked: HOLD always has a segment; stay safe if not
            return
        pause = self.time - seg.hold_start
        self.rig.shift_trajectory(pause)  # the waveform continues where it paused
        seg.phase_end += pause
        seg.moved_at += pause
        if seg.phase == "run":
            seg.paused += pause
        self.rig.resume_task()
        self._set_mode(DeviceMode.ACTIVE, "resumed")

    def hold(
        self, kind: EventKind = EventKind.MODE_CHANGE, why: str = "hold", value: float = 0.0
    ) -> None:
        """ACTIVE -> HOLD, HOMING -> IDLE; anything else is left as it is."""
        if self.mode == DeviceMode.ACTIVE:
            self.rig.hold()
            if self.segment is not None:
                self.segment.hold_start = self.time
            self._set_mode(DeviceMode.HOLD, why, kind=kind, value=value)
        elif self.mode == DeviceMode.HOMING:
            self.rig.hold()
            self._set_mode(DeviceMode.IDLE, f"{why}: homing stopped", kind=kind, value=value)

    def estop(self) -> None:
        # The e-stop is the trip (none latched before it): ctl.bleed then holds a chamber
        # the air checks named from the next tick, which the event says.
        chamber = self.rig.service_chamber if self.rig.trip == Trip.NONE else -1
        if chamber >= 0:
            self._held = {chamber}  # this event says so
        self.rig.estop()
        self.rig.set_vent(False)
        self._end_segment()
        self.homed = False
        if self.mode != DeviceMode.ESTOP:
            text = "emergency stop"
            if chamber >= 0:
                part = where(Trip.AIR_BALANCE, chamber)
                text += (
                    f"; {part} held by its own valves (a leak, a stuck valve or its "
                    "transducer: service)"
                )
            self._set_mode(DeviceMode.ESTOP, text, kind=EventKind.ESTOP, code=Trip.ESTOP)

    def rearm(self) -> None:
        self.rig.rearm()
        self._held = set()
        if self.mode in (DeviceMode.ESTOP, DeviceMode.FAULT):
            self._set_mode(DeviceMode.IDLE, "re-armed; home before moving")

    def release(self) -> None:
        self.rig.set_vent(True)
        self.homed = False
        if self.mode in (DeviceMode.READY, DeviceMode.HOLD):
            self._end_segment()
            self._set_mode(DeviceMode.IDLE, "releasing: the platform sinks; home before moving")

    def fault(self, code: Trip, text: str) -> None:
        """Latch FAULT now (valves closed at the hardware too), e.g. on a software error."""
        self.rig.latch_trip(code)
        self.rig.close_valves_now()
        self._end_segment()
        self.homed = False
        if self.mode != DeviceMode.FAULT:
            self._set_mode(DeviceMode.FAULT, text, kind=EventKind.FAULT, code=code)

    def watchdog(self, silent_ms: float, limit_ms: float) -> None:
        if self.mode in (DeviceMode.ACTIVE, DeviceMode.HOMING) and silent_ms > limit_ms:
            self.hold(EventKind.WATCHDOG, f"no valid frame for {silent_ms:.0f} ms", silent_ms)

    # -- supervision, once per pass -------------------------------------------------------
    def step(self) -> None:
        if self.rig.mode == Mode.FAULT and self.mode not in (DeviceMode.ESTOP, DeviceMode.FAULT):
            trip = self.rig.trip
            self._end_segment()
            self.homed = False
            kind = EventKind.FAULT if trip in FAULT_TRIPS else EventKind.LIMIT
            text = event_text(trip, self.rig.trip_channel)
            if trip == Trip.VALVE:
                self._held = {self.rig.trip_channel}  # the trip's event names its chamber
            self._set_mode(DeviceMode.FAULT, text, kind=kind, code=trip)
            return
        self._report_release()
        self._report_held()
        chamber = self.rig.service_chamber
        if chamber >= 0 and not self._service_reported:
            self._service_reported = True
            part = where(Trip.AIR_BALANCE, chamber)
            self.on_event(
                EventKind.SERVICE,
                self.mode,
                self.mode,
                int(Trip.AIR_BALANCE),
                float(chamber),
                f"AIR_BALANCE on {part}: a leak, a stuck valve or its transducer; "
                f"{'homing' if self.mode == DeviceMode.HOMING else 'this segment'} ends under "
                "control, then its own valves hold it until serviced",
            )
        elif chamber < 0:
            self._service_reported = False
        self._report_rings()
        if self._supply_step():
            return
        if self.mode == DeviceMode.HOMING:
            self._homing_step()
        elif self.mode == DeviceMode.ACTIVE and self.segment is not None:
            self._segment_step(self.segment)

    def _supply_step(self) -> bool:
        """A low air supply holds what moves (ACTIVE -> HOLD, HOMING -> IDLE); at rest it is
        said once each time it falls, so that the station can tell the patient before an
        exercise is refused for it. Whether the pass stops here."""
        if not self.rig.supply_low:
            self._supply_reported = False
            return False
        supply = float(self.rig.state.sensors[12]) - self.rig.config.atmosphere
        if self.mode in (DeviceMode.ACTIVE, DeviceMode.HOMING):
            self._supply_reported = True
            self.hold(
                EventKind.SUPPLY_LOW,
                f"air supply low ({supply / 1e5:.1f} bar): held until it recovers",
                supply,
            )
            return True
        if not self._supply_reported and self.mode in _AT_REST:
            self._supply_reported = True
            self.on_event(
                EventKind.SUPPLY_LOW,
                self.mode,
                self.mode,
                0,
                supply,
                f"air supply low ({supply / 1e5:.1f} bar): nothing starts until it recovers; "
                "check the compressor and its hose",
            )
        return False

    def _report_release(self) -> None:
        """An event when the controller stopped a release (ctl.watch_release), once."""
        chamber, why = self.rig.release_stopped
        if chamber < 0 or self._release_reported:
            self._release_reported = chamber >= 0
            return
        self._release_reported = True
        why = {
            "gained": "its air rose (intake stuck open): "
            + (
                "exhaust and other side hold it"  # ctl.HOLD_BALANCE
                if self.rig.params.sup.release_balance
                else "its exhaust holds it"
            ),
            "kept": "it kept its air (exhaust stuck shut, tube blocked): held",
            "lost": "it emptied first (exhaust stuck open, leak): its intake holds it",
        }[why]
        self._valve_event(chamber, f"release stopped, {why}")

    def _valve_event(self, chamber: int, what: str) -> None:
        """A FAULT event (code VALVE) on ``chamber`` that leaves the mode as it is."""
        part = where(Trip.VALVE, chamber)
        self.on_event(
            EventKind.FAULT, self.mode, self.mode, int(Trip.VALVE), float(chamber),
            f"VALVE on {part}: {what}",
        )  # fmt: skip

    def _report_held(self) -> None:
        """An event, once per chamber, when after a trip or an e-stop the controller holds a
        chamber by a valve of its own (ctl.bleed; a second fault's chamber as well as the
        first's); not again for a chamber the stop's own event named. Each says why, and
        only what the controller saw: a chamber the air checks had named while the loop ran
        (its valves were driven then, not shut), or one whose air reading moved after the
        stop with every valve shut. Either is read through the chamber's transducer, so a
        transducer off by a little (under the jump rule) is named so too: the sentence
        lists it with the valve and the leak."""
        if self.mode not in (DeviceMode.ESTOP, DeviceMode.FAULT):
            return
        for chamber in self.rig.held_chambers:
            if chamber in self._held or chamber == self.rig.release_stopped[0]:
                continue
            self._held.add(chamber)
            why = (
                "its air did not add up with its valves while the loop ran"
                if chamber == self.rig.service_chamber
                else "its air reading moved with every valve shut"
            )
            self._valve_event(
                chamber,
                f"{why} (a stuck valve, a leak, or its transducer): {self._hold_text(chamber)}",
            )

    def _hold_text(self, chamber: int) -> str:
        """What holds a chamber ``_report_held`` names. With the supply lost (a SUPPLY_LOSS
        trip on the supply's transducer) no intake feeds (ctl.bleed): a chamber losing air
        goes on losing it, and only its exhaust still bleeds one that gains."""
        if self.rig.trip != Trip.SUPPLY_LOSS or self.rig.trip_channel == SUPPLY_BY_AIR:
            return "its own valves hold it"
        feeding = self.rig.held_feeding(chamber)
        if feeding is None:
            return "with the air supply lost only its exhaust holds it, if it gains air"
        if feeding:
            return "with the air supply lost nothing can hold it: it keeps losing air"
        return "its exhaust holds it"

    def _report_rings(self) -> None:
        """An event for each ring the guard damped since the last pass (device.ring)."""
        state = self.rig.state
        for axis in range(6):
            rings = float(state.ring[axis, ring.G_RINGS])
            factor = float(state.ring[axis, ring.G_FACTOR])
            if rings > self._rings[axis]:
                hz = float(state.ring[axis, ring.G_HZ])
                # The law's damping from the next period on: its kept map still has the last.
                law = float(state.impedance_map[axis, 2]) * factor / self._factors[axis]
                self.on_event(
                    EventKind.DAMPING_RAISED,
                    self.mode,
                    self.mode,
                    axis,
                    factor,
                    f"{AXES[axis]} rang at {hz:.0f} Hz with the foot on it: damping raised "
                    f"{factor:.2f} times (law {law:.2f}) until its K or B changes",
                )
            self._rings[axis] = rings
            self._factors[axis] = factor

    def segment_time(self) -> float:
        """Time into the running segment, pauses excluded (0 before its run starts)."""
        seg = self.segment
        if seg is None or seg.phase == "approach":
            return 0.0
        now = seg.hold_start if self.mode == DeviceMode.HOLD else self.time
        return min(now - seg.run_start - seg.paused, seg.plan.duration)

    def _homing_step(self) -> None:
        s = self.rig.state
        mid = 0.5 * self.rig.geometry.stroke
        elapsed = self.time - self._homing_start
        travel = HOMING_LEG_SPEED * elapsed
        target = np.empty(6)
        rate = np.empty(6)
        for i in range(6):
            d = mid - self._homing_from[i]
            step = min(abs(d), travel)
            target[i] = self._homing_from[i] + math.copysign(step, d)
            rate[i] = 0.0 if step >= abs(d) else math.copysign(HOMING_LEG_SPEED, d)
        self.rig.apply_leg_targets(target, rate)
        planned = float(np.max(np.abs(mid - self._homing_from))) / HOMING_LEG_SPEED
        if np.all(np.abs(s.leg_x - mid) < HOMING_TOLERANCE) and elapsed >= planned:
            if self._home_since is None:
                self._home_since = self.time
            elif self.time - self._home_since >= HOMING_SETTLE:
                self.rig.hold()
                self.homed = True
                self._set_mode(DeviceMode.READY, "at home", kind=EventKind.HOMED)
        else:
            self._home_since = None
            if elapsed > planned + HOMING_TIMEOUT_EXTRA:
                self.rig.latch_trip(Trip.HOMING)

    def _commanded(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Where the command stands now, relative to home and clipped into the device's
        range: its waveform's part and the whole, the compliance's offset included (both the
        measured pose when no task runs)."""
        s = self.rig.state
        lim = self.rig.limits
        home = self.rig.geometry.home_pose
        if self.rig.mode == Mode.TASK:
            whole = s.pose_cmd - home
            path = whole - s.x_m
        else:
            whole = path = s.pose - home
        return np.clip(path, lim.rom_low, lim.rom_high), np.clip(whole, lim.rom_low, lim.rom_high)

    def _move_to(self, now: NDArray[np.float64], start: NDArray[np.float64]) -> float:
        """Ramp every axis from ``now`` to ``start`` (relative to home); how long it takes (s).

        Built valid: both lie inside the device's range and the ramps run at the approach
        speeds, below every axis speed limit.
        """
        longest = 0.0
        targets = []
        for k in range(6):
            rate = APPROACH_SPEED[k]
            targets.append(AxisTarget.ramp(float(now[k]), float(start[k]), rate))
            longest = max(longest, abs(float(start[k]) - float(now[k])) / rate)
        self.rig.apply_track(targets)
        return longest

    def _approach_range(self, seg: Segment) -> None:
        """The range in force during the approach: from where the command stood as it began
        to the segment's range, closing in on the latter at the approach speeds. It always
        holds the approach's ramp (which moves at those speeds towards a start inside the
        segment's range), and is the segment's own range by the approach's end."""
        plan = seg.plan
        travel = np.asarray(APPROACH_SPEED) * max(self.time - seg.moved_at, 0.0)
        low = np.minimum(np.asarray(plan.rom_low), seg.reach_low + travel)
        high = np.maximum(np.asarray(plan.rom_high), seg.reach_high - travel)
        self.rig.narrow_range(low, high)

    def _segment_step(self, seg: Segment) -> None:
        t = self.time
        plan = seg.plan
        if seg.phase == "approach" and t >= seg.phase_end:
            self.rig.apply_track(plan.targets)
            self.rig.narrow_limits(plan.rom_low, plan.rom_high, plan.force_limit, plan.torque_limit)
            seg.phase = "run"
            seg.run_start = t
            seg.paused = 0.0
        elif seg.phase == "approach":
            self._approach_range(seg)
        elif seg.phase == "run" and t - seg.run_start - seg.paused >= plan.duration:
            # Home from where the command is, its compliant offset included, held as it
            # stands and brought back at the approach speeds; the device's limits again once
            # nothing is compliant. The range lifted while the axis was still compliant let
            # a foot pushing 15 N m against a 3 deg range throw pitch to 8.7 deg in 30 ms
            # (LEG_SPEED), and the return, from the waveform's part alone, left the offset
            # where it was.
            _, whole = self._commanded()
            self.rig.release_impedance()
            self.rig.restore_limits()
            seg.phase_end = t + self._move_to(whole, np.zeros(6))
            seg.phase = "return"
        elif seg.phase == "return" and t >= seg.phase_end + RETURN_SETTLE:
            self.rig.hold()
            self.segment = None
            self._set_mode(
                DeviceMode.READY, f"segment {plan.segment_id} done", kind=EventKind.SEGMENT_DONE
            )

    def _end_segment(self) -> None:
        self.rig.restore_limits()
        self.segment = None
        if self.rig.mode != Mode.TASK:
            # Nothing is rendered any more: the next segment's K and B start where it asks,
            # not slewed from this one's. (While running, a new segment slews as it must.)
            self.rig.release_impedance()

    def _set_mode(
        self,
        mode: DeviceMode,
        text: str,
        kind: EventKind = EventKind.MODE_CHANGE,
        code: int = 0,
        value: float = 0.0,
    ) -> None:
        before, self.mode = self.mode, mode
        self.on_event(kind, before, mode, int(code), value, text)
