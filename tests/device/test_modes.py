"""The mode machine's segments on the real plant: the range of motion a segment was accepted
with holds for as long as its compliance does, and a live K and B never blind a check.

A rig and its mode machine are stepped as the device service steps them (one pass a
millisecond), every command checked by :mod:`device.commands` as the service checks it.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from device import commands, supervision
from device.axes import AXES
from device.client import AxisPlan, build_segment
from device.commands import CheckedImpedance, CheckedSegment
from device.hardware import SimulatedHardware
from device.limits import APPROACH_SPEED
from device.modes import ModeMachine
from device.plant.faults import Fault, FaultKind
from device.plant.model import SCRIPT_RAMP, SCRIPT_SINE
from device.plant.params import PlantConfig
from device.protocol import messages as msg
from device.protocol.messages import DeviceMode, EventKind
from device.rig import Rig
from device.safety import Trip
from device.waveforms import Waveform
from lab import safety
from sessions.prescription import ExerciseKind
from tests.device.test_service import PITCH as SERVICE_PITCH

PASS_TICKS = 7
"""Interrupts in one pass of the service (1 ms)."""


class Device:
    """A rig and its mode machine, as the device service runs them."""

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        self.events: list[tuple[object, ...]] = []
        self.modes = ModeMachine(rig, lambda *e: self.events.append(e))
        rig.compile()
        rig.advance(1)

    def send(self, command: msg.Message) -> None:
        """Check ``command`` as the service does (raises CommandError) and apply it."""
        seg = self.modes.segment
        ctx = commands.Context(
            limits=self.rig.limits,
            geometry=self.rig.geometry,
            mode=self.modes.mode,
            trip=self.rig.trip,
            compliant=seg.plan.compliant if seg is not None else None,
            legs=tuple(self.rig.state.leg_x.tolist()),
            supply_low=self.rig.supply_low,
            service=self.rig.service_chamber >= 0,
        )
        c = commands.check(command, ctx)
        if isinstance(c, CheckedSegment):
            self.modes.start_segment(c)
        elif isinstance(c, CheckedImpedance):
            self.modes.set_impedance(c)
        elif isinstance(c, msg.ArmHome):
            self.modes.arm_home()
        elif isinstance(c, msg.HoldCmd):
            self.modes.hold()
        elif isinstance(c, msg.Resume):
            self.modes.resume()

    def run(self, seconds: float, each: Callable[[], object] | None = None) -> None:
        for _ in range(round(seconds * 1000)):
            self.rig.advance(PASS_TICKS)
            self.modes.step()
            if each is not None:
                each()

    def home(self) -> None:
        self.send(msg.ArmHome())
        for _ in range(15000):
            if self.modes.mode != DeviceMode.HOMING:
                break
            self.run(0.001)
        assert self.modes.mode == DeviceMode.READY

    def push(self, axis: int, newtons_m: float, over: float) -> None:
        """The foot pushes about ``axis``, ramping up to ``newtons_m`` over ``over`` s."""
        hw = self.rig.hardware
        hw.script_torque(axis, SCRIPT_RAMP, self.rig.time, newtons_m / over, newtons_m)  # type: ignore[attr-defined]

    @property
    def pose(self) -> np.ndarray:
        """The platform's true pose relative to home (the plant's)."""
        return self.rig.hardware.state.pose - self.rig.geometry.home_pose  # type: ignore[attr-defined,no-any-return]

    def phase(self) -> str:
        seg = self.modes.segment
        return seg.phase if seg is not None else self.modes.mode.name

    def kinds(self) -> list[EventKind]:
        return [e[0] for e in self.events]  # type: ignore[misc]


def narrowed(
    dev: Device, seg_id: int, duration: float, plans: dict[str, AxisPlan], **ranges: float
) -> msg.StartSegment:
    """A segment of ``plans`` whose ranges (``pitch=3`` for +-3 deg, ``roll_low`` and
    ``roll_high`` for an end each) narrow the device's own."""
    lim = dev.rig.limits
    low, high = list(lim.rom_low), list(lim.rom_high)
    for name, deg in ranges.items():
        axis, _, end = name.partition("_")
        k = AXES.index(axis)
        if end in ("", "low"):
            low[k] = math.radians(-deg if end == "" else deg)
        if end in ("", "high"):
            high[k] = math.radians(deg)
    return build_segment(lim, seg_id, duration, plans, tuple(low), tuple(high))


