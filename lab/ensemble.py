"""The control benchmark on many plausible plants: ``ankle bench control --ensemble N``.

Each plant is drawn from the ranges of the parameter table (``device.plant.params.draw_plant``:
every ranged parameter uniform in its range, and the per-valve and per-sensor spreads of
its unit), and the benchmark's experiments run on it unchanged. For every metric the result
names the nominal plant's value, the median and the worst over the ensemble, and the plant
that gave the worst, with the command that runs it again.

A plant on which an experiment tripped or saturated gives no number for that experiment's
metrics: it counts in ``trips`` (or ``invalid``) and its metric's worst is then ``None`` (not
met), never the number of a run that was not one.
"""

from __future__ import annotations

import functools
import math
import os
import re
import statistics
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

from device.rig import CommandError
from lab import experiments
from lab.targets import Target


@dataclass(frozen=True)
class Metric:
    key: str
    label: str
    experiment: str
    worst: str  # "max": larger is worse; "min": smaller is worse
    target: float


METRICS: tuple[Metric, ...] = (
    Metric("step_rise_ms", "10 mm step: rise 10-90 % (ms)", "step", "max", 90.0),
    Metric("step_overshoot_pct", "10 mm step: overshoot (%)", "step", "max", 5.0),
    Metric("step_steady_error_mm", "10 mm step: steady error (mm)", "step", "max", 0.3),
    Metric("resolution_mm", "0.3 mm staircase: largest steady error (mm)", "staircase", "max", 0.3),
    Metric("pitch_bandwidth_hz", "pitch -3 dB at 2 deg (Hz)", "pitch_sweep", "min", 7.0),
    Metric("stiffness_error_pct", "rendered K = 50: error (%)", "impedance", "max", 5.0),
    Metric("damping_error_pct", "rendered B = 1: error (%)", "impedance_dynamic", "max", 5.0),
)

TARGETS: tuple[Target, ...] = (
    *(Target(f"ensemble_worst_{m.key}", m.label, m.target, m.worst) for m in METRICS),
    Target("ensemble_trips", "trips over the ensemble", 0, "eq"),
)


def measure(choice: experiments.PlantChoice) -> dict[str, Any]:
    """Every metric of :data:`METRICS` on one plant, with each experiment's health.

    An experiment whose rig tripped before it could even give its command (the device
    refuses commands while tripped) counts as tripped, with no number."""
    out: dict[str, Any] = {"plant": choice.describe(), "draw": choice.draw}
    health: dict[str, dict[str, Any]] = {}

    def attempt(name: str, run: Callable[[], Any]) -> Any:
        try:
            return run()
        except experiments.TrippedBeforeMeasurement as exc:
            health[name] = {"valid": False, "trip": exc.trip, "reason": str(exc), "saturated": []}
            return None
        except CommandError as exc:  # tripped earlier in the same rig: the command refused
            trip = re.search(r"tripped \((\w+)\)", str(exc))
            health[name] = {
                "valid": False,
                "trip": trip.group(1) if trip else "REFUSED",
                "reason": f"before the measurement: {exc}",
                "saturated": [],
            }
            return None

    with experiments.on_plant(choice):
        step = attempt("step", lambda: experiments.step(leg=1, mm=10.0))
        if step is not None:
            out["step_rise_ms"] = step.metrics.rise_ms
            out["step_overshoot_pct"] = step.metrics.overshoot_pct
            out["step_steady_error_mm"] = step.metrics.steady_error_mm
            health["step"] = _health(step.health)
        stairs = attempt("staircase", lambda: experiments.staircase(leg=1, step_mm=0.3))
        if stairs is not None:
            out["resolution_mm"] = stairs.resolution_mm
            health["staircase"] = _health(stairs.health)
        sweep = attempt("pitch_sweep", lambda: experiments.sweep("pitch", 2.0))
        if sweep is not None:
            out["pitch_bandwidth_hz"] = sweep.bandwidth_hz
            out["pitch_bandwidth_lower_bound"] = sweep.bandwidth_kind == "lower_bound"
            health["pitch_sweep"] = _health(sweep.health)
            if sweep.stopped_hz is not None:
                health["pitch_sweep"]["valid"] = False
                health["pitch_sweep"]["reason"] = f"stopped at {sweep.stopped_hz:g} Hz"
        imp = attempt(
            "impedance", lambda: experiments.impedance("pitch", k=50.0, b=1.0, torque=10.0)
        )
        if imp is not None:
            out["stiffness_error_pct"] = imp.error_pct
            health["impedance"] = _health(imp.health)
        dyn = attempt(
            "impedance_dynamic", lambda: experiments.impedance_dynamic("pitch", k=50.0, b=1.0)
        )
        if dyn is not None:
            out["damping_error_pct"] = dyn.damping_error_pct if dyn.fits else math.nan
            health["impedance_dynamic"] = _health(dyn.health)
    for m in METRICS:
        if not health[m.experiment]["valid"]:
            out[m.key] = None
    out["experiments"] = health
    out["trips"] = sorted({h["trip"] for h in health.values() if h["trip"]})
    return out


