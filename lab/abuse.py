"""``ankle bench abuse``: what bad clients do to a real server, and what everyone else sees.

The server runs as its own process (``python -m ankle server`` on a fresh data directory, as
``ankle bench server`` starts it). Before it starts, the database gets a therapist with a
patient, a station and a login token (``lab.serverbench.provision``), and two accounts with
real Argon2 passwords: one that signs in well, one whose password is guessed.

Three more processes:

- ``links``: the live links that must survive: the station streams telemetry at 50 Hz
  (with heartbeats and status each second, answering every command at once) and its
  therapist watches it on ``/ws/live/{id}``. No device: the station is this harness.
- ``attack``: one phase of abuse at a time, from its own process so that its CPU is not the
  measurer's:
  (a) bodies of 10 MiB and 100 MiB to JSON routes, streamed from one reused 1 MiB buffer,
      half with Content-Length and half chunked, four at a time;
  (b) 100 concurrent wrong sign-ins from a second loopback address (127.0.0.2) while the
      good account signs in from 127.0.0.1 (the time of that sign-in is measured);
  (c) one viewer sending 1,000 messages a second (heartbeats, every tenth a K/B change);
  (d) malformed requests of the kinds the server must answer with a 4xx: lone surrogates,
      numbers as text, NaN, a recording header that is not JSON, an end time that is NaN.
- this process: polls ``/health`` every 20 ms on a connection of its own (a thread with
  ``http.client``) and samples the server's resident memory (``/proc``) every 0.1 s.

``server_5xx`` counts every 5xx answer any client got, the polls included. On a small
machine every process shares the cores with whatever else runs there: the numbers are what
a clinic server on such a machine would show, neighbours included.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import http.client
import json
import math
import struct
import subprocess
import sys
import tempfile
import threading
import time
import uuid
import zlib
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lab.serverbench import ServerProcess, _number, jsonable, provision
from lab.targets import Target
from lab.targets import table as bench_table

MiB = 1024 * 1024
GOOD_EMAIL = "good@bench.test"
VICTIM_EMAIL = "victim@bench.test"
PASSWORD = "correct horse battery staple"
HEALTH_PERIOD_S = 0.02
RSS_PERIOD_S = 0.1
PHASE_TIMEOUT_S = 900.0

TARGETS: tuple[Target, ...] = (
    Target("health_p99_ms_bigbody", "/health p99 during large bodies (ms)", 100.0, "max"),
    Target("health_p99_ms_login_flood", "/health p99 during the sign-in flood (ms)", 100.0, "max"),
    Target("good_login_ms_under_flood", "a good sign-in during the flood (ms)", 1000.0, "max"),
    Target("health_p99_ms_ws_flood", "/health p99 during the WebSocket flood (ms)", 100.0, "max"),
    Target("health_p99_ms_malformed", "/health p99 during malformed requests (ms)", 100.0, "max"),
    Target("live_links_dropped", "live links dropped", 0, "eq"),
    Target("server_5xx", "5xx answers", 0, "eq"),
    Target("server_rss_ratio", "server memory, most / idle", 2.0, "max"),
)

ROWS: tuple[tuple[str, str], ...] = (
    ("health_p99_ms_idle", "/health p99 idle (ms)"),
    ("health_p99_ms_bigbody", "/health p99 during large bodies (ms)"),
    ("bigbody_refused", "large bodies refused (413)"),
    ("bigbody_s", "large bodies: time to send them all (s)"),
    ("health_p99_ms_login_flood", "/health p99 during the sign-in flood (ms)"),
    ("good_login_ms_under_flood", "a good sign-in during the flood (ms)"),
    ("login_flood_401", "flood sign-ins checked and refused (401)"),
    ("login_flood_429", "flood sign-ins throttled (429)"),
    ("health_p99_ms_ws_flood", "/health p99 during the WebSocket flood (ms)"),
    ("ws_flood_sent", "WebSocket flood messages sent"),
    ("ws_flood_rate", "WebSocket flood rate achieved (msg/s)"),
    ("health_p99_ms_malformed", "/health p99 during malformed requests (ms)"),
    ("malformed_4xx", "malformed requests answered 4xx"),
    ("live_links_dropped", "live links dropped"),
    ("viewer_telemetry", "telemetry messages the watching viewer got"),
    ("server_5xx", "5xx answers"),
    ("server_rss_mb_idle", "server memory idle (MiB)"),
    ("server_rss_mb_max", "server memory, most (MiB)"),
    ("server_rss_ratio", "server memory, most / idle"),
)


@dataclass(frozen=True)
class Sizes:
    """How much abuse: the defaults are the issue's; a test runs a tiny version."""

    bodies_10mib: int = 20
    bodies_100mib: int = 20
    logins: int = 100
    ws_rate: int = 1000
    ws_seconds: float = 3.0
    malformed: int = 200


