"""The valves watched while every valve is shut and while the platform is released.

``device.controller.watch_shut`` (the service's HOLD and READY: IDLE, every valve shut) and
``watch_release`` (a release after a hold or an e-stop: every exhaust pulsing, no intake)
have no place in the safety benchmark's matrix, which injects while the loop runs. This
benchmark measures them the same two ways:

- **Faults**: on the nominal unit (calibrated, both feet), every valve stuck open and leaks
  injected 0.3 s into a hold at home (``held``); every valve stuck open and a leak on every
  chamber injected into the safety matrix's pitch exercise, which the air checks name while
  the loop outruns them, and the hold that ends the segment 0.5 s later (``exercise+hold``,
  watched from the hold); and intakes and exhausts stuck open or shut injected 0, 0.5 and
  1 s into a release after a hold. Each watched 3 s: named or not (the chamber right), the
  detection time, the platform's largest turn (roll, pitch, yaw) and shift from its pose
  at the injection (or the hold): sideways (x, y), and down or up as well (z) where
  nothing releases it. A healthy release itself turns and shifts the platform as it
  sinks; the same release without the fault is measured for comparison, and so is the
  exercise's own hold.
- **Healthy**: the library's exercises x both feet on the nominal unit and drawn builds,
  stopped at a drawn moment by a hold (``hold_s`` long) or an e-stop, then released and
  watched 6 s: any trip of the hold, or a stopped release, is a false one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from device.hardware import SimulatedHardware
from device.plant.faults import Fault, FaultKind
from device.rig import Rig
from device.safety import Trip
from lab.safety import _drawn_rig, _rig, _start, start_exercise
from sessions.prescription import EXERCISE_LIBRARY

WATCH_S = 3.0
"""How long each injected run is watched (s)."""
STEP_S = 0.002
"""The run advances in steps this long to time the detection (s)."""
RELEASE_WATCH_S = 6.0
"""How long each healthy release is watched (s): the chambers are empty well before."""
TILT_TARGET_DEG, SHIFT_TARGET_MM = 2.0, 3.0
"""The issue's excursion targets."""

HELD: tuple[tuple[FaultKind, int, float], ...] = (
    *((FaultKind.VALVE_STUCK_OPEN, v, 0.0) for v in range(24)),  # every intake and exhaust
    (FaultKind.CHAMBER_LEAK, 1, 0.02),  # a fiftieth of a valve
    (FaultKind.CHAMBER_LEAK, 4, 0.1),  # a tenth
    (FaultKind.CHAMBER_LEAK, 5, 0.005),  # a two-hundredth: only its leg's air names it
    (FaultKind.CHAMBER_LEAK, 9, 0.01),  # a hundredth
)
EXERCISE_HELD: tuple[tuple[FaultKind, int, float], ...] = (
    *((FaultKind.VALVE_STUCK_OPEN, v, 0.0) for v in range(24)),
    *((FaultKind.CHAMBER_LEAK, c, 0.5) for c in range(12)),  # the safety matrix's size
)
EXERCISE_HOLD_AFTER_S = 0.5
"""How long the exercise runs on after the injection before the hold ends it (s): the air
checks name a valve stuck open or a leak within 7-23 ms (``ankle bench safety``)."""
RELEASED: tuple[tuple[FaultKind, int, float], ...] = (
    *((FaultKind.VALVE_STUCK_OPEN, v, 0.0) for v in (0, 2, 8, 10)),  # intakes
    *((FaultKind.VALVE_STUCK_OPEN, v, 0.0) for v in (1, 3, 9, 11)),  # exhausts
    (FaultKind.VALVE_STUCK_CLOSED, 9, 0.0),  # leg 3's exhausts
    (FaultKind.VALVE_STUCK_CLOSED, 11, 0.0),
)
RELEASE_AT_S = (0.0, 0.5, 1.0)
PATIENTS = ("relaxed", "resisting")


@dataclass(frozen=True)
class FaultRun:
    situation: str  # "held", "exercise+hold" or "released+S" (S s into the release)
    kind: str
    channel: int
    size: float
    patient: str
    named: bool  # a VALVE trip or a stopped release naming the fault's chamber
    chamber: int  # the chamber named (-1: none)
    detect_ms: float  # from the injection (nan: not named)
    tilt_deg: float
    shift_mm: float


def _held(patient: str) -> Rig:
    rig = _rig(patient, 2)
    rig.move_legs(rig.state.leg_x.copy())
    rig.run(1.0, log_hz=0)
    rig.hold()
    rig.run(0.3, log_hz=0)
    return rig


