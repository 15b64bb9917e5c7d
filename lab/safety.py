"""The device's safety, measured: injected faults, healthy runs, boundary commands.

Everything runs the real controller against the plant in simulated time (``Rig``), except
the boundary-command run, which goes through the real device service over a pty.

- **Fault matrix**: every fault kind of :mod:`device.plant.faults`, injected in three
  situations (holding at home, in the middle of a pitch exercise, while the patient pushes
  against the rendered stiffness). Each is *detected* when the controller latches a trip
  (or, for a drooping supply, raises its low-supply flag, on which the mode machine holds).
  Detection time is from the injection to that moment; the excursion is how far the true
  platform moved from where it was at the injection, until 0.5 s after it. A fault left
  unnamed is then used: the matrix's pitch exercise begins and is watched as long again.
- **Healthy runs**: every exercise of the library on a healthy plant, several seeds: any trip
  is a false trip.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from device import supervision
from device.axes import AXES, AXIS_INDEX
from device.controller import I_RINGS, ControllerConfig, Mode
from device.hardware import SimulatedHardware
from device.plant.faults import Fault, FaultKind
from device.plant.model import SCRIPT_RAMP, SCRIPT_SINE
from device.plant.params import PlantConfig
from device.rig import Rig
from device.tickloop import COL
from device.trips import Trip
from device.waveforms import AxisTarget, Waveform
from lab.experiments import PlantChoice
from lab.targets import Target
from lab.targets import table as render
from sessions.prescription import EXERCISE_LIBRARY, ExerciseKind

SCENARIOS = ("holding", "exercise", "pushing")
MATRIX_SCENARIOS = (*SCENARIOS, "settling")
"""The matrix's situations: :data:`SCENARIOS`, and the legs settling at mid stroke, 50 ms
into the joint move that starts every session (a fraction of a millimetre from where the
platform rests at start-up): the targets have stopped, so a reading frozen short of one
never sees it run away, and the loop's integral and the seals' friction fed forward push
each leg its last counts. A leg sensor frozen there let its leg run 21-33 mm before the
compensation's blind bound, a case the other three situations did not show."""
DROOP_ONSET_MAX_S = 1.0
"""How long a drooping supply may take to sag to the low mark (it took 0.44-0.48 s from the
default 6 bar to 3.5); it is watched ``after`` seconds from there."""
DORMANT_COUNTS = 2
"""A frozen sensor whose true value stayed within this many of its counts (ADC steps) of
where it froze, while watched, read what a live one would have (within its noise): the
fault had made no difference yet."""
AFTER_S = 0.5
"""How long each run goes on after the injection (s), unless told otherwise: long enough for
every detection the benchmark expects, too short to show what an undetected fault does over
seconds (``ankle bench safety --only KIND --after S`` looks longer)."""

# Per kind, the channel a single run takes by default and the value (0-based channels, see
# device.plant.faults); the matrix runs every channel of CHANNELS.
FAULTS: dict[FaultKind, tuple[int, float]] = {
    FaultKind.SUPPLY_LOSS: (-1, 0.0),
    FaultKind.SUPPLY_DROOP: (-1, 3.5),
    FaultKind.PRESSURE_OPEN: (4, 0.0),
    FaultKind.PRESSURE_SHORT: (4, 0.0),
    FaultKind.PRESSURE_STUCK: (4, 0.0),
    FaultKind.PRESSURE_OFFSET: (4, 1.5),
    FaultKind.LEG_STUCK: (2, 0.0),
    FaultKind.LEG_OFFSET: (2, 3.0),
    FaultKind.LEG_NOISE: (2, 0.5),
    FaultKind.FT_DEAD: (-1, 0.0),
    FaultKind.FT_SATURATED: (-1, 0.0),
    # Under both the jump rule (40 N in 1 ms) and the wrench cross-check (45 N): the worst
    # a bias can be and not be seen at once (80 N is now caught in 1 ms).
    FaultKind.FT_OFFSET: (2, 30.0),  # a torque channel takes FT_TORQUE_OFFSET
    FaultKind.VALVE_STUCK_OPEN: (8, 0.0),
    FaultKind.VALVE_STUCK_CLOSED: (9, 0.0),
    FaultKind.CHAMBER_LEAK: (4, 0.5),
}
FT_TORQUE_OFFSET = 3.0
"""The offset (N m) injected on a torque channel: under the jump rule (4 N m in 1 ms) and
the wrench cross-check (5.5 N m), as 30 N is on a force channel."""
CHANNELS: dict[FaultKind, tuple[int, ...]] = {
    **{kind: (channel,) for kind, (channel, _) in FAULTS.items()},
    **dict.fromkeys(
        (
            FaultKind.PRESSURE_OPEN,
            FaultKind.PRESSURE_SHORT,
            FaultKind.PRESSURE_STUCK,
            FaultKind.PRESSURE_OFFSET,
        ),
        tuple(range(13)),
    ),
    **dict.fromkeys(
        (FaultKind.LEG_STUCK, FaultKind.LEG_OFFSET, FaultKind.LEG_NOISE), tuple(range(6))
    ),
    FaultKind.FT_OFFSET: tuple(range(6)),  # 30 N on each force channel, 3 N m on each torque
    FaultKind.VALVE_STUCK_OPEN: tuple(range(24)),
    FaultKind.VALVE_STUCK_CLOSED: tuple(range(24)),
    FaultKind.CHAMBER_LEAK: tuple(range(12)),
}
"""Where the matrix injects each kind: on every channel it can strike. Which one changes
everything for some kinds (a frozen leg 2 is caught mid-exercise in 179 ms, a frozen leg 0
or 1 only after 435-459 ms and not at all while the patient pushes, where it let the
platform turn 6-7 deg within a second until the compensation's blind bound), and one
representative channel hid that."""


