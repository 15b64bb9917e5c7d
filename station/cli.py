"""``ankle station``: the patient's home station.

The patient's page is served from the station's own event loop, but it is web code and lives
in ``webui``, above this package: the caller hands its server in as ``page`` (``ankle`` does),
so the station never imports it and runs the same without it.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import os
import signal
import socket
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sessions.wire import BATCH_HZ, BATCH_HZ_MAX
from station.reasons import HOLD_LIMIT_S

if TYPE_CHECKING:  # loaded by run(): `ankle --help` needs no device link or web client
    from station.app import Station

HOLD_LIMIT_MAX_S = 3600.0


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
    p.add_argument(
        "--hold-limit",
        type=float,
        default=HOLD_LIMIT_S,
        metavar="S",
        help=f"end an exercise held (paused, HOLD, or held by the device) for S seconds: the "
        f"platform goes home, the session ends 'interrupted' (default {HOLD_LIMIT_S:g})",
    )
    p.add_argument(
        "--batch-hz",
        type=float,
        default=BATCH_HZ,
        metavar="HZ",
        help=f"telemetry messages a second to the server, each carrying the samples since the "
        f"last (default {BATCH_HZ:g}: 4 samples of the device's 100 Hz; 1..{BATCH_HZ_MAX:g})",
    )
    p.add_argument(
        "--page-port",
        type=int,
        default=8765,
        metavar="PORT",
        help="the patient's page on http://HOST:PORT/ (default 8765; 0: no page)",
    )
    p.add_argument(
        "--page-host",
        default="127.0.0.1",
        metavar="HOST",
        help="address the patient's page listens on (default 127.0.0.1: this computer only)",
    )


def port_taken(host: str, port: int) -> str | None:
    """Why nothing can listen on (host, port) now, e.g. "address already in use"; None if it
    can. Checked at start-up so that a taken port is an error, not a silently missing page."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host.strip("[]"), port))
        except OSError as exc:
            return (exc.strerror or str(exc)).lower()
    return None


PageServer = Callable[["Station", str, int], Coroutine[Any, Any, None]]
"""Serves the patient's page for a station on (host, port) until cancelled."""


def run(args: argparse.Namespace, page: PageServer | None = None) -> int:
    if not args.token:
        print("error: ankle station: --token (or ANKLE_STATION_TOKEN) is required")
        return 2
    if not 0 < args.hold_limit <= HOLD_LIMIT_MAX_S:  # also refuses nan
        print(
            f"error: ankle station: --hold-limit {args.hold_limit:g} is not a time from "
            f"more than 0 to {HOLD_LIMIT_MAX_S:g} s"
        )
        return 2
    if not 1 <= args.batch_hz <= BATCH_HZ_MAX:  # also refuses nan
        print(
            f"error: ankle station: --batch-hz {args.batch_hz:g} is not a rate from 1 to "
            f"{BATCH_HZ_MAX:g} messages a second"
        )
        return 2
    if not 0 <= args.page_port <= 65535:
        print(f"error: ankle station: --page-port {args.page_port} is not a port (0..65535)")
        return 2
    if page is not None and args.page_port:
        taken = port_taken(args.page_host, args.page_port)
        if taken is not None:
            print(
                f"error: ankle station: the patient's page cannot listen on "
                f"{args.page_host}:{args.page_port} ({taken}); is another station running? "
                "Stop it, or pass --page-port with a free port (0: no page)."
            )
            return 2
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    logging.getLogger("httpx").setLevel(logging.WARNING)  # one line per upload chunk is noise
    from station.app import Station, StationConfig

    station = Station(
        StationConfig(
            device=args.device,
            server=args.server,
            token=args.token,
            spool=args.spool,
            autostart=args.autostart,
            repeat_after_s=args.repeat_after,
            hold_limit_s=args.hold_limit,
            batch_hz=args.batch_hz,
            baud=args.baud,
        )
    )
    served = None
    if page is not None and args.page_port:
        served = (page, args.page_host, args.page_port)
    return asyncio.run(_main(station, served))


async def _main(station: Station, page: tuple[PageServer, str, int] | None = None) -> int:
    loop = asyncio.get_running_loop()
    task = asyncio.create_task(station.run())
    page_task: asyncio.Task[None] | None = None
    if page is not None:
        serve, host, port = page
        page_task = asyncio.create_task(serve(station, host, port), name="patient-page")
        page_task.add_done_callback(_page_ended)
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, task.cancel)
    try:
        with contextlib.suppress(asyncio.CancelledError):
            await task
    finally:
        if page_task is not None:
            page_task.cancel()
            await asyncio.gather(page_task, return_exceptions=True)
    return 0


def _page_ended(task: asyncio.Task[None]) -> None:
    # The exercise, its recording and the device's safety do not depend on the page: a page
    # that cannot listen (the port is taken) is reported and the station carries on.
    if not task.cancelled() and task.exception() is not None:
        logging.getLogger("ankle.station").error(
            "the patient's page is not available: %s", task.exception()
        )
