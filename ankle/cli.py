"""``ankle``: the system's command line."""

from __future__ import annotations

import argparse
import os
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
    server.add_argument(
        "--workers",
        type=int,
        default=1,
        help="server processes sharing the port (default 1); more than one needs the Redis "
        "relay (ANKLE_RELAY_URL) so that a station and its viewers may sit on different ones",
    )
    _add_admin(sub)
    _add_db(sub)
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


def _add_db(sub: argparse._SubParsersAction[device_cli.Parser]) -> None:
    db = sub.add_parser(
        "db",
        help="the server's database schema (ANKLE_DATABASE_URL): upgrade, show the revision, "
        "print the SQL and the grants for a DBA",
    )
    commands = db.add_subparsers(dest="db_command", required=True, parser_class=device_cli.Parser)
    commands.add_parser("upgrade", help="bring the schema up to date (safe to run at any time)")
    commands.add_parser("current", help="the database's revision and the one this server needs")
    sql = commands.add_parser(
        "sql", help="print the SQL that upgrades the schema, without connecting (for a DBA)"
    )
    sql.add_argument(
        "--from", dest="start", default=None, help="the database's revision (default: empty)"
    )
    grants = commands.add_parser(
        "grants",
        help="print the SQL giving the server's PostgreSQL role its privileges (the audit "
        "log: insert and read only)",
    )
    grants.add_argument("--role", required=True, help="the role the server connects as")
    for command in commands.choices.values():
        command.add_argument(
            "--data-dir", type=Path, default=None, help="default: ANKLE_DATA_DIR or ./ankle-data"
        )


def _db(args: argparse.Namespace) -> int:
    import asyncio

    from server import db
    from server.config import load_settings

    settings = load_settings(**({"data_dir": args.data_dir} if args.data_dir is not None else {}))
    if args.db_command == "sql":
        print(db.migration_sql(settings.database_url, args.start), end="")
        return 0
    if args.db_command == "grants":
        try:
            print(db.grants_sql(settings.database_url, args.role), end="")
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return device_cli.USAGE_ERROR
        return 0

    async def run() -> db.Revisions:
        await db.check_reachable(settings)
        engine = db.create_engine(settings)
        try:
            if args.db_command == "upgrade":
                await db.migrate(engine)
            return await db.revisions(engine)
        finally:
            await engine.dispose()

    found = asyncio.run(run())
    state = "up to date" if found.current == found.head else "behind: run `ankle db upgrade`"
    print(f"revision {found.current or 'none (empty database)'}; head {found.head}; {state}")
    return 0


def _server(args: argparse.Namespace) -> int:
    import asyncio

    from server.cli import serve, settings_into_environment
    from server.config import load_settings
    from server.db import check_reachable
    from webui.app import create_app

    if args.workers < 1:
        print("error: --workers must be 1 or more", file=sys.stderr)
        return device_cli.USAGE_ERROR
    overrides = {
        k: v
        for k, v in (("data_dir", args.data_dir), ("host", args.host), ("port", args.port))
        if v is not None
    }
    settings = load_settings(**overrides)
    if args.workers > 1 and not settings.relay_url:
        print(
            "error: --workers above 1 needs the live relay (ANKLE_RELAY_URL=redis://...):"
            " without it a station and its viewers on different processes would not"
            " see each other",
            file=sys.stderr,
        )
        return device_cli.USAGE_ERROR
    # One line each, not a traceback from every process's start-up.
    asyncio.run(check_reachable(settings, schema=True))
    if settings.relay_url:
        from server.redis_relay import check_reachable as check_relay

        asyncio.run(check_relay(settings.relay_url))
    settings_into_environment(settings, overrides)
    serve(settings, create_app, workers=args.workers, worker_factory="webui.app:create_app")
    return 0


def _admin(args: argparse.Namespace) -> int:
    import asyncio

    from server.cli import AdminError, create_user_async, reset_password_async
    from server.config import load_settings
    from server.db import check_reachable

    settings = load_settings(**({"data_dir": args.data_dir} if args.data_dir is not None else {}))
    asyncio.run(check_reachable(settings))
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
    """The ``ankle`` command. Its output piped into a reader that stops early (``| head``)
    ends it quietly, as other command-line tools end, not with a traceback."""
    try:
        code = _main(argv)
        sys.stdout.flush()  # inside the try: a closed pipe shows here, not at exit
        return code
    except BrokenPipeError:
        # Python flushes stdout again at exit: point it at nothing so that cannot fail too.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1


def _main(argv: Sequence[str] | None) -> int:
    parser = _parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] in (["run"], ["console"], ["server"], ["station"], ["admin"], ["db"]):
        try:
            args = parser.parse_args(argv)
        except device_cli.UsageError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return device_cli.USAGE_ERROR
        if args.command in ("admin", "db", "server"):
            from server.cli import ServerStartError
            from server.config import SettingsError
            from server.db import DatabaseUnreachable, SchemaNotCurrent
            from server.relay import RelayUnreachable

            command = {"admin": _admin, "db": _db, "server": _server}[args.command]
            try:
                return command(args)
            except SettingsError as exc:
                print(f"error: {exc}", file=sys.stderr)
                return device_cli.USAGE_ERROR
            # The setting may be right, and what it names away or not ready.
            except (
                DatabaseUnreachable,
                SchemaNotCurrent,
                RelayUnreachable,
                ServerStartError,
            ) as exc:
                print(f"error: {exc}", file=sys.stderr)
                return 1
        if args.command == "console":
            from device.console import run_console

            return run_console(args.seconds)
        if args.command == "run":
            from ankle.system import run_system

            return run_system(
                args.data_dir, args.host, args.port, args.seconds, page_port=args.page_port
            )
        from station.cli import run as run_station
        from webui.home.app import serve_patient_page

        return run_station(args, page=serve_patient_page)
    return device_cli.dispatch(parser, argv, _run)


def _run(args: argparse.Namespace) -> int:
    if args.command in ("sim", "bench"):
        return lab_cli.run_command(args)
    return device_cli.run_command(args)


if __name__ == "__main__":
    sys.exit(main())
