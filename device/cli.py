"""Command line of the device: the device service (``device``) and ``protocol``.

Mounted under the ``ankle`` command by :mod:`ankle.cli`; ``python -m device`` runs it alone
on the embedded PC (and is how the service is started as a child process). Experiments and
benchmarks are the lab's (:mod:`lab.cli`). Bad arguments give one line on stderr and exit
code 2.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from device.plant.params import HARDWARE_KINDS, PATIENTS

if TYPE_CHECKING:
    from device.calibration import Calibration

USAGE_ERROR = 2


class UsageError(Exception):
    """A one-line complaint about the command line."""


class Parser(argparse.ArgumentParser):
    """argparse that reports bad arguments in one line rather than usage + error."""

    def error(self, message: str) -> NoReturn:
        raise UsageError(f"{self.prog}: {message}")


def finite_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return value


def ranged(kind: Callable[[str], Any], lo: float, hi: float) -> Callable[[str], Any]:
    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not (math.isfinite(value) and lo <= value <= hi):
            raise argparse.ArgumentTypeError(f"{text} outside {lo:g}..{hi:g}")
        return value

    parse.__name__ = kind.__name__ if hasattr(kind, "__name__") else "value"
    return parse


def add_commands(sub: argparse._SubParsersAction[Parser]) -> None:
    """Register ``protocol`` and ``device`` on a parent parser's subcommands."""
    from device.commands import WATCHDOG_MS_MAX, WATCHDOG_MS_MIN  # what HELLO publishes

    sub.add_parser("protocol", help="print the serial protocol's messages (Markdown)")
    dev = sub.add_parser(
        "device",
        help="the device service: the controller paced to the wall clock, on a serial link",
    )
    dev.add_argument(
        "--hardware",
        choices=HARDWARE_KINDS,
        default="board",
        help="the plant simulation or the I/O board (default board)",
    )
    dev.add_argument(
        "--sim",
        dest="hardware",
        action="store_const",
        const="sim",
        help="same as --hardware sim",
    )
    dev.add_argument(
        "--link",
        default="pty",
        help="pty (prints the port to open), tcp://HOST:PORT, or a serial port name",
    )
    dev.add_argument("--baud", type=ranged(int, 1200, 12_000_000), default=921600)
    dev.add_argument(
        "--telemetry-hz", type=ranged(int, 1, 250), default=100, help="1..250 (default 100)"
    )
    dev.add_argument(
        "--watchdog-ms",
        type=ranged(int, WATCHDOG_MS_MIN, WATCHDOG_MS_MAX),
        default=200,
        help=f"{WATCHDOG_MS_MIN}..{WATCHDOG_MS_MAX} (default 200)",
    )
    dev.add_argument("--patient", choices=PATIENTS, default="relaxed", help="simulated patient")
    dev.add_argument(
        "--patient-torque",
        type=ranged(float, 0.0, 20.0),
        default=0.0,
        help="simulated patient pushes in pitch with this peak torque (N m, 0.1 Hz)",
    )
    dev.add_argument("--seconds", type=ranged(float, 0.0, 1e9), default=None)
    dev.add_argument(
        "--fault",
        type=fault_spec,
        action=FaultList,
        default=[],
        metavar="KIND@TIME[+DUR][:CHANNEL][=VALUE]",
        help="simulation only: inject a plant fault at TIME s after the start (repeatable; "
        "with --identify, of the identification), e.g. supply_loss@30 or pressure_open@12:4",
    )
    unit = dev.add_mutually_exclusive_group()
    unit.add_argument(
        "--calibration",
        type=Path,
        metavar="FILE",
        help="this unit's calibration (made by --identify): the controller subtracts its "
        "zeros from every reading and the device says so in its HELLO",
    )
    unit.add_argument(
        "--identify",
        type=Path,
        metavar="FILE",
        help="maintenance, nobody on the plate: pull every leg onto its lower stop, vent, "
        "read every sensor's zero and pulse every valve, save the calibration to FILE and "
        "exit (the simulation identifies its plant with the plate empty)",
    )
    unit.add_argument(
        "--uncalibrated",
        action="store_true",
        help="run without a calibration (development and maintenance): no sensor zero is "
        "subtracted and the checks allow for unread zeros and unknown seals, which a few "
        "plausible builds still trip. Without --calibration the simulation identifies its "
        "plant first, plate empty, and the I/O board refuses to start",
    )
    add_plant_options(dev, seed_default=0)