def _health(h: experiments.Health) -> dict[str, Any]:
    return {"valid": h.valid, "trip": h.trip, "reason": h.reason, "saturated": list(h.saturated)}


def _measure_draw(draw: int, noise_seed: int | None = None) -> dict[str, Any]:
    return measure(experiments.PlantChoice(draw=draw, seed=noise_seed))


def run(
    n: int,
    seed: int = 0,
    nominal: dict[str, Any] | None = None,
    progress: Callable[[str], None] | None = None,
    workers: int | None = None,
    noise_seed: int | None = None,
) -> dict[str, Any]:
    """Draw plants ``seed`` .. ``seed + n - 1`` and measure each; summarise every metric.

    ``nominal`` is the nominal plant's :func:`measure` (measured here if not given).
    ``noise_seed`` seeds every unit's sensor noise and valve jitter (None: each
    experiment's own): a plant's figures are one draw of that noise, and the worst over the
    fifty moves with it (README).
    """
    if n < 1:
        raise ValueError("an ensemble needs at least one plant")
    if nominal is None:
        nominal = measure(experiments.PlantChoice(seed=noise_seed))
    draws = list(range(seed, seed + n))
    measure_draw = functools.partial(_measure_draw, noise_seed=noise_seed)
    jobs = workers if workers is not None else min(2, os.cpu_count() or 1)
    plants: list[dict[str, Any]] = []
    if jobs > 1 and n > 1:
        with ProcessPoolExecutor(jobs) as pool:
            for r in pool.map(measure_draw, draws):
                plants.append(r)
                if progress:
                    progress(f"ensemble: plant {len(plants)}/{n} measured")
    else:
        for d in draws:
            plants.append(measure_draw(d))
            if progress:
                progress(f"ensemble: plant {len(plants)}/{n} measured")
    return summarise(plants, nominal, seed, noise_seed)


def summarise(
    plants: list[dict[str, Any]],
    nominal: dict[str, Any],
    seed: int = 0,
    noise_seed: int | None = None,
) -> dict[str, Any]:
    out: dict[str, Any] = {
        "ensemble_n": len(plants),
        "ensemble_seed": seed,
        "ensemble_noise_seed": noise_seed,
    }
    summary: dict[str, Any] = {}
    for m in METRICS:
        values = [(p[m.key], p["draw"]) for p in plants if p[m.key] is not None]
        values = [(v, d) for v, d in values if math.isfinite(v)]
        missing = [p["draw"] for p in plants if p[m.key] is None or not math.isfinite(p[m.key])]
        pick = max if m.worst == "max" else min
        worst = pick(values) if values else (math.nan, None)
        row = {
            "nominal": nominal.get(m.key),
            "median": statistics.median(v for v, _ in values) if values else None,
            "worst": worst[0] if values and not missing else None,
            "worst_measured": worst[0] if values else None,
            "worst_plant": worst[1] if values else None,
            "no_number_on": missing,
            "target": m.target,
        }
        worst_plant: int | None = missing[0] if missing else worst[1]
        row["worst_plant"] = worst_plant
        if worst_plant is not None:
            row["again"] = _again(m.experiment, worst_plant, noise_seed)
        summary[m.key] = row
        out[f"ensemble_worst_{m.key}"] = row["worst"]
    trips = [(p["draw"], t) for p in plants for t in p["trips"]]
    out["ensemble_trips"] = len(trips)
    out["ensemble_tripped_plants"] = sorted({d for d, _ in trips})
    out["ensemble"] = summary
    out["ensemble_plants"] = plants
    return out