def compliant_pitch(k: float, b: float) -> AxisPlan:
    return AxisPlan(Waveform.HOLD, stiffness=k, damping=b, compliant=True)


# -- the range of motion --------------------------------------------------------------------


@pytest.mark.parametrize(
    ("k", "b", "push", "deg"),
    [(40.0, 2.0, 15.0, 3.0), (5.0, 0.8, 8.0, 6.0), (0.0, 1.0, 15.0, 3.0)],
)
def test_the_range_holds_while_the_axis_is_compliant_and_the_return_is_gentle(
    k: float, b: float, push: float, deg: float
) -> None:
    """A relaxed foot pushes a compliant pitch against the therapist's range until the run
    ends. The range was lifted as the run ended, with the axis still compliant: pitch went
    from the 3 deg wall to 8.7 deg and tripped LEG_SPEED on leg 4 (K 40, 15 N m; 11.9 deg at
    K 0), or from 6.3 to 21.5 deg within 0.12 s at K 5 (8 N m), reported as a normal end.
    Now the return brings the command home from where it stands at the approach speeds,
    and the device's range comes back only once nothing is compliant."""
    dev = Device(safety._rig("relaxed", 1))
    dev.home()
    dev.send(narrowed(dev, 1, 3.0, {"pitch": compliant_pitch(k, b)}, pitch=deg))
    dev.push(4, push, 1.0)
    rows: list[tuple[str, float, float]] = []
    home_pitch = dev.rig.geometry.home_pose[4]

    def each() -> None:
        cmd = float(dev.rig.state.pose_cmd[4] - home_pitch)
        rows.append((dev.phase(), float(dev.pose[4]), cmd))

    dev.run(6.0, each)
    assert dev.rig.trip == Trip.NONE, dev.events
    assert EventKind.SEGMENT_DONE in dev.kinds() and dev.modes.mode == DeviceMode.READY
    run = [r for r in rows if r[0] == "run"]
    back = [r for r in rows if r[0] == "return"]
    assert max(r[1] for r in run) > math.radians(deg - 0.5), "the foot never reached the wall"
    # From the run's end on, the platform stays at the wall (the tracking error the
    # measured run itself shows: 0.16-0.3 deg) and its command comes home no faster than
    # the approach moves.
    assert max(r[1] for r in back) <= math.radians(deg + 0.35)
    # The command moves once a control period: over any 8 ms, 8 ms at the approach speed.
    cmd = np.array([r[2] for r in back])
    assert np.abs(cmd[8:] - cmd[:-8]).max() <= APPROACH_SPEED[4] * 0.008 * 1.001
    assert abs(back[-1][2]) < 1e-6, "the return did not end at home"


def test_the_range_is_in_force_from_the_approach_on() -> None:
    """Roll centred at 10 deg makes a 0.87 s approach; pitch is compliant within 3 deg and
    the foot pushes it. The range used to narrow only as the run began: pitch went to 10.9
    deg during the approach under the device's range, and the run's first period tripped
    RANGE_OF_MOTION with the platform at 11 deg."""
    dev = Device(safety._rig("relaxed", 1))
    dev.home()
    roll = AxisPlan(Waveform.HOLD, center=math.radians(10.0))
    dev.send(narrowed(dev, 1, 1.0, {"roll": roll, "pitch": compliant_pitch(40.0, 2.0)}, pitch=3))
    dev.push(4, 10.0, 0.25)
    peak = {"approach": 0.0, "run": 0.0}

    def each() -> None:
        phase = dev.phase()
        if phase in peak:
            peak[phase] = max(peak[phase], float(dev.pose[4]))

    dev.run(3.0, each)
    assert dev.rig.trip == Trip.NONE, dev.events
    assert EventKind.SEGMENT_DONE in dev.kinds()
    assert math.radians(2.5) < peak["approach"] <= math.radians(3.35), peak
    assert peak["run"] <= math.radians(3.35), peak