def add_plant_options(
    p: argparse.ArgumentParser, seed_default: int = 1, seed_help: str | None = None
) -> None:
    """``--plant KEY=VALUE``, ``--plant-draw N`` and ``--seed N``: which simulated plant."""
    p.add_argument(
        "--plant",
        type=plant_spec,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="simulation only: change one plant parameter from its nominal value "
        "(repeatable; `ankle sim params` lists the keys, units and plausible ranges); "
        "KEY unit picks another unit of the build (per-valve and per-sensor spreads)",
    )
    p.add_argument(
        "--plant-draw",
        type=ranged(int, 0, 2**31 - 1),
        default=None,
        metavar="N",
        help="simulation only: start from plant N of the ensemble (`ankle bench control "
        "--ensemble` names its worst plants so); --plant changes apply on top",
    )
    p.add_argument(
        "--seed",
        type=ranged(int, 0, 2**31 - 1),
        default=seed_default,
        help=seed_help
        or f"simulation only: seed of the sensor noise and valve jitter (default {seed_default})",
    )


def plant_spec(text: str) -> tuple[str, float]:
    """argparse type of ``--plant``: ``KEY=VALUE`` with a known key and a usable value."""
    from device.plant.params import PARAMETERS, check_override

    key, sep, value = text.partition("=")
    key = key.strip().replace("-", "_")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    if key != "unit" and key not in PARAMETERS:
        raise argparse.ArgumentTypeError(
            f"unknown plant parameter {key!r}; `ankle sim params` lists them"
        )
    try:
        number = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{key} needs a number, got {value!r}") from None
    try:
        check_override(key, number)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return key, number


def plant_config(args: argparse.Namespace, patient: str = "relaxed") -> Any:
    """The :class:`~device.plant.params.PlantConfig` that ``add_plant_options`` asked for."""
    from device.plant.params import PlantConfig, draw_plant

    base = PlantConfig(patient=patient)
    if getattr(args, "plant_draw", None) is not None:
        base = draw_plant(args.plant_draw, patient)
    return base.changed(tuple(getattr(args, "plant", ())))


def _fault_words(fault: Any) -> str:
    """``fault`` for the person who asked for it: when, and the part in the numbering the
    device's events use (from 1), beside the channel as ``--fault`` counts it (from 0)."""
    from device.plant.faults import describe

    return str(describe(fault))


