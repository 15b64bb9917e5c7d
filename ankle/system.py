"""``ankle run``: the whole system on one machine, on its embedded defaults.

Three processes, as in production: the server (SQLite under ``--data-dir``), the simulated
device service on a pseudo-terminal, and a home station that connects the two. A demo
therapist, patient, station and prescription are created on first start; their credentials
are kept in ``<data-dir>/demo-credentials.json`` (mode 0600) and printed. Ctrl-C stops the
station (the platform holds and homes), then the device (valves closed), then the server.

It supervises them: a child that exits is started again after a growing delay (1, 2, 4 …
16 s; a new device also gets a new station, on its new link), each restart said on the
output; a child that needs more than five restarts within two minutes is in a crash loop,
and everything stops with a message naming it. A port that is taken is an error before
anything starts.
"""

from __future__ import annotations

import collections
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, TextIO

from device.process import ServiceProcess, ServiceStartError
from server.cli import ServerStartError, wait_healthy
from station.cli import port_taken

PATIENT_PAGE_PORT = 8765
"""Where the station serves the patient's page, on localhost."""
DEMO_REPEAT_S = 180
"""The demo runs its exercise again this long after each one that finished: often enough to
watch, seldom enough that the history holds a day's sessions rather than a hundred an hour.
STOP on the patient's page ends the repeats until Start is pressed."""


class StartError(Exception):
    """The system could not start; the message says which part and why."""


@dataclass
class RestartPolicy:
    """When a child that exited is started again, and when to give up.

    The n-th restart within ``window_s`` waits ``first_delay_s * 2**(n-1)`` (at most
    ``max_delay_s``); a child that needs more than ``max_restarts`` restarts within
    ``window_s`` is in a crash loop and everything stops. One supervisor restarts its own
    children, so no jitter is needed: there is no crowd of clients to spread out.
    """

    first_delay_s: float = 1.0
    max_delay_s: float = 16.0
    window_s: float = 120.0
    max_restarts: int = 5

    def delay(self, recent: int) -> float:
        return float(min(self.max_delay_s, self.first_delay_s * 2**recent))


class _Child:
    """One supervised process: how to start it, and its recent restarts."""

    def __init__(
        self, name: str, start: Callable[[], _Proc], dependents: Sequence[_Child] = ()
    ) -> None:
        self.name = name
        self._start = start
        self.dependents = dependents
        """Children that hold a link this one opens: started again after it is."""
        self.proc: _Proc | None = None
        self.restarts: collections.deque[float] = collections.deque()
        self.due: float | None = None
        """When a scheduled restart falls due (monotonic seconds)."""

    def start(self) -> None:
        self.proc = self._start()
        self.due = None

    def exit_code(self) -> int | None:
        """Its exit code if it has exited (and no restart is already scheduled)."""
        if self.proc is None or self.due is not None:
            return None
        return self.proc.poll()

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.stop()


class _Proc(Protocol):
    def poll(self) -> int | None: ...

    def stop(self) -> None: ...

    def last_output(self) -> str: ...


class _Module:
    """``python -m ankle ARGS`` in its own session (Ctrl-C reaches us only; we stop the
    children in order), its output going to ours."""

    def __init__(self, *args: str, env: dict[str, str] | None = None) -> None:
        self.popen = subprocess.Popen(
            [sys.executable, "-m", "ankle", *args],
            env={**os.environ, **(env or {})},
            start_new_session=True,
        )

    def poll(self) -> int | None:
        return self.popen.poll()

    def stop(self, timeout: float = 10.0) -> None:
        if self.popen.poll() is not None:
            return
        self.popen.send_signal(signal.SIGTERM)
        try:
            self.popen.wait(timeout)
        except subprocess.TimeoutExpired:
            self.popen.kill()
            self.popen.wait()

    def last_output(self) -> str:
        return ""  # it writes to our own output: already on the screen