def test_a_range_that_leaves_out_home_is_reached_from_home() -> None:
    """Roll worked within 5..15 deg (home outside it, as a prescription may ask), pitch
    compliant within 3 deg and pushed: the range in force spans home and closes in on the
    segment's at the approach's speed, so neither axis trips, and the roll sine runs
    inside its range."""
    dev = Device(safety._rig("relaxed", 1))
    dev.home()
    roll = AxisPlan(
        Waveform.SINE, center=math.radians(10.0), amplitude=math.radians(4.0), frequency=0.5
    )
    segment = narrowed(
        dev,
        1,
        2.0,
        {"roll": roll, "pitch": compliant_pitch(40.0, 2.0)},
        pitch=3,
        roll_low=5,
        roll_high=15,
    )
    dev.send(segment)
    dev.push(4, 10.0, 0.25)
    roll_run: list[float] = []
    pitch_max = 0.0

    def each() -> None:
        nonlocal pitch_max
        pitch_max = max(pitch_max, float(dev.pose[4]))
        if dev.phase() == "run":
            roll_run.append(float(dev.pose[3]))

    dev.run(5.0, each)
    assert dev.rig.trip == Trip.NONE, dev.events
    assert EventKind.SEGMENT_DONE in dev.kinds()
    assert math.radians(5.0 - 0.3) <= min(roll_run) and max(roll_run) <= math.radians(15.0 + 0.3)
    assert pitch_max <= math.radians(3.35)


def test_a_narrower_segment_sent_mid_run_brings_the_pushed_axis_in_gently() -> None:
    """A wide segment's compliant pitch is pushed to 13 deg; a segment within 3 deg replaces
    it. The approach used to run under the device's range and narrow it as the run began,
    with the platform still far outside: a RANGE_OF_MOTION trip. Now the range in force
    starts where the command stands and closes in at the approach's speed."""
    dev = Device(safety._rig("relaxed", 1))
    dev.home()
    dev.send(narrowed(dev, 1, 10.0, {"pitch": compliant_pitch(20.0, 1.0)}))
    dev.push(4, 8.0, 0.4)
    dev.run(2.5)
    assert float(dev.pose[4]) > math.radians(10.0)
    dev.send(narrowed(dev, 2, 1.0, {"pitch": compliant_pitch(40.0, 2.0)}, pitch=3))
    highs: list[float] = []
    dev.run(4.0, lambda: highs.append(float(dev.rig.params.limits[1, 4])))
    assert dev.rig.trip == Trip.NONE, dev.events
    assert dev.kinds().count(EventKind.SEGMENT_DONE) == 1
    closing = np.diff(highs)
    assert closing.min() >= -APPROACH_SPEED[4] * 0.001 * 1.01


def test_a_segment_that_makes_a_pushed_axis_stiff_brings_it_home_gently() -> None:
    """A compliant pitch (K 20, B 1) is pushed 8 N m to 13 deg; the next segment leaves
    pitch stiff. Its approach started from the waveform's part alone while the compliance's
    offset was dropped at once: the command went 13.3 -> 0 deg in one control period and
    FOLLOWING tripped 4 ms later (21 of 1000 random segment changes that made an axis
    stiff). The offset is now folded into the approach's ramp."""
    dev = Device(safety._rig("relaxed", 1))
    dev.home()
    dev.send(narrowed(dev, 1, 10.0, {"pitch": compliant_pitch(20.0, 1.0)}))
    dev.push(4, 8.0, 0.4)
    dev.run(2.0)
    assert float(dev.pose[4]) > math.radians(10.0), "the foot never pushed pitch out"
    dev.send(narrowed(dev, 2, 2.0, {"roll": AxisPlan(Waveform.HOLD)}))
    home_pitch = dev.rig.geometry.home_pose[4]
    cmd: list[float] = []

    def each() -> None:
        if dev.phase() == "approach":
            cmd.append(float(dev.rig.state.pose_cmd[4] - home_pitch))

    dev.run(4.5, each)
    assert dev.rig.trip == Trip.NONE, dev.events
    assert dev.kinds().count(EventKind.SEGMENT_DONE) == 1
    assert cmd[0] > math.radians(10.0) and abs(cmd[-1]) < math.radians(0.1), (cmd[0], cmd[-1])
    # The command moves once a control period (4 ms): over any 8 ms, 8 ms at the approach
    # speed.
    steps = np.abs(np.array(cmd[8:]) - np.array(cmd[:-8]))
    assert steps.max() <= APPROACH_SPEED[4] * 0.008 * 1.001, steps.max()


