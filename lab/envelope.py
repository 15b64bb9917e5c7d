"""Stability envelope of the rendered impedance on the rotational axes (K-B map).

Per point: a fresh rig on the simulated plant (seed fixed), settled at home; impedance set
compliant on one axis only; hold (``rig.track({})``) for ``PRE`` s with no push at all
(spontaneous oscillation shows here); a patient torque pulse of ``PULSE_NM`` for
``PULSE_S`` on that axis (the scripted torque acts for the absent patient too: it is part of
the plant's patient wrench and the force sensor measures it); then ``POST`` s.

Recorded: trip code and time, peak-to-peak of the true platform angle in the last 1 s
(2-3 s after the pulse, when a correctly rendered soft setting has finished drifting back:
checked for K = 0, B = 10 on a relaxed ankle, about 0.04 deg of drift), the same after a
quadratic detrend (oscillation only), the commanded angle's p-p (also detrended), the mean
gap between the commanded and the true angle (a platform that "walks" away from its
command), whether it already oscillated or tripped before the push, and the dominant
frequency of the angle (the last 1 s, or the last 0.5 s before a trip).

Unstable (the basic criterion, with the p-p taken after a quadratic detrend so that the
correct slow return of a soft setting, e.g. K = 2, B = 5 with no foot, tau = B/K = 2.5 s,
is not counted as oscillation): tripped at any time, or detrended p-p > 0.2 deg in the last
1 s. Marginal (stricter, used for the envelope): also the command chattering (commanded
angle p-p > 0.5 deg in the last 1 s: the position loop is driven at 60-125 Hz, which the
platform filters but the legs and valves do not), the platform walking more than 0.5 deg
away from its command, or a push that tripped the speed limit at once (see run_point).

Usage:
    python -m lab.envelope [--axes roll,pitch,yaw] [--patients relaxed,resisting,absent]
        [--J <kg m2>] [--fmax <Hz>] [--K ...] [--B ...] [--pulse 2.0] [--json out.json]
        (no --J: the device's default virtual inertia; --J 0: none, the old compliance)
    python -m lab.envelope --stiffness [--J 0]     # experiments.impedance under this J
    python -m lab.envelope --verify [--json ...]   # run the recommended envelopes
    python -m lab.envelope --markdown map.json     # the B_min tables of a saved map
    python -m lab.envelope --builds 20 [--json ...] # least damping, nominal + 20 drawn builds
    python -m lab.envelope --draws 3,15,18 --patients stiff --axes roll,pitch  # those builds
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from collections.abc import Callable
from typing import Any
from unittest import mock

import numpy as np

from device.controller import I_RINGS, ControllerConfig
from device.geometry import AXIS_INDEX
from device.hardware import SimulatedHardware
from device.limits import SafetyLimits
from device.plant.model import SCRIPT_CONSTANT, SCRIPT_NONE
from device.plant.params import PARAMETERS, PlantConfig
from device.rig import Rig
from device.safety import Trip
from device.tickloop import COL
from lab import experiments

K_GRID = (0, 2, 5, 10, 20, 50, 100, 200, 350, 500)
B_GRID = (0, 0.05, 0.1, 0.2, 0.3, 0.5, 1, 2, 5, 10)
PATIENTS = ("relaxed", "resisting", "absent")
STIFF = "stiff"
"""A fourth patient: one who resists on the stiffest ankle of the plant's plausible range
(``ankle_stiffness_*`` at the top of their rows in device.plant.params), whatever build it
stands on. The ankle is the patient's, not the build's: a drawn build's own ankle is one
draw of it, and the envelope must hold for any patient on any build."""
ROT_AXES = ("roll", "pitch", "yaw")


def stiffest_ankle() -> tuple[tuple[str, float], ...]:
    """Plant changes that put the ankle at the top of its plausible range on every
    rotational axis (an axis with no range keeps its nominal stiffness)."""
    out = []
    for axis in ROT_AXES:
        row = PARAMETERS[f"ankle_stiffness_{axis}"]
        out.append((row.name, row.high if row.high is not None else row.value))
    return tuple(out)


def plant_patient(patient: str) -> tuple[str, tuple[tuple[str, float], ...]]:
    """The plant's patient for ``patient`` and the plant changes it brings: ``stiff`` is a
    resisting patient on :func:`stiffest_ankle`; the plant's own patients bring none."""
    if patient == STIFF:
        return "resisting", stiffest_ankle()
    return patient, ()


