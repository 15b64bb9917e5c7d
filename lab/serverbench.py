"""``ankle bench server``: the live relay under many stations and viewers, on a real server.

The server runs as its own process (``python -m ankle server`` on a fresh data directory and
a free port), so its CPU time is its own (its CPU-time clock, :func:`cpu_seconds`). Before it
starts, the database is given N therapists, each with a patient, a station and a login token,
written directly (no Argon2 logins to wait for). The load comes from two more processes:

- ``stations``: N simulated home stations, no device. Each connects to ``/ws/station``,
  says hello, then sends telemetry as the real station does: a
  :class:`~sessions.wire.TelemetryBatch` of 4 samples 25 times a second (100 samples a
  second) stamped with ``sent = time.time()``, a heartbeat and a status once a second, and
  answers every :class:`~sessions.wire.Command` at once with an ``ok``
  :class:`~sessions.wire.CommandResult`. Their phases are spread over the 40 ms period, as
  independent stations' would be.
- ``viewers``: one (or more) therapist per station on ``/ws/live/{id}``. Each takes the
  latency of every telemetry batch it gets (receive time - ``sent``; same machine, same
  clock) and counts its samples, sends a heartbeat, a ``set_impedance`` and (half a second
  later) a ``hold`` command once a second, and times each command from its sending to its
  result (a K/B change includes the server's audit write of its request row; a HOLD does
  not wait for the database).

After all are connected and a short warm-up, the processes measure the same window. With
``sweep`` the same server then carries growing numbers of stations for a few seconds each,
until one fails; ``max_stations_p99_under_50ms`` is the largest count whose telemetry
latency p99 held with no connection lost.

On a small machine all three processes share the cores: the numbers are what the server
does while the load generator takes its part of the machine (``loadgen_cpu_pct``), and
whatever else runs there (``machine_cpu_pct``, all cores). ``server_cpu_us_per_message`` is
the server's CPU time over the station telemetry messages it took in: its cost per message,
which depends less on the neighbours than latency does (``server_cpu_us_per_sample`` is the
same per sample; before batches the two were one).

Beyond one process: with ``processes`` N > 1 (the Redis relay; a throwaway ``redis-server``
from :mod:`lab.services` unless a URL is given) station ``i`` is on process ``i mod N`` and
its viewers on the next, so every sample a viewer gets crossed processes
(``cross_process_latency_ms_p99``); the processes share one database. ``capacity`` adds the
capacity plan's sweeps (:data:`CAPACITY`): one server process pinned to one core with the
load generator on another, on each relay, and two processes. redis-server's CPU is read
from its clock like the servers'. A window that lost a connection, left a command
unanswered or could not send at rate reports those figures as None, with why
(:func:`problems`).

``heavy`` (``ankle bench server --heavy``) asks instead whether one request stops the server
answering others: the longest recording an upload takes, written by the station's own
recorder and uploaded as the station does, then its chart series, its metrics computed on
read, and a patient's progress and reports over a year of sessions, each fired in turn while
a thread asks ``/api/v1/health`` every 10 ms; with each, the server's CPU time over the wall
time.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import os
import queue
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from datetime import timedelta
from pathlib import Path
from typing import IO, Any

import numpy as np

from lab.services import free_port, spawned_redis
from lab.targets import Target
from lab.targets import table as bench_table

TELEMETRY_HZ = 100
"""Samples a second per station."""
SAMPLES_PER_BATCH = 4
"""Samples per telemetry message, as the real station at its default ``--batch-hz``."""
BATCH_HZ = TELEMETRY_HZ // SAMPLES_PER_BATCH
LATENCY_MS = 50.0
"""A live view this late is still live: the target of ``telemetry_latency_ms_p99``."""
SWEEP: tuple[int, ...] = (25, 50, 100, 150, 200, 250, 300, 350, 400, 500)
SWEEP_SECONDS = 5.0
WARMUP_S = 2.0
"""Between the last connection and the window: the server's queues settle."""
TAIL_S = 1.0
"""After the window: commands in flight get their answer."""
CONNECT_CONCURRENCY = 16
PHASES = 10
"""Stations' sends are spread over this many slots of the telemetry period."""
TEMPLATES = 64
STARTUP_S = 60.0
WORKER_TIMEOUT_S = 120.0
RATE_FLOOR = 0.98
"""Stations that sent less than this share of their telemetry did not load the server as
asked: their figures are not reported as valid."""
RELAYS = ("local", "redis")
STORES = ("sqlite", "postgres")
COMMAND_KEYS = (
    "kb_change_to_ack_ms_p50",
    "kb_change_to_ack_ms_p99",
    "hold_to_ack_ms_p50",
    "hold_to_ack_ms_p99",
)

TARGETS: tuple[Target, ...] = (
    Target("telemetry_latency_ms_p99", "telemetry station to viewer p99 (ms)", LATENCY_MS, "max"),
    Target(
        "telemetry_hz_per_station",
        "telemetry sent per station (Hz)",
        RATE_FLOOR * TELEMETRY_HZ,
        "min",
    ),
    # What a live view needs (the floor).
    Target("viewer_hz", "telemetry samples received per viewer (Hz)", 30.0, "min"),
    Target("kb_change_to_ack_ms_p99", "K/B change to the station's answer p99 (ms)", 100.0, "max"),
    Target("hold_to_ack_ms_p99", "HOLD to the station's answer p99 (ms)", 100.0, "max"),
    Target("disconnects", "connections lost", 0, "eq"),
    Target("max_stations_p99_under_50ms", "most stations with latency p99 <= 50 ms", 100, "min"),
    Target(
        "cross_process_latency_ms_p99",
        "telemetry p99, viewer on another process (ms)",
        LATENCY_MS,
        "max",
    ),
    Target(
        "max_stations_p99_under_50ms_1proc",
        "most stations, p99 <= 50 ms, 1 process on 1 core",
        300,
        "min",
    ),
    Target("redis_relay_efficiency", "the same with the Redis relay / local", 0.7, "min"),
)

ROWS: tuple[tuple[str, str], ...] = (
    ("processes", "server processes"),
    ("relay", "relay"),
    ("store", "store"),
    ("stations", "stations connected"),
    ("viewers", "viewers connected"),
    ("seconds", "measurement window (s)"),
    ("telemetry_hz_per_station", "telemetry sent per station (Hz)"),
    ("viewer_hz", "telemetry samples received per viewer (Hz)"),
    ("telemetry_latency_ms_p50", "telemetry station to viewer p50 (ms)"),
    ("telemetry_latency_ms_p99", "telemetry station to viewer p99 (ms)"),
    ("telemetry_latency_ms_max", "telemetry station to viewer max (ms)"),
    ("kb_change_to_ack_ms_p50", "K/B change to the station's answer p50 (ms)"),
    ("kb_change_to_ack_ms_p99", "K/B change to the station's answer p99 (ms)"),
    ("hold_to_ack_ms_p50", "HOLD to the station's answer p50 (ms)"),
    ("hold_to_ack_ms_p99", "HOLD to the station's answer p99 (ms)"),
    ("commands", "commands timed"),
    ("commands_failed", "commands refused or unanswered"),
    ("disconnects", "connections lost"),
    ("server_cpu_pct", "server CPU, all processes (% of one core)"),
    ("server_cpu_us_per_message", "server CPU per station telemetry message (us)"),
    ("server_cpu_us_per_sample", "server CPU per telemetry sample (us)"),
    ("redis_cpu_us_per_message", "redis-server CPU per station telemetry message (us)"),
    ("loadgen_cpu_pct", "load generator CPU (% of one core)"),
    ("machine_cpu_pct", "whole machine busy, all cores (%)"),
    ("max_stations_p99_under_50ms", "most stations with latency p99 <= 50 ms"),
    ("cross_process_latency_ms_p99", "telemetry p99, viewer on another process (ms)"),
    ("max_stations_p99_under_50ms_1proc", "most stations, p99 <= 50 ms, 1 process on 1 core"),
    (
        "max_stations_p99_under_50ms_1proc_redis",
        "most stations, p99 <= 50 ms, 1 process on 1 core, Redis relay",
    ),
    ("redis_relay_efficiency", "the same with the Redis relay / local"),
    ("max_stations_p99_under_50ms_2proc", "most stations, p99 <= 50 ms, 2 processes, Redis"),
)
STEP_KEYS = (
    "stations",
    "viewers",
    "telemetry_hz_per_station",
    "telemetry_skipped",
    "viewer_hz",
    "telemetry_latency_ms_p50",
    "telemetry_latency_ms_p99",
    "kb_change_to_ack_ms_p99",
    "hold_to_ack_ms_p99",
    "commands_failed",
    "disconnects",
    "server_cpu_pct",
    "server_cpu_us_per_message",
    "redis_cpu_us_per_message",
    "loadgen_cpu_pct",
    "machine_cpu_pct",
    "server_cores",
    "loadgen_cores",
)
"""What a sweep keeps of each step."""


