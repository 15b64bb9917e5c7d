"""Command line of the lab: ``sim`` experiments and ``bench control|link|server|abuse``.

Mounted under the ``ankle`` command by :mod:`ankle.cli`. Bad arguments give one line on
stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import math
import re
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any

import numpy as np

from device.cli import (
    FaultList,
    Parser,
    UsageError,
    add_plant_options,
    fault_kind,
    fault_spec,
    finite_float,
    ranged,
)
from device.commands import WATCHDOG_MS_MAX, WATCHDOG_MS_MIN, CommandError
from device.geometry import AXES


class SimParser(Parser):
    """:class:`Parser` that reads any negative number as a value: argparse takes only
    ``-1`` and ``-.5`` for numbers, and ``--mm -inf`` or ``--mm -1e3`` for an option it does
    not know ("expected one argument"), so the value never reached the check that says what
    is wrong with it."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = re.compile(
            r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|infinity|nan)$", re.IGNORECASE
        )


def add_commands(sub: argparse._SubParsersAction[Parser]) -> None:
    """Register ``sim`` and ``bench`` on a parent parser's subcommands."""
    sim = sub.add_parser("sim", help="experiments on the simulated device (simulated time)")
    ss = sim.add_subparsers(dest="experiment", required=True, parser_class=SimParser)

    p: Parser = ss.add_parser("step", help="position step of one leg (paper Fig. 9)")
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
    p.add_argument(
        "--torque",
        type=finite_float,
        default=None,
        help="patient's peak torque (N m; default 10 static, 5 dynamic)",
    )
    p.add_argument(
        "--mode",
        choices=("static", "dynamic"),
        default="static",
        help="static: a slow torque ramp, K from the slope; dynamic: sinusoidal torques, "
        "K and B from a least-squares fit",
    )
    p.add_argument(
        "--hz",
        type=_frequencies,
        default=None,
        help="dynamic mode: the patient's torque frequencies, comma-separated (default 0.5,1,2)",
    )
    _outputs(p)

    p = ss.add_parser("sweep", help="frequency response and -3 dB bandwidth of one axis")
    p.add_argument("--axis", choices=AXES, default="pitch")
    p.add_argument("--amplitude", type=finite_float, default=2.0)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    _faults(p)

    p = ss.add_parser("staircase", help="0.3 mm steps up and down: positioning resolution")
    p.add_argument("--leg", type=int, default=1)
    p.add_argument("--mm", type=finite_float, default=0.3)
    _outputs(p)

    p = ss.add_parser(
        "params", help="list the plant's parameters: nominal value, plausible range, unit"
    )
    p.add_argument(
        "--markdown", action="store_true", help="the whole table with reasons (docs/plant.md)"
    )

    bench = sub.add_parser("bench", help="benchmarks")
    bs = bench.add_subparsers(dest="bench", required=True, parser_class=Parser)
    p = bs.add_parser("control", help="the paper's headline results and the real-time factor")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plots", type=Path, help="write PNG figures into this folder")
    p.add_argument(
        "--ensemble",
        type=ranged(int, 0, 10000),
        default=0,
        metavar="N",
        help="also run the experiments on N plants drawn from the parameter table's ranges "
        "(draws SEED .. SEED+N-1) and report nominal, median and worst",
    )
    add_plant_options(
        p,
        seed_default=0,
        seed_help="the ensemble's first plant: draws SEED .. SEED+N-1 (default 0)",
    )
    p.add_argument(
        "--noise-seed",
        type=ranged(int, 0, 99999),
        default=None,
        metavar="S",
        help="seed of every unit's sensor noise and valve jitter in every experiment (default: "
        "each experiment's own, 1); a plant's figures are one draw of it",
    )
    p = bs.add_parser("link", help="serial link: ACK round trip, telemetry, pacing, watchdog")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--seconds", type=ranged(float, 1.0, 3600.0), default=60.0, help="telemetry window (s)"
    )
    p.add_argument(
        "--watchdog-runs", type=ranged(int, 1, 1000), default=20, help="link pulls to time"
    )
    p.add_argument(
        "--watchdog-ms",
        type=ranged(int, WATCHDOG_MS_MIN, WATCHDOG_MS_MAX),
        default=200,
        help="the device's watchdog for the run (default 200, the device's own): a longer one "
        "keeps a host that stalls on a busy machine from holding the exercise",
    )
    p = bs.add_parser(
        "safety",
        help="injected faults, healthy runs, boundary commands and the stiffness-damping edge",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--only",
        type=fault_kind,
        action="append",
        default=[],
        metavar="KIND",
        help="run only the fault matrix, for this fault kind (repeatable; e.g. leg_stuck)",
    )
    p.add_argument(
        "--after",
        type=ranged(float, 0.1, 10.0),
        default=0.5,
        metavar="S",
        help="watch each injected run this many seconds (default 0.5)",
    )
    p.add_argument(
        "--uncalibrated",
        action="store_true",
        help="run the nominal unit without its start-up identification, as the device runs "
        "without --calibration (the checks then allow for the heaviest plausible seals)",
    )
    p.add_argument(
        "--drawn",
        type=ranged(int, 1, 100000),
        default=None,
        metavar="N",
        help="instead of the matrix, N faults drawn at random (exercise, patient, unit, kind, "
        "channel, size, moment), each against its healthy twin and an e-stop (lab/faultdraws.py)",
    )
    p.add_argument(
        "--draw-seed",
        type=ranged(int, 0, 2**31 - 1),
        default=1,
        metavar="S",
        help="with --drawn: the seed the faults are drawn from (default 1)",
    )
    p = bs.add_parser(
        "shutwatch",
        help="valves stuck and leaks while every valve is shut and while the platform is "
        "released; healthy holds and releases (lab/shutwatch.py)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--builds",
        type=ranged(int, 0, 10000),
        default=4,
        metavar="N",
        help="healthy runs on the nominal unit and drawn builds 0..N-1 (default 4)",
    )
    p.add_argument(
        "--hold",
        type=ranged(float, 0.5, 600.0),
        default=10.0,
        metavar="S",
        help="each healthy hold's length before its release (default 10)",
    )
    p.add_argument(
        "--seed",
        type=ranged(int, 0, 2**31 - 1),
        default=1,
        metavar="S",
        help="the seed the healthy runs' moments and stops are drawn from (default 1)",
    )
    p = bs.add_parser(
        "zwidth", help="the stiffness and damping rendered stably per rotational axis (Z-width)"
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plots", type=Path, help="write zwidth.png into this folder")
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
        help="then 25, 50, 100 ... 500 stations for 5 s each, until p99 > 50 ms (default on)",
    )
    p.add_argument(
        "--capacity",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also sweep one server process pinned to one core (local and Redis relay) and "
        "two processes, for the capacity plan (default on)",
    )
    p.add_argument(
        "--processes", type=ranged(int, 1, 16), default=1, help="server processes (default 1)"
    )
    p.add_argument(
        "--relay",
        choices=("local", "redis"),
        default="local",
        help="live relay between processes; redis starts a throwaway redis-server unless "
        "--relay-url is given (default local)",
    )
    p.add_argument("--relay-url", default="", help="redis://host:port of a Redis to use")
    p.add_argument(
        "--store",
        choices=("sqlite", "postgres"),
        default="sqlite",
        help="sqlite: a new file; postgres: the existing database of --database-url",
    )
    p.add_argument(
        "--database-url",
        default="",
        help="with --store postgres: postgresql+asyncpg://user@host/db (default: "
        "ANKLE_DATABASE_URL)",
    )
    p.add_argument(
        "--heavy",
        action="store_true",
        help="instead: the heavy requests (the longest upload, its chart series, metrics on "
        "read, progress and reports over 1,000 sessions), each fired in turn while /health "
        "is asked every 10 ms",
    )
    p.add_argument(
        "--repeats", type=ranged(int, 1, 100), default=5, help="with --heavy: each request, times"
    )
    p = bs.add_parser(
        "abuse",
        help="large bodies, a sign-in flood, a WebSocket flood and malformed requests against "
        "a real server, while /health and a live link are watched",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--bodies-10mib", type=ranged(int, 0, 1000), default=20, help="default 20")
    p.add_argument("--bodies-100mib", type=ranged(int, 0, 1000), default=20, help="default 20")
    p.add_argument("--logins", type=ranged(int, 1, 1000), default=100, help="default 100")
    p.add_argument(
        "--ws-rate", type=ranged(int, 1, 100000), default=1000, help="messages/s, default 1000"
    )
    p.add_argument("--ws-seconds", type=ranged(float, 0.1, 600.0), default=3.0, help="default 3 s")
    p.add_argument("--malformed", type=ranged(int, 0, 100000), default=200, help="default 200")


def _frequencies(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a list of numbers: {text!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return values


def _faults(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--fault",
        type=fault_spec,
        action=FaultList,
        default=[],
        metavar="KIND@TIME[+DUR][:CHANNEL][=VALUE]",
        help="inject a plant fault at TIME s of simulated time (the 0.5 s settle at home "
        "included; repeatable), e.g. leg_stuck@0.8:2",
    )
    add_plant_options(p)


def _outputs(p: argparse.ArgumentParser) -> None:
    _faults(p)
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


INVALID = 1
"""Exit code of an experiment that ran but whose measurement is invalid (tripped or
saturated): it prints why and no number as if it were valid."""


def _health(h: Any) -> dict[str, Any]:
    """The keys every JSON result carries."""
    return {
        "tripped": h.tripped,
        "trip": h.trip,
        "trip_part": h.part,
        "trip_time_s": h.trip_time_s,
        "saturated": list(h.saturated),
        "valid": h.valid,
        "invalid_reason": h.reason,
        "warning": h.warning,
        "faults": [f.as_json() for f in h.faults],
    }


def _fault_lines(outcomes: Sequence[Any]) -> str:
    """A line for each fault injected with ``--fault``, in the device's numbering, and its
    fate: a user who wrote ``leg_stuck@1:2`` reads that the device calls that part leg 3,
    and whether and how soon it noticed (nothing at all in the result otherwise)."""
    return "".join(f"\nfault {o.words()}" for o in outcomes)


def _nulled(data: dict[str, Any], keys: Sequence[str]) -> dict[str, Any]:
    """``data`` with the measured ``keys`` set to None: an invalid run has no numbers."""
    return {k: (None if k in keys else v) for k, v in data.items()}


def run_command(args: argparse.Namespace) -> int:
    """Execute a parsed ``sim`` or ``bench`` command; 1 when the measurement is invalid."""
    if args.command == "bench":
        return _bench(args)
    if args.experiment == "params":
        from device.plant.params import parameter_lines, parameter_table_markdown

        print(parameter_table_markdown() if args.markdown else "\n".join(parameter_lines()))
        return 0
    return _experiment(args)


def _progress(line: str) -> None:
    """One progress line on stderr, rewritten in place (stdout stays the result)."""
    print(f"\r\x1b[2K{line}", end="", file=sys.stderr, flush=True)


@contextlib.contextmanager
def _service_error() -> Iterator[None]:
    """A service the bench needs (redis-server) that does not start: one line, exit 2."""
    from lab.services import ServiceError

    try:
        yield
    except ServiceError as exc:
        raise UsageError(f"ankle bench server: {exc}") from None


def _bench(args: argparse.Namespace) -> int:
    if args.bench == "safety":
        from lab import safety

        if args.drawn is not None:
            if args.only or args.uncalibrated:
                raise UsageError(
                    "ankle bench safety: --drawn runs its own faults on calibrated units; "
                    "it takes neither --only nor --uncalibrated"
                )
            from lab import faultdraws

            drawn = faultdraws.run(args.drawn, args.draw_seed, args.after, _progress)
            print(file=sys.stderr)
            print(json.dumps(_jsonable(drawn), indent=2) if args.json else faultdraws.table(drawn))
            return 0
        only = tuple(dict.fromkeys(args.only))
        sfresult = safety.run(
            progress=_progress, only=only, after=args.after, calibrated=not args.uncalibrated
        )
        print(file=sys.stderr)
        print(json.dumps(_jsonable(sfresult), indent=2) if args.json else safety.table(sfresult))
        return 0
    if args.bench == "shutwatch":
        from lab import shutwatch

        wresult = shutwatch.run(args.builds, args.hold, args.seed, _progress)
        print(file=sys.stderr)
        print(json.dumps(_jsonable(wresult), indent=2) if args.json else shutwatch.table(wresult))
        return 0
    if args.bench == "zwidth":
        from lab import zwidth

        zresult = zwidth.run(progress=_progress)
        print(file=sys.stderr)
        if args.plots is not None:
            zresult["plot"] = str(zwidth.figure(zresult, args.plots / "zwidth.png"))
        print(json.dumps(_jsonable(zresult), indent=2) if args.json else zwidth.table(zresult))
        return 0
    if args.bench == "server" and args.heavy:
        from lab import serverbench

        hresult = serverbench.heavy(repeats=args.repeats, progress=_progress)
        print(file=sys.stderr)
        print(
            json.dumps(serverbench.jsonable(hresult), indent=2)
            if args.json
            else serverbench.heavy_table(hresult)
        )
        return 0
    if args.bench == "server":
        from lab import serverbench

        try:
            serverbench.check_options(args.processes, args.relay, args.store, args.database_url)
        except ValueError as exc:
            raise UsageError(f"ankle bench server: {exc}") from None
        from rich.console import Console  # only the bench's progress line: lab's extra

        with Console(stderr=True).status("ankle bench server") as status, _service_error():
            sresult = serverbench.run(
                args.stations,
                args.viewers_per_station,
                args.seconds,
                args.sweep,
                processes=args.processes,
                relay=args.relay,
                relay_url=args.relay_url,
                store=args.store,
                database_url=args.database_url,
                capacity=args.capacity,
                progress=status.update,
            )
        print(
            json.dumps(serverbench.jsonable(sresult), indent=2)
            if args.json
            else serverbench.table(sresult)
        )
        return 0 if sresult["valid"] else INVALID
    if args.bench == "abuse":
        from lab import abuse, serverbench

        sizes = abuse.Sizes(
            args.bodies_10mib,
            args.bodies_100mib,
            args.logins,
            args.ws_rate,
            args.ws_seconds,
            args.malformed,
        )
        aresult = abuse.run(sizes, progress=_progress)
        print(file=sys.stderr)
        print(
            json.dumps(serverbench.jsonable(aresult), indent=2)
            if args.json
            else abuse.table(aresult)
        )
        return 0
    if args.bench == "link":
        from device.client import DeviceError
        from lab import linkbench

        try:
            lresult = linkbench.run(args.seconds, args.watchdog_runs, args.watchdog_ms)
        except (RuntimeError, DeviceError) as exc:  # no valid measurement: say why, in one line
            print(f"ankle bench link: {exc}", file=sys.stderr)
            return 1
        print(json.dumps(_jsonable(lresult), indent=2) if args.json else linkbench.table(lresult))
        return 0
    from lab import controlbench
    from lab import experiments as ex

    choice = ex.PlantChoice(args.plant_draw, tuple(args.plant), args.noise_seed)
    try:
        choice.config("relaxed")
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    result = controlbench.run(
        args.plots, choice, args.ensemble, args.seed, _progress, noise_seed=args.noise_seed
    )
    print(file=sys.stderr)
    print(json.dumps(_jsonable(result), indent=2) if args.json else controlbench.table(result))
    if not result["valid"] and not args.json:
        print("INVALID: " + "; ".join(f"{k}: {v}" for k, v in result["invalid"].items()))
    return 0 if result["valid"] else INVALID


def _experiment(args: argparse.Namespace) -> int:
    from lab import experiments as ex

    choice = ex.PlantChoice(args.plant_draw, tuple(args.plant), args.seed)
    try:
        choice.config("relaxed")
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    with ex.injected(tuple(getattr(args, "fault", ()))), ex.on_plant(choice):
        try:
            return _run_experiment(args)
        except ex.TrippedBeforeMeasurement as exc:
            health = ex.Health(
                True, exc.trip, None, (), False, str(exc), part=exc.part, faults=exc.faults
            )
            if args.json:
                print(json.dumps(_jsonable(_health(health) | {"plant": choice.describe()})))
            else:
                print(
                    f"INVALID: {exc} (on {choice.describe()}); no measurement"
                    + _fault_lines(health.faults)
                )
            return INVALID


def _run_experiment(args: argparse.Namespace) -> int:
    from lab import experiments as ex

    # Refuse what cannot be measured before anything is simulated (CommandError: exit 2).
    if args.experiment == "step":
        ex.check_step(args.leg, args.mm, args.duration)
    elif args.experiment == "sine":
        ex.check_sine(args.axis, args.amplitude, args.hz)
    elif args.experiment == "sweep":
        # The sweep ends below the device's speed limit; the rest must be measurable.
        ex.check_sine(args.axis, args.amplitude, ex.SWEEP_HZ[0])
    elif args.experiment == "staircase":
        ex.check_staircase(args.leg, args.mm)
    elif args.experiment == "impedance":
        if args.mode == "dynamic":
            args.torque = 5.0 if args.torque is None else args.torque
            ex.check_dynamic(args.axis, args.k, args.b, args.torque, args.hz or ex.IMPEDANCE_HZ)
        else:
            if args.hz is not None:
                raise CommandError("--hz is for --mode dynamic")
            args.torque = 10.0 if args.torque is None else args.torque
            ex.check_impedance(args.axis, args.k, args.b, args.torque)

    figure: Callable[[Path], Any] | None = None
    trace: tuple[list[str], list[np.ndarray]] | None = None
    measured: tuple[str, ...] = ()
    invalid_text: str | None = None
    data: dict[str, Any]
    if args.experiment == "step":
        r = ex.step(args.leg, args.mm, not args.no_deadband_comp, args.duration)
        m = r.metrics
        health = r.health
        what = (
            f"leg {r.leg} step {r.step_mm:g} mm "
            f"({'dead-band compensated' if r.compensate else 'uncompensated'})"
        )
        text = (
            f"{what}: rise {m.rise_ms:.1f} ms, overshoot {m.overshoot_pct:.2f} %, "
            f"settling {m.settling_ms:.0f} ms, steady-state error {m.steady_error_mm:.3f} mm"
        )
        data = {
            "leg": r.leg,
            "step_mm": r.step_mm,
            "deadband_compensation": r.compensate,
            **asdict(m),
        }
        measured = tuple(asdict(m))
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
        health = r2.health
        unit = "deg" if args.axis in AXES[3:] else "mm"
        what = f"{r2.axis} {r2.amplitude:.15g} {unit} at {r2.frequency:.15g} Hz"
        text = f"{what}: gain {r2.gain_db:+.2f} dB, phase {r2.phase_deg:.1f} deg"
        data = {
            "axis": r2.axis,
            "amplitude": r2.amplitude,
            "unit": unit,
            "hz": r2.frequency,
            "gain_db": r2.gain_db,
            "phase_deg": r2.phase_deg,
        }
        measured = ("gain_db", "phase_deg")
        trace = (["t_s", "command", "response"], [r2.t, r2.command, r2.response])
        figure = lambda path: _plots().bandwidth_figure(  # noqa: E731
            r2,
            ex.SweepResult(
                r2.axis,
                r2.amplitude,
                (r2.frequency,),
                (r2.gain_db,),
                (r2.phase_deg,),
                math.nan,
                "unknown",
                r2.health,
                None,
            ),
            path,
        )
    elif args.experiment == "impedance" and args.mode == "dynamic":
        rd = ex.impedance_dynamic(
            args.axis, args.k, args.b, args.torque, args.hz or ex.IMPEDANCE_HZ
        )
        health = rd.health
        freqs = ", ".join(f"{f:g}" for f in (args.hz or ex.IMPEDANCE_HZ))
        what = (
            f"{rd.axis}: K = {rd.stiffness:g} N m/rad, B = {rd.damping:g} N m s/rad, patient "
            f"torque {rd.torque:g} N m at {freqs} Hz"
        )
        data = {
            "axis": rd.axis,
            "mode": "dynamic",
            "k": rd.stiffness,
            "b": rd.damping,
            "torque": rd.torque,
            "hz": list(args.hz or ex.IMPEDANCE_HZ),
        }
        if rd.fits:
            j = rd.joint
            b_err = (
                f"{rd.damping_error_pct:.1f} %"
                if rd.damping > 0
                else f"{rd.damping_error:.3f} N m s/rad"
            )
            per = "; ".join(
                f"{f.hz:g} Hz: K {f.stiffness:.2f}, B {f.damping:.3f}" for f in rd.fits[:-1]
            )
            text = (
                f"{what}: rendered K {j.stiffness:.2f} N m/rad ({rd.stiffness_error_pct:.2f} % "
                f"error), B {j.damping:.3f} N m s/rad ({b_err} error) [{per}]; "
                f"the admittance law alone: K {j.law_stiffness:.2f}, B {j.law_damping:.3f}; "
                f"the patient's muscles feel K {j.patient_stiffness:.2f}, "
                f"B {j.patient_damping:.3f} (rendered + the passive ankle)"
            )
            measured = (
                "measured_stiffness",
                "measured_damping",
                "stiffness_error_pct",
                "damping_error",
                "damping_error_pct",
                "fits",
            )
            data |= {
                "measured_stiffness": j.stiffness,
                "measured_damping": j.damping,
                "stiffness_error_pct": rd.stiffness_error_pct,
                "damping_error": rd.damping_error,
                "damping_error_pct": rd.damping_error_pct,
                "fits": [asdict(f) for f in rd.fits],
            }
        else:
            text = what
    elif args.experiment == "impedance":
        r3 = ex.impedance(args.axis, args.k, args.b, args.torque)
        health = r3.health
        what = f"{r3.axis}: K = {r3.stiffness:g} N m/rad, B = {r3.damping:g} N m s/rad"
        text = (
            f"{what}: measured stiffness {r3.measured_stiffness:.2f} N m/rad "
            f"({r3.error_pct:.2f} % error)"
        )
        data = {
            "axis": r3.axis,
            "mode": "static",
            "k": r3.stiffness,
            "b": r3.damping,
            "torque": args.torque,
            "measured_stiffness": r3.measured_stiffness,
            "error_pct": r3.error_pct,
        }
        measured = ("measured_stiffness", "error_pct")
        trace = (["t_s", "angle_rad", "torque_nm"], [r3.t, r3.angle, r3.torque])
        figure = lambda path: _plots().impedance_figure(r3, path)  # noqa: E731
    elif args.experiment == "sweep":
        r4 = ex.sweep(args.axis, args.amplitude)
        health = r4.health
        rows = ", ".join(
            f"{f:g} Hz {g:+.1f} dB"
            for f, g in zip(r4.frequencies, r4.gains_db, strict=True)
            if math.isfinite(g)
        )
        what = f"{r4.axis} at {r4.amplitude:g} {'deg' if args.axis in AXES[3:] else 'mm'}"
        stop = ""
        if r4.stopped_hz is not None:
            why = f"tripped {r4.trip}" if r4.tripped else (r4.health.reason or "")
            stop = f"; {why} at {r4.stopped_hz:g} Hz, sweep stopped"
        if r4.bandwidth_kind == "measured":
            bw = f"{r4.bandwidth_hz:.2f} Hz" + (", below where it stopped" if stop else "")
        elif r4.bandwidth_kind == "lower_bound" and r4.stopped_hz is None:
            bw = f"above {r4.bandwidth_hz:g} Hz (gain never below -3 dB; lower bound)"
        elif r4.bandwidth_kind == "lower_bound":
            bw = f"not measured, only a lower bound: above {r4.bandwidth_hz:g} Hz"
        else:
            bw = "unknown"
        if math.isfinite(r4.speed_limit_hz):
            stop += (
                f"; the device refuses this amplitude above {r4.speed_limit_hz:.3g} Hz "
                "(its axis speed limit), so the sweep ends there"
            )
            if r4.bandwidth_kind == "lower_bound" and r4.stopped_hz is None:
                bw = f"above {r4.bandwidth_hz:g} Hz (gain never below -3 dB; lower bound)"
        text = f"{what}: -3 dB bandwidth {bw} ({rows}){stop}"
        data = {
            "axis": r4.axis,
            "amplitude": r4.amplitude,
            "frequencies": list(r4.frequencies),
            "gains_db": list(r4.gains_db),
            "phases_deg": list(r4.phases_deg),
            # A number only when measured; a lower bound is named as one.
            "bandwidth_hz": r4.bandwidth_hz if r4.bandwidth_kind == "measured" else None,
            "bandwidth_lower_bound_hz": (
                r4.bandwidth_hz if r4.bandwidth_kind == "lower_bound" else None
            ),
            "bandwidth_kind": r4.bandwidth_kind,
            "stopped_hz": r4.stopped_hz,
            "speed_limit_hz": r4.speed_limit_hz if math.isfinite(r4.speed_limit_hz) else None,
        }
        # An invalid sweep keeps the gains it measured before it stopped (the stopped
        # frequency's is null): they are valid points, but there is no bandwidth.
        if r4.stopped_hz is not None:
            invalid_text = f"INVALID: {stop[2:]} ({what}); -3 dB bandwidth {bw}" + (
                f"; gains before the stop: {rows}" if rows else ""
            )
    else:  # staircase
        r5 = ex.staircase(args.leg, args.mm)
        health = r5.health
        what = f"leg {r5.leg}, {r5.step_mm:g} mm steps"
        text = f"{what}: largest steady error {r5.resolution_mm:.3f} mm"
        data = {
            "leg": r5.leg,
            "step_mm": r5.step_mm,
            "resolution_mm": r5.resolution_mm,
            "errors_mm": list(r5.errors_mm),
        }
        measured = ("resolution_mm", "errors_mm")
        trace = (["t_s", "displacement_mm", "target_mm"], [r5.t, r5.displacement_mm, r5.target_mm])
        figure = lambda path: _plots().staircase_figure(r5, path)  # noqa: E731

    plant = ex.current_plant()
    data["plant"] = plant.describe()
    if plant.draw is not None or plant.changes:
        text += f" [on {plant.describe()}]"
    # The trace and the figure are written for an invalid run too: a run that tripped or
    # saturated is the one whose trace is wanted (its measurement is what is withheld).
    if getattr(args, "csv", None) and trace is not None:
        _write_csv(args.csv, trace[0], trace[1])
    verdict = invalid_text or f"INVALID: {health.words()} ({what}); no measurement"
    if getattr(args, "plot", None) and figure is not None:
        with _plots().invalid(None if health.valid else verdict):
            figure(args.plot)
    if not health.valid:
        if args.json:
            print(json.dumps(_jsonable(_nulled(data, measured) | _health(health))))
        else:
            print(verdict + _fault_lines(health.faults))
        return INVALID
    if health.words() and args.experiment != "sweep":
        text += f" [{health.words()}]"
    text += _fault_lines(health.faults)
    print(json.dumps(_jsonable(data | _health(health))) if args.json else text)
    return 0


def _plots() -> Any:
    from lab import plots

    return plots
