"""Faults the matrix does not name: drawn at random, each against its twins.

The fault matrix of :mod:`lab.safety` injects every fault kind on every channel, but in
four situations, at one size, on the nominal unit: a supervision tuned to it could pass it
and still miss the same fault elsewhere. Here each run draws, from one seed:

- an exercise of the library with its defaults, started at mid stroke, and a relaxed or a
  resisting patient who pushes a 0.3 Hz, 5 N m torque on each prescribed axis (as the
  healthy runs of :mod:`lab.safety`);
- the unit: the nominal one or a drawn build (:func:`device.plant.params.draw_plant`, 0-99),
  calibrated by its start-up identification as the device is;
- the fault kind, a channel it can strike, a size (the matrix's times 0.3, 0.6, 1 or 2 for
  the kinds that have one; a drooping supply sags to 1-4 bar), and the moment, 1-8 s into
  the exercise.

Each drawn fault runs three times from the same state: with the fault; without it (the
healthy twin, whose trip would be a false one and makes the draw invalid); and with an
e-stop at the injection's moment instead (the *safe state's own give*: every valve shut,
the foot still pushing on the trapped air). The excursion is measured as the matrix
measures it (:func:`lab.safety.excursion`): against the twin while the loop runs, then
against where the twin was when the loop let go. Its part before the loop let go is the
fault's alone; after, the platform is on the trapped air like the e-stop's, and the e-stop
twin says how far a healthy unit gives there with that patient at that moment.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from device.axes import AXES
from device.hardware import SimulatedHardware
from device.plant.faults import Fault, FaultKind
from device.rig import Rig
from device.tickloop import COL
from device.trips import Trip
from lab.safety import (
    AFTER_S,
    CHANNELS,
    FAULTS,
    FT_TORQUE_OFFSET,
    _drawn_rig,
    _rig,
    excursion,
    noticed,
    since_onset,
    start_exercise,
    watch,
)
from lab.targets import Target
from lab.targets import table as render
from sessions.prescription import EXERCISE_LIBRARY, ExerciseKind

SIZES = (0.3, 0.6, 1.0, 2.0)
"""Multiples of the matrix's size drawn for the kinds that have a size."""
SIZED = (
    FaultKind.PRESSURE_OFFSET,
    FaultKind.LEG_OFFSET,
    FaultKind.LEG_NOISE,
    FaultKind.FT_OFFSET,
    FaultKind.CHAMBER_LEAK,
)
BUILDS = 100
"""Drawn builds 0-99, or the nominal unit (one chance in ten)."""
AT_S = (1.0, 8.0)
"""The injection's moment, drawn between these many seconds into the exercise."""


_TRANSDUCER = frozenset({"PRESSURE_SENSOR", "FORCE_BALANCE", "AIR_BALANCE (service)", "VALVE"})
_LEG = frozenset({"LEG_SENSOR", "KINEMATICS", "AIR_BALANCE (service)"})
_FT = frozenset({"FORCE_SENSOR", "FOLLOWING"})
_AIR = frozenset({"VALVE", "AIR_BALANCE (service)", "FORCE_BALANCE", "FOLLOWING"})
_SUPPLY = frozenset({"SUPPLY_LOSS", "SUPPLY_LOW (hold)"})
RIGHT_NAMES: dict[FaultKind, frozenset[str]] = {
    FaultKind.SUPPLY_LOSS: _SUPPLY,
    FaultKind.SUPPLY_DROOP: _SUPPLY,
    FaultKind.PRESSURE_OPEN: _TRANSDUCER,
    FaultKind.PRESSURE_SHORT: _TRANSDUCER,
    FaultKind.PRESSURE_STUCK: _TRANSDUCER,
    FaultKind.PRESSURE_OFFSET: _TRANSDUCER,
    FaultKind.LEG_STUCK: _LEG,
    FaultKind.LEG_OFFSET: _LEG,
    FaultKind.LEG_NOISE: _LEG,
    FaultKind.FT_DEAD: _FT,
    FaultKind.FT_SATURATED: _FT,
    FaultKind.FT_OFFSET: _FT,
    FaultKind.VALVE_STUCK_OPEN: _AIR,
    FaultKind.VALVE_STUCK_CLOSED: _AIR,
    FaultKind.CHAMBER_LEAK: _AIR,
}
"""What a fault of each kind may be named (:func:`lab.safety.noticed`, the last word: a trip
after a service warning is what the technician reads): the trips whose sentence
(device.trips) sends the technician to the part that failed. A pressure transducer's fault
also reads as its chamber's air or its leg's forces not adding up, whose sentences name the
transducer; a leg sensor's as its chamber's air (the volume it reads is off; that sentence
names the length sensor); a force/torque sensor's as the platform pushed off its pose
(FOLLOWING: "check the foot's force/torque sensor zero" first); a valve's or a leak's as
any of the air's checks or the pose pushed off. Anything else (a length sensor named for a
transducer, a range or speed limit that stopped what nothing named) sends the technician
elsewhere."""