# -- provisioning ------------------------------------------------------------------------
@dataclass(frozen=True)
class Seat:
    """One station and its patient's therapist, as the load generator needs them."""

    station_id: int
    station_token: str
    therapist_token: str


async def provision(data_dir: Path, count: int, database_url: str = "") -> list[Seat]:
    """``count`` therapists, each with a patient, a station and a login token, written
    straight into the database (``database_url``, or a new SQLite file in ``data_dir``),
    migrated here first so that server processes sharing it never race to migrate. Their
    emails are new each run: a PostgreSQL database may be used again."""
    from server.config import Settings
    from server.db import create_engine, create_sessionmaker, migrate
    from server.models import AuthToken, Patient, Station, User, utcnow
    from server.security import new_token, token_hash

    engine = create_engine(Settings(data_dir=data_dir, database_url=database_url))
    run = uuid.uuid4().hex[:8]
    seats: list[Seat] = []
    try:
        await migrate(engine)
        async with create_sessionmaker(engine)() as db:
            expires = utcnow() + timedelta(days=1)
            for i in range(count):
                # No usable password: a malformed hash never verifies. The token is the way in.
                therapist = User(
                    email=f"bench-{run}-{i}@bench.test",
                    name=f"Bench therapist {i}",
                    role="therapist",
                    password_hash="!bench",
                )
                db.add(therapist)
                await db.flush()
                patient = Patient(therapist_id=therapist.id, display_name=f"Bench patient {i}")
                db.add(patient)
                await db.flush()
                station_token, user_token = new_token(), new_token()
                station = Station(
                    patient_id=patient.id, name=f"Bench {i}", token_hash=token_hash(station_token)
                )
                db.add(station)
                db.add(
                    AuthToken(
                        token_hash=token_hash(user_token), user_id=therapist.id, expires_at=expires
                    )
                )
                await db.flush()
                seats.append(Seat(station.id, station_token, user_token))
            await db.commit()
    finally:
        await engine.dispose()
    return seats


# -- processes ---------------------------------------------------------------------------
def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process, all its threads.

    Read from the process's own CPU-time clock (Linux: the clock id ``clock_getcpuclockid``
    returns, ``(~pid << 3) | 2``), which counts nanoseconds; ``/proc/<pid>/stat`` counts
    10 ms ticks, and a short run of a few stations gave redis-server 0 ticks (a CPU per
    message of 0.0). ``/proc`` is the fallback where the clock cannot be read.
    """
    with contextlib.suppress(OSError, OverflowError):
        return time.clock_gettime((~pid << 3) | 2)
    with open(f"/proc/{pid}/stat") as fh:
        fields = fh.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def machine_cpu() -> tuple[float, float]:
    """(busy, total) CPU seconds of the whole machine, all cores (``/proc/stat``)."""
    with open("/proc/stat") as fh:
        ticks = [int(x) for x in fh.readline().split()[1:]]
    hz = os.sysconf("SC_CLK_TCK")
    idle = ticks[3] + ticks[4]  # idle + iowait
    return (sum(ticks) - idle) / hz, sum(ticks) / hz


def split_cores() -> tuple[set[int], set[int]] | None:
    """(the server's core, the load generator's core), or None where this process may not
    use two cores or cannot set affinity."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    cores = sorted(os.sched_getaffinity(0))
    return ({cores[0]}, {cores[1]}) if len(cores) >= 2 else None


@contextlib.contextmanager
def pinned(cores: set[int] | None) -> Iterator[None]:
    """Processes started inside run only on ``cores``: a child inherits the affinity of the
    thread that forks it, so nothing is pinned after it started (no thread escapes)."""
    if cores is None:
        yield
        return
    before = os.sched_getaffinity(0)
    os.sched_setaffinity(0, cores)
    try:
        yield
    finally:
        os.sched_setaffinity(0, before)


def _stop(proc: subprocess.Popen[Any], timeout: float = 10.0) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


class ServerProcess:
    """``python -m ankle server`` on ``data_dir`` and a free port, until :meth:`stop`.
    ``env`` adds settings (``ANKLE_RELAY_URL``, ``ANKLE_DATABASE_URL``); ``cores`` pins it."""

    def __init__(
        self,
        data_dir: Path,
        argv: Sequence[str] | None = None,
        env: dict[str, str] | None = None,
        name: str = "server",
        cores: set[int] | None = None,
    ) -> None:
        from server.cli import wait_healthy

        self.port = free_port()
        self.log = data_dir / f"{name}.log"
        environ = {
            **os.environ,
            "ANKLE_DATA_DIR": str(data_dir),
            "ANKLE_HOST": "127.0.0.1",
            "ANKLE_PORT": str(self.port),
            **(env or {}),
        }
        with self.log.open("wb") as out, pinned(cores):
            self.proc = subprocess.Popen(
                list(argv or [sys.executable, "-m", "ankle", "server"]),
                env=environ,
                stdout=out,
                stderr=subprocess.STDOUT,
            )
        try:
            wait_healthy(self.url, self.proc, timeout=STARTUP_S)
        except Exception:
            self.stop()
            raise

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def stop(self) -> None:
        _stop(self.proc)