@dataclass(frozen=True)
class FaultRun:
    kind: str
    scenario: str
    seed: int
    injected: int
    """The channel the fault was injected on (-1: none or all)."""
    detected: bool
    trip: str
    channel: int
    detect_ms: float
    """From the fault's onset to the trip (or the low-supply flag); NaN if never."""
    onset_ms: float
    """From the injection to the onset: how long a drooping supply took to sag to the low
    mark (0 for every other fault, NaN if it never got there)."""
    excursion_deg: float
    excursion_mm: float
    notes: str = ""
    dormant: bool = False
    """The fault made no difference yet while watched: a valve stuck shut that the loop never
    told to open (a leg resting in the quiet hold has every valve shut), or a chamber's
    transducer or a leg's sensor frozen on a value that stayed true (the chamber's pressure
    or the leg within :data:`DORMANT_COUNTS` of where it froze). Nothing can tell such a
    part from a healthy one until it is used; counted as undetected all the same."""
    used_trip: str = ""
    """For a fault left unnamed while watched, what the run noticed once the matrix's pitch
    exercise then began and used every leg and valve (:func:`noticed`'s words, ``NONE`` if
    nothing within ``after`` seconds); empty for a fault named while watched."""
    used_detect_ms: float = math.nan
    """...how long after the exercise began (ms); NaN if not then either."""
    used_excursion_deg: float = math.nan
    used_excursion_mm: float = math.nan
    """...and how far the platform went from the same exercise without the fault."""


def _rig(
    patient: str, seed: int, calibrated: bool = True, config: ControllerConfig | None = None
) -> Rig:
    """The nominal unit on noise ``seed``, with its start-up identification as deployed (the
    systemd unit in deploy/ starts the device with ``--calibration``): the seals' friction
    the checks take out and allow for is the unit's own. ``calibrated=False``: as the
    service runs without a calibration. ``config``: the controller's settings (their
    calibration replaced by the unit's when calibrated)."""
    from lab.experiments import calibration_of

    cfg = PlantConfig(patient=patient)
    config = ControllerConfig() if config is None else config
    if calibrated:  # first: identifying seeds the plant's random generator itself
        config = dataclasses.replace(config, calibration=calibration_of(cfg))
    return Rig(SimulatedHardware(cfg, seed=seed), config)


def _start(rig: Rig, scenario: str) -> None:
    """Put the rig in the scenario, running, 0.5 s before the injection (settling: the
    joint move to mid stroke just sent, 50 ms before it)."""
    rig.move_legs(np.full(6, 0.5 * rig.geometry.stroke))
    if scenario == "settling":
        return
    rig.run(0.5, log_hz=0)
    if scenario == "holding":
        return
    if scenario == "exercise":
        _pitch_exercise(rig)
        return
    _compliant_pitch(rig, 50.0)
    rig.track({})
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    hw.script_torque(4, SCRIPT_RAMP, rig.time, 10.0, 8.0)  # up to 8 N m in 0.8 s


def _compliant_pitch(rig: Rig, stiffness: float) -> None:
    """Pitch rendered compliant (``stiffness`` N m/rad, 1 N m s/rad), the other axes held."""
    K, B = np.zeros(6), np.zeros(6)
    K[4], B[4] = stiffness, 1.0
    rig.set_impedance(K, B, [k == 4 for k in range(6)])


def _pitch_exercise(rig: Rig) -> None:
    """The matrix's exercise, begun now: a pitch sine of 8 deg at 0.5 Hz, compliant at 30."""
    _compliant_pitch(rig, 30.0)
    rig.track({"pitch": AxisTarget(Waveform.SINE, 0.0, math.radians(8.0), 0.5)})


def _then_used(rig: Rig, after: float) -> tuple[np.ndarray, float, float]:
    """What follows a fault left unnamed while watched: the matrix's pitch exercise begins,
    which drives every leg and both chambers of each, and is watched ``after`` seconds:
    (true pose log, detection s, stop s), both from its start, NaN if never."""
    rig.clear_log()
    _pitch_exercise(rig)
    detect, _, stop = watch(rig, None, after)
    return rig.log[:, [COL[f"pose_{a}"] for a in AXES]], detect, stop


def _watched_s(kind: FaultKind | None, after: float) -> float:
    """The longest a run of ``kind`` watched ``after`` seconds from its onset can last."""
    return after + (DROOP_ONSET_MAX_S if kind == FaultKind.SUPPLY_DROOP else 0.0)


def _run(
    kind: FaultKind | None,
    scenario: str,
    seed: int,
    channel: int | None = None,
    after: float = AFTER_S,
    calibrated: bool = True,
) -> tuple[Rig, np.ndarray, float, float, float]:
    """One scenario with ``kind`` injected (or none): (rig, true pose log, detection s,
    onset s, stop s), all from the injection; the onset is when the fault became one (a
    drooping regulator's output crossing the low mark), 0 for any other; the stop is when
    the loop let go of the platform (a trip) or held it (a low supply), NaN if it never
    did (a service warning leaves the loop running)."""
    rig = _rig("relaxed", seed, calibrated)
    _start(rig, scenario)
    rig.run({"holding": 0.1, "settling": 0.05}.get(scenario, 0.5), log_hz=0)
    rig.clear_log()
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    if kind is not None:
        default, value = FAULTS[kind]
        channel = default if channel is None else channel
        if kind == FaultKind.FT_OFFSET and channel >= 3:
            value = FT_TORQUE_OFFSET
        duration = 0.3 if kind == FaultKind.LEG_NOISE else math.inf
        hw.inject(Fault(kind, float(hw.state.time[0]), channel, value, duration))
    detect, onset, stop = watch(rig, kind, after)
    pose = rig.log[:, [COL[f"pose_{a}"] for a in AXES]]
    return rig, pose, detect, onset, stop


