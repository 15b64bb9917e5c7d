"""The device service: the controller as a running process on the embedded PC.

One loop, one thread, in the style of a controller's background loop beside its interrupt:
each pass reads whatever the link has (never waiting), checks and applies the commands,
checks the watchdog, runs one chunk of interrupts (:data:`CHUNK_TICKS`, 1 ms), supervises
the modes and sends what is due. With the simulated plant the chunk runs in simulated time
and the loop sleeps until wall time has caught up, so simulated time never runs ahead of the
wall clock; how far it trails (the pacing lag) is measured every chunk.

Each command is checked once, by :mod:`device.commands`, against exactly the limits the
device publishes in ``DeviceHello``, and answered ACK or NACK; the mode machine
(:mod:`device.modes`) then applies it and never refuses it later. Nothing that happens inside
a pass ends the service: an exception in any stage latches FAULT (trip ``SOFTWARE``, every
valve closed, an event naming the stage and the error) and the loop goes on answering
commands and sending telemetry.
"""

from __future__ import annotations

import collections
import os
import signal
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from types import FrameType
from typing import TextIO

from device import commands
from device import controller as ctl
from device.calibration import Calibration
from device.commands import (
    SEGMENT_DURATION_MAX,
    WATCHDOG_MS_MAX,
    WATCHDOG_MS_MIN,
    CheckedImpedance,
    CheckedSegment,
    CommandError,
)
from device.hardware import SimulatedHardware
from device.modes import ModeMachine
from device.plant.params import TICK_HZ
from device.protocol import messages as msg
from device.protocol.framing import MAX_BODY, Frame, FrameDecoder
from device.protocol.messages import DeviceMode, EventKind, NackCode
from device.rig import Rig
from device.transport import Link
from device.trips import Trip

FIRMWARE = "ankle-device 0.2.0"
CHUNK_TICKS = 7
"""Interrupts per pass of the loop (1 ms): the granularity of command, watchdog and pacing."""
CONTROL_TICKS = ctl.CONTROL_PERIOD
"""One PWM/control period (28 ticks, 4 ms): a lag beyond it counts as an overrun."""
TELEMETRY_HZ_MAX = 250
EVENTS_KEPT = 64
REPLIES_KEPT = 256
"""Replies remembered by sequence number: a repeated command is answered, not re-run."""
MAX_CATCH_UP = 1.0
"""Behind the wall clock by more than this (s, a stopped process), the clock is re-anchored:
the time lost is skipped, and counted (``Telemetry.clock_resets``)."""
FRAMES_PER_PASS = 4
"""Most frames acted on (each answered) per pass: a host sending frames back to back takes
a small, bounded share of a pass, never the control chunk's time. Far above what a station
sends (tens of frames a second); the rest wait for the next passes."""
READ_PER_PASS = 256
"""Most bytes read per pass from a link with no line rate (TCP, a pty): some 20 short frames,
a quarter of the largest (a segment arrives in a few passes). What is not read stays in the
host's socket and slows a flooding host down, as a serial line's rate would."""

__all__ = [
    "SEGMENT_DURATION_MAX",
    "WATCHDOG_MS_MAX",
    "WATCHDOG_MS_MIN",
    "DeviceService",
    "ServiceConfig",
    "serve",
]


@dataclass(frozen=True)
class ServiceConfig:
    telemetry_hz: int = 100
    watchdog_ms: int = 200


@dataclass
class PacingStats:
    lags_ms: collections.deque[float] = field(
        default_factory=lambda: collections.deque(maxlen=1 << 16)
    )
    overruns: int = 0
    """Episodes of falling more than one control period behind the wall clock."""
    clock_resets: int = 0
    """Passes that found the loop over :data:`MAX_CATCH_UP` behind and skipped the time lost
    (each also ends an overrun episode, so the next pass behind starts another)."""
    steps: int = 0
    behind: bool = False