class Worker:
    """A load generator process (``python -m lab.serverbench stations|viewers``): it reads its
    configuration, connects everything, says ``ready``, then waits for the window."""

    def __init__(
        self, role: str, config: dict[str, Any], log_dir: Path, cores: set[int] | None = None
    ) -> None:
        self.role = role
        self.errors = log_dir / f"{role}.log"
        with self.errors.open("wb") as errors, pinned(cores):
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "lab.serverbench", role],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=errors,
                text=True,
            )
        self._lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()
        self._write(json.dumps(config))

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self._lines.put(line)
        self._lines.put("")  # end of output

    def _write(self, line: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def _line(self, timeout: float) -> str:
        try:
            line = self._lines.get(timeout=timeout)
        except queue.Empty:
            line = ""
        if not line:
            _stop(self.proc)
            tail = self.errors.read_text(errors="replace")[-3000:]
            raise WorkerFailed(f"the {self.role} load generator failed:\n{tail}")
        return line

    def ready(self) -> None:
        if self._line(WORKER_TIMEOUT_S).strip() != "ready":
            raise WorkerFailed(f"the {self.role} load generator said something unexpected")

    def go(self, start: float, end: float) -> None:
        self._write(json.dumps({"start": start, "end": end}))

    def result(self, timeout: float) -> dict[str, Any]:
        out: dict[str, Any] = json.loads(self._line(timeout))
        return out

    def stop(self) -> None:
        _stop(self.proc)
        for stream in (self.proc.stdin, self.proc.stdout):
            if stream is not None:
                with contextlib.suppress(OSError):
                    stream.close()


class WorkerFailed(RuntimeError):
    """A load generator ended early (a connection refused, a server gone): its log's tail."""


# -- the system under test ---------------------------------------------------------------
@dataclass(frozen=True)
class Setup:
    """How the server side is laid out for one measurement."""

    processes: int = 1
    relay: str = "local"
    """``local`` (in-process; one server process only) or ``redis``."""
    pin: bool = False
    """One server process on one core, the load generator on another (``split_cores``)."""

    def text(self) -> str:
        n = f"{self.processes} process{'es' if self.processes > 1 else ''}"
        return f"{n}, {self.relay} relay{', pinned' if self.pin else ''}"


CAPACITY: dict[str, Setup] = {
    "1proc": Setup(1, "local", pin=True),
    "1proc_redis": Setup(1, "redis", pin=True),
    "2proc": Setup(2, "redis"),
}
"""The capacity plan's sweeps, by the suffix of their ``max_stations_p99_under_50ms_*``."""


@dataclass
class Cluster:
    """Running server processes of one :class:`Setup` on one database (and one Redis)."""

    servers: list[ServerProcess]
    loadgen_cores: set[int] | None
    redis_pid: int | None

    def stop(self) -> None:
        for s in self.servers:
            s.stop()


@contextlib.contextmanager
def cluster(
    setup: Setup,
    data_dir: Path,
    name: str,
    relay_url: str = "",
    database_url: str = "",
    redis_pid: int | None = None,
) -> Iterator[Cluster]:
    """``setup.processes`` servers sharing ``data_dir``'s (or ``database_url``'s) database,
    and ``relay_url``'s Redis with the Redis relay."""
    cores = split_cores() if setup.pin else None
    if setup.pin and cores is None:
        raise Unavailable("this process may not pin two cores (sched_setaffinity)")
    env = {"ANKLE_DATABASE_URL": database_url} if database_url else {}
    if setup.relay == "redis":
        env["ANKLE_RELAY_URL"] = relay_url
    servers: list[ServerProcess] = []
    try:
        for k in range(setup.processes):
            servers.append(
                ServerProcess(
                    data_dir, env=env, name=f"{name}-{k}", cores=cores[0] if cores else None
                )
            )
        yield Cluster(
            servers, cores[1] if cores else None, redis_pid if setup.relay == "redis" else None
        )
    finally:
        for s in servers:
            s.stop()


class Unavailable(RuntimeError):
    """A measurement this machine cannot make (the message says why)."""


# -- one measurement ---------------------------------------------------------------------
def _pct(values: Sequence[float], q: float) -> float:
    return float(np.percentile(values, q)) if len(values) else math.nan


def measure(
    system: Cluster,
    seats: Sequence[Seat],
    viewers_per_station: int,
    seconds: float,
    commands: bool = True,
) -> dict[str, Any]:
    """One window of ``seconds`` with these stations and their viewers (who send a K/B
    change and a HOLD each second if ``commands``). Station ``i`` is on server process
    ``i mod N`` and its viewers on the next process (the same one when N is 1)."""
    servers = system.servers
    n = len(servers)
    urls = [s.url.replace("http://", "ws://") for s in servers]
    log_dir = servers[0].log.parent
    stations = Worker(
        "stations",
        {
            "processes": n,
            "items": [[s.station_id, s.station_token, urls[i % n]] for i, s in enumerate(seats)],
        },
        log_dir,
        system.loadgen_cores,
    )
    viewers: Worker | None = None
    try:
        stations.ready()
        viewers = Worker(
            "viewers",
            {
                "commands": commands,
                "items": [
                    [s.station_id, s.therapist_token, urls[(i + 1) % n]]
                    for i, s in enumerate(seats)
                    for _ in range(viewers_per_station)
                ],
            },
            log_dir,
            system.loadgen_cores,
        )
        viewers.ready()
        start = time.time() + WARMUP_S
        end = start + seconds
        for w in (stations, viewers):
            w.go(start, end)
        pids = [s.proc.pid for s in servers] + [stations.proc.pid, viewers.proc.pid]
        if system.redis_pid is not None:
            pids.append(system.redis_pid)
        time.sleep(max(0.0, start - time.time()))
        cpu0, machine0 = [cpu_seconds(p) for p in pids], machine_cpu()
        server_cores = sorted(os.sched_getaffinity(servers[0].proc.pid))
        loadgen_cores = sorted(os.sched_getaffinity(stations.proc.pid))
        time.sleep(max(0.0, end - time.time()))
        cpu1, machine1 = [cpu_seconds(p) for p in pids], machine_cpu()
        sent, seen = stations.result(WORKER_TIMEOUT_S), viewers.result(WORKER_TIMEOUT_S)
    finally:
        stations.stop()
        if viewers is not None:
            viewers.stop()
    used = [b - a for a, b in zip(cpu0, cpu1, strict=True)]
    cpu = [100.0 * u / seconds for u in used]
    n_viewers = max(seen["connected"], 1)
    latency: list[float] = seen["latency_ms"]
    acks: list[float] = seen["ack_ms"]["set_impedance"]
    holds: list[float] = seen["ack_ms"]["hold"]
    batches = max(sent["batches"], 1)
    per_process: list[int] = sent["batches_by_process"]
    server_cpu_us = 1e6 * sum(used[:n])
    redis_us = 1e6 * used[n + 2] if system.redis_pid is not None else math.nan
    return {
        "processes": n,
        "stations": sent["connected"],
        "viewers": seen["connected"],
        "seconds": seconds,
        "telemetry_hz_per_station": sent["telemetry"] / seconds / max(sent["connected"], 1),
        "telemetry_skipped": sent["skipped"],
        "viewer_hz": seen["samples"] / seconds / n_viewers,
        "telemetry_latency_ms_p50": _pct(latency, 50),
        "telemetry_latency_ms_p99": _pct(latency, 99),
        "telemetry_latency_ms_max": max(latency) if latency else math.nan,
        "kb_change_to_ack_ms_p50": _pct(acks, 50),
        "kb_change_to_ack_ms_p99": _pct(acks, 99),
        "hold_to_ack_ms_p50": _pct(holds, 50),
        "hold_to_ack_ms_p99": _pct(holds, 99),
        "commands": len(acks) + len(holds),
        "commands_failed": seen["commands_failed"],
        "disconnects": sent["disconnects"] + seen["disconnects"],
        "server_cpu_pct": sum(cpu[:n]),
        "server_cpu_pct_per_process": cpu[:n],
        "server_cpu_us_per_message": server_cpu_us / batches,
        "server_cpu_us_per_sample": server_cpu_us / max(sent["telemetry"], 1),
        # Each process's CPU over the messages of the stations it holds: with N > 1 it also
        # carries the viewers of the previous process's stations.
        "server_cpu_us_per_message_per_process": [
            1e6 * used[k] / max(per_process[k % len(per_process)], 1) for k in range(n)
        ],
        "redis_cpu_pct": 100.0 * redis_us / 1e6 / seconds,
        "redis_cpu_us_per_message": redis_us / batches,
        "loadgen_cpu_pct": cpu[n] + cpu[n + 1],
        "stations_cpu_pct": cpu[n],
        "viewers_cpu_pct": cpu[n + 1],
        "machine_cpu_pct": 100.0 * (machine1[0] - machine0[0]) / (machine1[1] - machine0[1]),
        "load_average": os.getloadavg()[0],
        "server_cores": server_cores,
        "loadgen_cores": loadgen_cores,
        "cores": os.cpu_count(),
    }


def problems(result: dict[str, Any]) -> dict[str, str]:
    """Keys of ``result`` whose numbers cannot be trusted, with why: a lost connection makes
    every figure suspect, a short send rate the telemetry figures, an unanswered command the
    command round trips (their percentiles would leave it out)."""
    bad: dict[str, str] = {}
    telemetry = ("telemetry_latency_ms_p50", "telemetry_latency_ms_p99", "viewer_hz")
    rate = result["telemetry_hz_per_station"]
    if rate < RATE_FLOOR * TELEMETRY_HZ:
        why = f"stations sent {rate:.0f} Hz, not {TELEMETRY_HZ}: " + (
            f"the server did not read ({result['telemetry_skipped']} batches skipped)"
            if result["telemetry_skipped"]
            else f"the load generator fell behind ({result['loadgen_cpu_pct']:.0f} % CPU)"
        )
        bad.update(dict.fromkeys(telemetry, why))
    if result["commands_failed"]:
        why = f"{result['commands_failed']} commands unanswered"
        bad.update(dict.fromkeys(COMMAND_KEYS, why))
    if result["disconnects"]:
        why = f"{result['disconnects']} connections lost"
        bad.update(dict.fromkeys((*telemetry, *COMMAND_KEYS), why))
    return bad


def _held(result: dict[str, Any]) -> str | None:
    """None if the latency target held at this count, else why not."""
    bad = problems(result)
    if bad:
        return next(iter(bad.values()))
    p99 = result["telemetry_latency_ms_p99"]
    if result["stations"] == 0 or math.isnan(p99):
        return "no telemetry"
    return None if p99 <= LATENCY_MS else f"latency p99 {p99:.0f} ms"


def sweep_counts_of(
    system: Cluster,
    seats: Sequence[Seat],
    counts: Sequence[int],
    viewers_per_station: int,
    seconds: float,
    commands: bool,
    say: Callable[[str], None],
    what: str,
) -> dict[str, Any]:
    """Growing counts of stations on one cluster until the latency target fails: the largest
    count that held, why the sweep stopped, and each step's figures."""
    held: int | None = None
    stopped = "top of the sweep"
    steps: list[dict[str, Any]] = []
    for i, n in enumerate(counts):
        say(f"{what}: {n} stations ({i + 1}/{len(counts)})")
        try:
            step = measure(system, seats[:n], viewers_per_station, seconds, commands)
        except WorkerFailed as exc:
            stopped = f"at {n} stations the load generator failed: {str(exc)[-300:]}"
            break
        steps.append({k: step[k] for k in STEP_KEYS})
        why = _held(step)
        if why is not None:
            stopped = f"at {n} stations: {why}"
            break
        held = n
    return {"max": held, "stopped": stopped, "steps": steps}


def run(
    stations: int = 100,
    viewers_per_station: int = 1,
    seconds: float = 20.0,
    sweep: bool = True,
    sweep_counts: Sequence[int] = SWEEP,
    sweep_seconds: float = SWEEP_SECONDS,
    commands: bool = True,
    processes: int = 1,
    relay: str = "local",
    relay_url: str = "",
    store: str = "sqlite",
    database_url: str = "",
    capacity: bool = False,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """The benchmark: one window at ``stations`` on ``processes`` server processes (the
    ``relay`` between them; ``redis`` starts a throwaway redis-server unless ``relay_url``
    names one), then (``sweep``) one per count in ``sweep_counts`` until the latency target
    fails. ``capacity`` adds the sweeps of the capacity plan: one server process pinned to
    one core with each relay, and two processes. ``store`` ``postgres`` needs the
    ``database_url`` of an existing PostgreSQL. The servers inherit this process's
    environment (``ANKLE_*`` to try server options). Raises ValueError for a combination
    that cannot run, naming the option."""
    check_options(processes, relay, store, database_url)
    say = progress or (lambda _: None)
    counts = sorted(set(sweep_counts))
    asked = Setup(processes, relay)
    plan = [(k, s) for k, s in CAPACITY.items() if capacity]
    wants_redis = relay == "redis" or any(s.relay == "redis" for _, s in plan)
    with contextlib.ExitStack() as stack:
        data_dir = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="ankle-bench-")))
        redis_pid: int | None = None
        if wants_redis and not relay_url:
            say("starting redis-server")
            server_redis = stack.enter_context(spawned_redis(data_dir / "redis"))
            relay_url, redis_pid = server_redis.url, server_redis.proc.pid
        say("provisioning stations and therapists")
        seats = asyncio.run(
            provision(data_dir, max([stations, *counts]), _store_url(store, database_url))
        )
        db_url = _store_url(store, database_url)

        def on(setup: Setup, name: str) -> contextlib.AbstractContextManager[Cluster]:
            # Each cluster on its own Redis database: no lease of the last one lingers.
            url = f"{relay_url.rstrip('/')}/{len(used)}" if redis_pid is not None else relay_url
            used.append(name)
            return cluster(setup, data_dir, name, url, db_url, redis_pid)

        def sweep_on(system: Cluster, setup: Setup) -> dict[str, Any]:
            return sweep_counts_of(
                system,
                seats,
                counts,
                viewers_per_station,
                sweep_seconds,
                commands,
                say,
                setup.text(),
            )

        used: list[str] = []
        with on(asked, "server") as system:
            say(f"{asked.text()}: {stations} stations, {seconds:g} s window")
            result = measure(system, seats[:stations], viewers_per_station, seconds, commands)
            found = sweep_on(system, asked) if sweep else None
        capacity_runs: dict[str, dict[str, Any]] = {}
        for key, setup in plan:
            try:
                with on(setup, key) as system:
                    capacity_runs[key] = sweep_on(system, setup)
            except Unavailable as exc:
                capacity_runs[key] = {"max": None, "stopped": str(exc), "steps": []}
    return summary(result, asked, store, found, capacity_runs)