def test_a_segment_that_makes_a_pushed_axis_compliant_lets_it_go_gently() -> None:
    """Pitch held stiff at home while the foot pushes 8 N m; the next segment makes it
    compliant (K 20, B 1). Its offset started at 0 against the whole push: the command
    moved at 4.1 rad/s (twice the published axis speed) to 13 deg. It now catches up with
    the foot at the approach speed and settles where the push puts it on K."""
    dev = Device(safety._rig("relaxed", 1))
    dev.home()
    dev.send(narrowed(dev, 1, 10.0, {"pitch": AxisPlan(Waveform.HOLD)}))
    dev.push(4, 8.0, 0.4)
    dev.run(2.0)
    dev.send(narrowed(dev, 2, 5.0, {"pitch": compliant_pitch(20.0, 1.0)}))
    home_pitch = dev.rig.geometry.home_pose[4]
    cmd: list[float] = []
    dev.run(4.0, lambda: cmd.append(float(dev.rig.state.pose_cmd[4] - home_pitch)))
    assert dev.rig.trip == Trip.NONE, dev.events
    assert not dev.rig.state.catch_up.any(), "it never caught up"
    steps = np.abs(np.array(cmd[8:]) - np.array(cmd[:-8]))
    assert steps.max() <= APPROACH_SPEED[4] * 0.008 * 1.05, steps.max() / 0.008
    assert float(dev.pose[4]) > math.radians(10.0)


# -- live K and B ---------------------------------------------------------------------------

PITCH_SINE = AxisPlan(
    Waveform.SINE,
    center=math.radians(10.0),
    amplitude=math.radians(5.0),
    frequency=0.5,
    stiffness=30.0,
    damping=1.0,
    compliant=True,
)


def _offset_named_ms(changes: Callable[[Device, float], None]) -> float:
    """Milliseconds from a 3 N m offset on the pitch torque channel, 2.2 s into a compliant
    pitch sine, to its FORCE_SENSOR trip, with ``changes(dev, t)`` called every pass."""
    dev = Device(safety._rig("relaxed", 1))
    dev.home()
    dev.send(narrowed(dev, 1, 6.0, {"pitch": PITCH_SINE}))
    dev.run(2.2)
    hw = dev.rig.hardware
    hw.inject(Fault(FaultKind.FT_OFFSET, float(hw.state.time[0]), 4, 3.0))  # type: ignore[attr-defined]
    t0 = dev.rig.time
    for _ in range(1000):
        changes(dev, dev.rig.time - t0)
        dev.run(0.001)
        if dev.rig.trip != Trip.NONE:
            break
    assert dev.rig.trip == Trip.FORCE_SENSOR and dev.rig.trip_channel == 4, dev.rig.trip
    return (dev.rig.time - t0) * 1e3


def _set(k: float) -> msg.SetImpedance:
    return msg.SetImpedance(stiffness=(0, 0, 0, 0, k, 0), damping=(0, 0, 0, 0, 1.0, 0))


def test_the_same_impedance_again_changes_nothing() -> None:
    """A host that re-sends its K and B (every 30 ms here) used to restart the cross-checks'
    40 ms wait each time: a 3 N m offset on the pitch torque went unnamed for good, the
    platform 3.7-4.0 deg from its healthy twin. Unchanged values change nothing, so it is
    named as fast as with no command at all (20 ms)."""
    sent = {"next": 0.0}

    def resend(dev: Device, t: float) -> None:
        if t >= sent["next"] - 1e-9:
            armed = int(dev.rig.state.counters[supervision.C_SIDE_ARMED])
            dev.send(_set(30.0))
            assert int(dev.rig.state.counters[supervision.C_SIDE_ARMED]) == armed
            sent["next"] += 0.03

    assert _offset_named_ms(resend) <= 30.0


