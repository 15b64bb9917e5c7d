"""``ankle run``: the whole system on one machine, on its embedded defaults.

Three processes, as in production: the server (SQLite under ``--data-dir``), the simulated
device service on a pseudo-terminal, and a home station that connects the two. A demo
therapist, patient, station and prescription are created on first start; their credentials
are kept in ``<data-dir>/demo-credentials.json`` (mode 0600) and printed. Ctrl-C stops the
station (the platform holds and homes), then the device (valves closed), then the server.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, TextIO

from device.process import ServiceProcess, ServiceStartError
from server.cli import ServerStartError, wait_healthy

PATIENT_PAGE_PORT = 8765
"""Where the station serves the patient's page, on localhost."""


class StartError(Exception):
    """The system could not start; the message says which part and why."""


def _python_module(*args: str, env: dict[str, str] | None = None) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", "ankle", *args],
        env={**os.environ, **(env or {})},
        start_new_session=True,  # Ctrl-C reaches us only; we stop the children in order
    )


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _stop(proc: subprocess.Popen[bytes] | None, timeout: float = 10.0) -> None:
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def run_system(
    data_dir: Path,
    host: str = "127.0.0.1",
    port: int = 8000,
    seconds: float | None = None,
    out: TextIO = sys.stdout,
    page_port: int = PATIENT_PAGE_PORT,
) -> int:
    from server.cli import provision_demo
    from server.config import Settings

    settings = Settings(data_dir=data_dir, host=host, port=port)
    # A service manager, `timeout` or a closed terminal stops us with SIGTERM or SIGHUP, not
    # Ctrl-C: the same orderly stop, or the children (started in their own sessions) would be
    # left running without us.
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _interrupt)
    url = f"http://{host}:{port}"
    creds: dict[str, Any] = provision_demo(settings)
    server = station = None
    device: ServiceProcess | None = None
    env = {"ANKLE_DATA_DIR": str(data_dir), "ANKLE_HOST": host, "ANKLE_PORT": str(port)}
    try:
        print(f"ankle: starting the server on {url} (data in {data_dir})", file=out)
        server = _python_module("server", env=env)
        try:
            wait_healthy(url, server)
        except ServerStartError as exc:
            raise StartError(str(exc)) from None
        print("ankle: starting the simulated device (first start compiles for ~20 s)", file=out)
        try:
            device = ServiceProcess("--link", "pty", "--patient-torque", "3")
        except ServiceStartError as exc:
            raise StartError(str(exc)) from None
        station = _python_module(
            "station",
            "--device",
            device.link,
            "--server",
            url,
            "--spool",
            str(data_dir / "station"),
            "--autostart",
            "--repeat-after",
            "15",
            "--page-port",
            str(page_port),
            env={"ANKLE_STATION_TOKEN": creds["station_token"]},
        )
        _banner(out, url, device.link, creds, page_port)
        deadline = None if seconds is None else time.monotonic() + seconds
        while deadline is None or time.monotonic() < deadline:
            for name, proc in (("server", server), ("station", station)):
                if proc.poll() is not None:
                    raise StartError(f"the {name} exited with code {proc.returncode}")
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    except StartError as exc:
        print(f"ankle: {exc}", file=sys.stderr)
        return 1
    finally:
        _stop(station)
        if device is not None:
            device.stop()
        _stop(server)
        print("ankle: stopped; valves closed.", file=out)
    return 0


def _banner(out: TextIO, url: str, link: str, creds: dict[str, Any], page_port: int) -> None:
    station_id = creds.get("station_id")
    lines = [
        "",
        "  The ankle telerehabilitation system is running (simulated device).",
        f"  Therapist dashboard        {url}/app/",
        f"  Therapist sign-in          {creds.get('therapist_email')} / "
        f"{creds.get('therapist_password')}",
        f"  Live view of the demo      {url}/app/live/{station_id}",
        f"  Patient's page (station)   http://127.0.0.1:{page_port}/",
        f"  API and its documentation  {url}/api/v1/docs",
        f"  WebSocket message schemas  {url}/api/v1/schemas/ws",
        f"  Device link                {link}",
        f"  Demo patient               {creds.get('patient_name', '')} "
        f"(id {creds.get('patient_id')}), station {station_id}",
        "  The station runs the demo prescription now and again 15 s after each session;",
        "  watch it live, then review it under the patient's sessions. Ctrl-C stops everything.",
        "",
    ]
    print("\n".join(lines), file=out, flush=True)