SETTLE = 0.5
PRE = 0.5
PULSE_NM = 2.0
PULSE_S = 0.1
POST = 3.0
PP_LIMIT_DEG = 0.2
CMD_PP_LIMIT_DEG = 0.5
WALK_LIMIT_DEG = 0.5
SPEED_TRIP_S = 0.2
SPEED_TRIP_MAX_HZ = 3.0
LOG_HZ = 1000.0

Point = dict[str, Any]
"""One measured point (see _run_point for its keys)."""
BMinTable = dict[str, dict[str, dict[float, float | None]]]
"""Per axis, patient, K: the least grid B (None: no grid B passes)."""


def _standard_plant(patient: str) -> PlantConfig:
    return PlantConfig(patient=patient)


# The plant each point runs on; verify(heavy=True) swaps in a heavier foot.
_plant_config: Callable[[str], PlantConfig] = _standard_plant


def _config(J: float | None, fmax: float | None = None) -> ControllerConfig:
    if J is None:
        return ControllerConfig()  # the device's default virtual inertia
    # Virtual inertia on the rotations only (the ankle's axes).
    return ControllerConfig(
        virtual_inertia=(0.0, 0.0, 0.0, J, J, J), virtual_frequency_max=fmax or 0.0
    )


def dominant_hz(y: np.ndarray, fs: float) -> float:
    n = len(y)
    if n < 16:
        return float("nan")
    t = np.arange(n)
    y = y - np.polyval(np.polyfit(t, y, 1), t)
    w = np.hanning(n)
    nfft = max(4096, 1 << (n - 1).bit_length())
    spec = np.abs(np.fft.rfft(y * w, nfft))
    f = np.fft.rfftfreq(nfft, 1.0 / fs)
    band = (f >= 0.5) & (f <= 200.0)
    return float(f[band][np.argmax(spec[band])])


def run_point(
    axis: str,
    patient: str,
    K: float,
    B: float,
    J: float | None = None,
    pulse: float = PULSE_NM,
    seed: int = 1,
    fmax: float | None = None,
    limits: SafetyLimits | None = None,
    unit: experiments.PlantChoice | None = None,
    ring_guard: bool = True,
) -> Point:
    """One point; a push that trips the speed limit at once is retried with a quarter push.

    ``limits``: the rig's own (lab.zwidth lifts the published envelope to measure below it).
    ``unit``: a unit (nominal or drawn) identified first and run with its calibration, as
    the device runs (unless ``unit.calibrate`` is False); None: the standard plant,
    uncalibrated, as sections 1-5 of docs/envelope.md were measured. ``ring_guard``: False
    measures the loop alone, without the device's ring guard (device.ring) on top.

    A LEG_SPEED trip within ``SPEED_TRIP_S`` of the push, with no oscillation before the push
    and a monotonic run-up to it (dominant frequency of the last 0.5 s under
    ``SPEED_TRIP_MAX_HZ``), is the admittance asking for a speed the legs may not reach (up
    to F/B rad/s, or impulse/J with a virtual inertia), not an oscillation: it is reported
    (``speed_trip``, counted as marginal) and the point is classified on the retry.
    """
    r = _run_point(axis, patient, K, B, J, pulse, seed, fmax, limits, unit, ring_guard)
    r["speed_trip"] = False
    if (
        r["trip"] == "LEG_SPEED"
        and 0.0 <= r["trip_t"] < SPEED_TRIP_S
        and r["pre_pp_deg"] < PP_LIMIT_DEG
        and r["f_hz"] < SPEED_TRIP_MAX_HZ
    ):
        r2 = _run_point(axis, patient, K, B, J, pulse / 4.0, seed, fmax, limits, unit, ring_guard)
        r2["speed_trip"] = True
        r2["first_trip_t"] = r["trip_t"]
        r2["marginal"] = True
        return r2
    return r