# -- measuring, in this process ----------------------------------------------------------------
def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return math.nan


@dataclass
class Monitor:
    """Polls /health and samples the server's memory in a thread until :meth:`stop`."""

    port: int
    pid: int
    polls: list[tuple[float, float, int]] = field(default_factory=list)
    rss: list[tuple[float, float]] = field(default_factory=list)
    _stop: threading.Event = field(default_factory=threading.Event)
    _threads: list[threading.Thread] = field(default_factory=list)

    def start(self) -> None:
        for target in (self._poll, self._sample):
            t = threading.Thread(target=target, daemon=True)
            t.start()
            self._threads.append(t)

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(30)

    def _poll(self) -> None:
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=30)
        while not self._stop.is_set():
            t0 = time.monotonic()
            try:
                conn.request("GET", "/api/v1/health")
                r = conn.getresponse()
                r.read()
                status = r.status
            except (OSError, http.client.HTTPException):
                status = 0
                conn.close()
                conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=30)
            t1 = time.monotonic()
            self.polls.append((t0, t1 - t0, status))
            self._stop.wait(max(0.0, HEALTH_PERIOD_S - (t1 - t0)))
        conn.close()

    def _sample(self) -> None:
        while not self._stop.is_set():
            with contextlib.suppress(OSError):
                self.rss.append((time.monotonic(), rss_mb(self.pid)))
            self._stop.wait(RSS_PERIOD_S)

    def p99_ms(self, start: float, end: float) -> float:
        seen = [dt for t, dt, _ in list(self.polls) if start <= t < end]
        return float(np.percentile(seen, 99)) * 1e3 if seen else math.nan

    def server_errors(self) -> int:
        return sum(1 for _, _, status in self.polls if status >= 500 or status == 0)

    def rss_between(self, start: float, end: float) -> list[float]:
        return [mb for t, mb in list(self.rss) if start <= t < end]


# -- the worker processes ----------------------------------------------------------------------
def _attack(config: dict[str, Any]) -> dict[str, Any]:
    proc = subprocess.run(
        [sys.executable, "-m", "lab.abuse", "attack"],
        input=json.dumps(config),
        capture_output=True,
        text=True,
        timeout=PHASE_TIMEOUT_S,
        check=False,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"the {config['phase']} attack failed:\n{proc.stderr[-3000:]}")
    out: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return out