def check_options(processes: int, relay: str, store: str, database_url: str) -> None:
    """Refuse a combination that cannot run, with a sentence naming the option."""
    database_url = _store_url(store, database_url) if store == "postgres" else database_url
    if relay not in RELAYS:
        raise ValueError(f"--relay must be one of {', '.join(RELAYS)}, not {relay!r}")
    if store not in STORES:
        raise ValueError(f"--store must be one of {', '.join(STORES)}, not {store!r}")
    if processes < 1:
        raise ValueError(f"--processes must be at least 1, not {processes}")
    if processes > 1 and relay == "local":
        raise ValueError(
            "--processes above 1 needs --relay redis: the local relay keeps live links "
            "in one process"
        )
    if store == "postgres" and not database_url.startswith("postgresql"):
        raise ValueError(
            "--store postgres needs --database-url (or ANKLE_DATABASE_URL) of an existing "
            "PostgreSQL: postgresql+asyncpg://user@host/db"
        )
    if store == "sqlite" and database_url and not database_url.startswith("sqlite"):
        raise ValueError(f"--database-url {database_url!r} is not SQLite: add --store postgres")


def _store_url(store: str, database_url: str) -> str:
    """The servers' database URL: empty for SQLite in the run's data directory; for
    PostgreSQL the one given, else ``ANKLE_DATABASE_URL`` (a site's may name its SQLite
    file, so only ``postgres`` reads it)."""
    if store != "postgres":
        return ""
    return database_url or os.environ.get("ANKLE_DATABASE_URL", "")


