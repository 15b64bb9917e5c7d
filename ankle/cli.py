"""``ankle``: the system's command line."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from device import cli as device_cli


def main(argv: Sequence[str] | None = None) -> int:
    parser = device_cli.Parser(
        prog="ankle",
        description="Ankle telerehabilitation on the Rutgers Ankle: device, simulation, "
        "benchmarks.",
    )
    sub = parser.add_subparsers(dest="command", required=True, parser_class=device_cli.Parser)
    run = sub.add_parser("run", help="run the system on its embedded defaults (simulated device)")
    run.add_argument(
        "--seconds",
        type=float,
        default=None,
        help="stop after this much time (default: until Ctrl-C)",
    )
    device_cli.add_commands(sub)
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["run"]:
        from device.console import run_console

        try:
            args = parser.parse_args(argv)
        except device_cli.UsageError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return device_cli.USAGE_ERROR
        return run_console(args.seconds)
    return device_cli.dispatch(parser, argv)


if __name__ == "__main__":
    sys.exit(main())