def watch(rig: Rig, kind: FaultKind | None, after: float) -> tuple[float, float, float]:
    """Run ``rig`` on from now, logging at 1 kHz, for ``after`` seconds from the onset of
    ``kind`` (injected now, or None): (detection s, onset s, stop s), all from now, NaN if
    never. The onset is when the fault became one (a drooping regulator's output crossing
    the low mark), now for any other; the stop is when the loop let go of the platform (a
    trip) or held it (a low supply, answered as the device service's mode machine does)."""
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    t0 = rig.time
    detect = onset = stop = math.nan
    step = 0.001
    low_mark = supervision.SupervisionConfig().supply_low + rig.config.atmosphere
    # Watched for ``after`` from the onset (the first step for every fault but a drooping
    # supply, whose output sags for 0.4-0.5 s before it is a fault at all).
    for _ in range(round(_watched_s(kind, after) / step)):
        if not math.isnan(onset) and rig.time - t0 >= onset + after - step / 2:
            break
        rig.run(step, log_hz=1000.0)
        # A sagging supply is a fault only from where it can no longer be trusted to carry
        # the foot (the low mark): until then there is nothing to detect. The supply is the
        # regulator's output: the manifold behind it dips up to 0.15 bar lower for a few
        # milliseconds each time valves draw, in healthy running too, which the supervision
        # is right to ride out (timed from the manifold's first dip, detection read 36 ms
        # longer: 64-72 ms against 31-35).
        sagging = kind == FaultKind.SUPPLY_DROOP and hw.state.supply[1] > low_mark
        if math.isnan(onset) and not sagging:
            onset = rig.time - t0 - step
        seen = rig.mode == Mode.FAULT or rig.supply_low or rig.service_chamber >= 0
        if math.isnan(detect) and seen:
            detect = rig.time - t0
        if math.isnan(stop) and (rig.mode == Mode.FAULT or rig.supply_low):
            stop = rig.time - t0
            if rig.mode != Mode.FAULT:
                # What the device service's mode machine does on a low supply
                # (device.modes): HOLD, every valve shut, the segment paused.
                rig.hold()
    return detect, onset, stop


def since_onset(detect: float, onset: float) -> float:
    """A detection time (s, from :func:`watch`) counted from the fault's onset instead: NaN
    if never noticed, 0 if noticed before the onset (a drooping supply whose manifold dipped
    under the low mark as intakes drew while the regulator's output was still above it)."""
    if math.isnan(detect):
        return math.nan
    if math.isnan(onset) or detect < onset:
        return 0.0
    return detect - onset


def noticed(rig: Rig) -> str:
    """What ``rig`` noticed: a service warning (``AIR_BALANCE (service)``), else its trip,
    else a low supply's hold (``SUPPLY_LOW (hold)``), or ``NONE``."""
    if rig.service_chamber >= 0 and rig.trip == Trip.NONE:
        return "AIR_BALANCE (service)"
    if rig.supply_low and rig.trip == Trip.NONE:
        return "SUPPLY_LOW (hold)"
    return rig.trip.name


def excursion(faulty: np.ndarray, healthy: np.ndarray, stop_row: int | None) -> np.ndarray:
    """Largest motion the fault caused, per axis: the departure from the same run without
    the fault while the loop runs, then, once it let go of the platform (a trip closes the
    valves) or held it (a low supply), the departure from where the run without the fault
    was at that moment (which goes on moving with the exercise)."""
    n = min(len(faulty), len(healthy))
    end = n if stop_row is None else min(stop_row + 1, n)
    before = np.abs(faulty[:end] - healthy[:end]).max(axis=0)
    if stop_row is None or stop_row >= n:
        whole: np.ndarray = before
        return whole
    after = np.abs(faulty[stop_row:] - healthy[stop_row]).max(axis=0)
    result: np.ndarray = np.maximum(before, after)
    return result


@functools.cache
def _healthy_pose(scenario: str, seed: int, after: float, calibrated: bool = True) -> np.ndarray:
    """The twin run without the fault: the same for every fault kind and channel (the plant
    and the controller are deterministic for a seed), so simulated once."""
    _, pose, _, _, _ = _run(None, scenario, seed, after=after, calibrated=calibrated)
    pose.flags.writeable = False
    return pose


@functools.cache
def _healthy_used_pose(
    scenario: str, seed: int, watched: float, after: float, calibrated: bool
) -> np.ndarray:
    """The twin of :func:`_then_used`: the same run without the fault, ``watched`` seconds
    from the moment of the injection, then the exercise watched ``after`` seconds."""
    rig, _, _, _, _ = _run(None, scenario, seed, after=watched, calibrated=calibrated)
    pose, _, _ = _then_used(rig, after)
    pose.flags.writeable = False
    return pose


