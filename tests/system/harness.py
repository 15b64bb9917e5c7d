"""The whole system as separate processes: server, simulated device on a pty, home station.

Nothing is in-process but the test's own clients (httpx for REST, websockets for the live
view), so what is tested is what ``make run`` starts.

It runs on one of two stacks (``STACKS``; tests/system's conftest runs each system test on
both):

- ``sqlite-local``: one server process on a SQLite file, with the in-process relay;
- ``pg-redis-2proc``: two server processes sharing a PostgreSQL database, a Redis relay and
  the data directory. The station connects to the first; the therapist's API and live view
  use the second, so everything the therapist sees of the station crossed processes.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar

import httpx
import pytest
import pytest_asyncio
from websockets.asyncio.client import ClientConnection, connect

from device.process import ServiceProcess
from server.cli import provision_demo, wait_healthy
from server.config import Settings
from sessions import wire
from tests.server.postgres import Cluster

M = TypeVar("M")

WATCHDOG_MS = 500
"""The device's watchdog in these tests (200 ms on a patient's device, ``ankle device``'s
default). A station sharing two cores with a browser's software WebGL, a server and the tests
can miss 200 ms of frames now and then, and a hold nobody caused fails a test about something
else; the watchdog's own tests stall the station for twice this, so it still holds for certain."""


def short_strength(title: str, repetitions: int = 2) -> dict[str, Any]:
    """A strength prescription of 4 s repetitions against K 40 N m/rad, B 2 N m s/rad:
    short enough for a test to run whole."""
    return {
        "exercise": "strength",
        "title": title,
        "axes": [
            {
                "axis": "pitch",
                "stiffness": 40.0,
                "damping": 2.0,
                "waveform": "sine",
                "amplitude": 6.0,
                "frequency": 0.5,
            }
        ],
        "sets": 1,
        "repetitions": repetitions,
        "repetition_s": 4.0,
        "rest_s": 0.0,
    }


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


Stack = Literal["sqlite-local", "pg-redis-2proc"]
STACKS: tuple[Stack, ...] = ("sqlite-local", "pg-redis-2proc")
RELAY_LEASE_S = 3.0
"""A station's presence lease on the Redis relay: short, so a killed server's stations go
offline within a test's patience, long enough for a loaded machine to refresh it."""