class _Device:
    """The simulated device service on a pseudo-terminal (``device.process``)."""

    def __init__(self) -> None:
        try:
            self.service = ServiceProcess("--link", "pty", "--patient-torque", "3")
        except ServiceStartError as exc:
            raise StartError(str(exc)) from None

    def poll(self) -> int | None:
        return self.service.proc.poll()

    def stop(self) -> None:
        self.service.stop()

    def last_output(self) -> str:
        return "\n".join(list(self.service.output)[-10:])


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def _interrupt(signum: int, frame: object) -> None:
    """The first stop signal starts the orderly stop; the ones after it are ignored (each
    child's stop is bounded: SIGKILL after 10 s). ``make run`` under ``timeout`` or a
    service manager gets SIGTERM twice (make passes on its own), and the second, raised
    inside the stop, cut it short: the server and the station were left running."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)
    raise KeyboardInterrupt


def _describe(code: int) -> str:
    if code < 0:
        try:
            return f"was killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"was killed by signal {-code}"
    return f"exited with code {code}"


def _check_ports(host: str, port: int, page_port: int) -> None:
    for what, where, option in (
        ("the server", (host, port), "--port"),
        ("the patient's page", ("127.0.0.1", page_port), "--page-port"),
    ):
        taken = port_taken(*where)
        if taken is not None:
            raise StartError(
                f"{what} cannot listen on {where[0]}:{where[1]} ({taken}). Is the system "
                f"already running? Stop it, or choose another port with {option}."
            )


def run_system(
    data_dir: Path,
    host: str = "127.0.0.1",
    port: int = 8000,
    seconds: float | None = None,
    out: TextIO = sys.stdout,
    page_port: int = PATIENT_PAGE_PORT,
    policy: RestartPolicy | None = None,
) -> int:
    from server.cli import provision_demo
    from server.config import Settings

    policy = policy or RestartPolicy()
    settings = Settings(data_dir=data_dir, host=host, port=port)
    # A service manager, `timeout` or a closed terminal stops us with SIGTERM or SIGHUP, not
    # Ctrl-C: the same orderly stop, or the children (started in their own sessions) would be
    # left running without us.
    for sig in STOP_SIGNALS:
        signal.signal(sig, _interrupt)
    url = f"http://{host}:{port}"
    env = {"ANKLE_DATA_DIR": str(data_dir), "ANKLE_HOST": host, "ANKLE_PORT": str(port)}
    children: list[_Child] = []
    try:
        _check_ports(host, port, page_port)
        creds: dict[str, Any] = provision_demo(settings)

        def start_server() -> _Proc:
            proc = _Module("server", env=env)
            try:
                wait_healthy(url, proc.popen)
            except ServerStartError as exc:
                proc.stop()
                raise StartError(str(exc)) from None
            return proc

        def start_station() -> _Proc:
            assert isinstance(device.proc, _Device)
            return _Module(
                "station",
                *("--device", device.proc.service.link, "--server", url),
                *(
                    "--spool",
                    str(data_dir / "station"),
                    "--autostart",
                    "--repeat-after",
                    str(DEMO_REPEAT_S),
                ),
                *("--page-port", str(page_port)),
                env={"ANKLE_STATION_TOKEN": creds["station_token"]},
            )

        server = _Child("server", start_server)
        station = _Child("station", start_station)
        device = _Child("device", _Device, dependents=[station])
        print(f"ankle: starting the server on {url} (data in {data_dir})", file=out)
        children.append(server)
        server.start()
        print("ankle: starting the simulated device (first start compiles for ~2 min)", file=out)
        children.append(device)
        device.start()
        children.append(station)
        station.start()
        _banner(out, url, creds, page_port)
        _supervise(children, policy, seconds, out)
    except KeyboardInterrupt:
        pass
    except StartError as exc:
        print(f"ankle: {exc}", file=sys.stderr)
        return 1
    finally:
        # The station first (the platform holds and homes), then the device (valves
        # closed), then the server.
        for child in reversed(children):
            child.stop()
        if children:
            print("ankle: stopped; valves closed.", file=out)
    return 0


def _supervise(
    children: list[_Child], policy: RestartPolicy, seconds: float | None, out: TextIO
) -> None:
    """Restart a child that exits, with backoff, until ``seconds`` have passed (or forever).

    The station talks to the device over the device's link, which a new device process
    opens afresh: when the device is restarted, so are its dependents (after it).
    """
    deadline = None if seconds is None else time.monotonic() + seconds
    while deadline is None or time.monotonic() < deadline:
        now = time.monotonic()
        for child in children:
            code = child.exit_code()
            if code is not None:
                _schedule_restart(child, code, policy, now, out)
        for child in children:
            if child.due is not None and now >= child.due:
                print(f"ankle: restarting the {child.name}", file=out, flush=True)
                child.start()
                for dependent in child.dependents:
                    print(
                        f"ankle: restarting the {dependent.name} on the new {child.name}",
                        file=out,
                        flush=True,
                    )
                    dependent.stop()
                    dependent.start()
        time.sleep(0.2)


def _schedule_restart(
    child: _Child, code: int, policy: RestartPolicy, now: float, out: TextIO
) -> None:
    while child.restarts and now - child.restarts[0] > policy.window_s:
        child.restarts.popleft()
    last = child.proc.last_output() if child.proc is not None else ""
    if len(child.restarts) >= policy.max_restarts:
        tail = f" Its last output:\n{last}" if last else ""
        raise StartError(
            f"the {child.name} {_describe(code)} again: {len(child.restarts)} restarts in "
            f"{policy.window_s:g} s is a crash loop, so everything stops. Look at its log "
            f"above to see why.{tail}"
        )
    delay = policy.delay(len(child.restarts))
    child.restarts.append(now)
    child.due = now + delay
    print(
        f"ankle: the {child.name} {_describe(code)}; restarting it in {delay:g} s "
        f"(restart {len(child.restarts)} of at most {policy.max_restarts} in "
        f"{policy.window_s:g} s)",
        file=out,
        flush=True,
    )
    if last:
        print(f"ankle: the {child.name}'s last output:\n{last}", file=out, flush=True)


def _banner(out: TextIO, url: str, creds: dict[str, Any], page_port: int) -> None:
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
        f"  Demo patient               {creds.get('patient_name', '')} "
        f"(id {creds.get('patient_id')}), station {station_id}",
        "  The station runs the demo prescription now and again "
        f"{DEMO_REPEAT_S // 60} minutes after each one it finishes (STOP on the patient's page",
        "  ends that until Start is pressed); watch it live, then review it under the",
        "  patient's sessions. Ctrl-C stops everything.",
        "",
    ]
    print("\n".join(lines), file=out, flush=True)