def summary(
    result: dict[str, Any],
    asked: Setup,
    store: str,
    found: dict[str, Any] | None,
    capacity_runs: dict[str, dict[str, Any]],
) -> dict[str, Any]:
    """The measured window, its validity, the sweeps and the capacity figures in one dict;
    a figure that cannot be trusted is None, with why in ``invalid``."""
    out = dict(result)
    out["relay"], out["store"] = asked.relay, store
    bad = problems(result)
    for key in bad:
        out[key] = None
    out["invalid"] = bad
    out["valid"] = not bad
    held = [n for n in (found["max"] if found else None,) if n is not None]
    if _held(result) is None:
        held.append(result["stations"])
    out["max_stations_p99_under_50ms"] = max(held) if held else None
    if found:
        out["sweep"] = found["steps"]
        out["sweep_stopped"] = found["stopped"]
    # Cross-process: this window when it had several processes, else the two-process sweep's
    # step nearest below this window's station count.
    cross = math.nan
    if asked.processes > 1:
        cross = _number(out["telemetry_latency_ms_p99"])
    elif "2proc" in capacity_runs:
        below = [
            s
            for s in capacity_runs["2proc"]["steps"]
            if s["stations"] <= result["stations"] and not problems(s)
        ]
        cross = below[-1]["telemetry_latency_ms_p99"] if below else math.nan
    out["cross_process_latency_ms_p99"] = cross
    for key in CAPACITY:
        out[f"max_stations_p99_under_50ms_{key}"] = capacity_runs.get(key, {}).get("max")
    one, redis = (capacity_runs.get(k, {}).get("max") for k in ("1proc", "1proc_redis"))
    out["redis_relay_efficiency"] = redis / one if one and redis is not None else math.nan
    if capacity_runs:
        out["capacity"] = capacity_runs
    out["targets_met"] = {
        t.key: t.met(_number(out.get(t.key))) and t.key not in bad for t in TARGETS
    }
    return out


def _number(value: Any) -> float:
    return math.nan if value is None else float(value)


def jsonable(result: dict[str, Any]) -> dict[str, Any]:
    """The result with NaN as null (strict JSON)."""

    def clean(v: Any) -> Any:
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, list):
            return [clean(x) for x in v]
        return v

    out: dict[str, Any] = clean(result)
    return out


def table(result: dict[str, Any]) -> str:
    """The Markdown tables: the window (an untrustworthy figure shows INVALID and why), then
    each sweep's steps and why it stopped."""
    shown = {k: (math.nan if result.get(k) is None else result[k]) for k, _ in ROWS}
    parts = [bench_table(shown, ROWS, TARGETS, result.get("invalid") or None)]
    sweeps = [("this setup", result.get("sweep"), result.get("sweep_stopped"))]
    for key, found in (result.get("capacity") or {}).items():
        sweeps.append((CAPACITY[key].text(), found["steps"], found["stopped"]))
    for title, steps, stopped in sweeps:
        if steps is None:
            continue
        parts.append(f"\n{title}: stopped {stopped}\n\n" + _steps_table(steps))
    return "\n".join(parts)