def _run_point(
    axis: str,
    patient: str,
    K: float,
    B: float,
    J: float | None,
    pulse: float,
    seed: int,
    fmax: float | None = None,
    limits: SafetyLimits | None = None,
    unit: experiments.PlantChoice | None = None,
    ring_guard: bool = True,
) -> Point:
    ax = AXIS_INDEX[axis]
    config = dataclasses.replace(_config(J, fmax), ring_guard=ring_guard)
    foot, changes = plant_patient(patient)
    if unit is None:
        hw = SimulatedHardware(_plant_config(foot).changed(changes), seed=seed)
    else:
        unit = dataclasses.replace(unit, changes=(*unit.changes, *changes))
        hw, config = experiments.unit_hardware(unit, foot, config, seed)
    rig = Rig(hw, config, limits=limits if limits is not None else SafetyLimits())
    rig.move_legs(np.full(6, 0.5 * rig.geometry.stroke))
    rig.run(SETTLE, log_hz=0)
    rig.clear_log()
    Kv, Bv = np.zeros(6), np.zeros(6)
    Kv[ax], Bv[ax] = K, B
    rig.set_impedance(Kv, Bv, [i == ax for i in range(6)])
    rig.track({})
    rig.run(PRE, log_hz=LOG_HZ)
    t_pulse = rig.time
    hw.script_torque(ax, SCRIPT_CONSTANT, t_pulse, pulse, 0.0)
    rig.run(PULSE_S, log_hz=LOG_HZ)
    hw.script_torque(ax, SCRIPT_NONE, 0.0, 0.0, 0.0)
    rig.run(POST, log_hz=LOG_HZ)
    log = rig.log
    t = log[:, 0]
    home = rig.geometry.home_pose[ax]
    ang = np.degrees(log[:, COL[f"pose_{axis}"]] - home)
    trip_col = log[:, COL["trip"]]
    tripped = bool(np.any(trip_col != 0))
    trip_t = float("nan")
    trip_name = "NONE"
    if tripped:
        i_trip = int(np.argmax(trip_col != 0))
        trip_t = float(t[i_trip] - t_pulse)
        trip_name = Trip(int(trip_col[i_trip])).name
        seg = ang[max(0, i_trip - 500) : i_trip]
        pp_raw = pp_det = cmd_pp = walk = float("nan")
    else:
        seg = ang[t >= t[-1] - 1.0]
        pp_raw = float(np.ptp(seg))
        x = np.arange(len(seg))
        pp_det = float(np.ptp(seg - np.polyval(np.polyfit(x, seg, 2), x)))
        cmd = np.degrees(log[:, COL[f"pose_cmd_{axis}"]] - home)[t >= t[-1] - 1.0]
        cmd_pp = float(np.ptp(cmd - np.polyval(np.polyfit(x, cmd, 2), x)))
        walk = float(np.mean(seg) - np.mean(cmd))
    f = dominant_hz(seg, LOG_HZ)
    # Spontaneous: oscillation (or trip) before the push.
    pre = ang[t < t_pulse]
    pre_trip = tripped and trip_t < 0
    pre_pp = float(np.ptp(pre[len(pre) // 2 :])) if len(pre) else float("nan")
    unstable = tripped or pp_det > PP_LIMIT_DEG
    marginal = unstable or cmd_pp > CMD_PP_LIMIT_DEG or abs(walk) > WALK_LIMIT_DEG
    return {
        "axis": axis,
        "patient": patient,
        "pulse_nm": pulse,
        "K": K,
        "B": B,
        "J": float(rig.params.virtual_inertia[ax]),
        "J_eff": float(
            max(rig.params.virtual_inertia[ax], K / rig.params.virtual_omega2)
            if rig.params.virtual_inertia[ax] > 0 and rig.params.virtual_omega2 > 0
            else rig.params.virtual_inertia[ax]
        ),
        "unstable": unstable,
        "marginal": marginal,
        "tripped": tripped,
        "trip": trip_name,
        "trip_t": trip_t,
        "spontaneous": pre_trip or pre_pp > PP_LIMIT_DEG,
        "pre_pp_deg": pre_pp,
        "pp_raw_deg": pp_raw,
        "pp_det_deg": pp_det,
        "cmd_pp_deg": cmd_pp,
        "walk_deg": walk,
        "f_hz": f,
        "peak_deg": float(np.max(np.abs(ang))),
        "rings": int(rig.state.istate[I_RINGS]),
    }


def b_min_table(results: list[Point], key: str = "unstable") -> BMinTable:
    """Per axis, patient, K: the least grid B above which every grid B is stable."""
    out: dict[str, dict[str, dict[float, dict[float, bool]]]] = {}
    for r in results:
        out.setdefault(r["axis"], {}).setdefault(r["patient"], {}).setdefault(r["K"], {})[
            r["B"]
        ] = r[key]
    table: BMinTable = {}
    for axis, pats in out.items():
        for pat, ks in pats.items():
            for K, bs in ks.items():
                bmin: float | None = None
                for B in sorted(bs, reverse=True):
                    if bs[B]:
                        break
                    bmin = B
                table.setdefault(axis, {}).setdefault(pat, {})[K] = bmin
    return table


def stiffness_check(
    J: float | None,
    fmax: float | None,
    cases: tuple[tuple[str, float, float, float], ...] = (("pitch", 50.0, 1.0, 10.0),),
) -> list[Point]:
    """The paper's stiffness rendering (experiments.impedance, Figure 12) under this J."""
    import lab.experiments as ex

    base = _config(J, fmax)

    # The only ControllerConfig call in lab.experiments (its _rig) passes just this keyword.
    def patched(*, deadband_compensation: bool) -> ControllerConfig:
        return dataclasses.replace(base, deadband_compensation=deadband_compensation)

    with mock.patch.object(ex, "ControllerConfig", patched):
        out: list[Point] = []
        for axis, k, b, tq in cases:
            r = ex.impedance(axis, k=k, b=b, torque=tq)
            out.append(
                {
                    "axis": axis,
                    "K": k,
                    "B": b,
                    "torque": tq,
                    "J": J,
                    "fmax": fmax,
                    "measured": r.measured_stiffness,
                    "error_pct": r.error_pct,
                }
            )
        return out


def markdown(path: str, key: str = "b_min_strict") -> str:
    """Markdown table of a saved map: per axis and patient, B_min for each K, then the max."""
    with open(path) as fh:
        d = json.load(fh)
    tab = d[key]
    Ks = sorted({float(k) for pats in tab.values() for row in pats.values() for k in row})
    lines = ["| axis | patient | " + " | ".join(f"K={k:g}" for k in Ks) + " |"]
    lines.append("|---|---|" + "---|" * len(Ks))
    for axis, pats in tab.items():
        worst: dict[float, float] = {}
        for pat, row in pats.items():
            vals = {float(k): v for k, v in row.items()}
            cells = []
            for k in Ks:
                v = vals.get(k)
                cells.append("none" if v is None else f"{v:g}")
                w = worst.get(k, 0.0)
                worst[k] = math.inf if v is None or w == math.inf else max(w, v)
            lines.append(f"| {axis} | {pat} | " + " | ".join(cells) + " |")
        lines.append(
            f"| {axis} | **all** | "
            + " | ".join(f"**{'none' if worst[k] == math.inf else f'{worst[k]:g}'}**" for k in Ks)
            + " |"
        )
    return "\n".join(lines)


# Recommended least damping (N m s/rad) per axis: (K from, B_min) steps, 2x the measured
# boundary (strict criterion, worst of the three patients), held until the next step.
ENVELOPE: dict[str, dict[str, tuple[tuple[float, float], ...]]] = {
    "no_virtual_inertia": {
        "roll": ((0, 4.0), (100, 2.0), (200, 0.1)),
        "pitch": ((0, 2.0), (100, 1.0), (200, 0.1)),
        "yaw": ((0, 1.0), (50, 0.6), (100, 0.1)),
    },
    "virtual_inertia": {  # measured with J = max(0.03, K / (2 pi 12 Hz)^2); now 9 Hz
        "roll": ((0, 1.0), (5, 0.6), (50, 0.2)),
        "pitch": ((0, 1.0), (5, 0.6), (50, 0.2)),
        "yaw": ((0, 0.6), (50, 0.2)),
    },
}


def envelope_b(kind: str, axis: str, K: float) -> float:
    b = math.inf
    for k_from, b_min in ENVELOPE[kind][axis]:
        if k_from <= K:
            b = b_min
    return b


def verify(kind: str, seeds: tuple[int, ...] = (1, 2), heavy: bool = False) -> list[Point]:
    """Run every patient at B = envelope(K) on grid and in-between K, several seeds."""
    global _plant_config
    J = 0.0 if kind == "no_virtual_inertia" else None
    Ks = (0, 1, 2, 3, 5, 7, 10, 20, 35, 50, 75, 100, 150, 200, 275, 350, 425, 500)
    original = _plant_config
    if heavy:  # a heavier foot (x1.5 mass, x2 inertia): more inertia fed back by the sensor

        def heavy_plant(patient: str) -> PlantConfig:
            return original(patient).with_overrides(
                foot_mass=1.6,
                foot_inertia_pitch=0.008,
                foot_inertia_roll=0.002,
                foot_inertia_yaw=0.008,
            )

        _plant_config = heavy_plant
    try:
        out: list[Point] = []
        for axis in ROT_AXES:
            for pat in PATIENTS:
                for K in Ks:
                    B = envelope_b(kind, axis, K)
                    for seed in seeds:
                        r = run_point(axis, pat, float(K), B, J, seed=seed)
                        r["seed"], r["heavy_foot"] = seed, heavy
                        out.append(r)
        return out
    finally:
        _plant_config = original


BUILD_K = (0.0, 5.0, 20.0, 50.0, 200.0, 500.0)
"""Stiffnesses of the over-builds map: the lower edge and inside of each band of K."""
BUILD_B = (0.2, 0.4, 0.6, 0.8, 1.0, 1.5, 2.0, 3.0, 5.0)
"""Dampings tried in turn at each K, from the lightest: the first stable one is kept."""
BUILD_MARGIN = 1.25
"""The published least damping is this times the worst least damping over the builds
(itself an upper bound: the true boundary lies up to one rung of ``BUILD_B`` below), and
never less than before the builds were mapped."""


def floor_at(b: float) -> SafetyLimits:
    """The device's limits with every rotational axis's least damping at ``b``: lab only,
    to measure below the published envelope with the law rendering ``b`` itself above its
    lag corner (none of the loop's lag taken out there; below the corner the law takes it
    out as the device does, ``ControllerConfig.impedance_lag_corner``)."""
    return dataclasses.replace(SafetyLimits(), damping_min=(0.0,) * 9 + (b,) * 9)


def least_damping_over_builds(
    draws: tuple[int, ...],
    progress: Callable[[str], None] | None = None,
    patients: tuple[str, ...] = PATIENTS,
    axes: tuple[str, ...] = ROT_AXES,
) -> dict[str, list[float | None]]:
    """Per unit (the nominal one, then drawn builds ``draws``), axis and patient (of
    ``axes`` and ``patients``; :data:`STIFF` among them puts the stiffest ankle on each): at each
    :data:`BUILD_K`, the least damping of :data:`BUILD_B` that renders stably (strict
    criterion) with the device's floor at that same damping, as the device would if it
    published it: the law then renders that damping above its lag corner. Each
    unit is identified first (device.identify) and run with its calibration, as the
    device runs. None where no rung is stable. Keys ``"<unit> <axis> <patient>"``, the
    unit ``nominal`` or the draw."""
    out: dict[str, list[float | None]] = {}
    for draw in (None, *draws):
        unit = experiments.PlantChoice(draw=draw)
        name = "nominal" if draw is None else str(draw)
        for axis in axes:
            for patient in patients:
                row: list[float | None] = []
                for K in BUILD_K:
                    least = None
                    for B in BUILD_B:
                        point = run_point(axis, patient, K, B, limits=floor_at(B), unit=unit)
                        if not point["marginal"]:
                            least = B
                            break
                    row.append(least)
                out[f"{name} {axis} {patient}"] = row
                if progress is not None:
                    progress(f"{name} {axis} {patient}: {row}")
    return out


def _rung(b: float) -> str:
    return "none stable" if math.isinf(b) else f"{b:g}"


def builds_table(rows: dict[str, list[float | None]]) -> str:
    """The worst least damping over the builds per axis and patient, which builds set it,
    and the least damping per axis and band of K it implies (:data:`BUILD_MARGIN`)."""
    lines = [
        "| axis | patient | nominal | worst over the builds | set by |",
        "|---|---|---|---|---|",
    ]
    worst_axis: dict[str, list[float]] = {}
    axes = [a for a in ROT_AXES if any(k.split()[1] == a for k in rows)]
    patients = list(dict.fromkeys(k.split()[2] for k in rows))
    for axis in axes:
        axis_worst = [0.0] * len(BUILD_K)
        for patient in patients:
            mine = {k.split()[0]: v for k, v in rows.items() if k.split()[1:] == [axis, patient]}
            worst: list[float] = []
            who: list[str] = []
            for i in range(len(BUILD_K)):
                values: dict[str, float] = {}
                for b, v in mine.items():
                    x = v[i]
                    values[b] = math.inf if x is None else x
                w = max(values.values())
                worst.append(w)
                if w > BUILD_B[0]:
                    who += [b for b, x in values.items() if x == w and b not in who]
                axis_worst[i] = max(axis_worst[i], w)
            nominal = mine.get("nominal", [])
            lines.append(
                f"| {axis} | {patient} | {' / '.join(fmt(x) for x in nominal)} | "
                f"{' / '.join(_rung(x) for x in worst)} | {', '.join(who[:5]) or '-'} |"
            )
        worst_axis[axis] = axis_worst
    lines += ["", f"K: {' / '.join(fmt(k) for k in BUILD_K)} N m/rad", ""]
    limits = SafetyLimits()
    for axis in axes:
        bands = []
        for band, edge in enumerate(limits.envelope_stiffness):
            upper = (
                limits.envelope_stiffness[band + 1]
                if band + 1 < len(limits.envelope_stiffness)
                else math.inf
            )
            w = max(x for k, x in zip(BUILD_K, worst_axis[axis], strict=True) if edge <= k < upper)
            now = limits.damping_min_at(AXIS_INDEX[axis], edge)
            bands.append(
                f"K >= {edge:g}: worst {_rung(w)}, x{BUILD_MARGIN:g} {BUILD_MARGIN * w:.2f}, "
                f"published {now:g}"
            )
        lines.append(f"{axis}: " + "; ".join(bands))
    return "\n".join(lines)


def fmt(v: float | None) -> str:
    return "-" if v is None else (f"{v:g}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--axes", default=",".join(ROT_AXES))
    ap.add_argument("--patients", default=",".join(PATIENTS))
    ap.add_argument("--K", default=",".join(str(k) for k in K_GRID))
    ap.add_argument("--B", default=",".join(str(b) for b in B_GRID))
    ap.add_argument(
        "--J", type=float, default=None, help="virtual inertia (kg m2); default: the device's"
    )
    ap.add_argument("--pulse", type=float, default=PULSE_NM)
    ap.add_argument(
        "--fmax", type=float, default=None, help="cap on sqrt(K/J) (Hz): J grows with K"
    )
    ap.add_argument("--json", default=None)
    ap.add_argument("--quiet", action="store_true")
    ap.add_argument(
        "--stiffness",
        action="store_true",
        help="only run the stiffness-rendering check (experiments.impedance) under this J",
    )
    ap.add_argument("--verify", action="store_true", help="check the recommended envelope")
    ap.add_argument("--markdown", default=None, help="print a saved map (JSON) as tables")
    ap.add_argument(
        "--builds",
        type=int,
        default=None,
        help="the least stable damping on the nominal unit and drawn builds 0..N-1 (of "
        "--axes, for --patients; stiff: a resisting patient on the stiffest plausible ankle)",
    )
    ap.add_argument(
        "--draws", default=None, help="as --builds, on these drawn builds (comma-separated)"
    )
    a = ap.parse_args(argv)
    if a.builds is not None or a.draws is not None:
        draws = (
            tuple(range(a.builds))
            if a.draws is None
            else tuple(int(d) for d in a.draws.split(",") if d)
        )
        rows = least_damping_over_builds(
            draws,
            None if a.quiet else lambda m: print(m, flush=True),
            patients=tuple(a.patients.split(",")),
            axes=tuple(a.axes.split(",")),
        )
        print(builds_table(rows))
        if a.json:
            with open(a.json, "w") as fh:
                json.dump(rows, fh, indent=1)
        return 0
    if a.markdown:
        for key in ("b_min", "b_min_strict"):
            print(f"\n{key}:\n")
            print(markdown(a.markdown, key))
        return 0
    if a.verify:
        res = []
        for kind in ("virtual_inertia", "no_virtual_inertia"):
            for heavy in (False, True):
                rs = verify(kind, heavy=heavy)
                res += rs
                bad = [r for r in rs if r["marginal"]]
                worst = max(
                    rs, key=lambda r: r["pp_det_deg"] if r["pp_det_deg"] == r["pp_det_deg"] else 9
                )
                print(
                    f"{kind:20s} heavy_foot={heavy}: {len(rs)} runs, {len(bad)} failing the "
                    f"strict criterion; largest p-p {worst['pp_det_deg']:.3f} deg "
                    f"({worst['axis']} {worst['patient']} K={worst['K']:g} B={worst['B']:g})"
                )
                for r in bad:
                    print(
                        f"   FAIL {r['axis']} {r['patient']} K={r['K']:g} B={r['B']:g} "
                        f"seed={r['seed']} "
                        f"trip={r['trip']} pp={r['pp_det_deg']:.3f} cmd={r['cmd_pp_deg']:.3f} "
                        f"walk={r['walk_deg']:.2f} speed_trip={r['speed_trip']} f={r['f_hz']:.1f}"
                    )
        if a.json:
            with open(a.json, "w") as fh:
                json.dump(res, fh, indent=1, default=str)
        return 0
    if a.stiffness:
        cases = (
            *((ax, 50.0, 1.0, 10.0) for ax in ROT_AXES),
            ("pitch", 20.0, 1.0, 6.0),  # the cases of tests/device/test_targets.py
            ("pitch", 100.0, 1.0, 10.0),
            ("pitch", 10.0, 1.0, 3.0),
            ("pitch", 200.0, 1.0, 10.0),
            ("pitch", 500.0, 1.0, 10.0),
            ("pitch", 50.0, 0.3, 10.0),
        )
        res = stiffness_check(a.J, a.fmax, cases)
        for r in res:
            print(
                f"{r['axis']:5s} K={r['K']:5g} B={r['B']:4g} J={r['J']} fmax={r['fmax']}: "
                f"measured {r['measured']:.2f} N m/rad, error {r['error_pct']:.2f} %"
            )
        json.dump(res, sys.stdout)
        print()
        return 0
    Ks = [float(x) for x in a.K.split(",")]
    Bs = [float(x) for x in a.B.split(",")]
    results = []
    t0 = time.time()
    for axis in a.axes.split(","):
        for pat in a.patients.split(","):
            for K in Ks:
                for B in Bs:
                    if K == 0 and B == 0:
                        continue  # refused by the device
                    r = run_point(axis, pat, K, B, a.J, a.pulse, fmax=a.fmax)
                    results.append(r)
                    if not a.quiet:
                        print(
                            f"{axis:5s} {pat:9s} K={K:5g} B={B:5g} "
                            f"{'UNST' if r['unstable'] else ('marg' if r['marginal'] else 'ok  ')}"
                            f"{'S' if r['speed_trip'] else ' '} trip={r['trip']:15s} "
                            f"t={r['trip_t']:6.3f} pp={r['pp_raw_deg']:7.3f} "
                            f"det={r['pp_det_deg']:7.3f} "
                            f"cmd={r['cmd_pp_deg']:7.3f} walk={r['walk_deg']:7.2f} "
                            f"pre={r['pre_pp_deg']:6.3f} f={r['f_hz']:6.1f}",
                            flush=True,
                        )
    table = b_min_table(results)
    strict = b_min_table(results, "marginal")
    print(f"\n# wall {time.time() - t0:.0f} s, J={a.J}, fmax={a.fmax}")
    for name, tab in (("unstable (basic)", table), ("marginal (strict)", strict)):
        print(f"B_min on the grid, criterion {name}: least B from which all larger grid B pass")
        print("axis  patient    " + " ".join(f"{k:>6g}" for k in Ks))
        for axis, pats in tab.items():
            for pat, row in pats.items():
                print(f"{axis:5s} {pat:9s}  " + " ".join(f"{fmt(row.get(k)):>6s}" for k in Ks))
    payload = {
        "J": a.J,
        "fmax": a.fmax,
        "pulse_nm": a.pulse,
        "results": results,
        "b_min": table,
        "b_min_strict": strict,
    }
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(payload, fh, indent=1, default=str)
    else:
        json.dump(payload["b_min"], sys.stdout, default=str)
        print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
