"""``ankle``: the system's command line."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from device import cli as device_cli
from lab import cli as lab_cli


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
    lab_cli.add_commands(sub)
    return parser


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
    return device_cli.dispatch(parser, argv, _run)


def _run(args: argparse.Namespace) -> int:
    if args.command in ("sim", "bench"):
        return lab_cli.run_command(args)
    return device_cli.run_command(args)


if __name__ == "__main__":
    sys.exit(main())