def _again(experiment: str, draw: int, noise_seed: int | None = None) -> str:
    command = {
        "step": "ankle sim step --leg 1 --mm 10",
        "staircase": "ankle sim staircase --leg 1 --mm 0.3",
        "pitch_sweep": "ankle sim sweep --axis pitch --amplitude 2",
        "impedance": "ankle sim impedance --axis pitch --k 50 --b 1",
        "impedance_dynamic": "ankle sim impedance --axis pitch --k 50 --b 1 --mode dynamic",
    }[experiment]
    again = f"{command} --plant-draw {draw}"
    return again if noise_seed is None else f"{again} --seed {noise_seed}"


def table(result: dict[str, Any]) -> str:
    """Nominal, median and worst side by side (what the README shows)."""
    noise = result.get("ensemble_noise_seed")
    lines = [
        f"Ensemble of {result['ensemble_n']} plants (draws {result['ensemble_seed']}.."
        f"{result['ensemble_seed'] + result['ensemble_n'] - 1}"
        + ("" if noise is None else f", noise seed {noise}")
        + f"); trips: {result['ensemble_trips']}",
        "",
        "| metric | nominal | median | worst | worst plant | target | met |",
        "|---|---:|---:|---:|---:|---|---|",
    ]
    notes: list[str] = []
    for m in METRICS:
        row = result["ensemble"][m.key]

        def f(v: Any) -> str:
            return "no number" if v is None else f"{v:.3g}"

        worst = f(row["worst"])
        if row["no_number_on"]:
            why = []
            for d in row["no_number_on"]:
                health = _health_of(result, d, m.experiment)
                # "tripped CODE" when the rig tripped, else "not valid": a ring guard, a
                # saturation or a stopped sweep leaves a figure that is not the one asked
                why.append(
                    f"{d} (tripped {health['trip']})" if health.get("trip") else f"{d} (not valid)"
                )
                if health.get("reason"):
                    notes.append(f"- plant {d}, {m.experiment}: {health['reason']}")
            worst = f"no number on plant {', '.join(why)}; {f(row['worst_measured'])} on the rest"
        target = ("<= " if m.worst == "max" else ">= ") + f"{m.target:g}"
        met = row["worst"] is not None and (
            row["worst"] <= m.target if m.worst == "max" else row["worst"] >= m.target
        )
        plant = "" if row["worst_plant"] is None else str(row["worst_plant"])
        if row["no_number_on"] and row.get("worst_measured") is not None:
            measured = [
                p for p in result["ensemble_plants"] if p["draw"] not in row["no_number_on"]
            ]
            pick = max if m.worst == "max" else min
            plant += " / " + str(pick(measured, key=lambda p: p[m.key])["draw"])
        lines.append(
            f"| {m.label} | {f(row['nominal'])} | {f(row['median'])} | {worst} | {plant} | "
            f"{target} | {'yes' if met else 'NO'} |"
        )
    if notes:
        lines += ["", "Why a plant gave no number:", *dict.fromkeys(notes)]
    return "\n".join(lines)


def _health_of(result: dict[str, Any], draw: int, experiment: str) -> dict[str, Any]:
    for p in result.get("ensemble_plants", []):
        if p["draw"] == draw:
            health: dict[str, Any] = p.get("experiments", {}).get(experiment, {})
            return health
    return {}