def misnamed(kind: str, trip: str) -> bool:
    """Whether a fault of ``kind`` (a :class:`FaultKind` name), noticed as ``trip`` (a
    :func:`lab.safety.noticed` answer), was named as another part; False if unnoticed."""
    return trip != "NONE" and trip not in RIGHT_NAMES[FaultKind[kind]]


@dataclass(frozen=True)
class Draw:
    exercise: str
    patient: str
    unit: int
    """-1: the nominal unit; else the drawn build's number."""
    kind: str
    channel: int
    value: float
    at_s: float


@dataclass(frozen=True)
class DrawnRun:
    draw: Draw
    valid: bool
    """False when the healthy twin tripped or warned (a false trip, reported as such)."""
    twin_trip: str
    detected: bool
    trip: str
    """The trip, ``SUPPLY_LOW (hold)`` or ``AIR_BALANCE (service)``, ``NONE`` if unseen."""
    detect_ms: float
    """From the fault's onset (:func:`lab.safety.since_onset`): the injection, or where a
    drooping supply's regulator output crossed the low mark."""
    excursion_deg: float
    excursion_mm: float
    while_running_deg: float
    """The part before the loop let go (or all of it, if it never did): the fault's alone."""
    while_running_mm: float
    estop_deg: float
    """How far the platform gave over the same watch after an e-stop at the injection."""
    estop_mm: float


def draw(rng: np.random.Generator) -> Draw:
    """One fault, situation and unit, drawn as the module's docstring says."""
    exercises = list(EXERCISE_LIBRARY)
    kinds = list(CHANNELS)
    exercise = exercises[int(rng.integers(len(exercises)))]
    patient = ("relaxed", "resisting")[int(rng.integers(2))]
    unit = -1 if rng.random() < 0.1 else int(rng.integers(BUILDS))
    kind = kinds[int(rng.integers(len(kinds)))]
    channels = CHANNELS[kind]
    channel = int(channels[int(rng.integers(len(channels)))])
    value = FAULTS[kind][1]
    if kind == FaultKind.FT_OFFSET and channel >= 3:
        value = FT_TORQUE_OFFSET
    size = float(SIZES[int(rng.integers(len(SIZES)))])
    if kind in SIZED:
        value *= size
    if kind == FaultKind.SUPPLY_DROOP:
        value = float(rng.uniform(1.0, 4.0))
    at_s = float(rng.uniform(*AT_S))
    return Draw(exercise.value, patient, unit, kind.name, channel, value, at_s)


def _unit(d: Draw) -> Rig:
    return _rig(d.patient, 1) if d.unit < 0 else _drawn_rig(d.patient, d.unit)