@dataclass
class System:
    """The running system. ``port`` is the server the therapist uses (API, dashboard, live
    view); ``station_port`` the one the station connects to: the same on one process."""

    data_dir: Path
    port: int
    creds: dict[str, Any]
    station_port: int = 0
    server_env: dict[str, str] = field(default_factory=dict)
    """The store and relay every server process shares (empty: SQLite in data_dir, local)."""
    servers: list[subprocess.Popen[bytes]] = field(default_factory=list)
    station: subprocess.Popen[bytes] | None = None
    logs: list[Path] = field(default_factory=list)
    page_port: int = 0
    device: ServiceProcess = field(init=False)
    """The simulated device, on a pty (the fixture starts it while the servers start)."""

    def __post_init__(self) -> None:
        self.station_port = self.station_port or self.port

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def station_url(self) -> str:
        return f"http://127.0.0.1:{self.station_port}"

    @property
    def station_id(self) -> int:
        return int(self.creds["station_id"])

    def _spawn(self, name: str, *args: str, env: dict[str, str]) -> subprocess.Popen[bytes]:
        log = self.data_dir / f"{name}-{len(self.logs)}.log"
        self.logs.append(log)
        with log.open("wb") as out:
            return subprocess.Popen(
                [sys.executable, "-m", "ankle", *args],
                env={**os.environ, **env},
                stdout=out,
                stderr=subprocess.STDOUT,
            )

    def start_servers(self) -> None:
        """Start the server processes (all at once) and wait until each answers."""
        ports = list(dict.fromkeys((self.station_port, self.port)))
        env = {"ANKLE_DATA_DIR": str(self.data_dir / "server"), **self.server_env}
        self.servers = [
            self._spawn("server", "server", env={**env, "ANKLE_PORT": str(port)}) for port in ports
        ]
        for port, proc in zip(ports, self.servers, strict=True):
            wait_healthy(f"http://127.0.0.1:{port}", proc, timeout=90.0)

    def stop_servers(self, sig: int = signal.SIGTERM) -> None:
        """Stop every server process with ``sig`` (SIGKILL: as a crash or a power cut)."""
        for proc in self.servers:
            self.stop(proc, sig)

    def start_station(self, *args: str) -> None:
        """Start the station; ``args`` are more of its options (``--hold-limit 3``)."""
        # A free port of its own, never the default: tests run side by side with a demo.
        self.page_port = free_port()
        self.station = self._spawn(
            "station",
            "station",
            "--device",
            self.device.link,
            "--server",
            self.station_url,
            "--spool",
            str(self.spool),
            "--page-port",
            str(self.page_port),
            *args,
            env={"ANKLE_STATION_TOKEN": self.creds["station_token"]},
        )

    @property
    def page_url(self) -> str:
        """The patient's page, served by the station (after ``start_station``)."""
        return f"http://127.0.0.1:{self.page_port}/"

    @property
    def spool(self) -> Path:
        return self.data_dir / "station"

    def stop(self, proc: subprocess.Popen[bytes] | None, sig: int = signal.SIGTERM) -> None:
        if proc is not None and proc.poll() is None:
            proc.send_signal(sig)
            try:
                proc.wait(15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()

    def log_tail(self) -> str:
        return "\n".join(f"--- {p.name}\n{p.read_text()[-3000:]}" for p in self.logs)


@pytest.fixture
def stack(request: pytest.FixtureRequest) -> Stack:
    """The stack a system test runs on: ``sqlite-local`` unless parametrized (see STACKS)."""
    chosen: Stack = getattr(request, "param", "sqlite-local")
    return chosen


def _server_env(stack: Stack, request: pytest.FixtureRequest) -> dict[str, str]:
    """What every server process of ``stack`` is given: a new PostgreSQL database and an
    emptied Redis database of this test's own, or nothing (SQLite, in-process relay). Each
    freezes its start-up out of the garbage collector's reach, as a deployed server does
    (the test process itself does not: tests/conftest.py)."""
    production = {"ANKLE_GC_FREEZE": "true"}
    if stack == "sqlite-local":
        return production
    cluster: Cluster = request.getfixturevalue("pg_cluster")
    name = cluster.create_database()
    request.addfinalizer(lambda: cluster.drop_database(name))
    return production | {
        "ANKLE_DATABASE_URL": cluster.url(name),
        "ANKLE_RELAY_URL": request.getfixturevalue("relay_url"),
        "ANKLE_RELAY_LEASE_S": f"{RELAY_LEASE_S:g}",
    }


@pytest.fixture
def device_args() -> tuple[str, ...]:
    """More options for the simulated device; a test parametrizes this to change it, e.g.
    ``("--fault", "supply_droop@0=3")`` for a platform whose compressor is off from the start."""
    return ()


@pytest.fixture
def system(
    tmp_path: Path, stack: Stack, device_args: tuple[str, ...], request: pytest.FixtureRequest
) -> Iterator[System]:
    port = free_port()
    station_port = free_port() if stack == "pg-redis-2proc" else port
    server_env = _server_env(stack, request)
    settings = Settings(
        data_dir=tmp_path / "server",
        port=port,
        database_url=server_env.get("ANKLE_DATABASE_URL", ""),
    )
    # In a thread: Playwright's sync API keeps an event loop running in this one.
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        creds = pool.submit(provision_demo, settings).result()
    sysm = System(tmp_path, port, creds, station_port, server_env)
    # The servers start in a thread while the device starts here (it dies with this
    # process only if started from the main thread), a few seconds sooner than one by one.
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        servers = pool.submit(sysm.start_servers)
        try:
            sysm.device = ServiceProcess(
                "--link",
                "pty",
                "--patient-torque",
                "3",
                "--watchdog-ms",
                str(WATCHDOG_MS),
                *device_args,
                start_timeout=600.0,  # generous: a cold cache compiles, slowly when loaded
            )
            servers.result()
            yield sysm
        finally:
            concurrent.futures.wait([servers])
            sysm.stop(sysm.station)
            if hasattr(sysm, "device"):
                sysm.device.stop()
            sysm.stop_servers()


@pytest_asyncio.fixture
async def therapist(system: System) -> AsyncIterator[httpx.AsyncClient]:
    async with httpx.AsyncClient(base_url=system.url, timeout=30.0) as client:
        r = await client.post(
            "/api/v1/auth/login",
            json={
                "email": system.creds["therapist_email"],
                "password": system.creds["therapist_password"],
            },
        )
        assert r.status_code == 200, r.text
        client.headers["Authorization"] = f"Bearer {r.json()['access_token']}"
        yield client


def bearer(client: httpx.AsyncClient) -> str:
    return str(client.headers["Authorization"]).split(" ", 1)[1]


async def live(system: System, token: str) -> ClientConnection:
    return await connect(
        f"ws://127.0.0.1:{system.port}/ws/live/{system.station_id}",
        subprotocols=[wire.SUBPROTOCOL, f"{wire.BEARER_PREFIX}{token}"],  # type: ignore[list-item]
        max_size=wire.MAX_MESSAGE_BYTES,
        open_timeout=30,  # the library's 10 s is an idle machine's
    )


_last_beat: dict[int, float] = {}


async def next_of(ws: ClientConnection, kind: type[Any], timeout: float = 30.0) -> Any:
    """The next message of a type, skipping the others; sends the viewer's heartbeat. For
    ``TelemetryMsg``: the newest sample of the next telemetry batch."""
    deadline = time.monotonic() + timeout
    while True:
        now = time.monotonic()
        if now - _last_beat.get(id(ws), 0.0) >= wire.HEARTBEAT_S:
            await ws.send(wire.Heartbeat(sent=time.time()).model_dump_json())
            _last_beat[id(ws)] = now
        left = deadline - now
        if left <= 0:
            raise TimeoutError(f"no {kind.__name__} within {timeout} s")
        try:
            raw = await asyncio.wait_for(ws.recv(), min(left, wire.HEARTBEAT_S))
        except TimeoutError:
            continue
        message = wire.VIEWER_DOWN.validate_json(raw)
        if kind is wire.TelemetryMsg and isinstance(message, wire.TelemetryBatch):
            return message.newest()
        if isinstance(message, kind):
            return message


def dump(obj: Any) -> str:
    return json.dumps(obj, indent=1, default=str)[:2000]


async def until(
    ws: ClientConnection, kind: type[M], done: Callable[[M], bool], timeout: float
) -> M:
    """The first message of ``kind`` for which ``done`` holds (see :func:`next_of`)."""
    deadline = time.monotonic() + timeout
    while True:
        message: M = await next_of(ws, kind, timeout=max(0.1, deadline - time.monotonic()))
        if done(message):
            return message


async def status_until(
    ws: ClientConnection, done: Callable[[wire.StatusMsg], bool], timeout: float
) -> wire.StatusMsg:
    return await until(ws, wire.StatusMsg, done, timeout)


async def start_exercise(
    system: System, therapist: httpx.AsyncClient, body: dict[str, Any], *station_args: str
) -> tuple[int, ClientConnection, wire.StatusMsg]:
    """Prescribe ``body``, start the station (with ``station_args``), start the exercise from
    the live view; the prescription, the open live view and the first status naming the
    session."""
    r = await therapist.post(
        f"/api/v1/patients/{system.creds['patient_id']}/prescriptions", json=body
    )
    assert r.status_code == 201, r.text
    pid = int(r.json()["id"])
    system.start_station(*station_args)
    ws = await live(system, bearer(therapist))
    await next_of(ws, wire.Welcome)
    await status_until(ws, lambda s: s.device_link == "connected", 30)
    await ws.send(
        wire.Command(request_id="start", action="start", prescription_id=pid).model_dump_json()
    )
    result = await next_of(ws, wire.CommandResult, 10)
    assert result.request_id == "start" and result.ok, result
    status = await status_until(ws, lambda s: s.session_id is not None, 15)
    return pid, ws, status


async def active(ws: ClientConnection, timeout: float) -> wire.TelemetryMsg:
    """The first telemetry of a repetition in progress."""
    return await until(ws, wire.TelemetryMsg, lambda t: t.mode == "ACTIVE", timeout)


async def sessions_of(client: httpx.AsyncClient, pid: int) -> list[dict[str, Any]]:
    r = await client.get("/api/v1/sessions", params={"prescription_id": pid})
    assert r.status_code == 200, r.text
    return list(r.json())


async def uploaded(client: httpx.AsyncClient, pid: int, timeout: float) -> list[dict[str, Any]]:
    deadline = time.monotonic() + timeout
    while not (found := await sessions_of(client, pid)):
        assert time.monotonic() < deadline, "the session never reached the server"
        await asyncio.sleep(0.25)
    return found
