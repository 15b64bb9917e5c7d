"""The patient's page app with a real home station and the simulated device on a real pty.

No server runs: the station works offline, as it must at a patient's home, and its sessions
stay in the spool, where the tests read them back. The page is served by
``serve_patient_page`` in the test's event loop, as the station's process does, and driven by
a raw WebSocket client that sends what a browser would (or would not).
"""

from __future__ import annotations

import asyncio
import io
import json
import socket
import time
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
import pytest_asyncio
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.typing import Origin

from device.hardware import SimulatedHardware
from device.plant.faults import Fault, FaultKind
from device.plant.model import SCRIPT_SINE
from device.plant.params import PlantConfig
from device.protocol.messages import DeviceMode
from device.service import WATCHDOG_MS_MAX, ServiceConfig
from device.transport import PtyLink
from sessions import wire
from sessions.prescription import PrescriptionBody
from sessions.recording import read
from sessions.summary import summarize
from station.app import Station
from station.config import StationConfig
from tests.device.service_thread import service_in_thread
from webui.home.app import MAX_MESSAGE_BYTES, serve_patient_page
from webui.home.game import game_field

PRESCRIPTION_ID = 41
BODY = PrescriptionBody.model_validate(
    {
        "exercise": "strength",
        "title": "Toes down, toes up",
        "instructions": "Push your toes down, then bring them up. Slowly.",
        "axes": [{"axis": "pitch", "stiffness": 40.0, "damping": 2.0}],
        "sets": 2,
        "repetitions": 2,
        "repetition_s": 3.0,
        "rest_s": 4.0,
    }
)
PATIENT_TORQUE_NM = 4.0
PATIENT_HZ = 0.5


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def plant() -> SimulatedHardware:
    """The simulated platform (a test may inject a fault into it)."""
    return SimulatedHardware(PlantConfig(patient="relaxed"), seed=9)


@pytest.fixture
def device(plant: SimulatedHardware) -> Iterator[PtyLink]:
    """The simulated device in a thread; the patient's foot pushes in pitch, 4 N·m, 0.5 Hz."""
    hardware = plant
    hardware.script_torque(4, SCRIPT_SINE, 0.0, PATIENT_TORQUE_NM, PATIENT_HZ)
    # The longest watchdog the device allows: the test shares its process, and its machine,
    # with the device; a stall there is not what it tests.
    config = ServiceConfig(telemetry_hz=100, watchdog_ms=WATCHDOG_MS_MAX)
    with service_in_thread(hardware, config) as link:
        yield link


@dataclass
class Home:
    station: Station
    port: int
    spool: Path

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    async def page(self, origin: str | None = None, host: str = "127.0.0.1") -> ClientConnection:
        return await connect(
            f"ws://{host}:{self.port}/ws",
            origin=Origin(origin if origin is not None else self.url),
            open_timeout=5.0,
        )


@pytest_asyncio.fixture
async def home(device: PtyLink, tmp_path: Path) -> AsyncIterator[Home]:
    station = Station(
        StationConfig(
            device=device.name,
            server=f"http://127.0.0.1:{free_port()}",  # nobody listens: offline
            token="not-used-offline",
            spool=tmp_path / "spool",
        )
    )
    station.prescriptions = [
        wire.PrescriptionItem(id=PRESCRIPTION_ID, version=1, patient_id=3, body=BODY)
    ]
    port = free_port()
    running = asyncio.create_task(station.run())
    page = asyncio.create_task(serve_patient_page(station, "127.0.0.1", port))
    deadline = time.monotonic() + 10
    while True:
        try:
            _, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.close()
            await writer.wait_closed()
            break
        except OSError:
            assert time.monotonic() < deadline, "the page never listened"
            assert not page.done(), page
            await asyncio.sleep(0.05)
    try:
        yield Home(station, port, tmp_path / "spool")
    finally:
        page.cancel()
        running.cancel()
        _, stuck = await asyncio.wait({page, running}, timeout=20.0)
        assert not stuck, "the station or its page did not stop:\n" + task_stacks()