def _watch(d: Draw, what: str, after: float) -> tuple[Rig, np.ndarray, float, float]:
    """``what`` (fault, twin or estop) from ``d.at_s`` into the exercise, watched as the
    matrix watches (:func:`lab.safety.watch`): (rig, true pose log, detection s from the
    fault's onset, stop s from the injection). A twin that tripped before the fault's
    moment comes back with an empty log."""
    rig = _unit(d)
    start_exercise(rig, ExerciseKind(d.exercise))
    rig.run(d.at_s, log_hz=0)
    if what == "twin" and noticed(rig) != Trip.NONE.name:
        return rig, np.zeros((0, 6)), math.nan, math.nan  # a false trip
    rig.clear_log()
    kind = FaultKind[d.kind]
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    if what == "fault":
        duration = 0.3 if kind == FaultKind.LEG_NOISE else math.inf
        hw.inject(Fault(kind, float(hw.state.time[0]), d.channel, d.value, duration))
    elif what == "estop":
        rig.estop()
    detect, onset, stop = watch(rig, kind if what == "fault" else None, after)
    pose = rig.log[:, [COL[f"pose_{a}"] for a in AXES]]
    return rig, pose, since_onset(detect, onset), stop


def _moved(moved: np.ndarray) -> tuple[float, float]:
    return float(np.degrees(moved[3:].max())), float(moved[:3].max() * 1e3)


def run_draw(d: Draw, after: float = AFTER_S) -> DrawnRun:
    twin_rig, twin, _, _ = _watch(d, "twin", after)
    twin_trip = noticed(twin_rig)
    if len(twin) == 0:
        twin_trip += ", before the fault's moment"
        return DrawnRun(d, False, twin_trip, False, "NONE", *(math.nan,) * 7)
    rig, pose, detect, stop = _watch(d, "fault", after)
    _, held, _, _ = _watch(d, "estop", after)
    row = None if math.isnan(stop) else round(stop * 1000.0)
    deg, mm = _moved(excursion(pose, twin, row))
    end = len(pose) if row is None else row + 1
    run_deg, run_mm = _moved(excursion(pose[:end], twin[:end], None))
    estop_deg, estop_mm = _moved(excursion(held, twin, 0))
    trip = noticed(rig)
    return DrawnRun(
        draw=d,
        valid=twin_trip == Trip.NONE.name,
        twin_trip=twin_trip,
        detected=not math.isnan(detect),
        trip=trip,
        detect_ms=detect * 1e3,
        excursion_deg=deg,
        excursion_mm=mm,
        while_running_deg=run_deg,
        while_running_mm=run_mm,
        estop_deg=estop_deg,
        estop_mm=estop_mm,
    )


TARGETS = (
    Target("drawn_false_trips", "healthy twins that tripped or warned", 0.0, "eq"),
    Target("drawn_running_deg_max", "motion before the loop let go, worst (deg)", 2.0, "max"),
    Target("drawn_running_mm_max", "motion before the loop let go, worst (mm)", 3.0, "max"),
)
ROWS: tuple[tuple[str, str], ...] = (
    ("drawn_faults", "faults drawn (exercise, patient, unit, kind, channel, size, moment)"),
    ("drawn_detected", "detected"),
    ("drawn_undetected", "not detected within the watch"),
    ("drawn_undetected_moved", "...of them with the platform 0.5 deg or 1 mm off its twin"),
    ("drawn_misnamed", "...named as another part than the one that failed (RIGHT_NAMES)"),
    ("drawn_detect_ms_max", "detection time, worst (ms)"),
    ("drawn_detect_ms_p50", "detection time, median (ms)"),
    ("drawn_false_trips", "healthy twins that tripped or warned"),
    ("drawn_running_deg_max", "motion before the loop let go, worst (deg)"),
    ("drawn_running_mm_max", "motion before the loop let go, worst (mm)"),
    ("drawn_excursion_deg_max", "excursion with the safe state's give, worst (deg)"),
    ("drawn_excursion_mm_max", "excursion with the safe state's give, worst (mm)"),
    ("drawn_over_2deg_3mm", "...runs over 2 deg or 3 mm"),
    ("drawn_estop_deg_max", "an e-stop at the same moments: the safe state's give (deg)"),
    ("drawn_estop_mm_max", "...(mm)"),
)