@pytest.mark.parametrize("every_ms", [5, 30])
def test_a_host_sending_segments_fast_cannot_blind_the_cross_checks(every_ms: int) -> None:
    """Each new segment makes the moment check wait 40 ms (its legs chase a new target). A
    host that sent the same compliant pitch sine again every 30 ms restarted that wait each
    time: a 3 N m offset on the pitch torque went unnamed for good (3 s; sent every 5 ms,
    until a leg sensor was blamed at 259 ms). A command that comes while the checks wait no
    longer lengthens the wait, and they judge at least as long as they waited before the
    next one, so it is named within a wait and a judging spell (57 ms)."""
    next_at, seg_id = [0.0], [2]

    def resend(dev: Device, t: float) -> None:
        if t >= next_at[0] - 1e-9:
            dev.send(narrowed(dev, seg_id[0], 6.0, {"pitch": PITCH_SINE}))
            seg_id[0] += 1
            next_at[0] += every_ms / 1e3

    assert _offset_named_ms(resend) <= 100.0


def test_a_new_impedance_leaves_the_checks_judging() -> None:
    """K 30 -> 100 on the compliant pitch as a 3 N m offset lands on its torque channel:
    with the cross-checks held off for 40 ms after each change it was named in 46-56 ms
    and the platform turned 2.4-3.0 deg; a K or B change disturbs none of them (see
    ``Rig.apply_impedance``), so it is named as without the change (20 ms). A host changing
    K every 30 ms cannot blind them either."""
    changed = {"done": False}

    def once(dev: Device, t: float) -> None:
        if not changed["done"]:
            dev.send(_set(100.0))
            changed["done"] = True

    assert _offset_named_ms(once) <= 30.0
    turn = {"next": 0.0, "k": 30.0}

    def alternate(dev: Device, t: float) -> None:
        if t >= turn["next"] - 1e-9:
            turn["k"] = 130.0 - turn["k"]
            dev.send(_set(turn["k"]))
            turn["next"] += 0.03

    assert _offset_named_ms(alternate) <= 30.0


# -- hold and resume ------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [4, 6, 7])
def test_holds_and_resumes_two_milliseconds_apart_trip_nothing(seed: int) -> None:
    """A host that sends hold and resume 2 ms apart (a double click, a station's retry, an
    attacker): a hold that began and ended inside a leg's 4 ms PWM period left that
    period's pulses counted in the valve windows though the valves had shut for part of
    it, and the resume drove what was left of them. On a healthy plant a chamber's air
    then fell short of what its valves were told: a VALVE trip within 100 pairs on 10 of
    20 noise seeds (these three among them; 1-3 ms apart at random, on 3 of 200). A hold
    now stops every leg at once: nothing is left to drive and the windows start again."""
    dev = Device(Rig(SimulatedHardware(PlantConfig(patient="relaxed"), seed=seed)))
    dev.home()
    dev.run(int(np.random.default_rng(seed).integers(0, 300)) / 1e3)  # at home a while
    dev.send(build_segment(dev.rig.limits, 1, 120.0, {"pitch": SERVICE_PITCH}))
    dev.run(0.002)
    for _ in range(100):
        dev.send(msg.HoldCmd())
        # Shut at once, and no pulse of the period it cut short left to drive.
        assert not dev.rig.state.valves.any() and not dev.rig.state.slots.any()
        dev.run(0.002)
        dev.send(msg.Resume())
        dev.run(0.002)
    dev.run(0.5)
    assert dev.rig.trip == Trip.NONE, dev.events[-1]
    assert EventKind.SERVICE not in dev.kinds()
    assert dev.modes.mode == DeviceMode.ACTIVE


