"""``ankle``: the system's command line."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from device import cli as device_cli
from device import installed_version
from lab import cli as lab_cli


def _parser() -> device_cli.Parser:
    parser = device_cli.Parser(
        prog="ankle",
        description="Ankle telerehabilitation on the Rutgers Ankle: server, home station, "
        "device, simulation, benchmarks.",
    )
    parser.add_argument("--version", action="version", version=f"ankle {installed_version()}")
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
    _add_admin(sub)
    from station.cli import add_arguments

    add_arguments(sub.add_parser("station", help="the patient's home station"))
    device_cli.add_commands(sub)
    lab_cli.add_commands(sub)
    return parser


def _add_admin(sub: argparse._SubParsersAction[device_cli.Parser]) -> None:
    admin = sub.add_parser(
        "admin",
        help="accounts on the server's database (ANKLE_* settings): create the first admin, "
        "reset a password",
    )
    commands = admin.add_subparsers(
        dest="admin_command", required=True, parser_class=device_cli.Parser
    )
    create = commands.add_parser(
        "create-user",
        help="create a therapist or admin; without --password-stdin a one-time password is "
        "printed once and must be changed at the first sign-in",
    )
    create.add_argument("--email", required=True)
    create.add_argument("--name", required=True)
    create.add_argument("--role", required=True, choices=("admin", "therapist"))
    create.add_argument(
        "--password-stdin",
        action="store_true",
        help="read the account's own password from the first line of standard input",
    )
    reset = commands.add_parser(
        "reset-password",
        help="print a new one-time password (changed at the next sign-in); ends every login",
    )
    reset.add_argument("--email", required=True)
    for command in (create, reset):
        command.add_argument(
            "--data-dir", type=Path, default=None, help="default: ANKLE_DATA_DIR or ./ankle-data"
        )


def _admin(args: argparse.Namespace) -> int:
    import asyncio

    from server.cli import AdminError, create_user_async, reset_password_async
    from server.config import Settings

    settings = Settings(**({"data_dir": args.data_dir} if args.data_dir is not None else {}))
    try:
        if args.admin_command == "create-user":
            password = None
            if args.password_stdin:
                password = sys.stdin.readline().rstrip("\r\n")
                if not password:
                    raise AdminError("--password-stdin: standard input has no password")
            user, one_time = asyncio.run(
                create_user_async(settings, args.email, args.name, args.role, password)
            )
            print(f"Created {user.role} {user.name} <{user.email}> (id {user.id}).")
            if one_time is not None:
                print(f"One-time password: {one_time}")
                print("It is shown only now and must be changed at the first sign-in.")
            return 0
        user, one_time = asyncio.run(reset_password_async(settings, args.email))
    except AdminError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return device_cli.USAGE_ERROR
    print(f"New one-time password for {user.name} <{user.email}>: {one_time}")
    print("It is shown only now and must be changed at the next sign-in; every login of the")
    print("account has ended.")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] in (["run"], ["console"], ["server"], ["station"], ["admin"]):
        try:
            args = parser.parse_args(argv)
        except device_cli.UsageError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return device_cli.USAGE_ERROR
        if args.command == "admin":
            return _admin(args)
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