def _exercise_held(patient: str, fault: Fault | None) -> Rig:
    """The safety matrix's pitch exercise with ``fault`` injected (if any), ended by a hold
    ``EXERCISE_HOLD_AFTER_S`` later (what the device's modes do when a segment ends)."""
    rig = _rig(patient, 2)
    _start(rig, "exercise")
    rig.run(0.5, log_hz=0)
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    if fault is not None:
        hw.inject(Fault(fault.kind, float(hw.state.time[0]), fault.channel, fault.value))
    rig.run(EXERCISE_HOLD_AFTER_S, log_hz=0)
    rig.hold()
    return rig


def _watch(rig: Rig, fault: Fault | None, released: bool) -> tuple[int, float, float, float]:
    """Inject ``fault`` now (if any) and watch: (chamber named, ms to it, tilt, shift).
    A VALVE trip latched already names its chamber at 0 ms."""
    hw = rig.hardware
    assert isinstance(hw, SimulatedHardware)
    if fault is not None:
        hw.inject(Fault(fault.kind, float(hw.state.time[0]), fault.channel, fault.value))
    start = np.array(hw.state.pose[:6])
    named, at = -1, float("nan")
    if not released and rig.trip == Trip.VALVE:
        named, at = rig.trip_channel, 0.0
    tilt = shift = 0.0
    across = 2 if released else 3  # a release sinks the platform on purpose
    for i in range(round(WATCH_S / STEP_S)):
        rig.run(STEP_S, log_hz=0)
        d = np.abs(np.array(hw.state.pose[:6]) - start)
        tilt = max(tilt, float(np.degrees(d[3:6].max())))
        shift = max(shift, float(d[:across].max() * 1e3))
        if named < 0:
            if released and rig.release_stopped[0] >= 0:
                named, at = rig.release_stopped[0], (i + 1) * STEP_S * 1e3
            elif not released and rig.trip == Trip.VALVE:
                named, at = rig.trip_channel, (i + 1) * STEP_S * 1e3
    return named, at, tilt, shift


def fault_runs(
    progress: Callable[[str], None] | None = None,
) -> tuple[list[FaultRun], dict[str, list[float]]]:
    """Every fault of ``HELD``, ``EXERCISE_HELD`` and ``RELEASED`` on both feet; and the
    healthy release's (and the exercise's hold's) own motion over the same windows, per
    foot and moment."""
    rows: list[FaultRun] = []
    total = len(PATIENTS) * (len(HELD) + len(EXERCISE_HELD) + len(RELEASED) * len(RELEASE_AT_S))
    for patient in PATIENTS:
        for kind, channel, size in HELD:
            if progress:
                progress(f"shut watch: fault {len(rows) + 1}/{total}")
            rig = _held(patient)
            named, at, tilt, shift = _watch(rig, Fault(kind, 0.0, channel, size), False)
            rows.append(
                FaultRun("held", kind.name.lower(), channel, size, patient,
                         named == _chamber(kind, channel), named, at, tilt, shift)
            )  # fmt: skip
        for kind, channel, size in EXERCISE_HELD:
            if progress:
                progress(f"shut watch: fault {len(rows) + 1}/{total}")
            rig = _exercise_held(patient, Fault(kind, 0.0, channel, size))
            named, at, tilt, shift = _watch(rig, None, False)
            rows.append(
                FaultRun("exercise+hold", kind.name.lower(), channel, size, patient,
                         named == _chamber(kind, channel), named, at, tilt, shift)
            )  # fmt: skip
        for after in RELEASE_AT_S:
            for kind, channel, size in RELEASED:
                if progress:
                    progress(f"shut watch: fault {len(rows) + 1}/{total}")
                rig = _held(patient)
                rig.set_vent(True)
                rig.run(after, log_hz=0)
                named, at, tilt, shift = _watch(rig, Fault(kind, 0.0, channel, size), True)
                rows.append(
                    FaultRun(f"released+{after:g}", kind.name.lower(), channel, size, patient,
                             named == _chamber(kind, channel), named, at, tilt, shift)
                )  # fmt: skip
    own: dict[str, list[float]] = {}
    for patient in PATIENTS:
        for after in RELEASE_AT_S:
            rig = _held(patient)
            rig.set_vent(True)
            rig.run(after, log_hz=0)
            _, _, tilt, shift = _watch(rig, None, True)
            own[f"{patient} released+{after:g}"] = [tilt, shift]
        _, _, tilt, shift = _watch(_exercise_held(patient, None), None, False)
        own[f"{patient} exercise+hold"] = [tilt, shift]
    return rows, own


def _chamber(kind: FaultKind, channel: int) -> int:
    return (
        channel // 2
        if kind in (FaultKind.VALVE_STUCK_OPEN, FaultKind.VALVE_STUCK_CLOSED)
        else channel
    )


