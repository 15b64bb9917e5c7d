"""``ankle station``: the patient's home station."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import os
import signal
from pathlib import Path

from station.app import Station, StationConfig


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--device",
        required=True,
        help="the platform's serial link: a port (/dev/ttyUSB0), a pty name or socket://H:P",
    )
    p.add_argument("--server", required=True, help="the server's URL, e.g. http://clinic:8000")
    p.add_argument(
        "--token",
        default=os.environ.get("ANKLE_STATION_TOKEN"),
        help="this station's token (default: $ANKLE_STATION_TOKEN); given once at provisioning",
    )
    p.add_argument(
        "--spool",
        type=Path,
        default=Path("ankle-station"),
        help="directory for sessions waiting to upload (default: ./ankle-station)",
    )
    p.add_argument("--baud", type=int, default=921600)
    p.add_argument(
        "--autostart",
        action="store_true",
        help="start the first active prescription as soon as the platform is connected",
    )
    p.add_argument(
        "--repeat-after",
        type=float,
        default=None,
        metavar="S",
        help="with --autostart: start it again S seconds after each session (a demo)",
    )


def run(args: argparse.Namespace) -> int:
    if not args.token:
        print("error: ankle station: --token (or ANKLE_STATION_TOKEN) is required")
        return 2
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    logging.getLogger("httpx").setLevel(logging.WARNING)  # one line per upload chunk is noise
    station = Station(
        StationConfig(
            device=args.device,
            server=args.server,
            token=args.token,
            spool=args.spool,
            autostart=args.autostart,
            repeat_after_s=args.repeat_after,
            baud=args.baud,
        )
    )
    return asyncio.run(_main(station))


async def _main(station: Station) -> int:
    loop = asyncio.get_running_loop()
    task = asyncio.create_task(station.run())
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, task.cancel)
    with contextlib.suppress(asyncio.CancelledError):
        await task
    return 0