def run_fault(
    kind: FaultKind,
    scenario: str,
    seed: int = 1,
    channel: int | None = None,
    after: float = AFTER_S,
    calibrated: bool = True,
) -> FaultRun:
    """``kind`` injected in ``scenario`` on ``channel`` (default: the one of FAULTS), watched
    for ``after`` seconds, on the nominal unit with its calibration (or without)."""
    healthy = _healthy_pose(scenario, seed, _watched_s(kind, after), calibrated)
    channel = FAULTS[kind][0] if channel is None else channel
    rig, pose, detect, onset, stop = _run(kind, scenario, seed, channel, after, calibrated)
    # Against the healthy twin while the loop runs (a service warning leaves it running),
    # then against where the twin was when the loop let go of the platform or held it.
    row = None if math.isnan(stop) else round(stop * 1000.0)
    moved = excursion(pose, healthy, row)
    trip = rig.trip
    dormant = False
    params = rig.hardware.params if isinstance(rig.hardware, SimulatedHardware) else None
    if kind == FaultKind.VALVE_STUCK_CLOSED:
        slots = rig.log[:, COL[f"slots{channel // 2}"]]
        dormant = not bool((slots > 0).any() if channel % 2 == 0 else (slots < 0).any())
    elif kind == FaultKind.PRESSURE_STUCK and channel < 12 and params is not None:
        true = rig.log[:, COL[f"pressure_g{channel}"]]
        dormant = float(np.ptp(true)) <= DORMANT_COUNTS * params.pressure_lsb
    elif kind == FaultKind.LEG_STUCK and params is not None:
        true = rig.log[:, COL[f"leg_x{channel}"]]
        dormant = float(np.ptp(true)) <= DORMANT_COUNTS * params.leg_lsb
    service = rig.service_chamber >= 0 and trip == Trip.NONE
    seen, seen_channel = noticed(rig), rig.service_chamber if service else rig.trip_channel
    used: dict[str, Any] = {}
    if math.isnan(detect):
        # Unnamed: does the exercise that follows name it once it uses the part?
        watched = round(len(pose) * 1e-3, 3)  # logged at 1 kHz from the injection
        used_pose, used_detect, used_stop = _then_used(rig, after)
        twin = _healthy_used_pose(scenario, seed, watched, after, calibrated)
        used_row = None if math.isnan(used_stop) else round(used_stop * 1000.0)
        used_moved = excursion(used_pose, twin, used_row)
        used = {
            "used_trip": noticed(rig),
            "used_detect_ms": used_detect * 1e3,
            "used_excursion_deg": float(np.degrees(used_moved[3:].max())),
            "used_excursion_mm": float(used_moved[:3].max() * 1e3),
        }
    return FaultRun(
        kind=kind.name,
        scenario=scenario,
        seed=seed,
        injected=channel,
        detected=not math.isnan(detect),
        trip=seen,
        channel=seen_channel,
        detect_ms=since_onset(detect, onset) * 1e3,
        onset_ms=onset * 1e3,
        excursion_deg=float(np.degrees(moved[3:].max())),
        excursion_mm=float(moved[:3].max() * 1e3),
        dormant=dormant,
        **used,
    )


@dataclass(frozen=True)
class HealthyRun:
    exercise: str
    patient: str
    seed: int
    seconds: float
    trip: str
    """NONE unless the healthy run tripped (a false trip)."""
    supply_low: bool
    service: bool
    """The device asked for service (a chamber's air did not add up): a false alarm here."""
    residual_max_n: float
    """Largest filtered force-balance residual seen (N): the margin to its limit."""
    plant: str = "nominal"
    """The plant: ``nominal``, or ``draw N`` (a drawn build, calibrated as the device is)."""
    wrench_force_max_n: float = 0.0
    """Largest filtered residual force of the legs against the force sensor (N)."""
    wrench_torque_max_nm: float = 0.0
    """...and torque (N m)."""
    air_flow_max: float = 0.0
    """Largest chamber air residual as a share of its tolerance (1 would ask for service)."""
    rings: int = 0
    """Rings the guard saw and damped (device.ring): a foot made the loop ring."""
    turn_share_max: float = 0.0
    """Largest share of its allowance the moment residual took (1 names a torque offset)."""
    lift_share_max: float = 0.0
    """...and the vertical residual (1 names a vertical force offset; 0 where the unit's
    load bias was not identified and the vertical check does not judge)."""
    answer_max: float = 0.0
    """How near a valve came to not answering its sure pulses (1 asks for service; 0 where
    the valves were not identified and the answer rule does not judge)."""
    steady_share_max: float = 0.0
    """Largest share of its floor the force-balance residual of a leg that carried it alone
    took (1 for 0.1 s names that leg, ``FORCE_BALANCE``; 0 where the seals were not
    identified and the rule does not judge)."""


def _library_targets(
    kind: ExerciseKind,
) -> tuple[dict[str, AxisTarget], np.ndarray, np.ndarray, list[bool]]:
    template = EXERCISE_LIBRARY[kind]
    body = template.defaults
    targets: dict[str, AxisTarget] = {}
    K, B = np.zeros(6), np.zeros(6)
    compliant = [False] * 6
    for a in body.axes:
        k = AXIS_INDEX[a.axis]
        if a.waveform == "sine":
            targets[a.axis] = AxisTarget(
                Waveform.SINE, math.radians(a.center), math.radians(a.amplitude), a.frequency
            )
        else:
            targets[a.axis] = AxisTarget(Waveform.HOLD, math.radians(a.center))
        if template.compliant:
            K[k], B[k], compliant[k] = a.stiffness, a.damping, True
    return targets, K, B, compliant


def _drawn_rig(patient: str, draw: int) -> Rig:
    """Drawn build ``draw``, calibrated by its start-up identification as the device is."""
    from device.plant.params import draw_plant
    from lab.experiments import calibration_of

    cfg = draw_plant(draw, patient)
    config = ControllerConfig(calibration=calibration_of(cfg))
    return Rig(SimulatedHardware(cfg, seed=draw), config=config)


def start_exercise(rig: Rig, kind: ExerciseKind) -> None:
    """Start the library's ``kind`` at mid stroke with its defaults, the patient pushing a
    0.3 Hz, 5 N m torque on each prescribed axis from 0.5 s on."""
    targets, K, B, compliant = _library_targets(kind)
    rig.move_legs(np.full(6, 0.5 * rig.geometry.stroke))
    rig.run(0.5, log_hz=0)
    if any(compliant):
        rig.set_impedance(K, B, compliant)
    rig.track(targets)
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    for axis in targets:
        hw.script_torque(AXIS_INDEX[axis], SCRIPT_SINE, rig.time + 0.5, 5.0, 0.3)