def healthy(
    builds: int, hold_s: float, seed: int, progress: Callable[[str], None] | None = None
) -> dict[str, Any]:
    """The library x both feet on the nominal unit and drawn builds ``0..builds-1``."""
    rng = np.random.default_rng(seed)
    runs = 0
    seconds = 0.0
    false: list[dict[str, Any]] = []
    units = [-1, *range(builds)]
    total = len(units) * len(EXERCISE_LIBRARY) * len(PATIENTS)
    for unit in units:
        for exercise in EXERCISE_LIBRARY:
            for patient in PATIENTS:
                if progress:
                    progress(f"shut watch: healthy {runs + 1}/{total}")
                rig = _rig(patient, 1) if unit < 0 else _drawn_rig(patient, unit)
                start_exercise(rig, exercise)
                rig.run(float(rng.uniform(1.0, 6.0)), log_hz=0)
                tripped = rig.trip != Trip.NONE
                if tripped:  # the exercise's own trip (the safety benchmark's to judge)
                    continue
                estop = bool(rng.integers(2))
                if estop:
                    rig.estop()
                else:
                    rig.hold()
                    rig.run(hold_s, log_hz=0)
                    seconds += hold_s
                held = rig.trip
                rig.set_vent(True)
                rig.run(RELEASE_WATCH_S, log_hz=0)
                seconds += RELEASE_WATCH_S
                runs += 1
                stop = rig.release_stopped
                if held not in (Trip.NONE, Trip.ESTOP) or stop[0] >= 0:  # any trip held
                    false.append(
                        {"unit": unit, "exercise": exercise.value, "patient": patient,
                         "estop": estop, "hold_trip": held.name, "release_stop": list(stop)}
                    )  # fmt: skip
    return {"runs": runs, "seconds": seconds, "false": false}


def run(
    builds: int = 4,
    hold_s: float = 10.0,
    seed: int = 1,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    rows, own = fault_runs(progress)
    ok = healthy(builds, hold_s, seed, progress)
    named = [r for r in rows if r.named]
    worst_tilt = max(rows, key=lambda r: r.tilt_deg)
    worst_shift = max(rows, key=lambda r: r.shift_mm)
    over = [r for r in rows if r.tilt_deg > TILT_TARGET_DEG or r.shift_mm > SHIFT_TARGET_MM]
    return {
        "faults_total": len(rows),
        "faults_named": len(named),
        "detect_ms_max": max((r.detect_ms for r in named), default=float("nan")),
        "detect_ms_median": float(np.median([r.detect_ms for r in named])) if named else None,
        "excursion_deg_max": worst_tilt.tilt_deg,
        "excursion_mm_max": worst_shift.shift_mm,
        "over_targets": len(over),
        "release_own_motion": own,
        "healthy_runs": ok["runs"],
        "healthy_seconds": ok["seconds"],
        "false_stops": len(ok["false"]),
        "false": ok["false"],
        "faults": rows,
    }


def table(result: dict[str, Any]) -> str:
    lines = [
        f"faults named          {result['faults_named']} of {result['faults_total']}",
        "detection             none named"
        if result["detect_ms_median"] is None
        else f"detection             median {result['detect_ms_median']:.0f} ms, worst "
        f"{result['detect_ms_max']:.0f} ms",
        f"excursion, worst      {result['excursion_deg_max']:.2f} deg, "
        f"{result['excursion_mm_max']:.2f} mm (targets {TILT_TARGET_DEG:g} deg, "
        f"{SHIFT_TARGET_MM:g} mm; {result['over_targets']} runs over)",
        "a healthy release's (or the exercise's hold's) own motion over the same 3 s: "
        + ", ".join(
            f"{k} {v[0]:.2f} deg {v[1]:.2f} mm" for k, v in result["release_own_motion"].items()
        ),
        f"healthy               {result['healthy_runs']} holds or e-stops then releases, "
        f"{result['healthy_seconds']:.0f} s: {result['false_stops']} false",
        "",
        f"{'situation':13s} {'fault':18s} {'ch':>3s} {'size':>5s} {'foot':9s} {'named':5s} "
        f"{'ms':>5s} {'deg':>5s} {'mm':>5s}",
    ]
    for r in result["faults"]:
        ms = "-" if not r.named else f"{r.detect_ms:.0f}"
        lines.append(
            f"{r.situation:13s} {r.kind:18s} {r.channel:3d} {r.size:5.2f} {r.patient:9s} "
            f"{'yes' if r.named else 'NO':5s} {ms:>5s} {r.tilt_deg:5.2f} {r.shift_mm:5.2f}"
        )
    return "\n".join(lines)