def task_stacks() -> str:
    out = io.StringIO()
    for task in asyncio.all_tasks():
        print(task, file=out)
        task.print_stack(file=out)
    return out.getvalue()


async def next_msg(ws: ClientConnection, kind: str, timeout: float = 10.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError(f"no {kind} message within {timeout} s")
        message = json.loads(await asyncio.wait_for(ws.recv(), left))
        if message["type"] == kind:
            return dict(message)


async def status_where(ws: ClientConnection, timeout: float = 60.0, **want: Any) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while True:
        status = await next_msg(ws, "status", max(0.01, deadline - time.monotonic()))
        if all(status[k] == v for k, v in want.items()):
            return status


async def drain(ws: ClientConnection) -> None:
    """Read until the server closes the socket."""
    while True:
        await asyncio.wait_for(ws.recv(), 5.0)


async def ask(ws: ClientConnection, action: dict[str, Any]) -> dict[str, Any]:
    await ws.send(json.dumps(action))
    return await next_msg(ws, "result" if "type" in action else "error")


# -- who may use the page ----------------------------------------------------------------------
@pytest.mark.asyncio
async def test_the_page_and_its_files_are_served_to_this_computer_only(home: Home) -> None:
    async with httpx.AsyncClient(base_url=home.url) as client:
        r = await client.get("/")
        assert r.status_code == 200
        assert (await client.head("/")).status_code == 200  # the page's "are you back?"
        assert "script-src 'self'" in r.headers["content-security-policy"]
        assert '<script type="module" src="/static/home.js">' in r.text
        js = await client.get("/static/home.js")
        assert js.status_code == 200 and "javascript" in js.headers["content-type"]
        assert "new WebSocket" in js.text
        game = await client.get("/static/game.js")
        assert game.status_code == 200 and "javascript" in game.headers["content-type"]
        css = await client.get("/static/home.css")
        assert css.status_code == 200 and css.headers["content-type"].startswith("text/css")
        # Only the page's own files: not the dashboard's, not a path outside static/.
        assert (await client.get("/static/api.js")).status_code == 404
        assert (await client.get("/static/js/api.js")).status_code == 404
        assert (await client.get("/static/..%2Fapp.py")).status_code == 404
        assert (await client.get("/static/home.html")).status_code == 404
        # A name that resolves here but is not this computer's: DNS rebinding.
        r = await client.get("/", headers={"Host": f"evil.example:{home.port}"})
        assert r.status_code == 400
        assert (await client.get(f"http://localhost:{home.port}/")).status_code == 200
        # The socket's messages, for any other client: the models are the one source.
        schemas = (await client.get("/schemas")).json()
        ups = schemas["page_to_station"]["discriminator"]["mapping"]
        assert set(ups) == {"start", "pause", "resume", "stop", "game_score"}
        downs = schemas["station_to_page"]["discriminator"]["mapping"]
        assert set(downs) == {"today", "status", "foot", "progress", "result", "error"}


@pytest.mark.asyncio
async def test_another_website_cannot_open_the_socket(home: Home) -> None:
    refused = [
        ("http://evil.example", "127.0.0.1"),  # another site in the patient's browser
        (f"http://evil.example:{home.port}", "127.0.0.1"),
        (f"https://127.0.0.1:{home.port}", "127.0.0.1"),  # not the page's scheme
        (f"http://127.0.0.1:{home.port + 1}", "127.0.0.1"),  # another local port
        (f"http://127.0.0.1:{home.port}", "localhost"),  # origin and host disagree
        ("null", "127.0.0.1"),  # a sandboxed frame or a file:// page
        ("", "127.0.0.1"),  # no Origin at all
    ]
    for origin, host in refused:
        with pytest.raises(InvalidStatus) as refusal:
            await home.page(origin=origin, host=host)
        assert refusal.value.response.status_code == 403, origin
    # Nothing that was refused reached the station.
    assert home.station.status().phase == "idle" and home.station.run_ is None

    ws = await home.page(origin=f"http://localhost:{home.port}", host="localhost")
    try:
        today = await next_msg(ws, "today")
        assert [e["id"] for e in today["exercises"]] == [PRESCRIPTION_ID]
    finally:
        await ws.close()


# -- what the page is told -------------------------------------------------------------------
@pytest.mark.asyncio
async def test_the_page_gets_today_status_every_second_and_the_foot(home: Home) -> None:
    ws = await home.page()
    try:
        today = await next_msg(ws, "today")
        (ex,) = today["exercises"]
        assert ex["title"] == "Toes down, toes up"
        assert ex["instructions"] == BODY.instructions
        assert (ex["sets"], ex["repetitions"], ex["rest_s"]) == (2, 2, 4.0)
        assert ex["minutes"] == 1  # 2·2·3 s + 4 s of rest
        assert ex["game"] == {"pitch": [-10.0, 10.0], "roll": None}

        status = await status_where(ws, device="connected")
        assert status["online"] is False  # no server: the page says "working offline"
        assert status["phase"] == "idle"

        # Nothing changes while idle, and still the status comes at least once a second.
        t0, count = time.monotonic(), 0
        feet: list[float] = []
        while time.monotonic() - t0 < 2.5:
            message = json.loads(await asyncio.wait_for(ws.recv(), 2.0))
            count += message["type"] == "status"
            if message["type"] == "foot":
                feet.append(time.monotonic())
        assert count >= 2
        rate = (len(feet) - 1) / (feet[-1] - feet[0])
        assert 24.0 <= rate <= 36.0, rate
    finally:
        await ws.close()


# -- what the page may ask --------------------------------------------------------------------
@pytest.mark.asyncio
async def test_malformed_messages_are_answered_and_change_nothing(home: Home) -> None:
    ws = await home.page()
    try:
        await status_where(ws, device="connected")
        bad = [
            ("not json", "Invalid JSON"),
            ('{"action": "start"}', "discriminator 'type'"),
            ('{"type": "fly"}', "does not match"),
            ('{"type": "start"}', "start.prescription_id: Field required"),
            ('{"type": "start", "prescription_id": "all"}', "start.prescription_id"),
            ('{"type": "pause", "force": true}', "pause.force: Extra inputs"),
            ('{"type": "stop", "id": ' + json.dumps("x" * 65) + "}", "stop.id"),
            (
                '{"type": "game_score", "session_id": "s", "game": 1, "score": 9, '
                '"gates": 3, "missed": 0}',
                "score + missed must equal gates",
            ),
            (
                '{"type": "game_score", "session_id": "s", "game": 1, "score": -1, '
                '"gates": -1, "missed": 0}',
                "game_score.score",
            ),
            ("[1, 2, 3]", "should be an object"),
        ]
        for text, says in bad:
            await ws.send(text)
            error = await next_msg(ws, "error")
            assert says in error["text"], (text, error)
        await ws.send(b'{"type": "stop"}')
        assert "not binary" in (await next_msg(ws, "error"))["text"]

        # Well formed but not possible now: refused in words, still nothing done.
        refusals: list[tuple[dict[str, Any], str]] = [
            ({"type": "pause"}, "nothing to pause"),
            ({"type": "resume"}, "not paused"),
            ({"type": "start", "prescription_id": 999}, "prescription 999 is not an active"),
        ]
        for action, says in refusals:
            result = await ask(ws, {**action, "id": "r1"})
            assert result["ok"] is False and says in result["text"], result
            assert result["id"] == "r1" and result["action"] == action["type"]
        score = {"session_id": "s", "game": 1, "score": 1, "gates": 1, "missed": 0}
        result = await ask(ws, {"type": "game_score", **score})
        assert result["ok"] is False and "ended" in result["text"]
        assert home.station.note("game_score", score) is False  # and directly: no session

        status = await next_msg(ws, "status")
        assert status["phase"] == "idle" and status["session_id"] is None
        assert status["device_mode"] in ("IDLE", "READY")
        assert not list(home.spool.glob("*.rec"))

        # The socket stayed open through all of it; only an oversized message closes it.
        await ws.send(json.dumps({"type": "stop", "id": "y" * MAX_MESSAGE_BYTES}))
        with pytest.raises(ConnectionClosed) as closed:
            await drain(ws)
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 1009
    finally:
        await ws.close()


@pytest.mark.asyncio
async def test_the_patient_starts_pauses_resumes_plays_and_stops(home: Home) -> None:
    ws = await home.page()
    try:
        await status_where(ws, device="connected")
        result = await ask(ws, {"type": "start", "prescription_id": PRESCRIPTION_ID})
        assert result["ok"], result
        running = await status_where(ws, phase="running", device_mode="ACTIVE")
        session = running["session_id"]
        assert session and running["prescription_id"] == PRESCRIPTION_ID
        assert (running["set"], running["rep"], running["sets"], running["repetitions"]) == (
            1,
            1,
            2,
            2,
        )

        # The foot moves the plane: the simulated patient's push shows in pitch.
        pitches = [(await next_msg(ws, "foot"))["pitch"] for _ in range(45)]
        assert max(pitches) - min(pitches) > 1.0, pitches

        result = await ask(ws, {"type": "pause"})
        assert result["ok"], result
        await status_where(ws, 10.0, phase="paused", device_mode="HOLD")
        result = await ask(ws, {"type": "resume"})
        assert result["ok"], result
        await status_where(ws, 10.0, phase="running", device_mode="ACTIVE")

        score = {"session_id": session, "game": 7, "score": 2, "gates": 3, "missed": 1}
        assert (await ask(ws, {"type": "game_score", **score}))["ok"]
        stale = {**score, "session_id": "an-earlier-session"}
        assert not (await ask(ws, {"type": "game_score", **stale}))["ok"]

        # A rest between the sets, counted down.
        rest = await status_where(ws, 60.0, phase="rest")
        assert (rest["sets_done"], rest["reps_done"]) == (1, 2)
        assert 0.0 < rest["rest_remaining_s"] <= 4.0
        counted = [
            (await status_where(ws, 5.0, phase="rest"))["rest_remaining_s"] for _ in range(8)
        ]
        assert counted == sorted(counted, reverse=True) and counted[-1] < rest["rest_remaining_s"]

        result = await ask(ws, {"type": "stop"})
        assert result["ok"], result
        await status_where(ws, 60.0, phase="stopped", session_id=None)
        # STOP with nothing running still answers: the platform is made to hold still.
        assert (await ask(ws, {"type": "stop"}))["ok"]
    finally:
        await ws.close()

    (path,) = home.spool.glob("*.rec")
    rec = read(path)
    assert rec.header.session_id == session
    assert rec.end is not None and rec.end.reason == "stopped"
    by_patient = [(e.kind, e.by) for e in rec.events if e.by == "patient"]
    assert by_patient == [
        ("hold", "patient"),
        ("resume", "patient"),
        ("game_score", "patient"),
        ("stop", "patient"),
    ]
    (game,) = [e for e in rec.events if e.kind == "game_score"]
    assert game.detail == {"game": 7, "score": 2, "gates": 3, "missed": 1}
    assert game.t is not None  # on the device's clock, next to the samples
    summary = summarize(rec)
    assert summary.game is not None
    assert (summary.game.score, summary.game.gates, summary.game.missed) == (2, 3, 1)


@pytest.mark.asyncio
async def test_a_therapists_command_with_nothing_to_act_on_is_refused_alike(home: Home) -> None:
    """Resume with nothing held was answered "acknowledged by the device" while Stop with
    nothing running was refused; a Start with no prescription was refused as "no active
    prescription 0". Each is refused now, in words, and nothing moves."""
    deadline = time.monotonic() + 30
    while home.station.dev is None or home.station.dev.mode is None:
        assert time.monotonic() < deadline, "the station never reached the device"
        await asyncio.sleep(0.05)
    asked: list[tuple[dict[str, Any], str]] = [
        ({"action": "resume"}, "nothing to resume: no exercise is paused and the platform is"),
        ({"action": "stop"}, "no exercise is running"),
        ({"action": "start"}, "start needs a prescription_id"),
    ]
    for fields, says in asked:
        cmd = wire.Command(request_id="r", by="therapist:1", **fields)
        result = await home.station.command(cmd)
        assert (result.ok, result.code) == (False, "REFUSED"), result
        assert result.text.startswith(says), result
    assert home.station.run_ is None and not list(home.spool.glob("*.rec"))
    assert home.station.dev is not None and home.station.dev.mode != DeviceMode.ACTIVE


@pytest.mark.asyncio
async def test_a_start_the_device_would_refuse_is_refused_and_recorded(home: Home) -> None:
    """A torque limit of 1e-300 N·m reaches the device as float32 0: a prescription stored
    before the server refused it (the server's bound is the device's least, 2 N·m, since)
    must not start (ok false, the device's own sentence) and must leave a session that tells
    the therapist (an early end)."""
    tiny = BODY.model_copy(update={"torque_limit": 1e-300})  # as stored then: not re-checked
    home.station.prescriptions.append(
        wire.PrescriptionItem(id=PRESCRIPTION_ID + 1, version=1, patient_id=3, body=tiny)
    )
    ws = await home.page()
    try:
        await status_where(ws, device="connected")
        result = await ask(ws, {"type": "start", "prescription_id": PRESCRIPTION_ID + 1})
        assert not result["ok"], result
        assert "torque_limit 0 N m is below 2 N m" in result["text"], result
        status = await status_where(ws, 10.0, phase="stopped", session_id=None)
        assert "torque_limit" in status["message"], status
        assert status["device_mode"] != "ACTIVE"
    finally:
        await ws.close()
    (path,) = home.spool.glob("*.rec")
    rec = read(path)
    assert rec.end is not None and rec.end.reason == "stopped"
    assert "torque_limit 0 N m is below" in rec.end.text
    assert [e.kind for e in rec.events] == ["refused"]


@pytest.mark.asyncio
async def test_a_supply_lost_at_rest_is_told_and_forgotten_once_it_is_back(
    home: Home, plant: SimulatedHardware
) -> None:
    """The compressor is off before any exercise: the device flags its low supply, and the
    page's status says so in words the patient can act on, and flags it for the platform's
    light; a start is refused; once the air is back the notice and the flag go."""
    ws = await home.page()
    try:
        status = await status_where(ws, device="connected")
        assert status["supply_low"] is False, status
        plant.inject(Fault(FaultKind.SUPPLY_LOSS, float(plant.state.time[0]), -1))
        deadline = time.monotonic() + 20.0
        while True:
            status = await next_msg(ws, "status")
            # The flag and the notice come from the same telemetry: never one without the other.
            assert status["supply_low"] == ("air supply is low" in status["message"]), status
            if status["supply_low"]:
                break
            assert time.monotonic() < deadline, status
        assert "check that the compressor is on" in status["message"], status
        assert status["device_mode"] in ("IDLE", "READY", "HOLD"), status
        result = await ask(ws, {"type": "start", "prescription_id": PRESCRIPTION_ID})
        assert not result["ok"] and "air supply is low" in result["text"], result
        (path,) = home.spool.glob("*.rec")  # the therapist sees the attempt, as an early end
        rec = read(path)
        assert rec.end is not None and "air supply is low" in rec.end.text
        plant.clear_faults()
        deadline = time.monotonic() + 20.0
        while True:
            status = await next_msg(ws, "status")
            assert status["supply_low"] == ("air supply is low" in status["message"]), status
            if not status["supply_low"]:
                break
            assert time.monotonic() < deadline, status
    finally:
        await ws.close()


@pytest.mark.asyncio
async def test_a_live_change_that_changes_nothing_is_refused(home: Home) -> None:
    """Roll is not part of the pitch exercise, and an empty change asks for nothing: both are
    refused with a sentence, and the session records no impedance change."""
    ws = await home.page()
    try:
        await status_where(ws, device="connected")
        result = await ask(ws, {"type": "start", "prescription_id": PRESCRIPTION_ID})
        assert result["ok"], result
        await status_where(ws, phase="running", device_mode="ACTIVE")
        asks = {
            "roll": ({"roll": 500.0}, {"roll": 50.0}, "roll is not part of this exercise"),
            "empty": ({}, {}, "nothing to change"),
        }
        for rid, (k, b, said) in asks.items():
            cmd = wire.Command.model_validate(
                {"request_id": rid, "action": "set_impedance", "stiffness": k, "damping": b}
            )
            answer = await home.station.command(cmd)
            assert not answer.ok and answer.code == "REFUSED", answer
            assert said in answer.text and answer.change is None, answer
        # -0.0 is 0.0 on the way in.
        zero = wire.Command.model_validate_json(
            '{"request_id": "z", "action": "set_impedance", "stiffness": {"pitch": -0.0}}'
        )
        assert str(zero.stiffness) == "{'pitch': 0.0}"
        assert (await ask(ws, {"type": "stop"}))["ok"]
        await status_where(ws, 60.0, phase="stopped", session_id=None)
    finally:
        await ws.close()
    (path,) = home.spool.glob("*.rec")
    assert not [e for e in read(path).events if e.kind == "impedance"]


# -- serving ---------------------------------------------------------------------------------
@pytest.mark.asyncio
async def test_a_port_that_is_taken_is_an_error_for_the_caller(home: Home) -> None:
    with pytest.raises(OSError, match="already in use"):
        await serve_patient_page(home.station, "127.0.0.1", home.port)
    async with httpx.AsyncClient() as client:
        assert (await client.get(home.url)).status_code == 200  # the first page is unharmed


# -- the game's field ------------------------------------------------------------------------
def body(**axis: Any) -> PrescriptionBody:
    return PrescriptionBody.model_validate(
        {
            "exercise": axis.pop("exercise", "strength"),
            "axes": [{"stiffness": 20.0, "damping": 1.5, **axis}],  # inside every axis's envelope
        }
    )


def test_the_game_keeps_inside_the_prescribed_range() -> None:
    explicit = game_field(body(axis="pitch", rom_low=-5.0, rom_high=15.0))
    assert explicit is not None and explicit.pitch == (-3.0, 13.0)  # 80 % about the middle
    assert explicit.roll is None
    default = game_field(body(axis="roll"))
    assert default is not None and default.roll == (-8.0, 8.0) and default.pitch is None
    # A platform that sweeps the foot 14 degrees needs a field that wide.
    sine = game_field(
        body(
            exercise="flexibility",
            axis="pitch",
            waveform="sine",
            amplitude=14.0,
            frequency=0.1,
        )
    )
    assert sine is not None and sine.pitch == (-14.0, 14.0)
    # A narrow prescribed range wins over the default span.
    narrow = game_field(body(axis="pitch", rom_low=-4.0, rom_high=4.0))
    assert narrow is not None and narrow.pitch == (-3.2, 3.2)


def test_no_game_where_the_platform_does_not_yield_or_no_ankle_tilt_is_exercised() -> None:
    assert game_field(body(exercise="isometric", axis="pitch")) is None
    assert game_field(body(exercise="passive_rom", axis="pitch")) is None
    assert game_field(body(axis="yaw")) is None