class Links:
    """The station and the viewer that must stay up, in a process of their own."""

    def __init__(self, config: dict[str, Any], log: Path) -> None:
        with log.open("wb") as errors:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "lab.abuse", "links"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=errors,
                text=True,
            )
        self.log = log
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps(config) + "\n")
        self.proc.stdin.flush()
        if self.proc.stdout.readline().strip() != "ready":
            self.proc.kill()
            raise RuntimeError(f"the live links did not connect:\n{log.read_text()[-3000:]}")

    def finish(self) -> dict[str, Any]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write("stop\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        self.proc.wait(30)
        if not line:
            raise RuntimeError(f"the live links failed:\n{self.log.read_text()[-3000:]}")
        out: dict[str, Any] = json.loads(line)
        return out


# -- the benchmark ----------------------------------------------------------------------------
def run(sizes: Sizes = Sizes(), progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    say = progress or (lambda _line: None)
    with tempfile.TemporaryDirectory(prefix="ankle-bench-abuse-") as tmp:
        data_dir = Path(tmp)
        say("provisioning")
        seat = asyncio.run(_provision(data_dir))
        server = ServerProcess(data_dir)
        monitor = Monitor(server.port, server.proc.pid)
        try:
            result = _measure(server, monitor, seat, sizes, say)
        finally:
            monitor.stop()
            server.stop()
    result["server_5xx"] += monitor.server_errors()
    idle, most = result["server_rss_mb_idle"], result["server_rss_mb_max"]
    result["server_rss_ratio"] = most / idle if idle else math.nan
    result["sizes"] = sizes.__dict__
    result["targets_met"] = {t.key: t.met(_number(result[t.key])) for t in TARGETS}
    return result


async def _provision(data_dir: Path) -> dict[str, Any]:
    from server.cli import ensure_user_async
    from server.config import Settings

    (seat,) = await provision(data_dir, 1)
    settings = Settings(data_dir=data_dir)
    await ensure_user_async(settings, GOOD_EMAIL, "Good", "therapist", PASSWORD)
    await ensure_user_async(settings, VICTIM_EMAIL, "Victim", "therapist", PASSWORD)
    return {
        "station_id": seat.station_id,
        "station_token": seat.station_token,
        "therapist_token": seat.therapist_token,
    }


def _measure(
    server: ServerProcess,
    monitor: Monitor,
    seat: dict[str, Any],
    sizes: Sizes,
    say: Callable[[str], None],
) -> dict[str, Any]:
    base = {"url": server.url, **seat}
    say("connecting the live links")
    links = Links(base, server.log.parent / "links.log")
    monitor.start()
    say("idle")
    t0 = time.monotonic()
    time.sleep(2.0)
    idle_end = time.monotonic()
    idle_rss = monitor.rss_between(t0, idle_end)
    out: dict[str, Any] = {
        "health_p99_ms_idle": monitor.p99_ms(t0 + 0.5, idle_end),
        "server_rss_mb_idle": float(np.median(idle_rss)) if idle_rss else math.nan,
    }
    five = 0
    phases = (
        (
            "bigbody",
            "large bodies",
            {"bodies_10mib": sizes.bodies_10mib, "bodies_100mib": sizes.bodies_100mib},
        ),
        ("login_flood", "sign-in flood", {"logins": sizes.logins}),
        ("ws_flood", "WebSocket flood", {"rate": sizes.ws_rate, "seconds": sizes.ws_seconds}),
        ("malformed", "malformed requests", {"count": sizes.malformed}),
    )
    for key, words, options in phases:
        say(f"{words} ...")
        start = time.monotonic()
        got = _attack({**base, "phase": key, **options})
        end = time.monotonic()
        out[f"health_p99_ms_{key}"] = monitor.p99_ms(start, end)
        five += got.pop("server_5xx")
        out.update(got)
        say(f"{words}: /health p99 {out[f'health_p99_ms_{key}']:.1f} ms")
        time.sleep(0.5)  # the server's queues settle between phases
    say("closing the live links")
    kept = links.finish()
    rss = monitor.rss_between(idle_end, time.monotonic())
    out |= {
        "live_links_dropped": kept["dropped"],
        "viewer_telemetry": kept["viewer_telemetry"],
        "server_5xx": five,
        "server_rss_mb_max": max(rss) if rss else math.nan,
        "health_polls": len(monitor.polls),
    }
    return out


def table(result: dict[str, Any]) -> str:
    shown = {k: (math.nan if v is None else v) for k, v in result.items()}
    return bench_table(shown, ROWS, TARGETS)


# -- the attack process ----------------------------------------------------------------------
def _record(kind: int, payload: bytes) -> bytes:
    """One record of a session recording (``sessions.recording``), CRC and all."""
    head = struct.pack("<BI", kind, len(payload))
    return head + payload + struct.pack("<I", zlib.crc32(payload, zlib.crc32(head)))


async def _bigbody(config: dict[str, Any]) -> dict[str, Any]:
    import httpx

    chunk = b"[" + b"1," * (MiB // 2 - 1) + b"1"  # 1 MiB, reused: nothing big is built
    routes = ("/api/v1/auth/login", "/api/v1/patients", "/api/v1/users")
    jobs = [10] * config["bodies_10mib"] + [100] * config["bodies_100mib"]
    codes: list[int] = []
    gate = asyncio.Semaphore(4)
    auth = {"Authorization": f"Bearer {config['therapist_token']}"}

    async def body(mib: int) -> AsyncIterator[bytes]:
        for _ in range(mib):
            yield chunk

    async def one(i: int, mib: int, client: httpx.AsyncClient) -> None:
        headers = {**auth, "Content-Type": "application/json"}
        if i % 2 == 0:
            headers["Content-Length"] = str(mib * MiB)
        async with gate:
            try:
                r = await client.post(routes[i % len(routes)], content=body(mib), headers=headers)
                codes.append(r.status_code)
            except httpx.HTTPError:
                codes.append(0)

    t = time.monotonic()
    async with httpx.AsyncClient(base_url=config["url"], timeout=120) as client:
        await asyncio.gather(*(one(i, mib, client) for i, mib in enumerate(jobs)))
    return {
        "bigbody_refused": codes.count(413),
        "bigbody_other": len(codes) - codes.count(413),
        "bigbody_s": time.monotonic() - t,
        "server_5xx": sum(1 for c in codes if c >= 500),
    }


async def _login_flood(config: dict[str, Any]) -> dict[str, Any]:
    import httpx

    limits = httpx.Limits(max_connections=config["logins"] + 10)
    attacker = httpx.AsyncClient(
        base_url=config["url"],
        transport=httpx.AsyncHTTPTransport(local_address="127.0.0.2", limits=limits),
        timeout=120,
    )
    good = httpx.AsyncClient(base_url=config["url"], timeout=120)
    async with attacker, good:

        async def guess(i: int) -> int:
            r = await attacker.post(
                "/api/v1/auth/login", json={"email": VICTIM_EMAIL, "password": f"guess {i}"}
            )
            return r.status_code

        flood = [asyncio.create_task(guess(i)) for i in range(config["logins"])]
        await asyncio.sleep(0.05)  # the flood is queued when the colleague signs in
        t = time.perf_counter()
        r = await good.post("/api/v1/auth/login", json={"email": GOOD_EMAIL, "password": PASSWORD})
        good_ms = (time.perf_counter() - t) * 1e3
        codes = list(await asyncio.gather(*flood))
    return {
        "good_login_ms_under_flood": good_ms if r.status_code == 200 else math.nan,
        "good_login_status": r.status_code,
        "login_flood_401": codes.count(401),
        "login_flood_429": codes.count(429),
        "server_5xx": sum(1 for c in [*codes, r.status_code] if c >= 500),
    }


async def _ws_flood(config: dict[str, Any]) -> dict[str, Any]:
    from websockets.asyncio.client import connect
    from websockets.exceptions import ConnectionClosed

    from sessions import wire

    url = config["url"].replace("http://", "ws://") + f"/ws/live/{config['station_id']}"
    rate, seconds = config["rate"], config["seconds"]
    sent = 0
    closed = ""
    async with connect(
        url,
        subprotocols=[wire.SUBPROTOCOL, f"{wire.BEARER_PREFIX}{config['therapist_token']}"],  # type: ignore[list-item]
        max_size=wire.MAX_MESSAGE_BYTES,
        ping_interval=None,
        open_timeout=30,
    ) as ws:

        async def drain() -> None:
            with contextlib.suppress(ConnectionClosed):
                async for _ in ws:
                    pass

        reader = asyncio.create_task(drain())
        loop = asyncio.get_running_loop()
        start = loop.time()
        tick = 0.01
        per_tick = max(1, round(rate * tick))
        try:
            while loop.time() - start < seconds:
                for _ in range(per_tick):
                    # One command in 200 (5 a second at the default rate): within a link's
                    # budget (server.hub.COMMAND_WINDOW), so the flood lasts its seconds; a
                    # link past its budget is closed at once (tests/server/test_live_abuse).
                    if sent % 200 == 199:
                        text = wire.Command(
                            request_id=f"flood-{sent}",
                            action="set_impedance",
                            stiffness={"pitch": 30.0 + sent % 20},
                        ).model_dump_json()
                    else:
                        text = wire.Heartbeat(sent=time.time()).model_dump_json()
                    await ws.send(text)
                    sent += 1
                await asyncio.sleep(max(0.0, start + (sent / rate) - loop.time()))
        except ConnectionClosed as exc:
            closed = f"{exc.rcvd.code if exc.rcvd else ''} {exc.rcvd.reason if exc.rcvd else ''}"
        elapsed = loop.time() - start
        reader.cancel()
    return {
        "ws_flood_sent": sent,
        "ws_flood_rate": sent / elapsed if elapsed else math.nan,
        "ws_flood_closed": closed.strip(),
        "server_5xx": 0,
    }


async def _malformed(config: dict[str, Any]) -> dict[str, Any]:
    import httpx

    from sessions.prescription import EXERCISE_LIBRARY, ExerciseKind
    from sessions.recording import MAGIC, DeviceInfo, End, Header, RecordType, encode_json

    user = {"Authorization": f"Bearer {config['therapist_token']}"}
    station = {"Authorization": f"Bearer {config['station_token']}"}
    as_json = {"Content-Type": "application/json"}
    codes: list[int] = []
    async with httpx.AsyncClient(base_url=config["url"] + "/api/v1", timeout=60) as c:
        patient = (await c.get("/patients", headers=user)).json()[0]["id"]
        me = (await c.get("/station/me", headers=station)).json()
        rx = EXERCISE_LIBRARY[ExerciseKind.STRENGTH].defaults.model_dump(mode="json")
        axis = rx["axes"][0]

        def recording(sid: str, ended_at: str) -> bytes:
            header = Header(
                session_id=sid,
                station_id=config["station_id"],
                patient_id=me["patient_id"],
                prescription_id=0,
                prescription=rx,
                device=DeviceInfo(firmware="b", hardware="b", telemetry_hz=100, home_pose=[0] * 6),
                software="bench",
                started_at=time.time(),
            )
            end = End(
                ended_at=time.time(), reason="completed", sets_completed=0, repetitions_completed=0
            ).model_dump_json()
            end = end.replace(f'"ended_at":{json.loads(end)["ended_at"]}', f'"ended_at":{ended_at}')
            return MAGIC + encode_json(RecordType.HEADER, header) + _record(4, end.encode())

        async def bad_end(value: str) -> int:
            sid = str(uuid.uuid4())
            data = recording(sid, value)
            r = await c.patch(
                f"/uploads/{sid}", content=data, headers={**station, "Upload-Offset": "0"}
            )
            if r.status_code != 204:
                return r.status_code
            body = {"size": len(data), "sha256": hashlib.sha256(data).hexdigest()}
            return (
                await c.post(f"/uploads/{sid}/complete", json=body, headers=station)
            ).status_code

        async def bad_header() -> int:
            sid = str(uuid.uuid4())
            data = MAGIC + _record(1, b'{"session_id": not json')
            r = await c.patch(
                f"/uploads/{sid}", content=data, headers={**station, "Upload-Offset": "0"}
            )
            return r.status_code

        def raw(path: str, text: str, headers: dict[str, str]) -> Any:
            return c.post(path, content=text.encode(), headers={**headers, **as_json})

        kinds: list[Callable[[], Any]] = [
            lambda: raw("/auth/login", '{"email": "\\ud800", "password": "x"}', {}),
            lambda: raw("/auth/login", '{"email": "a@b.c", "password": "\\udfff"}', {}),
            lambda: raw("/auth/login", '{"email": NaN, "password": "x"}', {}),
            lambda: raw("/patients", '{"display_name": "\\ud83d"}', user),
            lambda: c.post(
                f"/patients/{patient}/prescriptions",
                headers=user,
                json={**rx, "axes": [{**axis, "stiffness": "40"}]},
            ),
            lambda: c.post(
                f"/patients/{patient}/prescriptions", headers=user, json={**rx, "sets": True}
            ),
            lambda: raw(
                f"/patients/{patient}/prescriptions",
                json.dumps({**rx, "axes": [{**axis, "stiffness": math.nan}]}),
                user,
            ),
            bad_header,
            lambda: bad_end("NaN"),
            lambda: bad_end("-1"),
            lambda: bad_end("1e300"),
        ]
        for i in range(config["count"]):
            result = await kinds[i % len(kinds)]()
            codes.append(result if isinstance(result, int) else result.status_code)
    return {
        "malformed_4xx": sum(1 for c in codes if 400 <= c < 500),
        "malformed_other": sum(1 for c in codes if not 400 <= c < 500),
        "server_5xx": sum(1 for c in codes if c >= 500),
    }


ATTACKS = {
    "bigbody": _bigbody,
    "login_flood": _login_flood,
    "ws_flood": _ws_flood,
    "malformed": _malformed,
}


# -- the live links process --------------------------------------------------------------------
async def _links(config: dict[str, Any]) -> dict[str, Any]:
    from websockets.asyncio.client import connect
    from websockets.exceptions import ConnectionClosed

    from lab.serverbench import _telemetry_templates
    from sessions import wire

    ws_url = config["url"].replace("http://", "ws://")
    dropped = 0
    viewer_telemetry = 0
    stopping = False
    station = await connect(
        f"{ws_url}/ws/station",
        additional_headers={"Authorization": f"Bearer {config['station_token']}"},
        max_size=wire.MAX_MESSAGE_BYTES,
        ping_interval=None,
        open_timeout=30,
    )
    await station.send(
        wire.StationHello(protocol=wire.PROTOCOL, software="bench").model_dump_json()
    )
    viewer = await connect(
        f"{ws_url}/ws/live/{config['station_id']}",
        subprotocols=[wire.SUBPROTOCOL, f"{wire.BEARER_PREFIX}{config['therapist_token']}"],  # type: ignore[list-item]
        max_size=wire.MAX_MESSAGE_BYTES,
        ping_interval=None,
        open_timeout=30,
    )

    async def station_reader() -> None:
        nonlocal dropped
        try:
            async for raw in station:
                message = json.loads(raw)
                if message.get("type") == "command":
                    result = wire.CommandResult(request_id=message["request_id"], ok=True)
                    await station.send(result.model_dump_json())
        except ConnectionClosed:
            pass
        if not stopping:
            dropped += 1

    async def viewer_reader() -> None:
        nonlocal dropped, viewer_telemetry
        try:
            async for raw in viewer:
                if json.loads(raw).get("type") == "telemetry":
                    viewer_telemetry += 1
        except ConnectionClosed:
            pass
        if not stopping:
            dropped += 1

    async def streams() -> None:
        templates = _telemetry_templates(16)
        status = wire.StatusMsg(sent=0.0, device_link="connected", device_mode="ACTIVE")
        k = 0
        with contextlib.suppress(ConnectionClosed):
            while True:
                head, tail = templates[k % len(templates)]
                await station.send(f"{head}{time.time()!r}{tail}")
                if k % 50 == 0:
                    now = time.time()
                    for ws in (station, viewer):
                        await ws.send(wire.Heartbeat(sent=now).model_dump_json())
                    await station.send(status.model_copy(update={"sent": now}).model_dump_json())
                k += 1
                await asyncio.sleep(0.02)

    tasks = [asyncio.create_task(f()) for f in (station_reader, viewer_reader, streams)]
    print("ready", flush=True)
    await asyncio.to_thread(sys.stdin.readline)
    stopping = True
    for t in tasks[2:]:
        t.cancel()
    await asyncio.gather(station.close(), viewer.close(), return_exceptions=True)
    await asyncio.gather(*tasks, return_exceptions=True)
    return {"dropped": dropped, "viewer_telemetry": viewer_telemetry}


def _worker(role: str) -> int:
    config = json.loads(sys.stdin.readline())
    if role == "links":
        result = asyncio.run(_links(config))
    else:
        result = asyncio.run(ATTACKS[config["phase"]](config))
    print(json.dumps(jsonable(result)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(_worker(sys.argv[1]))