def healthy_runs(
    seeds: tuple[int, ...] = (1, 2, 3),
    seconds: float = 10.0,
    progress: Callable[[str], None] | None = None,
    draws: tuple[int, ...] = (),
    calibrated: bool = True,
) -> list[HealthyRun]:
    """Every exercise of the library, a relaxed and a resisting patient who also pushes
    (a 0.3 Hz torque on each prescribed axis), on a healthy plant: any trip is false. The
    nominal plant with each of ``seeds`` (with its calibration, or without), then each
    drawn build of ``draws`` (always with its own)."""
    runs = []
    plants = [("nominal", seed) for seed in seeds] + [(f"draw {d}", d) for d in draws]
    total = len(EXERCISE_LIBRARY) * 2 * len(plants)
    for kind in EXERCISE_LIBRARY:
        for patient in ("relaxed", "resisting"):
            for plant, seed in plants:
                if plant == "nominal":
                    rig = _rig(patient, seed, calibrated)
                else:
                    rig = _drawn_rig(patient, seed)
                start_exercise(rig, kind)
                worst = 0.0
                monitor = rig.state.monitor
                peaks = slice(supervision.M_WRENCH_PEAK, supervision.M_WRENCH_PEAK + 2)
                monitor[peaks] = 0.0
                monitor[supervision.M_OBS_PEAK] = 0.0
                monitor[supervision.M_TURN_PEAK] = 0.0
                monitor[supervision.M_LIFT_PEAK] = 0.0
                monitor[supervision.M_ANSWER_PEAK] = 0.0
                monitor[supervision.M_STEADY_PEAK] = 0.0
                for _ in range(round(seconds / 0.05)):
                    rig.run(0.05, log_hz=0)
                    residual = monitor[supervision.M_RESIDUAL : supervision.M_RESIDUAL + 6]
                    worst = max(worst, float(np.abs(residual).max()))
                    if rig.mode == Mode.FAULT:
                        break
                runs.append(
                    HealthyRun(
                        kind.value,
                        patient,
                        seed,
                        seconds,
                        rig.trip.name,
                        rig.supply_low,
                        rig.service_chamber >= 0,
                        worst,
                        plant,
                        float(monitor[supervision.M_WRENCH_PEAK]),
                        float(monitor[supervision.M_WRENCH_PEAK + 1]),
                        float(monitor[supervision.M_OBS_PEAK]),
                        int(rig.state.istate[I_RINGS]),
                        float(monitor[supervision.M_TURN_PEAK]),
                        float(monitor[supervision.M_LIFT_PEAK]),
                        float(monitor[supervision.M_ANSWER_PEAK]),
                        float(monitor[supervision.M_STEADY_PEAK]),
                    )
                )
                if progress is not None:
                    progress(f"healthy {len(runs)}/{total}: {kind.value}, {patient}, {plant}")
    return runs


def fault_matrix(
    seeds: tuple[int, ...] = (1,),
    progress: Callable[[str], None] | None = None,
    kinds: tuple[FaultKind, ...] = tuple(FAULTS),
    after: float = AFTER_S,
    calibrated: bool = True,
) -> list[FaultRun]:
    """Each of ``kinds`` on each of its :data:`CHANNELS` in every situation, each watched for
    ``after`` seconds, on the nominal unit with its calibration (or without)."""
    runs = []
    total = sum(len(CHANNELS[k]) for k in kinds) * len(MATRIX_SCENARIOS) * len(seeds)
    for kind in kinds:
        for channel in CHANNELS[kind]:
            for scenario in MATRIX_SCENARIOS:
                for seed in seeds:
                    r = run_fault(kind, scenario, seed, channel, after, calibrated)
                    runs.append(r)
                    if progress is not None:
                        progress(
                            f"faults {len(runs)}/{total}: {kind.name} ch {channel} while {scenario}"
                        )
    return runs


# -- boundary commands through the real service ----------------------------------------


def _near(bound: float, rng: np.random.Generator) -> float:
    """A float32 at, just inside, just outside or a little off ``bound``."""
    b = np.float32(bound)
    choice = int(rng.integers(0, 4))
    if choice == 0:
        return float(b)
    if choice == 1:
        return float(np.nextafter(b, np.float32(np.inf)))
    if choice == 2:
        return float(np.nextafter(b, np.float32(-np.inf)))
    return float(np.float32(bound * (1.0 + rng.uniform(-0.05, 0.05))))


def boundary_run(
    count: int = 200, seed: int = 1, calibrated: bool = True
) -> tuple[int, int, int, int]:
    """Segments, impedance changes and configurations at and around every published bound,
    sent to the real service over a pty. Returns (sent, mismatched with the check module,
    service deaths, trips the accepted commands caused)."""
    import asyncio
    import dataclasses
    import threading

    from device import commands
    from device.client import CommandRefused, DeviceClient, build_segment
    from device.protocol.messages import DeviceMode
    from device.service import DeviceService, ServiceConfig
    from device.transport import PtyLink

    link = PtyLink()
    service = DeviceService(_rig("relaxed", seed, calibrated), link, ServiceConfig())
    thread = threading.Thread(target=service.run, daemon=True)
    thread.start()
    rng = np.random.default_rng(seed)
    lim = service.rig.limits
    mismatched = sent = 0

    async def main() -> None:
        nonlocal mismatched, sent
        dev = await DeviceClient.connect(link.name)
        try:
            assert dev.hello is not None
            await dev.arm_home()
            await dev.wait_for_mode(DeviceMode.READY, timeout=30.0)
            base = build_segment(dev.hello, 1, 0.05, {})
            for n in range(count):
                seg = base
                k = int(rng.integers(0, 6))
                which = int(rng.integers(0, 5))

                def put(name: str, value: object, seg: object = seg, k: int = k) -> object:
                    values = list(getattr(seg, name))
                    values[k] = value
                    return dataclasses.replace(seg, **{name: tuple(values)})  # type: ignore[type-var]

                if which == 0:
                    seg = put("center", _near(lim.rom_high[k], rng))  # type: ignore[assignment]
                elif which == 1:
                    seg = put("center", _near(lim.rom_low[k], rng))  # type: ignore[assignment]
                elif which in (2, 3):
                    field_ = "stiffness" if which == 2 else "damping"
                    top = lim.stiffness_max[k] if which == 2 else lim.damping_max[k]
                    seg = put("compliant", True)  # type: ignore[assignment]
                    seg = put(field_, _near(top, rng), seg)  # type: ignore[assignment]
                    other = "damping" if which == 2 else "stiffness"
                    seg = put(other, 1.0, seg)  # type: ignore[assignment]
                else:
                    seg = dataclasses.replace(seg, torque_limit=_near(lim.torque_limit, rng))
                seg = dataclasses.replace(seg, segment_id=n + 1)
                ctx = commands.Context(lim, service.rig.geometry, service.mode, service.rig.trip)
                try:
                    commands.check(seg, ctx)
                    expected = True
                except commands.CommandError:
                    expected = False
                try:
                    await dev.start_segment(seg)
                    got = True
                except CommandRefused:
                    got = False
                sent += 1
                mismatched += expected != got
                if service.mode == DeviceMode.FAULT:
                    break
            # The last accepted segment runs to its end: the device must come back READY.
            await dev.wait_for_mode(DeviceMode.READY, timeout=60.0)
            for hz, ms in (
                (dev.hello.telemetry_hz_max, 200),
                (dev.hello.telemetry_hz_max + 1, 200),
            ):
                sent += 1
                try:
                    await dev.configure(hz, ms)
                    mismatched += hz > dev.hello.telemetry_hz_max
                except CommandRefused:
                    mismatched += hz <= dev.hello.telemetry_hz_max
        finally:
            await dev.close()

    try:
        asyncio.run(main())
    finally:
        alive = thread.is_alive()
        service.stop()
        thread.join(5.0)
        service.shutdown()
    deaths = int(not alive) + service.software_faults
    trips = int(service.rig.trip != Trip.NONE)
    return sent, mismatched, deaths, trips


