"""``ankle``: the system's command line."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from device import cli as device_cli


def _parser() -> device_cli.Parser:
    parser = device_cli.Parser(
        prog="ankle",
        description="Ankle telerehabilitation on the Rutgers Ankle: server, home station, "
        "device, simulation, benchmarks.",
    )
    sub = parser.add_subparsers(dest="command", required=True, parser_class=device_cli.Parser)
    run = sub.add_parser(
        "run",
        help="the whole system on its embedded defaults: server, simulated device, station",
    )
    run.add_argument("--data-dir", type=Path, default=Path("ankle-data"))
    run.add_argument("--host", default="127.0.0.1")
    run.add_argument("--port", type=int, default=8000)
    run.add_argument(
        "--page-port", type=int, default=8765, help="the patient's page on this computer"
    )
    run.add_argument(
        "--seconds", type=float, default=None, help="stop after this long (default: Ctrl-C)"
    )
    console = sub.add_parser(
        "console", help="the simulated device with a console client, no server (one line/s)"
    )
    console.add_argument("--seconds", type=float, default=None)
    server = sub.add_parser("server", help="the server (settings from ANKLE_* variables)")
    server.add_argument("--data-dir", type=Path, default=None)
    server.add_argument("--host", default=None)
    server.add_argument("--port", type=int, default=None)
    from station.cli import add_arguments

    add_arguments(sub.add_parser("station", help="the patient's home station"))
    device_cli.add_commands(sub)
    _add_bench_server(sub)
    return parser


def _add_bench_server(sub: argparse._SubParsersAction[device_cli.Parser]) -> None:
    """``bench server``, next to the device's ``bench control`` and ``bench link``."""
    bench = sub.choices["bench"]
    benches = next(a for a in bench._actions if isinstance(a, argparse._SubParsersAction))
    p = benches.add_parser(
        "server", help="live relay: many simulated stations and viewers on a real server"
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--stations", type=device_cli._ranged(int, 1, 2000), default=100, help="default 100"
    )
    p.add_argument(
        "--viewers-per-station", type=device_cli._ranged(int, 1, 20), default=1, help="default 1"
    )
    p.add_argument(
        "--seconds", type=device_cli._ranged(float, 1.0, 3600.0), default=20.0, help="window (s)"
    )
    p.add_argument(
        "--sweep",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="then 25, 50, 100, 150, 200 stations for 5 s each, until p99 > 50 ms (default on)",
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] in (["run"], ["console"], ["server"], ["station"]):
        try:
            args = parser.parse_args(argv)
        except device_cli.UsageError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return device_cli.USAGE_ERROR
        if args.command == "console":
            from device.console import run_console

            return run_console(args.seconds)
        if args.command == "run":
            from ankle.system import run_system

            return run_system(
                args.data_dir, args.host, args.port, args.seconds, page_port=args.page_port
            )
        if args.command == "server":
            from server.cli import serve
            from server.config import Settings
            from webui.app import create_app

            overrides = {
                k: v
                for k, v in (("data_dir", args.data_dir), ("host", args.host), ("port", args.port))
                if v is not None
            }
            serve(Settings(**overrides), create_app)
            return 0
        from station.cli import run as run_station
        from webui.patient import serve_patient_page

        return run_station(args, page=serve_patient_page)
    if argv[:2] == ["bench", "server"]:
        try:
            args = parser.parse_args(argv)
        except device_cli.UsageError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return device_cli.USAGE_ERROR
        from server import bench

        result = bench.run(args.stations, args.viewers_per_station, args.seconds, args.sweep)
        print(json.dumps(bench.jsonable(result), indent=2) if args.json else bench.table(result))
        return 0
    return device_cli.dispatch(parser, argv)


if __name__ == "__main__":
    sys.exit(main())
