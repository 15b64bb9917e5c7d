"""The patient's page, served by the home station on this computer (``http://127.0.0.1:8765/``).

One page (``static/``: its HTML, script, game and style sheet) and one WebSocket, ``/ws``,
whose messages are in :mod:`webui.home.messages`; who may connect is :mod:`webui.home.hosts`.

webui is the top layer but the dependency rules keep it from importing ``station``: the page
needs only :class:`PatientStation`, which ``station.app.Station`` provides, and is served in
the station's own event loop by :func:`serve_patient_page`.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import math
import socket
import time
from collections.abc import Collection, Iterator
from pathlib import Path
from typing import Any, Protocol

import uvicorn
from fastapi import Depends, FastAPI, HTTPException, Request, WebSocket, WebSocketDisconnect
from fastapi.responses import FileResponse
from pydantic import BaseModel, ValidationError

from sessions import wire
from sessions.home_progress import HomeProgress
from sessions.prescription import EXERCISE_LIBRARY
from sessions.summary import GAME_EVENT
from webui.assets import CSP
from webui.home.game import game_field
from webui.home.hosts import LOOPBACK, WILDCARD, allowed_hosts, host_ok, origin_ok
from webui.home.messages import (
    PAGE_ACTION,
    ActionResult,
    Exercise,
    Foot,
    GameScore,
    PageError,
    PageStatus,
    Pause,
    Resume,
    Start,
    Stop,
    Today,
    YourProgress,
    page_schemas,
)
from webui.home.progress import progress_lines

STATIC = Path(__file__).resolve().parent / "static"
PAGE = "home.html"
"""The page itself, served at ``/`` only."""
FILES = {
    "home.js": "text/javascript",
    "game.js": "text/javascript",
    "home.css": "text/css",
}
"""What the page loads from ``/static/``, by name, and its type: nothing else in the folder
is served there."""

log = logging.getLogger("ankle.station.page")

FOOT_HZ = 30.0
"""Rate of :class:`Foot` messages: smooth enough for the game, light for the station's loop
(which also feeds the device's watchdog)."""
STATUS_EVERY_S = 1.0
MAX_MESSAGE_BYTES = 4096
"""Largest message the page may send; a longer one closes the socket (1009)."""


class PatientStation(Protocol):
    """What the page needs of the home station (``station.app.Station`` has it)."""

    @property
    def prescriptions(self) -> list[wire.PrescriptionItem]: ...

    @property
    def online(self) -> bool: ...

    @property
    def supply_low(self) -> bool: ...

    def status(self) -> wire.StatusMsg: ...

    async def command(self, cmd: wire.Command) -> wire.CommandResult: ...

    def note(self, kind: str, detail: dict[str, Any], by: str = "patient") -> bool: ...

    def foot(self) -> tuple[float, ...] | None: ...

    def progress(self) -> tuple[int, int]: ...

    @property
    def starts_again_at(self) -> float | None: ...

    @property
    def ended_link_lost(self) -> bool: ...

    @property
    def home_progress(self) -> HomeProgress | None: ...


# -- what the page shows -----------------------------------------------------------------------
def today(items: list[wire.PrescriptionItem]) -> Today:
    exercises = []
    for item in items:
        b = item.body
        template = EXERCISE_LIBRARY[b.exercise]
        exercises.append(
            Exercise(
                id=item.id,
                title=b.title or template.name,
                instructions=b.instructions or template.defaults.instructions,
                exercise=b.exercise.value,
                sets=b.sets,
                repetitions=b.repetitions,
                repetition_s=b.repetition_s,
                rest_s=b.rest_s,
                minutes=max(1, math.ceil(b.total_s() / 60)),
                game=game_field(b),
            )
        )
    return Today(exercises=exercises)


def page_status(station: PatientStation) -> PageStatus:
    s = station.status()
    sets_done, reps_done = station.progress()
    return PageStatus(
        online=station.online,
        pending_uploads=s.pending_uploads,
        refused_uploads=s.refused_uploads,
        device=s.device_link,
        device_mode=s.device_mode,
        phase=s.phase,
        session_id=s.session_id,
        prescription_id=s.prescription_id,
        set=s.set,
        rep=s.rep,
        sets=s.sets,
        repetitions=s.repetitions,
        sets_done=sets_done,
        reps_done=reps_done,
        rest_remaining_s=s.rest_remaining_s,
        message=s.message,
        link_lost=s.phase == "interrupted" and station.ended_link_lost,
        starts_again_at=station.starts_again_at,
        hold=s.hold,
        supply_low=station.supply_low,
    )


# -- the app -----------------------------------------------------------------------------------
def create_patient_app(station: PatientStation, hosts: Collection[str] = LOOPBACK) -> FastAPI:
    """The page, its two files and its WebSocket, for one station."""
    app = FastAPI(
        title="Ankle telerehabilitation: patient's page",
        docs_url=None,
        redoc_url=None,
        openapi_url=None,
    )

    def local(request: Request) -> None:
        if not host_ok(request.headers.get("host"), hosts):
            raise HTTPException(400, "this page is only served to this computer")

    # HEAD too: the page asks it whether the station is back before reopening its socket.
    @app.api_route(
        "/", methods=["GET", "HEAD"], dependencies=[Depends(local)], include_in_schema=False
    )
    async def index() -> FileResponse:
        return _file(PAGE, "text/html")

    @app.get("/static/{name}", dependencies=[Depends(local)], include_in_schema=False)
    async def static(name: str) -> FileResponse:
        if name not in FILES:
            raise HTTPException(404, "no such file")
        return _file(name, FILES[name])

    @app.get("/schemas", dependencies=[Depends(local)], include_in_schema=False)
    async def schemas() -> dict[str, Any]:
        return page_schemas()

    @app.websocket("/ws")
    async def ws(websocket: WebSocket) -> None:
        if not origin_ok(websocket.headers.get("origin"), websocket.headers.get("host"), hosts):
            log.warning(
                "refused a connection to the patient's page from origin %r (host %r)",
                websocket.headers.get("origin"),
                websocket.headers.get("host"),
            )
            await websocket.close(code=wire.CLOSE_POLICY)  # before accept: HTTP 403
            return
        await websocket.accept()
        await PageLink(station, websocket).run()

    return app


def _file(name: str, media_type: str) -> FileResponse:
    return FileResponse(
        STATIC / name,
        media_type=media_type,
        headers={"Cache-Control": "no-cache", "Content-Security-Policy": CSP},
    )


class PageLink:
    """One open page: pushes state, carries out the patient's actions."""

    _ids = itertools.count(1)

    def __init__(self, station: PatientStation, websocket: WebSocket) -> None:
        self.station = station
        self.ws = websocket
        self._send_lock = asyncio.Lock()

    async def send(self, message: BaseModel) -> None:
        async with self._send_lock:  # the pusher and the replies share one socket
            await self.ws.send_text(message.model_dump_json())

    async def run(self) -> None:
        pusher = asyncio.create_task(self._push(), name="patient-page-push")
        pusher.add_done_callback(_push_ended)
        try:
            while True:
                message = await self.ws.receive()
                if message["type"] == "websocket.disconnect":
                    return
                text = message.get("text")
                if text is None:
                    await self.send(PageError(text="send JSON text, not binary data"))
                    continue
                await self.send(await self.handle(text))
        finally:
            pusher.cancel()
            await asyncio.gather(pusher, return_exceptions=True)

    async def handle(self, text: str) -> BaseModel:
        try:
            action = PAGE_ACTION.validate_json(text)
        except ValidationError as exc:
            return PageError(text=f"not understood: {wire.error_text(exc, 200)}")
        ok, why = await self._carry_out(action)
        return ActionResult(id=action.id, action=action.type, ok=ok, text=why)

    async def _carry_out(
        self, action: Start | Pause | Resume | Stop | GameScore
    ) -> tuple[bool, str]:
        st = self.station
        now = st.status()
        phase = now.phase
        if isinstance(action, GameScore):
            if now.session_id != action.session_id:
                return False, "that exercise has ended; the score was not saved"
            detail = action.model_dump(include={"game", "score", "gates", "missed"})
            if not st.note(GAME_EVENT, detail):
                return False, "no exercise is running; the score was not saved"
            return True, ""
        if isinstance(action, Start):
            return await self._command("start", prescription_id=action.prescription_id)
        if isinstance(action, Pause):
            if phase not in ("running", "rest"):
                return False, "there is nothing to pause right now"
            return await self._command("hold")
        if isinstance(action, Resume):
            if phase != "paused":
                return False, "the exercise is not paused"
            return await self._command("resume")
        ok, why = await self._command("stop")
        if not ok and phase not in ("homing", "running", "rest", "paused"):
            # Nothing was running; still make sure the platform is holding still.
            return await self._command("hold")
        return ok, why

    async def _command(
        self, action: wire.Action, prescription_id: int | None = None
    ) -> tuple[bool, str]:
        result = await self.station.command(
            wire.Command(
                request_id=f"page-{next(self._ids)}",
                action=action,
                prescription_id=prescription_id,
                by="patient",
            )
        )
        return result.ok, "" if result.ok else result.text or result.code

    async def _push(self) -> None:
        last_items: list[wire.PrescriptionItem] | None = None
        last_progress: HomeProgress | None = None
        last_status: dict[str, Any] | None = None
        status_at = 0.0
        period = 1.0 / FOOT_HZ
        loop = asyncio.get_running_loop()
        next_tick = loop.time()
        while True:
            items = self.station.prescriptions
            if items is not last_items:  # the station replaces the list when it changes
                await self.send(today(items))
                last_items = items
            mine = self.station.home_progress
            if mine is not last_progress and mine is not None:  # a new one replaces the last
                await self.send(YourProgress(lines=progress_lines(mine)))
            last_progress = mine
            status = page_status(self.station)
            state = status.model_dump()
            now = time.monotonic()
            if state != last_status or now - status_at >= STATUS_EVERY_S:
                await self.send(status)
                last_status, status_at = state, now
            pose = self.station.foot()
            if pose is not None:
                await self.send(
                    Foot(
                        pitch=round(math.degrees(pose[4]), 2), roll=round(math.degrees(pose[3]), 2)
                    )
                )
            next_tick = max(next_tick + period, loop.time())
            await asyncio.sleep(next_tick - loop.time())


def _push_ended(task: asyncio.Task[None]) -> None:
    # A closed socket ends the pusher with one of these; anything else is a fault in the
    # page's code that leaves the patient looking at a page that no longer changes.
    if task.cancelled():
        return
    exc = task.exception()
    if exc is not None and not isinstance(exc, WebSocketDisconnect | RuntimeError):
        log.error("the patient's page stopped updating", exc_info=exc)


# -- serving -----------------------------------------------------------------------------------
class _Server(uvicorn.Server):
    """uvicorn in the station's loop: the station owns the signals (Ctrl-C stops the exercise
    first, then the page), so uvicorn must not take them over."""

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        yield


async def serve_patient_page(
    station: PatientStation, host: str = "127.0.0.1", port: int = 8765
) -> None:
    """Serve the page for ``station`` on (host, port) in the running loop until cancelled.

    The socket is bound here, so a port that is taken raises ``OSError`` to the caller
    (uvicorn itself would exit the whole process)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host.strip("[]"), port))
    except OSError:
        sock.close()
        raise
    bound = sock.getsockname()[1]
    config = uvicorn.Config(
        create_patient_app(station, allowed_hosts(host)),
        log_level="warning",
        lifespan="off",
        ws_max_size=MAX_MESSAGE_BYTES,
        ws_per_message_deflate=False,
        proxy_headers=False,
        server_header=False,
        timeout_graceful_shutdown=2,
    )
    server = _Server(config)
    shown = "localhost" if host in WILDCARD else host.strip("[]")
    shown = f"[{shown}]" if ":" in shown else shown
    log.info("the patient's page: http://%s:%d/", shown, bound)
    task = asyncio.ensure_future(server.serve(sockets=[sock]))
    try:
        await asyncio.shield(task)
    except asyncio.CancelledError:
        # Close the open pages and the socket before going: a cancelled serve() leaves both.
        server.should_exit = True
        await task
        raise
    finally:
        sock.close()
