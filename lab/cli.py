"""Command line of the lab: ``sim`` experiments and ``bench control|link|server``.

Mounted under the ``ankle`` command by :mod:`ankle.cli`. Bad arguments give one line on
stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any

import numpy as np

from device.cli import Parser, finite_float, ranged
from device.geometry import AXES


def add_commands(sub: argparse._SubParsersAction[Parser]) -> None:
    """Register ``sim`` and ``bench`` on a parent parser's subcommands."""
    sim = sub.add_parser("sim", help="experiments on the simulated device (simulated time)")
    ss = sim.add_subparsers(dest="experiment", required=True, parser_class=Parser)

    p = ss.add_parser("step", help="position step of one leg (paper Fig. 9)")
    p.add_argument("--leg", type=int, default=1, help="leg number 1..6")
    p.add_argument("--mm", type=finite_float, default=10.0, help="step size (mm)")
    p.add_argument(
        "--no-deadband-comp",
        action="store_true",
        help="drive the valves without dead-band compensation (eq. 2-3 off)",
    )
    p.add_argument("--duration", type=finite_float, default=1.0, help="seconds to record")
    _outputs(p)

    p = ss.add_parser("sine", help="pose tracking of a sine on one axis (paper Fig. 10)")
    p.add_argument("--axis", choices=AXES, default="pitch")
    p.add_argument(
        "--amplitude", type=finite_float, default=2.0, help="deg for roll/pitch/yaw, mm for x/y/z"
    )
    p.add_argument("--hz", type=finite_float, default=1.0)
    _outputs(p)

    p = ss.add_parser("impedance", help="patient pushes against rendered K, B (paper Fig. 12)")
    p.add_argument("--axis", choices=AXES[3:], default="pitch")
    p.add_argument("--k", type=finite_float, default=50.0, help="stiffness (N m/rad)")
    p.add_argument("--b", type=finite_float, default=1.0, help="damping (N m s/rad)")
    p.add_argument("--torque", type=finite_float, default=10.0, help="patient's peak torque (N m)")
    _outputs(p)

    p = ss.add_parser("sweep", help="frequency response and -3 dB bandwidth of one axis")
    p.add_argument("--axis", choices=AXES, default="pitch")
    p.add_argument("--amplitude", type=finite_float, default=2.0)
    p.add_argument("--json", action="store_true", help="print one JSON object")

    p = ss.add_parser("staircase", help="0.3 mm steps up and down: positioning resolution")
    p.add_argument("--leg", type=int, default=1)
    p.add_argument("--mm", type=finite_float, default=0.3)
    _outputs(p)

    ss.add_parser("params", help="print the plant's parameter table (Markdown)")

    bench = sub.add_parser("bench", help="benchmarks")
    bs = bench.add_subparsers(dest="bench", required=True, parser_class=Parser)
    p = bs.add_parser("control", help="the paper's headline results and the real-time factor")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plots", type=Path, help="write PNG figures into this folder")
    p = bs.add_parser("link", help="serial link: ACK round trip, telemetry, pacing, watchdog")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--seconds", type=ranged(float, 1.0, 3600.0), default=60.0, help="telemetry window (s)"
    )
    p.add_argument(
        "--watchdog-runs", type=ranged(int, 1, 1000), default=20, help="link pulls to time"
    )
    p = bs.add_parser(
        "server", help="live relay: many simulated stations and viewers on a real server"
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--stations", type=ranged(int, 1, 2000), default=100, help="default 100")
    p.add_argument("--viewers-per-station", type=ranged(int, 1, 20), default=1, help="default 1")
    p.add_argument("--seconds", type=ranged(float, 1.0, 3600.0), default=20.0, help="window (s)")
    p.add_argument(
        "--sweep",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="then 25, 50, 100, 150, 200 stations for 5 s each, until p99 > 50 ms (default on)",
    )


def _outputs(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--csv", type=Path, help="write the trace to this CSV file")
    p.add_argument("--plot", type=Path, help="write a PNG figure to this file")


def _jsonable(obj: Any) -> Any:
    if is_dataclass(obj) and not isinstance(obj, type):
        return {k: _jsonable(v) for k, v in asdict(obj).items() if not isinstance(v, np.ndarray)}
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None if math.isnan(obj) else ("inf" if obj > 0 else "-inf")
    if isinstance(obj, np.floating | np.integer):
        return _jsonable(obj.item())
    return obj


def _write_csv(path: Path, header: Sequence[str], columns: Sequence[np.ndarray]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for row in zip(*columns, strict=True):
            w.writerow([f"{float(v):.6g}" for v in row])


def run_command(args: argparse.Namespace) -> int:
    """Execute a parsed ``sim`` or ``bench`` command."""
    from lab import experiments as ex

    if args.command == "bench" and args.bench == "server":
        from lab import serverbench

        sresult = serverbench.run(args.stations, args.viewers_per_station, args.seconds, args.sweep)
        print(
            json.dumps(serverbench.jsonable(sresult), indent=2)
            if args.json
            else serverbench.table(sresult)
        )
        return 0
    if args.command == "bench" and args.bench == "link":
        from lab import linkbench

        lresult = linkbench.run(args.seconds, args.watchdog_runs)
        print(json.dumps(_jsonable(lresult), indent=2) if args.json else linkbench.table(lresult))
        return 0
    if args.command == "bench":
        from lab import controlbench as bench

        result = bench.run(args.plots)
        print(json.dumps(_jsonable(result), indent=2) if args.json else bench.table(result))
        return 0

    figure: Callable[[Path], Any] | None = None
    trace: tuple[list[str], list[np.ndarray]] | None = None
    data: Any
    if args.experiment == "params":
        from device.plant.params import parameter_table_markdown

        print(parameter_table_markdown())
        return 0
    if args.experiment == "step":
        r = ex.step(args.leg, args.mm, not args.no_deadband_comp, args.duration)
        m = r.metrics
        text = (
            f"leg {r.leg} step {r.step_mm:g} mm "
            f"({'dead-band compensated' if r.compensate else 'uncompensated'}): "
            f"rise {m.rise_ms:.1f} ms, overshoot {m.overshoot_pct:.2f} %, "
            f"settling {m.settling_ms:.0f} ms, steady-state error {m.steady_error_mm:.3f} mm"
        )
        data = {
            "leg": r.leg,
            "step_mm": r.step_mm,
            "deadband_compensation": r.compensate,
            **asdict(m),
        }
        trace = (
            [
                "t_s",
                "displacement_mm",
                "lower_bar",
                "upper_bar",
                "lower_duty_pct",
                "upper_duty_pct",
            ],
            [r.t, r.displacement_mm, *r.pressure_bar.T, *r.duty.T],
        )
        figure = lambda path: _plots().step_figure([r], path)  # noqa: E731
    elif args.experiment == "sine":
        r2 = ex.sine(args.axis, args.amplitude, args.hz)
        unit = "deg" if args.axis in AXES[3:] else "mm"
        text = (
            f"{r2.axis} {r2.amplitude:g} {unit} at {r2.frequency:g} Hz: "
            f"gain {r2.gain_db:+.2f} dB, phase {r2.phase_deg:.1f} deg"
        )
        data = {
            "axis": r2.axis,
            "amplitude": r2.amplitude,
            "unit": unit,
            "hz": r2.frequency,
            "gain_db": r2.gain_db,
            "phase_deg": r2.phase_deg,
        }
        trace = (["t_s", "command", "response"], [r2.t, r2.command, r2.response])
        figure = lambda path: _plots().bandwidth_figure(  # noqa: E731
            r2,
            ex.SweepResult(
                r2.axis, r2.amplitude, (r2.frequency,), (r2.gain_db,), (r2.phase_deg,), math.nan
            ),
            path,
        )
    elif args.experiment == "impedance":
        r3 = ex.impedance(args.axis, args.k, args.b, args.torque)
        text = (
            f"{r3.axis}: K = {r3.stiffness:g} N m/rad, B = {r3.damping:g} N m s/rad: "
            f"measured stiffness {r3.measured_stiffness:.2f} N m/rad "
            f"({r3.error_pct:.2f} % error)"
        )
        data = {
            "axis": r3.axis,
            "k": r3.stiffness,
            "b": r3.damping,
            "measured_stiffness": r3.measured_stiffness,
            "error_pct": r3.error_pct,
        }
        trace = (["t_s", "angle_rad", "torque_nm"], [r3.t, r3.angle, r3.torque])
        figure = lambda path: _plots().impedance_figure(r3, path)  # noqa: E731
    elif args.experiment == "sweep":
        r4 = ex.sweep(args.axis, args.amplitude)
        rows = ", ".join(
            f"{f:g} Hz {g:+.1f} dB" for f, g in zip(r4.frequencies, r4.gains_db, strict=True)
        )
        bw = (
            f"above {max(r4.frequencies):g} Hz (gain never below -3 dB)"
            if math.isinf(r4.bandwidth_hz)
            else f"{r4.bandwidth_hz:.2f} Hz"
        )
        text = f"{r4.axis} at {r4.amplitude:g}: -3 dB bandwidth {bw} ({rows})"
        data = r4
    else:  # staircase
        r5 = ex.staircase(args.leg, args.mm)
        text = (
            f"leg {r5.leg}, {r5.step_mm:g} mm steps: largest steady error {r5.resolution_mm:.3f} mm"
        )
        data = {
            "leg": r5.leg,
            "step_mm": r5.step_mm,
            "resolution_mm": r5.resolution_mm,
            "errors_mm": list(r5.errors_mm),
        }
        trace = (["t_s", "displacement_mm", "target_mm"], [r5.t, r5.displacement_mm, r5.target_mm])
        figure = lambda path: _plots().staircase_figure(r5, path)  # noqa: E731

    print(json.dumps(_jsonable(data)) if args.json else text)
    if getattr(args, "csv", None) and trace is not None:
        _write_csv(args.csv, trace[0], trace[1])
    if getattr(args, "plot", None) and figure is not None:
        figure(args.plot)
    return 0


def _plots() -> Any:
    from lab import plots

    return plots