# -- the stiffness-damping grid --------------------------------------------------------


def kb_point(
    axis: int, k: float, b: float, patient: str, seed: int = 1, draw: int | None = None
) -> tuple[bool, bool, float, int]:
    """Render K, B on one rotational axis and push it (2 N m for 0.1 s), measured as
    ``lab.envelope`` measures its maps: (stable, walked, detrended peak to peak of the last
    second in degrees). Stable as the issue asks: no trip (a push the legs cannot follow
    included), at most 0.2 deg peak to peak, and no chattering command either (the loop
    driven at 60-125 Hz, which the platform filters but the legs and valves do not).
    Walked: the platform came to rest more than 0.5 deg from its command, the envelope's
    stricter criterion, which is no oscillation: counted apart. Rings: how many the ring
    guard saw and damped (device.ring) before the last second was judged. ``draw``: on that
    drawn build, identified and run with its calibration; None: the standard plant."""
    from lab import envelope

    unit = None if draw is None else PlantChoice(draw=draw)
    point = envelope.run_point(AXES[axis], patient, k, b, seed=seed, unit=unit)
    chatter = bool(point["cmd_pp_deg"] > envelope.CMD_PP_LIMIT_DEG)
    stable = not (point["unstable"] or point["speed_trip"] or chatter)
    walked = bool(abs(point["walk_deg"]) > envelope.WALK_LIMIT_DEG)
    return stable, walked, float(point["pp_det_deg"]), int(point["rings"])


# -- the benchmark ------------------------------------------------------------------------

TARGETS: tuple[Target, ...] = (
    Target("faults_undetected", "faults not detected", 0, "eq"),
    Target("detect_ms_max", "detection time, worst (ms)", 50.0, "max"),
    Target("excursion_deg_max", "excursion after injection, worst (deg)", 2.0, "max"),
    Target("excursion_mm_max", "excursion after injection, worst (mm)", 3.0, "max"),
    Target("false_trips", "false trips over the healthy runs", 0, "eq"),
    Target("service_deaths", "service deaths in the boundary run", 0, "eq"),
    Target("boundary_mismatches", "boundary answers unlike the check module", 0, "eq"),
    Target("kb_grid_unstable", "unstable points on and inside the envelope's edge", 0, "eq"),
)

ROWS: tuple[tuple[str, str], ...] = (
    ("faults_total", "faults injected (kind x channel x situation)"),
    ("faults_detected", "faults detected"),
    ("faults_undetected", "faults not detected"),
    (
        "faults_undetected_dormant",
        "...of them dormant: a valve never told to open, a frozen reading that stayed true",
    ),
    ("faults_named_once_used", "...of them named once the exercise that followed used the part"),
    ("faults_never_named", "...of them not named then either"),
    ("used_detect_ms_max", "...named that long after the exercise began, worst (ms)"),
    ("used_excursion_deg_max", "...the platform off the same exercise without it, worst (deg)"),
    ("used_excursion_mm_max", "...the platform off the same exercise without it, worst (mm)"),
    ("detect_ms_max", "detection time, worst (ms)"),
    ("detect_ms_p50", "detection time, median (ms)"),
    ("excursion_deg_max", "excursion after injection, worst (deg)"),
    ("excursion_mm_max", "excursion after injection, worst (mm)"),
    ("healthy_seconds", "healthy exercise time simulated (s)"),
    ("false_trips", "false trips over the healthy runs"),
    ("residual_max_n", "largest healthy force-balance residual (N, limit 30)"),
    ("wrench_force_max_n", "largest healthy residual force, legs vs force sensor (N, limit 45)"),
    ("wrench_torque_max_nm", "largest healthy residual torque (N m, limit 5.5)"),
    ("turn_share_max", "largest healthy moment residual (share of its allowance, limit 1)"),
    ("lift_share_max", "largest healthy vertical residual (share of its allowance, limit 1)"),
    ("air_flow_max", "largest healthy chamber air residual (share of its tolerance)"),
    ("answer_max", "nearest a healthy valve came to not answering its pulses (limit 1)"),
    (
        "steady_share_max",
        "largest healthy residual a leg carried alone (share of its floor, limit 1 for 0.1 s)",
    ),
    ("boundary_commands", "boundary commands sent to the service"),
    ("boundary_mismatches", "boundary answers unlike the check module"),
    ("service_deaths", "service deaths in the boundary run"),
    (
        "kb_grid_points",
        "K-B points on the envelope's edge and at twice its B (nominal, 3 builds, 4 patients)",
    ),
    ("kb_grid_unstable", "unstable points on and inside the envelope's edge"),
    ("kb_grid_walked", "...still points that rested over 0.5 deg from their command"),
    ("kb_grid_guarded", "...points where the ring guard raised the damping"),
    ("healthy_rings", "rings the guard damped over the healthy runs"),
)

