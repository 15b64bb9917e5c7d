"""The device service: the controller as a running process on the embedded PC.

One loop, one thread, in the style of a controller's background loop beside its interrupt:
each pass reads whatever the link has (never waiting), acts on the checked commands, checks
the watchdog, runs one chunk of interrupts (:data:`CHUNK_TICKS`, 1 ms), supervises the
mode machine and sends what is due. With the simulated plant the chunk runs in simulated
time and the loop sleeps until wall time has caught up, so simulated time never runs ahead
of the wall clock; how far it trails (the pacing lag) is measured every chunk.

Modes (:class:`~device.protocol.messages.DeviceMode`)::

    IDLE --arm/home--> HOMING --at home--> READY --segment--> ACTIVE --done--> READY
                                                       ACTIVE <--resume-- HOLD <--hold/watchdog--
    any --e-stop--> ESTOP;  a tripped limit --> FAULT;  ESTOP/FAULT --re-arm--> IDLE

The valves are closed (pressures held) in every mode but HOMING and ACTIVE, and nothing
moves again after a stop until the host asks for it. Every command is checked here against
the device's own limits and answered with ACK or NACK; the compiled controller checks again.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import os
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from types import FrameType
from typing import Any, TextIO

import numpy as np

from device import controller as ctl
from device import safety
from device.controller import Mode, Waveform
from device.geometry import AXES
from device.hardware import SimulatedHardware
from device.plant.params import TICK_HZ
from device.protocol import messages as msg
from device.protocol.framing import MAX_BODY, Frame, FrameDecoder
from device.protocol.messages import DeviceMode, EventKind, NackCode
from device.rig import AxisTarget, CommandError, Rig
from device.safety import Trip
from device.transport import Link

FIRMWARE = "ankle-device 0.1.0"
CHUNK_TICKS = 7
"""Interrupts per pass of the loop (1 ms): the granularity of command, watchdog and pacing."""
CONTROL_TICKS = ctl.CONTROL_PERIOD
"""One PWM/control period (28 ticks, 4 ms): a lag beyond it counts as an overrun."""
TELEMETRY_HZ_MAX = 250
WATCHDOG_MS_MIN, WATCHDOG_MS_MAX = 50, 2000
SEGMENT_DURATION_MAX = 3600.0
"""Longest segment (s)."""
HOMING_LEG_SPEED = 0.010
"""Piston speed while homing (m/s): 5 s across the whole stroke."""
HOMING_TOLERANCE = 0.4e-3
"""Every piston this close to mid-stroke counts as home (m)."""
HOMING_SETTLE = 0.2
"""...for this long (s)."""
HOMING_TIMEOUT_EXTRA = 5.0
"""Seconds allowed beyond the planned homing move before it is a fault."""
APPROACH_SPEED = (0.01, 0.01, 0.01, 0.2, 0.2, 0.2)
"""Speed of the moves into and out of a segment (m/s, rad/s): 0.2 rad/s is 11 deg/s."""
EVENTS_KEPT = 64
REPLIES_KEPT = 256
"""Replies remembered by sequence number: a repeated command is answered, not re-run."""
MAX_CATCH_UP = 1.0
"""Behind the wall clock by more than this (s, a stopped process), the clock is re-anchored."""


@dataclass(frozen=True)
class ServiceConfig:
    telemetry_hz: int = 100
    watchdog_ms: int = 200


class Refused(Exception):
    """A command the device will not run: becomes a NACK; nothing was changed."""

    def __init__(self, code: NackCode, text: str, field: str = "") -> None:
        super().__init__(text)
        self.code = code
        self.field = field


@dataclass
class Segment:
    command: msg.StartSegment
    phase: str = "approach"
    """approach (to the waveform's start), run (the exercise), return (to home)."""
    phase_end: float = 0.0
    """Device time the current approach/return move ends."""
    run_start: float = 0.0
    paused: float = 0.0
    """Time spent in HOLD since the run phase started (s)."""
    hold_start: float = 0.0


@dataclass
class PacingStats:
    lags_ms: collections.deque[float] = field(
        default_factory=lambda: collections.deque(maxlen=1 << 16)
    )
    overruns: int = 0
    """Episodes of falling more than one control period behind the wall clock."""
    steps: int = 0
    behind: bool = False


class DeviceService:
    """The controller, its link and its mode machine."""

    def __init__(
        self,
        rig: Rig,
        link: Link,
        config: ServiceConfig = ServiceConfig(),
        clock: Callable[[], float] = time.perf_counter,
        out: TextIO = sys.stderr,
    ) -> None:
        self.rig = rig
        self.link = link
        self.clock = clock
        self.out = out
        self.decoder = FrameDecoder()
        self.mode = DeviceMode.IDLE
        self.homed = False
        self.segment: Segment | None = None
        self.telemetry_hz_max = self._telemetry_hz_max()
        self.telemetry_hz = min(config.telemetry_hz, self.telemetry_hz_max)
        self.watchdog_ms = config.watchdog_ms
        self.commands_refused = 0
        self.pacing = PacingStats()
        self.events: collections.deque[msg.Event] = collections.deque(maxlen=EVENTS_KEPT)
        self._event_id = 0
        self._tx_seq = 0
        self._nonce: int | None = None
        self._replies: collections.OrderedDict[int, msg.Message] = collections.OrderedDict()
        self._last_rx = clock()
        self._next_telemetry = 0.0
        self._homing_start = 0.0
        self._homing_from = np.zeros(6)
        self._home_since: float | None = None
        self._limits = rig.params.limits.copy()
        """The device's own limits; a segment narrows the controller's copy for its run."""
        self._stop = False
        self.rig.advance(1)  # one sensor read so the first telemetry is real

    # -- time ----------------------------------------------------------------------------
    @property
    def time(self) -> float:
        return self.rig.time

    def _telemetry_hz_max(self) -> int:
        bps = self.link.bits_per_second
        if bps is None:
            return TELEMETRY_HZ_MAX
        frame = msg.Telemetry.size() + 12  # header, CRC, COBS overhead and delimiter
        return max(1, min(TELEMETRY_HZ_MAX, int(0.8 * bps / 10.0 / frame)))

    # -- the loop ------------------------------------------------------------------------
    def step(self) -> None:
        """One pass: link in, commands, watchdog, one chunk of interrupts, supervision, out."""
        self._receive()
        self._watchdog()
        self.rig.advance(CHUNK_TICKS)
        self._supervise()
        if self.time >= self._next_telemetry:
            self._next_telemetry = max(self._next_telemetry + 1.0 / self.telemetry_hz, self.time)
            self._send(self.telemetry(), droppable=True)
        self.link.flush()

    def run(self, seconds: float | None = None) -> None:
        """Paced to the wall clock until ``seconds`` of device time or :meth:`stop`."""
        wall0 = self.clock()
        sim0 = self.time
        end = None if seconds is None else sim0 + seconds
        while not self._stop and (end is None or self.time < end):
            # Never run a chunk whose end lies ahead of the wall clock.
            ahead = (self.time + CHUNK_TICKS / TICK_HZ - sim0) - (self.clock() - wall0)
            if ahead > 0:
                time.sleep(ahead)
            self.step()
            lag = (self.clock() - wall0) - (self.time - sim0)
            self.pacing.steps += 1
            self.pacing.lags_ms.append(lag * 1e3)
            behind = lag > CONTROL_TICKS / TICK_HZ
            if behind and not self.pacing.behind:
                self.pacing.overruns += 1  # one per episode, however many passes catch up
            self.pacing.behind = behind
            if lag > MAX_CATCH_UP:
                wall0 = self.clock() - (self.time - sim0)

    def stop(self) -> None:
        self._stop = True

    def shutdown(self) -> None:
        """Close the valves and the link."""
        if self.rig.mode not in (Mode.FAULT, Mode.IDLE):
            self.rig.hold()
        self.rig.state.istate[ctl.I_VENT] = 0
        self.rig.advance(CHUNK_TICKS)  # let the valve outputs follow
        self.rig.hardware.close()
        self.link.close()

    # -- link ----------------------------------------------------------------------------
    def _send(self, message: msg.Message, droppable: bool = False) -> None:
        frame = msg.encode(message, self._tx_seq)
        if self.link.send(frame, droppable):
            self._tx_seq = (self._tx_seq + 1) & 0xFFFF

    def _receive(self) -> None:
        for _ in range(4):  # bounded: a flood cannot starve the control chunk
            data = self.link.read()
            if not data:
                return
            for frame in self.decoder.feed(data):
                self._last_rx = self.clock()
                self._on_frame(frame.type, frame.seq, frame.body, frame.version)

    def _on_frame(self, mtype: int, seq: int, body: bytes, version: int) -> None:
        if version != self.decoder.version:  # a handshake from another protocol version
            self._send(self.hello())
            return
        try:
            command = msg.decode(Frame(mtype, seq, body), "host")
        except msg.MessageError as exc:
            self._reply(seq, mtype, Refused(exc.code, str(exc)))
            return
        if isinstance(command, msg.Hello):
            if command.nonce != self._nonce:
                self._nonce = command.nonce
                self._replies.clear()
            self._send(self.hello())
            return
        cached = self._replies.get(seq)
        if cached is not None and getattr(cached, "command", None) == mtype:
            self._send(cached)  # a repeat (lost ACK or duplicated frame): answer, do not re-run
            return
        try:
            self._execute(command)
        except Refused as exc:
            self._reply(seq, mtype, exc)
        except CommandError as exc:
            self._reply(seq, mtype, Refused(NackCode.OUT_OF_RANGE, str(exc)))
        else:
            self._reply(seq, mtype, None)

    def _reply(self, seq: int, mtype: int, refused: Refused | None) -> None:
        reply: msg.Message
        if refused is None:
            reply = msg.Ack(ack_seq=seq, command=mtype, mode=self.mode)
        else:
            self.commands_refused += 1
            reply = msg.Nack(
                ack_seq=seq,
                command=mtype,
                mode=self.mode,
                code=refused.code,
                field=refused.field,
                text=str(refused),
            )
        self._replies[seq] = reply
        while len(self._replies) > REPLIES_KEPT:
            self._replies.popitem(last=False)
        self._send(reply)

    # -- commands ------------------------------------------------------------------------
    def _execute(self, c: msg.Message) -> None:
        bad = msg.non_finite_field(c)
        if bad is not None:
            raise Refused(NackCode.NOT_FINITE, f"{bad} must be finite numbers", bad)
        if isinstance(c, msg.Heartbeat):
            return
        if isinstance(c, msg.Configure):
            self._configure(c)
        elif isinstance(c, msg.EStop):
            self._estop()
        elif isinstance(c, msg.ReplayEvents):
            for event in self.events:
                if event.event_id > c.after_id:
                    self._send(event)
        elif isinstance(c, msg.Rearm):
            self._require(DeviceMode.ESTOP, DeviceMode.FAULT, why="nothing to re-arm")
            self.rig.rearm()
            self._set_mode(DeviceMode.IDLE, "re-armed; home before moving")
        elif isinstance(c, msg.HoldCmd):
            self._hold(EventKind.MODE_CHANGE, "hold")
        elif isinstance(c, msg.Release):
            self._release()
        else:
            self._latched_check()
            if isinstance(c, msg.ArmHome):
                self._arm_home()
            elif isinstance(c, msg.StartSegment):
                self._start_segment(c)
            elif isinstance(c, msg.SetImpedance):
                self._set_impedance(c)
            elif isinstance(c, msg.Resume):
                self._resume()
            else:
                raise Refused(NackCode.UNKNOWN_COMMAND, f"{type(c).__name__} is not a command")

    def _latched_check(self) -> None:
        if self.mode in (DeviceMode.ESTOP, DeviceMode.FAULT):
            trip = Trip(int(self.rig.state.istate[ctl.I_TRIP]))
            raise Refused(NackCode.LATCHED, f"{self.mode.name} ({trip.name}) is latched: re-arm")

    def _require(self, *modes: DeviceMode, why: str = "") -> None:
        if self.mode not in modes:
            names = " or ".join(m.name for m in modes)
            text = f"not in {self.mode.name}: needs {names}"
            raise Refused(NackCode.WRONG_MODE, f"{text} ({why})" if why else text)

    def _configure(self, c: msg.Configure) -> None:
        if not 1 <= c.telemetry_hz <= self.telemetry_hz_max:
            raise Refused(
                NackCode.OUT_OF_RANGE,
                f"telemetry_hz {c.telemetry_hz} outside 1..{self.telemetry_hz_max}",
                "telemetry_hz",
            )
        if not WATCHDOG_MS_MIN <= c.watchdog_ms <= WATCHDOG_MS_MAX:
            raise Refused(
                NackCode.OUT_OF_RANGE,
                f"watchdog_ms {c.watchdog_ms} outside {WATCHDOG_MS_MIN}..{WATCHDOG_MS_MAX}",
                "watchdog_ms",
            )
        self.telemetry_hz = c.telemetry_hz
        self.watchdog_ms = c.watchdog_ms
        self._next_telemetry = self.time

    def _arm_home(self) -> None:
        self._require(DeviceMode.IDLE, DeviceMode.READY, DeviceMode.HOLD)
        self._end_segment()
        s = self.rig.state
        s.istate[ctl.I_VENT] = 0
        self._homing_start = self.time
        self._homing_from = s.leg_x.copy()
        self._home_since = None
        self.rig.move_legs(s.leg_x.copy())
        self.homed = False
        self._set_mode(DeviceMode.HOMING, "homing")

    def _start_segment(self, c: msg.StartSegment) -> None:
        self._require(DeviceMode.READY, DeviceMode.ACTIVE)
        targets = self._validate_segment(c)
        K = np.array(c.stiffness)
        B = np.array(c.damping)
        # Everything checked: from here on nothing refuses.
        self._end_segment()
        self.rig.set_impedance(K, B, c.compliant)
        seg = Segment(c)
        start = np.array([t.center for t in targets.values()])
        self._move_to(start, seg)
        self.segment = seg
        self._set_mode(DeviceMode.ACTIVE, f"segment {c.segment_id}")

    def _validate_segment(self, c: msg.StartSegment) -> dict[str, AxisTarget]:
        lim = _wire_limits(self.rig.limits)
        if c.segment_id == 0:
            raise Refused(
                NackCode.OUT_OF_RANGE, "segment_id 0 means none; use 1 or more", "segment_id"
            )
        if not 0.0 < c.duration <= SEGMENT_DURATION_MAX:
            raise Refused(
                NackCode.OUT_OF_RANGE,
                f"duration {c.duration:g} s outside (0, {SEGMENT_DURATION_MAX:g}]",
                "duration",
            )
        if not 0.0 < c.force_limit <= lim.force_limit:
            raise Refused(
                NackCode.OUT_OF_RANGE,
                f"force_limit {c.force_limit:g} N outside (0, {lim.force_limit:g}]",
                "force_limit",
            )
        if not 0.0 < c.torque_limit <= lim.torque_limit:
            raise Refused(
                NackCode.OUT_OF_RANGE,
                f"torque_limit {c.torque_limit:g} N m outside (0, {lim.torque_limit:g}]",
                "torque_limit",
            )
        targets: dict[str, AxisTarget] = {}
        for k, axis in enumerate(AXES):
            lo, hi = c.rom_low[k], c.rom_high[k]
            if not lim.rom_low[k] <= lo <= hi <= lim.rom_high[k]:
                raise Refused(
                    NackCode.OUT_OF_RANGE,
                    f"{axis} range {lo:.4g}..{hi:.4g} is not within the device's "
                    f"{lim.rom_low[k]:.4g}..{lim.rom_high[k]:.4g}",
                    "rom_low" if lo < lim.rom_low[k] or lo > hi else "rom_high",
                )
            kind = c.waveform[k]
            center = c.center[k]
            if kind == Waveform.SINE:
                amp, f = abs(c.amplitude[k]), c.frequency[k]
                extent, speed = (center - amp, center + amp), 2.0 * math.pi * f * amp
                if not 0.0 <= f <= 20.0:
                    raise Refused(
                        NackCode.OUT_OF_RANGE,
                        f"{axis} frequency {f:g} outside 0..20 Hz",
                        "frequency",
                    )
                target = AxisTarget(Waveform.SINE, center, c.amplitude[k], f)
            elif kind == Waveform.RAMP:
                end, rate = c.ramp_end[k], abs(c.ramp_rate[k])
                extent, speed = (min(center, end), max(center, end)), rate
                target = AxisTarget(Waveform.RAMP, center, rate, end)
            else:
                extent, speed = (center, center), 0.0
                target = AxisTarget(Waveform.HOLD, center)
            if extent[0] < lo or extent[1] > hi:
                raise Refused(
                    NackCode.OUT_OF_RANGE,
                    f"{axis} waveform spans {extent[0]:.4g}..{extent[1]:.4g}, outside the "
                    f"segment's range {lo:.4g}..{hi:.4g}",
                    "center",
                )
            if speed > lim.axis_speed_max[k]:
                raise Refused(
                    NackCode.OUT_OF_RANGE,
                    f"{axis} waveform peaks at {speed:.3g}/s, above {lim.axis_speed_max[k]:g}/s",
                    "frequency" if kind == Waveform.SINE else "ramp_rate",
                )
            targets[axis] = target
        self._check_impedance(c.stiffness, c.damping, c.compliant)
        return targets

    def _check_impedance(
        self, K: tuple[float, ...], B: tuple[float, ...], compliant: tuple[bool, ...]
    ) -> None:
        lim = _wire_limits(self.rig.limits)
        for k, axis in enumerate(AXES):
            if not 0.0 <= K[k] <= lim.stiffness_max[k]:
                raise Refused(
                    NackCode.OUT_OF_RANGE,
                    f"{axis} stiffness {K[k]:g} outside 0..{lim.stiffness_max[k]:g}",
                    "stiffness",
                )
            if not 0.0 <= B[k] <= lim.damping_max[k]:
                raise Refused(
                    NackCode.OUT_OF_RANGE,
                    f"{axis} damping {B[k]:g} outside 0..{lim.damping_max[k]:g}",
                    "damping",
                )
            if compliant[k] and K[k] == 0.0 and B[k] == 0.0:
                raise Refused(
                    NackCode.OUT_OF_RANGE,
                    f"{axis} is compliant: stiffness and damping cannot both be zero",
                    "stiffness",
                )

    def _set_impedance(self, c: msg.SetImpedance) -> None:
        self._require(DeviceMode.ACTIVE, DeviceMode.HOLD, why="no segment is loaded")
        assert self.segment is not None
        compliant = self.segment.command.compliant
        self._check_impedance(c.stiffness, c.damping, compliant)
        self.rig.set_impedance(np.array(c.stiffness), np.array(c.damping), compliant)

    def _resume(self) -> None:
        self._require(DeviceMode.HOLD)
        seg = self.segment
        assert seg is not None
        pause = self.time - seg.hold_start
        s = self.rig.state
        s.trajectory[:, 4] += pause  # the waveform continues where it paused
        seg.phase_end += pause
        if seg.phase == "run":
            seg.paused += pause
        s.istate[ctl.I_MODE] = Mode.TASK
        self._set_mode(DeviceMode.ACTIVE, "resumed")

    def _hold(self, kind: EventKind, why: str, value: float = 0.0) -> None:
        if self.mode == DeviceMode.ACTIVE:
            self.rig.hold()
            assert self.segment is not None
            self.segment.hold_start = self.time
            self._set_mode(DeviceMode.HOLD, why, kind=kind, value=value)
        elif self.mode == DeviceMode.HOMING:
            self.rig.hold()
            self._set_mode(DeviceMode.IDLE, f"{why}: homing stopped", kind=kind, value=value)

    def _estop(self) -> None:
        self.rig.estop()
        self.rig.state.istate[ctl.I_VENT] = 0
        self._end_segment()
        self.homed = False
        if self.mode != DeviceMode.ESTOP:
            self._set_mode(
                DeviceMode.ESTOP, "emergency stop", kind=EventKind.ESTOP, code=Trip.ESTOP
            )

    def _release(self) -> None:
        self._require(
            DeviceMode.IDLE,
            DeviceMode.READY,
            DeviceMode.HOLD,
            DeviceMode.ESTOP,
            DeviceMode.FAULT,
            why="hold first",
        )
        self.rig.state.istate[ctl.I_VENT] = 1
        self.homed = False
        if self.mode in (DeviceMode.READY, DeviceMode.HOLD):
            self._end_segment()
            self._set_mode(DeviceMode.IDLE, "releasing: the platform sinks; home before moving")

    # -- supervision ---------------------------------------------------------------------
    def _watchdog(self) -> None:
        if self.mode not in (DeviceMode.ACTIVE, DeviceMode.HOMING):
            return
        silent = self.clock() - self._last_rx
        if silent * 1e3 > self.watchdog_ms:
            self._hold(
                EventKind.WATCHDOG,
                f"no valid frame for {silent * 1e3:.0f} ms",
                value=silent * 1e3,
            )

    def _supervise(self) -> None:
        s = self.rig.state
        if self.rig.mode == Mode.FAULT and self.mode not in (DeviceMode.ESTOP, DeviceMode.FAULT):
            trip = Trip(int(s.istate[ctl.I_TRIP]))
            self._end_segment()
            self.homed = False
            kind = EventKind.FAULT if trip in _FAULTS else EventKind.LIMIT
            self._set_mode(DeviceMode.FAULT, f"trip: {trip.name}", kind=kind, code=trip)
            return
        if self.mode == DeviceMode.HOMING:
            self._homing_step()
        elif self.mode == DeviceMode.ACTIVE and self.segment is not None:
            self._segment_step(self.segment)

    def _homing_step(self) -> None:
        s = self.rig.state
        mid = 0.5 * self.rig.geometry.stroke
        elapsed = self.time - self._homing_start
        travel = HOMING_LEG_SPEED * elapsed
        for i in range(6):
            d = mid - self._homing_from[i]
            step = min(abs(d), travel)
            s.leg_target[i] = self._homing_from[i] + math.copysign(step, d)
            s.leg_target_rate[i] = 0.0 if step >= abs(d) else math.copysign(HOMING_LEG_SPEED, d)
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
                ctl.trip(s, int(Trip.HOMING))

    def _move_to(self, start: np.ndarray, seg: Segment) -> None:
        """Ramp every axis from where the command is now to ``start`` (relative to home)."""
        s = self.rig.state
        home = self.rig.geometry.home_pose
        now = s.pose_cmd - home - s.x_m if self.rig.mode == Mode.TASK else s.pose - home
        lim = self.rig.limits
        now = np.clip(now, lim.rom_low, lim.rom_high)
        targets = {}
        longest = 0.0
        for k, axis in enumerate(AXES):
            rate = APPROACH_SPEED[k]
            targets[axis] = AxisTarget(Waveform.RAMP, float(now[k]), rate, float(start[k]))
            longest = max(longest, abs(start[k] - now[k]) / rate)
        self.rig.track(targets)
        seg.phase_end = self.time + longest

    def _segment_step(self, seg: Segment) -> None:
        t = self.time
        c = seg.command
        if seg.phase == "approach" and t >= seg.phase_end:
            targets = {
                axis: AxisTarget(
                    Waveform(c.waveform[k]),
                    c.center[k],
                    abs(c.ramp_rate[k]) if c.waveform[k] == Waveform.RAMP else c.amplitude[k],
                    c.ramp_end[k] if c.waveform[k] == Waveform.RAMP else c.frequency[k],
                )
                for k, axis in enumerate(AXES)
            }
            self.rig.track(targets)
            self._narrow_limits(c)
            seg.phase = "run"
            seg.run_start = t
            seg.paused = 0.0
        elif seg.phase == "run" and t - seg.run_start - seg.paused >= c.duration:
            self._restore_limits()
            self._move_to(np.zeros(6), seg)
            seg.phase = "return"
        elif seg.phase == "return" and t >= seg.phase_end + 0.1:
            self.rig.hold()
            self.segment = None
            self._set_mode(
                DeviceMode.READY, f"segment {c.segment_id} done", kind=EventKind.SEGMENT_DONE
            )

    def _narrow_limits(self, c: msg.StartSegment) -> None:
        """The controller enforces the segment's range and wrench limits while it runs."""
        lim = self.rig.params.limits
        lim[safety.ROW_ROM_LOW] = c.rom_low
        lim[safety.ROW_ROM_HIGH] = c.rom_high
        lim[safety.ROW_SCALARS, 0] = c.force_limit
        lim[safety.ROW_SCALARS, 1] = c.torque_limit

    def _restore_limits(self) -> None:
        self.rig.params.limits[:] = self._limits

    def _end_segment(self) -> None:
        self._restore_limits()
        self.segment = None
        if self.rig.mode != Mode.TASK:
            # Nothing is rendered any more: the next segment's K and B start where it asks,
            # not slewed from this one's. (While running, a new segment slews as it must.)
            self.rig.state.compliant[:] = 0.0

    def _set_mode(
        self,
        mode: DeviceMode,
        text: str,
        kind: EventKind = EventKind.MODE_CHANGE,
        code: int = 0,
        value: float = 0.0,
    ) -> None:
        before, self.mode = self.mode, mode
        self._event_id += 1
        event = msg.Event(
            event_id=self._event_id,
            time=self.time,
            kind=kind,
            mode_from=before,
            mode_to=mode,
            code=int(code),
            value=value,
            text=text,
        )
        self.events.append(event)
        self._send(event)

    # -- outgoing ------------------------------------------------------------------------
    def telemetry(self) -> msg.Telemetry:
        s = self.rig.state
        home = self.rig.geometry.home_pose
        seg = self.segment
        flags = msg.TelemetryFlags.NONE
        if self.homed:
            flags |= msg.TelemetryFlags.HOMED
        if s.istate[ctl.I_VENT]:
            flags |= msg.TelemetryFlags.VENTING
        seg_time = 0.0
        if seg is not None:
            flags |= msg.TelemetryFlags.SEGMENT
            if seg.phase != "approach":
                now = seg.hold_start if self.mode == DeviceMode.HOLD else self.time
                seg_time = min(now - seg.run_start - seg.paused, seg.command.duration)
        lags = self.pacing.lags_ms
        return msg.Telemetry(
            time=self.time,
            mode=self.mode,
            trip=Trip(int(s.istate[ctl.I_TRIP])),
            flags=flags,
            segment_id=seg.command.segment_id if seg is not None else 0,
            segment_time=seg_time,
            pose=tuple((s.pose - home).tolist()),
            pose_cmd=tuple((s.pose_cmd - home).tolist()),
            legs=tuple(s.leg_x.tolist()),
            pressures=tuple(s.pressure.tolist()),
            supply=float(s.sensors[12] - self.rig.config.atmosphere),
            wrench=tuple((s.wrench - s.tare).tolist()),
            stiffness=tuple(s.stiffness.tolist()),
            damping=tuple(s.damping.tolist()),
            duty=tuple(s.slots.tolist()),
            frames_ok=self.decoder.stats.frames & 0xFFFFFFFF,
            frames_dropped=self.decoder.stats.dropped & 0xFFFFFFFF,
            commands_refused=self.commands_refused & 0xFFFFFFFF,
            overruns=self.pacing.overruns & 0xFFFFFFFF,
            pacing_lag_ms=lags[-1] if lags else 0.0,
            last_event_id=self._event_id,
        )

    def hello(self) -> msg.DeviceHello:
        lim = self.rig.limits
        g = self.rig.geometry
        hw = self.rig.hardware
        simulated = isinstance(hw, SimulatedHardware)
        caps = msg.Capability.TASK_SPACE | msg.Capability.IMPEDANCE | msg.Capability.RELEASE
        caps |= msg.Capability.EVENT_REPLAY
        if simulated:
            caps |= msg.Capability.SIMULATED
        return msg.DeviceHello(
            firmware=FIRMWARE,
            hardware="sim" if simulated else "board",
            capabilities=caps,
            tick_hz=TICK_HZ,
            pwm_hz=TICK_HZ // CONTROL_TICKS,
            telemetry_hz=self.telemetry_hz,
            telemetry_hz_max=self.telemetry_hz_max,
            watchdog_ms=self.watchdog_ms,
            watchdog_ms_min=WATCHDOG_MS_MIN,
            watchdog_ms_max=WATCHDOG_MS_MAX,
            stroke=g.stroke,
            min_length=g.min_length,
            home_pose=tuple(g.home_pose.tolist()),
            base_joints=tuple(g.base_joints.ravel().tolist()),
            platform_joints=tuple(g.platform_joints.ravel().tolist()),
            rom_low=lim.rom_low,
            rom_high=lim.rom_high,
            stiffness_max=lim.stiffness_max,
            damping_max=lim.damping_max,
            stiffness_slew=lim.stiffness_slew,
            damping_slew=lim.damping_slew,
            axis_speed_max=lim.axis_speed_max,
            force_limit=lim.force_limit,
            torque_limit=lim.torque_limit,
            leg_speed_limit=lim.leg_speed_limit,
            segment_duration_max=SEGMENT_DURATION_MAX,
        )


def _wire_limits(limits: safety.SafetyLimits) -> safety.SafetyLimits:
    """The limits as the host sees them in HELLO (float32), so a host that asks for exactly
    the device's limit is not refused by a rounding difference."""
    values: dict[str, Any] = {}
    for f in dataclasses.fields(limits):
        v = getattr(limits, f.name)
        values[f.name] = (
            tuple(float(np.float32(x)) for x in v) if isinstance(v, tuple) else float(np.float32(v))
        )
    return safety.SafetyLimits(**values)


_FAULTS = (Trip.SENSOR_INVALID, Trip.KINEMATICS, Trip.COMMAND_INVALID, Trip.HOMING)

assert msg.Telemetry.size() <= MAX_BODY


REALTIME_PRIORITY = 20
"""SCHED_FIFO priority of the service loop: above every ordinary process, below the kernel's
own interrupt threads (50)."""


def realtime_priority() -> str:
    """Ask the OS to schedule this process ahead of ordinary ones, as a controller must be.

    It needs CAP_SYS_NICE (root, or ``setcap cap_sys_nice+ep`` on the interpreter); without it
    the service still runs, and the pacing lag and overrun counters show what it costs.
    """
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(REALTIME_PRIORITY))
    except (OSError, AttributeError) as exc:
        return (
            f"ordinary scheduling ({exc.__class__.__name__}: real-time priority needs CAP_SYS_NICE)"
        )
    return f"real-time priority (SCHED_FIFO {REALTIME_PRIORITY})"


def serve(
    service: DeviceService, seconds: float | None = None, announce: TextIO = sys.stdout
) -> int:
    """Run until Ctrl-C or SIGTERM (or ``seconds``), then close the valves and the link."""

    def on_signal(signum: int, frame: FrameType | None) -> None:
        service.stop()

    previous = signal.signal(signal.SIGTERM, on_signal)
    scheduling = realtime_priority()
    print(
        f"ankle device: serving on {service.link.name} "
        f"(telemetry {service.telemetry_hz} Hz, watchdog {service.watchdog_ms} ms, "
        f"{scheduling})",
        file=announce,
        flush=True,
    )
    try:
        service.run(seconds)
    except KeyboardInterrupt:
        pass
    finally:
        service.shutdown()
        signal.signal(signal.SIGTERM, previous)
        print("ankle device: stopped; valves closed.", file=announce, flush=True)
    return 0