def run(
    count: int,
    seed: int = 1,
    after: float = AFTER_S,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """``count`` drawn faults from ``seed``, summed up, with every run."""
    started = time.perf_counter()
    rng = np.random.default_rng(seed)
    runs = []
    for i in range(count):
        d = draw(rng)
        if progress is not None:
            where = "nominal" if d.unit < 0 else f"build {d.unit}"
            progress(
                f"drawn {i + 1}/{count}: {d.kind} ch {d.channel} at {d.at_s:.2f} s of "
                f"{d.exercise}, {d.patient}, {where}"
            )
        runs.append(run_draw(d, after))
    valid = [r for r in runs if r.valid]
    found = sorted(r.detect_ms for r in valid if r.detected)
    missed = [r for r in valid if not r.detected]

    def worst(values: list[float]) -> float:
        return max(values) if values else math.nan

    out: dict[str, Any] = {
        "drawn_faults": len(runs),
        "drawn_seed": seed,
        "after_s": after,
        "drawn_false_trips": len(runs) - len(valid),
        "drawn_detected": len(found),
        "drawn_undetected": len(missed),
        "drawn_undetected_moved": sum(
            r.excursion_deg >= 0.5 or r.excursion_mm >= 1.0 for r in missed
        ),
        "drawn_misnamed": sum(r.detected and misnamed(r.draw.kind, r.trip) for r in valid),
        "drawn_detect_ms_max": worst(found),
        "drawn_detect_ms_p50": float(np.median(found)) if found else math.nan,
        "drawn_running_deg_max": worst([r.while_running_deg for r in valid]),
        "drawn_running_mm_max": worst([r.while_running_mm for r in valid]),
        "drawn_excursion_deg_max": worst([r.excursion_deg for r in valid]),
        "drawn_excursion_mm_max": worst([r.excursion_mm for r in valid]),
        "drawn_over_2deg_3mm": sum(r.excursion_deg > 2.0 or r.excursion_mm > 3.0 for r in valid),
        "drawn_estop_deg_max": worst([r.estop_deg for r in valid]),
        "drawn_estop_mm_max": worst([r.estop_mm for r in valid]),
        "drawn": [
            {**asdict(r.draw), **{k: v for k, v in asdict(r).items() if k != "draw"}} for r in runs
        ],
    }
    out["wall_s"] = time.perf_counter() - started
    out["targets_met"] = {t.key: t.met(float(out[t.key])) for t in TARGETS}
    return out


def table(result: dict[str, Any]) -> str:
    """The summary, then every run that was not detected, moved over the targets or whose
    twin tripped."""
    lines = [render(result, ROWS, TARGETS), ""]
    notable = [
        r
        for r in result["drawn"]
        if not r["valid"]
        or not r["detected"]
        or misnamed(r["kind"], r["trip"])
        or r["excursion_deg"] > 2.0
        or r["excursion_mm"] > 3.0
    ]
    if notable:
        lines += [
            "| exercise | patient | unit | fault | ch | size | at (s) | trip | detect (ms) "
            "| running (deg / mm) | with the give (deg / mm) | e-stop (deg / mm) |",
            "|---|---|---|---|---:|---:|---:|---|---:|---:|---:|---:|",
        ]
        for r in notable:
            unit = "nominal" if r["unit"] < 0 else f"build {r['unit']}"
            trip = r["trip"] if r["valid"] else f"twin: {r['twin_trip']}"
            ms = "-" if math.isnan(r["detect_ms"]) else f"{r['detect_ms']:.0f}"
            lines.append(
                f"| {r['exercise']} | {r['patient']} | {unit} | {r['kind'].lower()} "
                f"| {r['channel']} | {r['value']:g} | {r['at_s']:.2f} | {trip} | {ms} "
                f"| {r['while_running_deg']:.2f} / {r['while_running_mm']:.2f} "
                f"| {r['excursion_deg']:.2f} / {r['excursion_mm']:.2f} "
                f"| {r['estop_deg']:.2f} / {r['estop_mm']:.2f} |"
            )
    return "\n".join(lines)