@pytest.mark.parametrize("patient", ["relaxed", "resisting"])
@pytest.mark.parametrize("kind", [ExerciseKind.BALANCE, ExerciseKind.ROM_ASSESSMENT])
def test_a_resume_while_the_foot_pushes_catches_up_gently(kind: ExerciseKind, patient: str) -> None:
    """The library's exercise, the foot pushing a 5 N m, 0.3 Hz sine on each axis (as
    ``lab.safety.start_exercise``), held 1 s into the push and resumed 1.5 s later. The
    compliance stood still through the hold while the push reversed, and the law took the
    whole mismatch at once: the roll command went 6.95 -> 1.39 deg in 20 ms and LEG_SPEED
    tripped 30 ms after the resume (14 of 72 random holds in BALANCE and ROM_ASSESSMENT).
    Each compliant axis now catches up at no more than the approach speed, then renders
    its K and B again."""
    targets, K, B, compliant = safety._library_targets(kind)
    plans = {
        axis: AxisPlan(
            t.kind,
            t.center,
            t.amplitude,
            t.frequency,
            stiffness=float(K[AXES.index(axis)]),
            damping=float(B[AXES.index(axis)]),
            compliant=compliant[AXES.index(axis)],
        )
        for axis, t in targets.items()
    }
    dev = Device(safety._rig(patient, 1))
    dev.home()
    dev.send(build_segment(dev.rig.limits, 1, 30.0, plans))
    dev.run(1.0)
    hw = dev.rig.hardware
    for axis in targets:
        hw.script_torque(AXES.index(axis), SCRIPT_SINE, dev.rig.time, 5.0, 0.3)  # type: ignore[attr-defined]
    dev.run(1.0)
    dev.send(msg.HoldCmd())
    dev.run(1.5)
    dev.send(msg.Resume())
    s = dev.rig.state
    rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    dev.run(4.0, lambda: rows.append((s.pose_cmd.copy(), s.x_m.copy(), s.catch_up.copy())))
    assert dev.rig.trip == Trip.NONE, dev.events
    assert dev.modes.mode == DeviceMode.ACTIVE
    cmd = np.array([r[0] for r in rows])
    x_m = np.array([r[1] for r in rows])
    catching = np.array([r[2] for r in rows]) > 0.5
    axes = [AXES.index(a) for a in targets]
    assert catching[0, axes].all(), "the resume did not start a catch-up"
    # The command, over a control period, never as fast as the published limit.
    speed = np.abs(cmd[4:, axes] - cmd[:-4, axes]).max() / 0.004
    assert speed < 0.75 * max(dev.rig.limits.axis_speed_max[k] for k in axes), speed
    # The compliance moves at most a control period's approach step per pass while it
    # catches up, and it has caught up within 3 s.
    for k in axes:
        moving = catching[:-1, k]
        step = np.abs(np.diff(x_m[:, k]))[moving]
        assert step.max() <= APPROACH_SPEED[k] * 0.004 * 1.001, (AXES[k], step.max())
        ends = np.flatnonzero(~catching[:, k])
        assert ends.size and ends[0] < 3000, (AXES[k], ends[:1])
        assert not catching[ends[0] :, k].any()


def test_a_compliance_that_caught_up_renders_its_stiffness() -> None:
    """The foot's push on a compliant pitch (K 20, B 1) rises to 8 N m during a hold: after
    the resume the compliance catches up at the approach speed (1.1 s) and the platform
    then settles where its twin that was never held did (the foot's equilibrium on K)."""

    def settle(held: bool) -> tuple[float, float]:
        """Where pitch settles, and its command's fastest over 8 ms (two control periods)
        from the resume on."""
        dev = Device(safety._rig("relaxed", 1))
        dev.home()
        dev.send(narrowed(dev, 1, 30.0, {"pitch": compliant_pitch(20.0, 1.0)}))
        dev.run(1.0)
        if held:
            dev.send(msg.HoldCmd())
        dev.push(4, 8.0, 0.4)
        dev.run(1.0)
        if held:
            dev.send(msg.Resume())
        home_pitch = dev.rig.geometry.home_pose[4]
        cmd: list[float] = []
        dev.run(4.0, lambda: cmd.append(float(dev.rig.state.pose_cmd[4] - home_pitch)))
        assert dev.rig.trip == Trip.NONE, dev.events
        assert not dev.rig.state.catch_up.any()
        fastest = np.abs(np.array(cmd[8:]) - np.array(cmd[:-8])).max() / 0.008
        return float(dev.pose[4]), float(fastest)

    (free, _), (held, fastest) = settle(False), settle(True)
    assert fastest <= 1.5 * APPROACH_SPEED[4], fastest
    assert free > math.radians(10.0), free
    assert abs(held - free) < math.radians(0.3), (math.degrees(free), math.degrees(held))