def _steps_table(steps: Sequence[dict[str, Any]]) -> str:
    def f(v: Any, digits: int = 1) -> str:
        return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}f}"

    lines = [
        "| stations | viewers | sent/station (Hz) | viewer (Hz) | latency p50 (ms) "
        "| latency p99 (ms) | K/B ack p99 (ms) | HOLD ack p99 (ms) | lost | server CPU (%) "
        "| server us/msg | redis us/msg |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for s in steps:
        lines.append(
            f"| {s['stations']} | {s['viewers']} | {f(s['telemetry_hz_per_station'])} "
            f"| {f(s['viewer_hz'])} | {f(s['telemetry_latency_ms_p50'])} "
            f"| {f(s['telemetry_latency_ms_p99'])} | {f(s['kb_change_to_ack_ms_p99'])} "
            f"| {f(s['hold_to_ack_ms_p99'])} | {s['disconnects']} "
            f"| {f(s['server_cpu_pct'], 0)} | {f(s['server_cpu_us_per_message'], 0)} "
            f"| {f(s.get('redis_cpu_us_per_message'), 0)} |"
        )
    return "\n".join(lines)


# -- the load generator processes ---------------------------------------------------------
class _Window:
    def __init__(self) -> None:
        self.start = math.inf
        self.end = math.inf
        self.set = asyncio.Event()

    def inside(self, t: float) -> bool:
        return self.start <= t < self.end


async def _go(window: _Window) -> None:
    line = await asyncio.to_thread(sys.stdin.readline)
    times = json.loads(line)
    window.start, window.end = float(times["start"]), float(times["end"])
    window.set.set()


async def _connect_all(items: list[list[Any]], open_one: Any) -> list[Any]:
    gate = asyncio.Semaphore(CONNECT_CONCURRENCY)

    async def one(item: list[Any]) -> Any:
        async with gate:
            return await open_one(*item)

    return list(await asyncio.gather(*(one(i) for i in items)))


def _telemetry_templates(count: int = TEMPLATES) -> list[tuple[str, str]]:
    """Plausible telemetry batches (``SAMPLES_PER_BATCH`` samples each) as text, each split
    where ``sent`` goes. Their numbers differ, as a moving device's do (identical messages
    would make compression free)."""
    from sessions import wire

    rng = random.Random(1)

    def six(scale: float) -> list[float]:
        return [round(rng.uniform(-scale, scale), 7) for _ in range(6)]

    out = []
    for i in range(count):
        rows = [
            {
                "t": round(12.0 + (i * SAMPLES_PER_BATCH + j) / TELEMETRY_HZ, 6),
                "mode": "ACTIVE",
                "trip": 0,
                "segment_id": 1,
                "set": 1,
                "rep": 3,
                "pose": six(0.1),
                "pose_cmd": six(0.1),
                "legs": six(0.05),
                "pressures": [round(rng.uniform(1e5, 6e5), 1) for _ in range(12)],
                "wrench": six(20.0),
                "stiffness": [20000.0, 20000.0, 20000.0, 30.0, 30.0, 10.0],
                "damping": [200.0, 200.0, 200.0, 1.0, 1.0, 0.5],
                "lag_ms": round(rng.uniform(0.0, 0.5), 3),
                "overruns": 0,
                "frames_dropped": 0,
            }
            for j in range(SAMPLES_PER_BATCH)
        ]
        text = wire.TelemetryBatch.of(rows, sent=0.0).model_dump_json()
        head, tail = text.split('"sent":0.0', 1)
        out.append((head + '"sent":', tail))
    return out


async def _stations(config: dict[str, Any]) -> dict[str, Any]:
    from websockets.asyncio.client import ClientConnection, connect
    from websockets.exceptions import ConnectionClosed

    from sessions import wire

    window = _Window()
    templates = _telemetry_templates()
    hello = wire.StationHello(protocol=wire.PROTOCOL, software="ankle bench").model_dump_json()
    live: set[ClientConnection] = set()
    stats = {"telemetry": 0, "batches": 0, "disconnects": 0, "skipped": 0}
    by_process = [0] * int(config["processes"])
    process_of: dict[ClientConnection, int] = {}
    closing = False

    async def answer(ws: ClientConnection) -> None:
        try:
            async for raw in ws:
                message = json.loads(raw)
                if message.get("type") == "command":
                    result = wire.CommandResult(request_id=message["request_id"], ok=True)
                    await ws.send(result.model_dump_json())
        except ConnectionClosed:
            pass
        if ws in live and not closing:
            stats["disconnects"] += 1
        live.discard(ws)

    async def open_one(station_id: int, token: str, url: str) -> ClientConnection:
        ws = await connect(
            f"{url}/ws/station",
            additional_headers={"Authorization": f"Bearer {token}"},
            max_size=wire.MAX_MESSAGE_BYTES,
            open_timeout=30.0,
            ping_interval=None,
        )
        await ws.send(hello)
        welcome = json.loads(await ws.recv())
        if welcome.get("type") != "welcome":
            raise RuntimeError(f"station {station_id}: no welcome but {welcome}")
        return ws

    conns = await _connect_all(config["items"], open_one)
    live.update(conns)
    for i, ws in enumerate(conns):
        process_of[ws] = i % len(by_process)  # as measure() placed them
    readers = [asyncio.create_task(answer(ws)) for ws in conns]
    slots: list[list[ClientConnection]] = [[] for _ in range(PHASES)]
    for i, ws in enumerate(conns):
        slots[i % PHASES].append(ws)
    status = wire.StatusMsg(sent=0.0, device_link="connected", device_mode="ACTIVE")

    async def tick() -> None:
        loop = asyncio.get_running_loop()
        dt = 1.0 / BATCH_HZ / PHASES
        next_t = loop.time()
        k = 0
        beat_slot = random.randrange(BATCH_HZ)
        while time.time() < window.end:
            slot = slots[k % PHASES]
            now = time.time()
            counting = window.inside(now)
            second = (k // PHASES) % BATCH_HZ == beat_slot
            for j, ws in enumerate(slot):
                if ws not in live:
                    continue
                # A real station drops samples rather than queue them behind a slow link.
                if ws.transport.get_write_buffer_size() > 256 * 1024:
                    stats["skipped"] += 1
                    continue
                try:
                    head, tail = templates[(k + j) % TEMPLATES]
                    await ws.send(f"{head}{time.time()!r}{tail}")
                    if second:
                        now = time.time()
                        await ws.send(wire.Heartbeat(sent=now).model_dump_json())
                        await ws.send(status.model_copy(update={"sent": now}).model_dump_json())
                except ConnectionClosed:
                    continue
                if counting:
                    stats["telemetry"] += SAMPLES_PER_BATCH
                    stats["batches"] += 1
                    by_process[process_of[ws]] += 1
            k += 1
            next_t += dt
            delay = next_t - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            elif delay < -0.1:  # far behind: do not burst to catch up
                next_t = loop.time()

    print("ready", flush=True)
    go = asyncio.create_task(_go(window))
    sender = asyncio.create_task(tick())
    await go
    await sender
    await asyncio.sleep(TAIL_S)  # the viewers' last commands get answered
    closing = True
    await asyncio.gather(*(ws.close() for ws in conns), return_exceptions=True)
    for r in readers:
        r.cancel()
    return {"connected": len(conns), "batches_by_process": by_process, **stats}


async def _viewers(config: dict[str, Any]) -> dict[str, Any]:
    from websockets.asyncio.client import ClientConnection, connect
    from websockets.exceptions import ConnectionClosed

    from sessions import wire

    window = _Window()
    latency: list[float] = []
    samples = 0
    acks: dict[str, list[float]] = {"set_impedance": [], "hold": []}
    pending: dict[str, tuple[str, float]] = {}
    stats = {"disconnects": 0, "commands_failed": 0}
    live: set[ClientConnection] = set()
    closing = False

    async def watch(ws: ClientConnection) -> None:
        nonlocal samples
        try:
            async for raw in ws:
                now = time.time()
                message = json.loads(raw)
                kind = message["type"]
                if kind == "telemetry":
                    if window.inside(now):
                        latency.append(round((now - message["sent"]) * 1e3, 3))
                        samples += len(message["t"])
                elif kind == "result":
                    asked = pending.pop(message["request_id"], None)
                    if asked is not None:
                        action, sent = asked
                        if message["ok"]:
                            acks[action].append(round((time.perf_counter() - sent) * 1e3, 3))
                        else:
                            stats["commands_failed"] += 1
        except ConnectionClosed:
            pass
        if ws in live and not closing:
            stats["disconnects"] += 1
        live.discard(ws)

    async def open_one(station_id: int, token: str, url: str) -> ClientConnection:
        ws = await connect(
            f"{url}/ws/live/{station_id}",
            subprotocols=[wire.SUBPROTOCOL, f"{wire.BEARER_PREFIX}{token}"],  # type: ignore[list-item]
            max_size=wire.MAX_MESSAGE_BYTES,
            open_timeout=30.0,
            ping_interval=None,
        )
        async with asyncio.timeout(30.0):
            while (welcome := json.loads(await ws.recv())).get("type") != "welcome":
                pass  # the server may send telemetry first (uvicorn's legacy websockets)
        if not welcome.get("online"):
            raise RuntimeError(f"viewer of station {station_id}: the station is offline")
        return ws

    conns = await _connect_all(config["items"], open_one)
    live.update(conns)
    watchers = [asyncio.create_task(watch(ws)) for ws in conns]
    slots: list[list[tuple[int, ClientConnection]]] = [[] for _ in range(100)]
    for i, ws in enumerate(conns):
        slots[i % len(slots)].append((i, ws))

    async def tick() -> None:
        """Every viewer once a second, spread: a heartbeat and a K/B change, and half a
        second later a HOLD."""
        loop = asyncio.get_running_loop()
        dt = 1.0 / len(slots)
        next_t = loop.time()
        k = 0
        while time.time() < window.end:
            commanding = config["commands"] and window.inside(time.time())
            for i, ws in slots[k % len(slots)]:
                if ws not in live:
                    continue
                try:
                    await ws.send(wire.Heartbeat(sent=time.time()).model_dump_json())
                    if commanding:
                        rid = f"v{i}-{k}"
                        k_pitch = 30.0 + (k // len(slots)) % 2 * 10.0
                        cmd = wire.Command(
                            request_id=rid,
                            action="set_impedance",
                            stiffness={"pitch": k_pitch},
                            damping={"pitch": 1.0},
                        )
                        pending[rid] = (cmd.action, time.perf_counter())
                        await ws.send(cmd.model_dump_json())
                except ConnectionClosed:
                    continue
            for i, ws in slots[(k + len(slots) // 2) % len(slots)]:
                if ws not in live or not commanding:
                    continue
                hold = wire.Command(request_id=f"h{i}-{k}", action="hold")
                pending[hold.request_id] = (hold.action, time.perf_counter())
                with contextlib.suppress(ConnectionClosed):
                    await ws.send(hold.model_dump_json())
            k += 1
            next_t += dt
            delay = next_t - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)

    print("ready", flush=True)
    go = asyncio.create_task(_go(window))
    sender = asyncio.create_task(tick())
    await go
    await sender
    await asyncio.sleep(TAIL_S + 0.5)
    stats["commands_failed"] += len(pending)  # never answered
    closing = True
    await asyncio.gather(*(ws.close() for ws in conns), return_exceptions=True)
    for w in watchers:
        w.cancel()
    return {
        "connected": len(conns),
        "latency_ms": latency,
        "samples": samples,
        "ack_ms": acks,
        **stats,
    }


# -- heavy requests: does one request stop the server answering others? -----------------------
HEAVY_HZ = 100
"""Telemetry rate of the long recording, as the station records by default."""
POLL_PERIOD_S = 0.01
"""How often the cheap route is asked while a heavy request runs."""
HEAVY_IDLE_S = 3.0
HEAVY_REPEATS = 5
"""Times each heavy request is fired, one after the other."""
HEAVY_SESSIONS = 1000
"""Sessions of the patient whose progress and reports are asked for: three a day for a
year, each a 3 min session."""
STALL_MS = 50.0
"""A cheap request this late, beyond its idle time, was held by another's work."""
HEAVY_CASES: tuple[tuple[str, str], ...] = (
    ("upload_complete", "upload complete: check and summarise the longest recording"),
    ("series", "session series, default 2,000 points"),
    ("series_max", "session series, 20,000 points (the most)"),
    ("session_metrics", "one session whose metrics are computed on read"),
    ("progress", "progress over all the patient's sessions"),
    ("report_fhir", "FHIR bundle of all the patient's sessions"),
    ("report_pdf", "PDF report of all the patient's sessions"),
)


def longest_samples(limit_bytes: int) -> int:
    """Samples of the longest recording an upload of ``limit_bytes`` takes: all but a
    kilobyte per 50,000 samples (records, header, events, end) is samples."""
    from sessions.recording import SAMPLE_DTYPE

    return int(limit_bytes // SAMPLE_DTYPE.itemsize * 0.999)


def write_recording(
    path: Path, samples: int, station_id: int, patient_id: int, started_at: float
) -> None:
    """A strength session of ``samples`` samples at :data:`HEAVY_HZ` written as the station
    writes one (:class:`sessions.recording.RecordingWriter`): a repetition every 6 s (each
    set of 100 repetitions, then the next; 20 sets at most, then again from the first), the
    foot pushed through ±15° of pitch against 40 N·m/rad, its events and its end record."""
    from device.protocol.messages import DeviceMode
    from sessions.prescription import (
        AXIS_INDEX,
        EXERCISE_LIBRARY,
        REPETITIONS_MAX,
        SETS_MAX,
        ExerciseKind,
    )
    from sessions.recording import (
        SAMPLE_DTYPE,
        DeviceInfo,
        End,
        Header,
        RecordingWriter,
        SessionEvent,
    )

    prescription = EXERCISE_LIBRARY[ExerciseKind.STRENGTH].defaults.model_dump(mode="json")
    prescription |= {"sets": SETS_MAX, "repetitions": REPETITIONS_MAX}
    header = Header(
        session_id=path.stem,
        station_id=station_id,
        patient_id=patient_id,
        prescription_id=0,
        prescription=prescription,
        device=DeviceInfo(
            firmware="sim", hardware="sim", telemetry_hz=HEAVY_HZ, home_pose=[0.0] * 6
        ),
        software="bench",
        started_at=started_at,
    )
    pitch = AXIS_INDEX["pitch"]
    per_rep = 6 * HEAVY_HZ
    block = 50_000
    reps = 0
    with RecordingWriter(path, header) as writer:
        for first in range(0, samples, block):
            i = np.arange(first, min(first + block, samples))
            rows = np.zeros(len(i), SAMPLE_DTYPE)
            rows["t"] = 10.0 + i / HEAVY_HZ
            rows["wall"] = started_at + i / HEAVY_HZ
            rows["mode"] = int(DeviceMode.ACTIVE)
            n = i // per_rep
            rows["set"] = (n // REPETITIONS_MAX) % SETS_MAX + 1
            rows["rep"] = n % REPETITIONS_MAX + 1
            q = np.radians(15.0) * np.sin(2 * np.pi * (i % per_rep) / per_rep)
            rows["pose"][:, pitch] = q
            rows["pose_cmd"][:, pitch] = 0.0
            rows["wrench"][:, pitch] = -40.0 * q
            rows["wrench"][:, 2] = -300.0
            rows["pressures"] = 3e5 + 1e5 * np.sin(i / 50.0)[:, None]
            rows["supply"] = 6e5
            rows["stiffness"][:, pitch] = 40.0
            rows["damping"][:, pitch] = 2.0
            for row in rows.tolist():
                writer.add(tuple(row))
            done = int(n[-1]) if (i[-1] + 1) % per_rep == 0 else int(n[-1]) - 1
            for k in range(reps, done + 1):
                writer.event(
                    SessionEvent(
                        kind="rep_done",
                        t=10.0 + (k + 1) * per_rep / HEAVY_HZ,
                        wall=started_at + (k + 1) * per_rep / HEAVY_HZ,
                        detail={
                            "set": k // REPETITIONS_MAX % SETS_MAX + 1,
                            "rep": k % REPETITIONS_MAX + 1,
                        },
                    )
                )
            reps = max(reps, done + 1)
            writer.flush()
        writer.end(
            End(
                ended_at=started_at + samples / HEAVY_HZ,
                reason="completed",
                text="",
                sets_completed=min(SETS_MAX, reps // REPETITIONS_MAX),
                repetitions_completed=min(SETS_MAX * REPETITIONS_MAX, reps),
            )
        )


class Poller:
    """Asks a cheap route every :data:`POLL_PERIOD_S` on a connection of its own, in a
    thread, and keeps (start, latency, status) of each answer."""

    def __init__(self, port: int, path: str, token: str = "") -> None:
        self.port, self.path = port, path
        self.headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.polls: list[tuple[float, float, int]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        import http.client

        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=60)
        while not self._stop.is_set():
            t0 = time.monotonic()
            try:
                conn.request("GET", self.path, headers=self.headers)
                r = conn.getresponse()
                r.read()
                status = r.status
            except (OSError, http.client.HTTPException):
                status = 0
                conn.close()
                conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=60)
            t1 = time.monotonic()
            self.polls.append((t0, t1 - t0, status))
            self._stop.wait(max(0.0, POLL_PERIOD_S - (t1 - t0)))
        conn.close()

    def between(self, start: float, end: float) -> dict[str, Any]:
        seen = [dt * 1e3 for t, dt, _ in list(self.polls) if start <= t < end]
        failed = sum(1 for t, _, s in list(self.polls) if start <= t < end and s != 200)
        return {
            "polls": len(seen),
            "p50_ms": _pct(seen, 50),
            "p99_ms": _pct(seen, 99),
            "max_ms": max(seen) if seen else math.nan,
            "failed": failed,
        }

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(60)


async def _heavy_provision(data_dir: Path) -> Seat:
    (seat,) = await provision(data_dir, 1)
    return seat


async def _clone_sessions(data_dir: Path, template_id: int, count: int) -> None:
    """``count`` copies of session ``template_id`` (its summary and its file), one every
    8 hours back from it: a patient with a year of sessions."""
    from server.config import Settings
    from server.db import create_engine, create_sessionmaker
    from server.models import Session

    engine = create_engine(Settings(data_dir=data_dir))
    try:
        async with create_sessionmaker(engine)() as db:
            row = await db.get(Session, template_id)
            assert row is not None
            for k in range(1, count):
                back = timedelta(hours=8 * k)
                db.add(
                    Session(
                        session_uuid=str(uuid.uuid4()),
                        station_id=row.station_id,
                        patient_id=row.patient_id,
                        prescription_id=row.prescription_id,
                        started_at=row.started_at - back,
                        ended_at=None if row.ended_at is None else row.ended_at - back,
                        end_reason=row.end_reason,
                        size_bytes=row.size_bytes,
                        sha256=row.sha256,
                        summary=row.summary,
                        file_path=row.file_path,
                        upload_complete=True,
                    )
                )
            await db.commit()
    finally:
        await engine.dispose()


async def _forget_metrics(data_dir: Path, session_id: int) -> None:
    """The session's summary as stored before the metrics existed: the next read computes
    them from its recording."""
    from server.config import Settings
    from server.db import create_engine, create_sessionmaker
    from server.models import Session

    engine = create_engine(Settings(data_dir=data_dir))
    try:
        async with create_sessionmaker(engine)() as db:
            row = await db.get(Session, session_id)
            assert row is not None and row.summary is not None
            row.summary = {**row.summary, "metrics": None}
            await db.commit()
    finally:
        await engine.dispose()


def _upload(client: Any, path: Path, pid: int) -> tuple[dict[str, Any], float, float, float]:
    """Upload ``path`` as the station does (``station.uploader``): its chunks, then the
    request that completes it. The session, the seconds the chunks and the completion took,
    and the server's (process ``pid``) CPU seconds during the completion."""
    from station.uploader import CHUNK, sha256_file

    url = f"/api/v1/uploads/{path.stem}"
    size = path.stat().st_size
    t0 = time.monotonic()
    with path.open("rb") as f:
        offset = 0
        while offset < size:
            f.seek(offset)
            r = client.patch(
                url,
                content=f.read(CHUNK),
                headers={
                    "Upload-Offset": str(offset),
                    "Content-Type": "application/offset+octet-stream",
                },
            )
            r.raise_for_status()
            offset = int(r.headers["Upload-Offset"])
    digest = sha256_file(path)
    c1, t1 = cpu_seconds(pid), time.monotonic()
    done = client.post(f"{url}/complete", json={"size": size, "sha256": digest})
    c2, t2 = cpu_seconds(pid), time.monotonic()
    done.raise_for_status()
    return dict(done.json()), t1 - t0, t2 - t1, c2 - c1


def heavy(
    samples: int | None = None,
    sessions: int = HEAVY_SESSIONS,
    repeats: int = HEAVY_REPEATS,
    cases: Sequence[str] = tuple(dict(HEAVY_CASES)),
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Each heavy request of :data:`HEAVY_CASES` fired ``repeats`` times, one after the other,
    on a real server, while another client asks ``/api/v1/health`` every 10 ms: the cheap
    route's latency idle and under each, each heavy request's own time, and the server's CPU
    time over the wall time (1.0: a core busy all along)."""
    import httpx

    from server.config import Settings

    say = progress or (lambda _line: None)
    limit = Settings.model_fields["upload_max_bytes"].default
    count = longest_samples(limit) if samples is None else samples
    with tempfile.TemporaryDirectory(prefix="ankle-bench-heavy-") as tmp:
        data_dir = Path(tmp)
        seat = asyncio.run(_heavy_provision(data_dir))
        engine_patient = _seat_patient(data_dir, seat)
        spool = data_dir / "spool"
        spool.mkdir()
        say(f"writing a recording of {count} samples")
        long_rec = spool / f"{uuid.uuid4()}.rec"
        started = time.time() - 86400.0
        write_recording(long_rec, count, seat.station_id, engine_patient, started)
        short_rec = spool / f"{uuid.uuid4()}.rec"
        write_recording(short_rec, 3 * 60 * HEAVY_HZ, seat.station_id, engine_patient, started)
        server = ServerProcess(data_dir)
        poller = Poller(server.port, "/api/v1/health")
        out: dict[str, Any] = {
            "recording_samples": count,
            "recording_hours": count / HEAVY_HZ / 3600,
            "recording_mb": long_rec.stat().st_size / 1e6,
            "upload_max_bytes": limit,
            "sessions": sessions,
            "repeats": repeats,
            "cases": {},
        }
        try:
            station = httpx.Client(
                base_url=server.url,
                headers={"Authorization": f"Bearer {seat.station_token}"},
                timeout=600.0,
            )
            therapist = httpx.Client(
                base_url=server.url,
                headers={"Authorization": f"Bearer {seat.therapist_token}"},
                timeout=600.0,
            )
            time.sleep(1.0)
            t0 = time.monotonic()
            time.sleep(HEAVY_IDLE_S)
            out["idle"] = poller.between(t0, time.monotonic())
            say("uploading the longest recording")
            c0, w0 = cpu_seconds(server.proc.pid), time.monotonic()
            session, chunks_s, complete_s, complete_cpu = _upload(
                station, long_rec, server.proc.pid
            )
            c1, w1 = cpu_seconds(server.proc.pid), time.monotonic()
            out["upload_chunks_s"] = chunks_s
            if "upload_complete" in cases:
                out["cases"]["upload_complete"] = {
                    **poller.between(w1 - complete_s, w1),
                    "request_s": [complete_s],
                    "server_cpu_ratio": complete_cpu / complete_s,
                }
            out["upload_all"] = {
                **poller.between(w0, w1),
                "server_cpu_ratio": (c1 - c0) / (w1 - w0),
            }
            short, _, _, _ = _upload(station, short_rec, server.proc.pid)
            asyncio.run(_clone_sessions(data_dir, short["id"], sessions))
            patient = session["patient_id"]
            report = {"since": "2000-01-01"}
            requests: dict[str, tuple[str, dict[str, Any]]] = {
                "series": (f"/api/v1/sessions/{session['id']}/series", {}),
                "series_max": (f"/api/v1/sessions/{session['id']}/series", {"points": 20000}),
                "session_metrics": (f"/api/v1/sessions/{session['id']}", {}),
                "progress": (f"/api/v1/patients/{patient}/progress", {}),
                "report_fhir": (f"/api/v1/patients/{patient}/fhir", report),
                "report_pdf": (f"/api/v1/patients/{patient}/report.pdf", report),
            }
            for key, (url, params) in requests.items():
                if key not in cases:
                    continue
                say(key)
                took: list[float] = []
                cpu = wall = 0.0
                windows: list[tuple[float, float]] = []
                for _ in range(repeats):
                    if key == "session_metrics":
                        asyncio.run(_forget_metrics(data_dir, session["id"]))
                    time.sleep(0.2)
                    c0, w0 = cpu_seconds(server.proc.pid), time.monotonic()
                    r = therapist.get(url, params=params)
                    c1, w1 = cpu_seconds(server.proc.pid), time.monotonic()
                    r.raise_for_status()
                    took.append(w1 - w0)
                    cpu += c1 - c0
                    wall += w1 - w0
                    windows.append((w0, w1))
                seen = [poller.between(a, b) for a, b in windows]
                polls = [
                    dt * 1e3
                    for t, dt, _ in list(poller.polls)
                    if any(a <= t < b for a, b in windows)
                ]
                out["cases"][key] = {
                    "polls": len(polls),
                    "p50_ms": _pct(polls, 50),
                    "p99_ms": _pct(polls, 99),
                    "max_ms": max(s["max_ms"] for s in seen),
                    "failed": sum(s["failed"] for s in seen),
                    "request_s": took,
                    "bytes": len(r.content),
                    "server_cpu_ratio": cpu / wall if wall else math.nan,
                }
        finally:
            poller.stop()
            server.stop()
    return out


def _seat_patient(data_dir: Path, seat: Seat) -> int:
    async def find() -> int:
        from server.config import Settings
        from server.db import create_engine, create_sessionmaker
        from server.models import Station

        engine = create_engine(Settings(data_dir=data_dir))
        try:
            async with create_sessionmaker(engine)() as db:
                station = await db.get(Station, seat.station_id)
                assert station is not None
                return station.patient_id
        finally:
            await engine.dispose()

    return asyncio.run(find())


HEAVY_ROWS: tuple[tuple[str, str], ...] = (
    ("idle", "idle"),
    ("upload_all", "the whole upload of the longest recording: 1 MiB chunks, then complete"),
    *HEAVY_CASES,
)


def heavy_table(result: dict[str, Any]) -> str:
    """One row per heavy request: the cheap route's latency under it, its own time, the
    server's CPU time over the wall time."""
    lines = [
        f"longest recording: {result['recording_samples']} samples "
        f"({result['recording_hours']:.2f} h at {HEAVY_HZ} Hz, {result['recording_mb']:.0f} MB); "
        f"{result['sessions']} sessions for progress and reports; each request "
        f"{result['repeats']} times",
        "",
        "| request | /health p50 / p99 / max (ms) | request time (s) | server CPU / wall |",
        "|---|---:|---:|---:|",
    ]
    for key, text in HEAVY_ROWS:
        found = result[key] if key in ("idle", "upload_all") else result["cases"].get(key)
        if found is None:
            continue
        took = found.get("request_s") or []
        when = (
            f"{min(took):.3f}-{max(took):.3f}"
            if len(took) > 1
            else (f"{took[0]:.3f}" if took else "")
        )
        ratio = found.get("server_cpu_ratio", math.nan)
        lines.append(
            f"| {text} | {found['p50_ms']:.1f} / {found['p99_ms']:.1f} / {found['max_ms']:.1f} "
            f"| {when} | {'' if math.isnan(ratio) else f'{ratio:.2f}'} |"
        )
    return "\n".join(lines)


def _worker(role: str, stdin: IO[str]) -> int:
    config = json.loads(stdin.readline())
    main = {"stations": _stations, "viewers": _viewers}[role]
    result = asyncio.run(main(config))
    print(json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(_worker(sys.argv[1], sys.stdin))