KB_STIFFNESS = (0.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 150.0, 170.0, 200.0, 250.0, 350.0, 500.0)
"""Every band edge of the envelope, its ends, and K = 150-250 closely: there yaw with a
resisting foot rang at 13 Hz inside the envelope (B 0.2-0.5) while the virtual frequency
was capped at 12 Hz, between grid points 100 and 200 of the first grid."""

KB_DAMPING_FACTORS = (1.0, 2.0)
"""Each K at the envelope's least B and at twice it: on the edge and inside."""


KB_DRAWS = (15, 18, 19)
"""Drawn builds the K-B grid also runs on, each identified and run with its calibration:
the ones whose boundaries set the published envelope (docs/envelope.md, section 6): a
light, long-tubed, low-friction platform, and long tubes with a resisting foot in roll."""


KB_PATIENTS = ("relaxed", "resisting", "absent", "stiff")
"""The plant's three patients on each unit's own drawn ankle, and a patient who resists on
the stiffest ankle of the plausible range (``lab.envelope.STIFF``): the ankle is the
patient's, and any patient may stand on any build."""


def kb_grid(
    patients: tuple[str, ...] = KB_PATIENTS,
    progress: Callable[[str], None] | None = None,
    draws: tuple[int | None, ...] = (None, *KB_DRAWS),
) -> list[tuple[str, float, float, str, bool, float, str, bool, int]]:
    """Every rotational axis, every grid K, at the least damping the envelope allows and at
    twice it (:data:`KB_DAMPING_FACTORS`), on the standard plant (None) and on each drawn
    build of ``draws``. Each row: axis, K, B, patient, stable, peak to peak, the unit
    (``nominal`` or ``build N``), whether it walked and the rings the guard damped
    (:func:`kb_point`)."""
    from device.limits import SafetyLimits

    lim = SafetyLimits().published()
    out = []
    total = 3 * len(KB_STIFFNESS) * len(KB_DAMPING_FACTORS) * len(patients) * len(draws)
    grid = itertools.product(draws, (3, 4, 5), KB_STIFFNESS, KB_DAMPING_FACTORS, patients)
    for draw, axis, k, factor, patient in grid:
        unit = "nominal" if draw is None else f"build {draw}"
        b = factor * lim.damping_min_at(axis, k)
        stable, walked, pp, rings = kb_point(axis, k, b, patient, draw=draw)
        out.append((AXES[axis], k, b, patient, stable, pp, unit, walked, rings))
        if progress is not None:
            progress(f"K-B grid {len(out)}/{total}: {unit} {AXES[axis]} K {k:g} B {b:g}")
    return out


HEALTHY_DRAWS = tuple(range(12))
"""Drawn builds the healthy runs also cover (draw 11 has the valves whose timing is furthest
from the type's, the hardest case for the chambers' air observer)."""


def _fault_summary(faults: list[FaultRun]) -> dict[str, Any]:
    """The fault matrix's keys of the benchmark."""
    detected = [f for f in faults if f.detected]
    times = sorted(f.detect_ms for f in detected)
    return {
        "faults_total": len(faults),
        "faults_detected": len(detected),
        "faults_undetected": len(faults) - len(detected),
        "faults_undetected_dormant": sum(f.dormant and not f.detected for f in faults),
        "detect_ms_max": max(times) if times else math.nan,
        "detect_ms_p50": float(np.median(times)) if times else math.nan,
        "excursion_deg_max": max(f.excursion_deg for f in faults),
        "excursion_mm_max": max(f.excursion_mm for f in faults),
        **_used_summary([f for f in faults if not f.detected]),
        "faults": [dataclasses.asdict(f) for f in faults],
    }


def _used_summary(missed: list[FaultRun]) -> dict[str, Any]:
    """What the exercise that followed made of the faults left unnamed while watched."""
    named = [f for f in missed if not math.isnan(f.used_detect_ms)]
    return {
        "faults_named_once_used": len(named),
        "faults_never_named": len(missed) - len(named),
        "used_detect_ms_max": max((f.used_detect_ms for f in named), default=math.nan),
        "used_excursion_deg_max": max((f.used_excursion_deg for f in missed), default=0.0),
        "used_excursion_mm_max": max((f.used_excursion_mm for f in missed), default=0.0),
    }


def run(
    progress: Callable[[str], None] | None = None,
    seeds: tuple[int, ...] = (1, 2),
    draws: tuple[int, ...] = HEALTHY_DRAWS,
    only: tuple[FaultKind, ...] = (),
    after: float = AFTER_S,
    calibrated: bool = True,
) -> dict[str, Any]:
    """Everything ``ankle bench safety`` measures, as one JSON-able object. With ``only``,
    just the fault matrix of those kinds (to reproduce one fault quickly); ``after`` is how
    long each injected run is watched; ``calibrated=False``: the nominal unit without its
    start-up identification (the drawn builds and the K-B grid are as always)."""
    started = time.perf_counter()
    kinds = only or tuple(FAULTS)
    faults = fault_matrix(
        seeds=(1,), progress=progress, kinds=kinds, after=after, calibrated=calibrated
    )
    out: dict[str, Any] = {**_fault_summary(faults), "after_s": after, "calibrated": calibrated}
    if only:
        out["only"] = [k.name for k in only]
    else:
        out.update(_the_rest(progress, seeds, draws, calibrated))
    out["wall_s"] = time.perf_counter() - started
    out["targets_met"] = {t.key: t.met(float(out[t.key])) for t in TARGETS if t.key in out}
    return out