class DeviceService:
    """The controller, its link and the loop around its mode machine."""

    def __init__(
        self,
        rig: Rig,
        link: Link,
        config: ServiceConfig = ServiceConfig(),
        clock: Callable[[], float] = time.perf_counter,
        out: TextIO = sys.stderr,
    ) -> None:
        self.rig = rig
        rig.compile()  # before it serves: never inside the loop
        self.link = link
        self.clock = clock
        self.out = out
        self.decoder = FrameDecoder()
        self._frames: collections.deque[Frame] = collections.deque()
        """Frames read but not yet acted on (:data:`FRAMES_PER_PASS`)."""
        self.read_per_pass = self._read_per_pass()
        self.modes = ModeMachine(rig, self._on_event)
        self.telemetry_hz_max = self._telemetry_hz_max()
        self.telemetry_hz = min(config.telemetry_hz, self.telemetry_hz_max)
        self.watchdog_ms = config.watchdog_ms
        self.commands_refused = 0
        self.software_faults = 0
        """Exceptions caught inside passes of the loop (each latched FAULT)."""
        self.pacing = PacingStats()
        self.events: collections.deque[msg.Event] = collections.deque(maxlen=EVENTS_KEPT)
        self._event_id = 0
        self._tx_seq = 0
        self._nonce: int | None = None
        self._replies: collections.OrderedDict[int, msg.Message] = collections.OrderedDict()
        self._last_rx = clock()
        self._next_telemetry = 0.0
        self._stop = False
        self.rig.advance(1)  # one sensor read so the first telemetry is real

    @property
    def mode(self) -> DeviceMode:
        return self.modes.mode

    @property
    def homed(self) -> bool:
        return self.modes.homed

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

    def _read_per_pass(self) -> int:
        bps = self.link.bits_per_second
        if bps is None:
            return READ_PER_PASS
        # Twice what the line delivers in a pass: the loop never falls behind the line.
        return max(64, int(2 * bps / 10.0 * CHUNK_TICKS / TICK_HZ))

    # -- the loop ------------------------------------------------------------------------
    def step(self) -> None:
        """One pass: link in, commands, watchdog, one chunk of interrupts, supervision, out.

        Each stage runs guarded: an exception becomes a latched FAULT and the pass goes on.
        """
        self._guarded("link", self._receive)
        self._guarded("watchdog", self._watchdog)
        self._guarded("control", self._control)
        self._guarded("modes", self.modes.step)
        self._guarded("telemetry", self._telemetry_due)
        self._guarded("link", self.link.flush)

    def _control(self) -> None:
        self.rig.advance(CHUNK_TICKS)

    def _telemetry_due(self) -> None:
        if self.time >= self._next_telemetry:
            self._next_telemetry = max(self._next_telemetry + 1.0 / self.telemetry_hz, self.time)
            self._send(self.telemetry(), droppable=True)

    def _guarded(self, stage: str, work: Callable[[], None]) -> None:
        try:
            work()
        except Exception as exc:  # the loop must outlive any error in one of its stages
            self._software_fault(stage, exc)

    def _software_fault(self, stage: str, exc: BaseException) -> None:
        """Latch FAULT for an error inside a pass; never raises itself."""
        self.software_faults += 1
        reason = f"{stage}: {type(exc).__name__}: {exc}"
        try:
            if self.software_faults <= 10:  # enough for the maintainer; no log flood
                print(f"ankle device: FAULT in {stage}:", file=self.out)
                traceback.print_exception(exc, file=self.out)
            self.modes.fault(Trip.SOFTWARE, reason)
        except Exception:  # the link or the log failed too: still close the valves
            try:
                self.rig.latch_trip(Trip.SOFTWARE)
                self.rig.close_valves_now()
            except Exception:
                pass

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
            before = self.time
            self.step()
            if self.time == before:
                # The controller did not advance (its stage failed): keep the pass's pace.
                sim0 -= CHUNK_TICKS / TICK_HZ
            lag = (self.clock() - wall0) - (self.time - sim0)
            self.pacing.steps += 1
            self.pacing.lags_ms.append(lag * 1e3)
            behind = lag > CONTROL_TICKS / TICK_HZ
            if behind and not self.pacing.behind:
                self.pacing.overruns += 1  # one per episode, however many passes catch up
            self.pacing.behind = behind
            if lag > MAX_CATCH_UP:
                # The time lost is given up, not caught up; counted, and the episode ends
                # here, so a loop kept behind counts an overrun per second lost.
                wall0 = self.clock() - (self.time - sim0)
                self.pacing.clock_resets += 1
                self.pacing.behind = False

    def stop(self) -> None:
        self._stop = True

    def shutdown(self) -> None:
        """Close the valves and the link."""
        try:
            self.rig.hold()
            self.rig.set_vent(False)
            self.rig.advance(CHUNK_TICKS)  # let the valve outputs follow
        finally:
            self.rig.close_valves_now()
            self.rig.hardware.close()
            self.link.close()

    # -- link ----------------------------------------------------------------------------
    def _send(self, message: msg.Message, droppable: bool = False) -> None:
        frame = msg.encode(message, self._tx_seq)
        if self.link.send(frame, droppable):
            self._tx_seq = (self._tx_seq + 1) & 0xFFFF

    def _receive(self) -> None:
        """Act on at most :data:`FRAMES_PER_PASS` frames, reading at most
        :attr:`read_per_pass` bytes, and only once those read before are done: a host that
        floods the link (valid frames or garbage) cannot starve the control chunk."""
        if not self._frames:
            data = self.link.read(self.read_per_pass)
            if self.link.take_new_peer():
                self._on_new_peer()
            if data:
                self._frames.extend(self.decoder.feed(data))
        for _ in range(min(FRAMES_PER_PASS, len(self._frames))):
            frame = self._frames.popleft()
            self._last_rx = self.clock()
            self._on_frame(frame.type, frame.seq, frame.body, frame.version)

    def _on_new_peer(self) -> None:
        """A new connection took the link over (TCP): the same as a new HELLO nonce. Nobody
        on it commanded the motion under way, and the host that did can no longer stop it:
        held, as if the old link had gone silent. The bytes of a frame the old host left
        half sent are not the start of the new host's first frame."""
        self.decoder.reset()
        self._nonce = None  # its HELLO is a first one: held already
        self._replies.clear()  # its sequence numbers are its own
        self.modes.hold(EventKind.WATCHDOG, "a new host connection (the link was taken over)")

    def _on_frame(self, mtype: int, seq: int, body: bytes, version: int) -> None:
        if version != self.decoder.version:  # a handshake from another protocol version
            self._send(self.hello())
            return
        try:
            command = msg.decode(Frame(mtype, seq, body), "host")
        except msg.MessageError as exc:
            self._reply(seq, mtype, CommandError(str(exc), exc.field, exc.code, exc.axis))
            return
        if isinstance(command, msg.Hello):
            if command.nonce != self._nonce:
                if self._nonce is not None:
                    # Another connection: a host that restarted faster than the watchdog.
                    # The motion under way was commanded over the old one, and nobody on
                    # this one asked for it: held, as if the old link had gone silent.
                    self.modes.hold(EventKind.WATCHDOG, "a new host connection (a new HELLO)")
                self._nonce = command.nonce
                self._replies.clear()
            self._send(self.hello())
            return
        cached = self._replies.get(seq)
        if cached is not None and getattr(cached, "command", None) == mtype:
            self._send(cached)  # a repeat (lost ACK or duplicated frame): answer, do not re-run
            return
        try:
            checked = commands.check(command, self._context())
        except CommandError as exc:
            self._reply(seq, mtype, exc)
            return
        try:
            self._apply(checked)
        except Exception as exc:
            self._software_fault("command", exc)
            self._reply(
                seq,
                mtype,
                CommandError(
                    "the device failed applying this command and is in FAULT",
                    code=NackCode.DEVICE_FAULT,
                ),
            )
            return
        self._reply(seq, mtype, None)

    def _context(self) -> commands.Context:
        seg = self.modes.segment
        return commands.Context(
            limits=self.rig.limits,
            geometry=self.rig.geometry,
            mode=self.mode,
            trip=self.rig.trip,
            telemetry_hz_max=self.telemetry_hz_max,
            compliant=seg.plan.compliant if seg is not None else None,
            legs=tuple(self.rig.state.leg_x.tolist()),
            supply_low=self.rig.supply_low,
            service=self.rig.service_chamber >= 0,
        )

    def _apply(self, c: commands.Checked) -> None:
        """Carry out a checked command; from here on nothing refuses."""
        m = self.modes
        if isinstance(c, CheckedSegment):
            m.start_segment(c)
        elif isinstance(c, CheckedImpedance):
            m.set_impedance(c)
        elif isinstance(c, msg.Configure):
            self.telemetry_hz = c.telemetry_hz
            self.watchdog_ms = c.watchdog_ms
            self._next_telemetry = self.time
        elif isinstance(c, msg.EStop):
            m.estop()
        elif isinstance(c, msg.ReplayEvents):
            for event in self.events:
                if event.event_id > c.after_id:
                    self._send(event)
        elif isinstance(c, msg.Rearm):
            m.rearm()
        elif isinstance(c, msg.HoldCmd):
            m.hold(EventKind.MODE_CHANGE, "hold")
        elif isinstance(c, msg.Release):
            m.release()
        elif isinstance(c, msg.ArmHome):
            m.arm_home()
        elif isinstance(c, msg.Resume):
            m.resume()

    def _reply(self, seq: int, mtype: int, refused: CommandError | None) -> None:
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

    # -- supervision ---------------------------------------------------------------------
    def _watchdog(self) -> None:
        self.modes.watchdog((self.clock() - self._last_rx) * 1e3, self.watchdog_ms)

    def _on_event(
        self,
        kind: EventKind,
        mode_from: DeviceMode,
        mode_to: DeviceMode,
        code: int,
        value: float,
        text: str,
    ) -> None:
        self._event_id += 1
        event = msg.Event(
            event_id=self._event_id,
            time=self.time,
            kind=kind,
            mode_from=mode_from,
            mode_to=mode_to,
            code=code,
            value=value,
            text=text,
        )
        self.events.append(event)
        self._send(event)

    # -- outgoing ------------------------------------------------------------------------
    def telemetry(self) -> msg.Telemetry:
        s = self.rig.state
        home = self.rig.geometry.home_pose
        seg = self.modes.segment
        flags = msg.TelemetryFlags.NONE
        if self.homed:
            flags |= msg.TelemetryFlags.HOMED
        if self.rig.venting:
            flags |= msg.TelemetryFlags.VENTING
        if seg is not None:
            flags |= msg.TelemetryFlags.SEGMENT
        if self.rig.supply_low:
            flags |= msg.TelemetryFlags.SUPPLY_LOW
        lags = self.pacing.lags_ms
        return msg.Telemetry(
            time=self.time,
            mode=self.mode,
            trip=self.rig.trip,
            flags=flags,
            segment_id=seg.plan.segment_id if seg is not None else 0,
            segment_time=self.modes.segment_time(),
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
            clock_resets=self.pacing.clock_resets & 0xFFFFFFFF,
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
        if self.rig.config.calibration != Calibration():
            caps |= msg.Capability.CALIBRATED
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
            envelope_stiffness=lim.envelope_stiffness,
            damping_min=lim.damping_min,
        )


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
