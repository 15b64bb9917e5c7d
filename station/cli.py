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
import signal
import socket
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from sessions.wire import BATCH_HZ, BATCH_HZ_MAX
from station.reasons import HOLD_LIMIT_S

if TYPE_CHECKING:  # loaded by run(): `ankle --help` (and `ankle device`, on the embedded PC,
    # which builds every command's options) needs no device link, web client or settings
    from station.app import Station
    from station.config import StationConfig


FLAGS: dict[str, str] = {
    "device": "--device",
    "server": "--server",
    "token": "--token",
    "spool": "--spool",
    "baud": "--baud",
    "autostart": "--autostart",
    "repeat_after_s": "--repeat-after",
    "hold_limit_s": "--hold-limit",
    "batch_hz": "--batch-hz",
    "page_port": "--page-port",
    "page_host": "--page-host",
}
"""Each setting's option (its variable is ANKLE_STATION_ and the setting's name in capitals)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options; each one left out keeps its ANKLE_STATION_* variable, or the default."""
    p.add_argument(
        "--device",
        dest="device",
        help="the platform's serial link: a port (/dev/ttyUSB0), a pty name or socket://H:P "
        "($ANKLE_STATION_DEVICE)",
    )
    p.add_argument(
        "--server",
        dest="server",
        help="the server's URL, e.g. http://clinic:8000 ($ANKLE_STATION_SERVER)",
    )
    p.add_argument(
        "--token",
        dest="token",
        help="this station's token ($ANKLE_STATION_TOKEN); given once at provisioning",
    )
    p.add_argument(
        "--spool",
        dest="spool",
        type=Path,
        help="directory for sessions waiting to upload (default: ./ankle-station)",
    )
    p.add_argument("--baud", dest="baud", type=int)
    p.add_argument(
        "--autostart",
        dest="autostart",
        action="store_const",
        const=True,
        help="start the first active prescription as soon as the platform is connected",
    )
    p.add_argument(
        "--repeat-after",
        dest="repeat_after_s",
        type=float,
        metavar="S",
        help="with --autostart: start it again S seconds after each session that finished "
        "(a demo); a stop ends the repeats until the next start",
    )
    p.add_argument(
        "--hold-limit",
        dest="hold_limit_s",
        type=float,
        metavar="S",
        help=f"end an exercise held (paused, HOLD, or held by the device) for S seconds: the "
        f"platform goes home, the session ends 'interrupted' (default {HOLD_LIMIT_S:g})",
    )
    p.add_argument(
        "--batch-hz",
        dest="batch_hz",
        type=float,
        metavar="HZ",
        help=f"telemetry messages a second to the server, each carrying the samples since the "
        f"last (default {BATCH_HZ:g}: 4 samples of the device's 100 Hz; 1..{BATCH_HZ_MAX:g})",
    )
    p.add_argument(
        "--page-port",
        dest="page_port",
        type=int,
        metavar="PORT",
        help="the patient's page on http://HOST:PORT/ (default 8765; 0: no page)",
    )
    p.add_argument(
        "--page-host",
        dest="page_host",
        metavar="HOST",
        help="address the patient's page listens on (default 127.0.0.1: this computer only)",
    )


def settings(args: argparse.Namespace) -> StationConfig:
    """The station's settings: the options given, over the ANKLE_STATION_* variables, over
    the defaults. Raises :class:`SettingsError` naming the option of a value refused."""
    from station.config import StationConfig

    given = {name: getattr(args, name) for name in FLAGS if getattr(args, name, None) is not None}
    try:
        return StationConfig(**given)
    except ValidationError as exc:
        first = exc.errors()[0]
        name = str(first["loc"][0]) if first["loc"] else ""
        flag = FLAGS.get(name, name)
        where = flag if name in given else f"{flag} (or ANKLE_STATION_{name.upper()})"
        raise SettingsError(f"{where} {first['msg']}") from None


class SettingsError(ValueError):
    """A setting refused, in one line naming its option."""


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
    try:
        config = settings(args)
    except SettingsError as exc:
        print(f"error: ankle station: {exc}")
        return 2
    from station.spool import Spool, SpoolInUse

    spool = Spool(config.spool)
    try:
        spool.lock()
    except SpoolInUse as exc:
        print(f"error: ankle station: {exc}")
        return 2
    if page is not None and config.page_port:
        taken = port_taken(config.page_host, config.page_port)
        if taken is not None:
            print(
                f"error: ankle station: the patient's page cannot listen on "
                f"{config.page_host}:{config.page_port} ({taken}); is another station running? "
                "Stop it, or pass --page-port with a free port (0: no page)."
            )
            return 2
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    logging.getLogger("httpx").setLevel(logging.WARNING)  # one line per upload chunk is noise
    from station.app import Station

    station = Station(config, spool)
    served = None
    if page is not None and config.page_port:
        served = (page, config.page_host, config.page_port)
    return asyncio.run(_main(station, served))


async def _main(station: Station, page: tuple[PageServer, str, int] | None = None) -> int:
    loop = asyncio.get_running_loop()
    task = asyncio.create_task(station.run())
    page_task: asyncio.Task[None] | None = None
    if page is not None:
        serve, host, port = page
        page_task = asyncio.create_task(serve(station, host, port), name="patient-page")
        page_task.add_done_callback(_page_ended)
    stopping: list[asyncio.Task[None]] = []

    def stop(sig: signal.Signals) -> None:
        # The first signal stops the station as STOP stops an exercise: the platform holds
        # and goes home, the session ends "stopped", saying so, and is on disk. Another one
        # (a supervisor sends two) does not cut that short; it is bounded (STOP_WAIT_S).
        if not stopping:
            why = f"the station was stopped ({sig.name})"
            stopping.append(asyncio.create_task(_stop(station, task, why), name="stopping"))

    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop, sig)
    try:
        with contextlib.suppress(asyncio.CancelledError):
            await task
    finally:
        if page_task is not None:
            page_task.cancel()
            await asyncio.gather(page_task, return_exceptions=True)
    return 0


async def _stop(station: Station, task: asyncio.Task[None], why: str) -> None:
    try:
        await station.wind_down(why)
    finally:
        task.cancel()


def _page_ended(task: asyncio.Task[None]) -> None:
    # The exercise, its recording and the device's safety do not depend on the page: a page
    # that cannot listen (the port is taken) is reported and the station carries on.
    if not task.cancelled() and task.exception() is not None:
        logging.getLogger("ankle.station").error(
            "the patient's page is not available: %s", task.exception()
        )