def fault_spec(text: str) -> Any:
    """argparse type of ``--fault``: a :class:`device.plant.faults.Fault`."""
    from device.plant.faults import parse_fault

    try:
        return parse_fault(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


class FaultList(argparse.Action):
    """``--fault``, repeatable: at most as many faults as the plant's fault table holds, so
    too many is a usage error here rather than a failure once the plant is built."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        from device.plant.faults import MAX_FAULTS

        faults = [*(getattr(namespace, self.dest, None) or ()), values]
        if len(faults) > MAX_FAULTS:
            raise argparse.ArgumentError(
                self, f"at most {MAX_FAULTS} at once (the plant's fault table holds {MAX_FAULTS})"
            )
        setattr(namespace, self.dest, faults)


def fault_kind(text: str) -> Any:
    """argparse type of a fault kind's name: a :class:`device.plant.faults.FaultKind`."""
    from device.plant.faults import parse_kind

    try:
        return parse_kind(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def run_command(args: argparse.Namespace) -> int:
    """Execute a parsed ``device`` or ``protocol`` command."""
    if args.command == "device":
        return _device(args)
    from device.protocol.messages import markdown_table

    print(markdown_table(), end="")
    return 0


def _device(args: argparse.Namespace) -> int:
    import faulthandler

    # A crash (or SIGABRT from whoever waits on a hung start) prints every thread's stack to
    # stderr: the journal on the embedded PC, the start error in a test.
    faulthandler.enable()
    from device.calibration import Calibration, IdentificationError
    from device.controller import ControllerConfig
    from device.hardware import HardwareError, SimulatedHardware, open_hardware
    from device.identify import identify_simulated
    from device.plant.model import SCRIPT_SINE
    from device.rig import Rig
    from device.service import DeviceService, ServiceConfig, serve
    from device.transport import LinkError, LinkSpecError, open_link

    if args.hardware != "sim" and (args.plant or args.plant_draw is not None):
        print(
            "error: --plant and --plant-draw change the plant simulation: use --sim",
            file=sys.stderr,
        )
        return USAGE_ERROR
    if args.identify is not None:
        return _identify(args)
    if args.hardware != "sim" and args.calibration is None and not args.uncalibrated:
        print(
            "error: the device runs a patient only with its unit's calibration: identify the "
            "unit once, plate empty (ankle device --identify FILE), then start it with "
            "--calibration FILE (or --uncalibrated for maintenance)",
            file=sys.stderr,
        )
        return USAGE_ERROR
    if args.hardware == "sim":
        print("ankle device: preparing the simulated device (first start compiles for ~2 min)...")
    calibration = Calibration()
    try:  # what the command line names first: a bad file or link fails before any wait
        if args.calibration is not None:
            calibration = Calibration.load(args.calibration)
        link = open_link(args.link, args.baud)
    except IdentificationError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except LinkError as exc:
        print(f"error: {exc.args[-1]}", file=sys.stderr)
        return USAGE_ERROR if isinstance(exc, LinkSpecError) else 1
    try:
        if args.calibration is None and args.hardware == "sim" and not args.uncalibrated:
            # As a deployed unit was identified before its first patient: the simulated
            # unit's twin, plate empty, first (it seeds the plant's random generator).
            print("ankle device: identifying the simulated unit, plate empty...", flush=True)
            calibration = identify_simulated(plant_config(args, args.patient))
        hardware = open_hardware(args.hardware, plant_config(args, args.patient), args.seed)
    except IdentificationError as exc:
        link.close()
        print(f"error: the simulated unit cannot be identified: {exc}", file=sys.stderr)
        return 1
    except HardwareError as exc:
        link.close()
        print(f"error: {exc.args[-1]}", file=sys.stderr)
        return 1
    if isinstance(hardware, SimulatedHardware) and args.patient_torque > 0:
        hardware.script_torque(4, SCRIPT_SINE, 1.0, args.patient_torque, 0.1)
    if args.fault and not isinstance(hardware, SimulatedHardware):
        print("error: --fault injects into the plant simulation: use --sim", file=sys.stderr)
        return USAGE_ERROR
    for fault in args.fault:
        assert isinstance(hardware, SimulatedHardware)
        try:
            hardware.inject(fault)
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return USAGE_ERROR
        print(f"ankle device: fault to inject {_fault_words(fault)}")
    if args.uncalibrated:
        print("ankle device: uncalibrated (--uncalibrated): sensor zeros are not subtracted")
    else:
        source = args.calibration or "identified at start, plate empty"
        print(f"ankle device: {describe(calibration)} ({source})")
    rig = Rig(hardware, ControllerConfig(calibration=calibration))
    service = DeviceService(rig, link, ServiceConfig(args.telemetry_hz, args.watchdog_ms))
    return serve(service, args.seconds)


def describe(calibration: Calibration) -> str:
    """One line for the technician: when the unit was identified, its largest zeros, its
    legs' friction and what they move, their largest load bias, and how many transducers
    a frozen reading is told by on their noise."""
    legs = max(abs(z) for z in calibration.leg_zero) * 1e3
    bar = max(abs(z) for z in calibration.pressure_zero) / 1e5
    valves = "valves identified" if calibration.valves_identified else "valves not identified"
    friction = (
        f"leg friction {min(calibration.leg_friction):.1f}-{max(calibration.leg_friction):.1f} N"
        if calibration.leg_friction
        else "leg friction not identified (none fed forward)"
    )
    mass = (
        f"the legs move {calibration.moving_mass:.2f} kg"
        if calibration.moving_mass
        else "moving mass not identified (the configured derivative gain)"
    )
    bias = (
        f"load bias up to {max(abs(b) for b in calibration.load_bias):.1f} N a leg"
        if calibration.load_bias
        else "load bias not identified (no vertical force cross-check)"
    )
    judged = sum(1 for n in calibration.pressure_still_reads if n > 0)
    channels = sum(1 for n in calibration.ft_still_reads if n > 0)
    still = (
        f"{judged} of 13 transducers and {channels} of 6 force/torque channels judged by "
        "their noise"
    )
    when = calibration.identified_at or "an unknown date"
    return (
        f"calibration of {when}: leg zeros up to {legs:.3f} mm, transducer zeros up to "
        f"{bar:.3f} bar, {valves}, {friction}, {mass}, {bias}, {still}"
    )


def _identify(args: argparse.Namespace) -> int:
    """``ankle device --identify FILE``: identify the unit, save, and exit."""
    from device.calibration import IdentificationError
    from device.hardware import HardwareError, SimulatedHardware, open_hardware
    from device.identify import identify

    # The plate must be empty: the simulation takes its patient off, a technician the foot.
    patient = "absent" if args.hardware == "sim" else args.patient
    try:
        hardware = open_hardware(args.hardware, plant_config(args, patient), args.seed)
    except HardwareError as exc:
        print(f"error: {exc.args[-1]}", file=sys.stderr)
        return 1
    if args.fault and not isinstance(hardware, SimulatedHardware):
        hardware.close()
        print("error: --fault injects into the plant simulation: use --sim", file=sys.stderr)
        return USAGE_ERROR
    for fault in args.fault:  # from the identification's start: a part broken before it
        assert isinstance(hardware, SimulatedHardware)
        try:
            hardware.inject(fault)
        except ValueError as exc:
            hardware.close()
            print(f"error: {exc}", file=sys.stderr)
            return USAGE_ERROR
        print(f"ankle device: fault to inject {_fault_words(fault)}")
    print("ankle device: identifying the unit; nobody may stand on the plate...", flush=True)
    try:
        calibration = identify(hardware)
        calibration.save(args.identify)
    except IdentificationError as exc:
        print(f"error: identification failed: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"error: cannot save the calibration to {args.identify}: {exc}", file=sys.stderr)
        return 1
    finally:
        hardware.close()
    print(f"ankle device: {describe(calibration)}; saved to {args.identify}")
    return 0


def main(argv: Sequence[str] | None = None, prog: str = "device") -> int:
    """Entry point of ``python -m device``."""
    parser = Parser(prog=prog, description="Rutgers Ankle device: the service and its protocol")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    add_commands(sub)
    return dispatch(parser, argv)


def dispatch(
    parser: argparse.ArgumentParser,
    argv: Sequence[str] | None,
    run: Callable[[argparse.Namespace], int] | None = None,
) -> int:
    """Parse and run (``run``, default :func:`run_command`), turning usage and command errors
    into one line and exit code 2."""
    from device.commands import CommandError

    try:
        args = parser.parse_args(argv)
        return (run or run_command)(args)
    except (UsageError, CommandError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return USAGE_ERROR