def _the_rest(
    progress: Callable[[str], None] | None,
    seeds: tuple[int, ...],
    draws: tuple[int, ...],
    calibrated: bool,
) -> dict[str, Any]:
    """The healthy runs, the boundary commands and the K-B grid."""
    healthy = healthy_runs(seeds=seeds, progress=progress, draws=draws, calibrated=calibrated)
    if progress is not None:
        progress("boundary commands through the service")
    sent, mismatched, deaths, boundary_trips = boundary_run(calibrated=calibrated)
    grid = kb_grid(progress=progress)
    return {
        "healthy_seconds": sum(h.seconds for h in healthy),
        "false_trips": sum(h.trip != Trip.NONE.name or h.supply_low or h.service for h in healthy),
        "residual_max_n": max(h.residual_max_n for h in healthy),
        "wrench_force_max_n": max(h.wrench_force_max_n for h in healthy),
        "wrench_torque_max_nm": max(h.wrench_torque_max_nm for h in healthy),
        "turn_share_max": max(h.turn_share_max for h in healthy),
        "lift_share_max": max(h.lift_share_max for h in healthy),
        "air_flow_max": max(h.air_flow_max for h in healthy),
        "answer_max": max(h.answer_max for h in healthy),
        "steady_share_max": max(h.steady_share_max for h in healthy),
        "healthy_plants": sorted({h.plant for h in healthy}),
        "boundary_commands": sent,
        "boundary_mismatches": mismatched,
        "service_deaths": deaths,
        "boundary_trips": boundary_trips,
        "kb_grid_points": len(grid),
        "kb_grid_unstable": sum(not g[4] for g in grid),
        "kb_grid_walked": sum(g[4] and g[7] for g in grid),
        "kb_grid_guarded": sum(g[8] > 0 for g in grid),
        "healthy_rings": sum(h.rings for h in healthy),
        "healthy": [dataclasses.asdict(h) for h in healthy],
        "false_trip_runs": [
            dataclasses.asdict(h)
            for h in healthy
            if h.trip != Trip.NONE.name or h.supply_low or h.service
        ],
        "kb_grid_units": sorted({g[6] for g in grid}),
        "kb_grid": [
            {
                "axis": a,
                "k": k,
                "b": b,
                "patient": pt,
                "stable": st,
                "pp_deg": pp,
                "unit": u,
                "walked": w,
                "rings": n,
            }
            for a, k, b, pt, st, pp, u, w, n in grid
        ],
    }


def fault_table(result: dict[str, Any]) -> str:
    """One row per fault kind: how it was detected, the worst time and motion."""
    lines = [
        "| fault | trip | detected | worst detection (ms) | worst excursion (deg / mm) |",
        "|---|---|---|---:|---:|",
    ]
    by_kind: dict[str, list[dict[str, Any]]] = {}
    for f in result["faults"]:
        by_kind.setdefault(f["kind"], []).append(f)
    for kind, runs in by_kind.items():
        lines.append(_fault_row(kind, runs))
    return "\n".join(lines)


def _nan(value: float | None) -> bool:
    """No number: NaN in the result as run, null in its JSON."""
    return value is None or math.isnan(value)


def _fault_row(kind: str, runs: list[dict[str, Any]]) -> str:
    found = [r for r in runs if r["detected"]]
    trips = sorted({r["trip"] for r in found})
    missed = [r for r in runs if not r["detected"]]
    channels = {r["injected"] for r in runs}
    named = [r["scenario"] + (f" ch {r['injected']}" if len(channels) > 1 else "") for r in missed]
    if len(missed) > 6:  # too many to name: how many in each situation
        named = [f"{sum(r['scenario'] == sc for r in missed)} {sc}" for sc in MATRIX_SCENARIOS]
    where = "missed: " + ", ".join(named) if missed else "all"
    dormant = sum(r.get("dormant", False) for r in missed)
    if dormant:
        what = "never told to open" if kind == "VALVE_STUCK_CLOSED" else "frozen on a true value"
        where += f"; {dormant} of them {what}"
    if missed and all("used_trip" in r for r in missed):
        used = [r for r in missed if not _nan(r["used_detect_ms"])]
        if used:
            where += (
                f"; {len(used)} of {len(missed)} named once the next exercise used them, "
                f"within {max(r['used_detect_ms'] for r in used):.0f} ms"
            )
        else:
            where += "; none named once the next exercise used them"
    worst = f"{max(r['detect_ms'] for r in found):.0f}" if found else "-"
    deg = max(r["excursion_deg"] for r in runs)
    mm = max(r["excursion_mm"] for r in runs)
    return (
        f"| {kind.lower()} | {', '.join(trips) or '-'} | {len(found)} of {len(runs)} ({where}) "
        f"| {worst} | {deg:.2f} / {mm:.2f} |"
    )


def table(result: dict[str, Any]) -> str:
    """The rows the result has (a run of ``only`` some kinds has the fault rows alone)."""
    rows = tuple(r for r in ROWS if r[0] in result)
    return render(result, rows, TARGETS) + "\n\n" + fault_table(result)


def main() -> None:
    t = time.perf_counter()
    for h in healthy_runs():
        print(
            f"{h.exercise:16s} {h.patient:9s} seed {h.seed} trip {h.trip} "
            f"low {h.supply_low} service {h.service} residual {h.residual_max_n:.1f} N"
        )
    for r in fault_matrix():
        print(
            f"{r.kind:20s} {r.scenario:9s} {'yes' if r.detected else 'NO ':3s} "
            f"{r.trip:18s} ch {r.channel:2d} {r.detect_ms:7.1f} ms "
            f"{r.excursion_deg:6.2f} deg {r.excursion_mm:6.2f} mm"
        )
    print(f"{time.perf_counter() - t:.1f} s")


if __name__ == "__main__":
    main()
