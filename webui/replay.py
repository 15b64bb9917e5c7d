"""The 3D replay of a recorded session, in viser's own recording format.

A replay is the live view's platform scene (:class:`webui.scene.PlatformScene`) driven by
the session's samples at :data:`REPLAY_HZ` on the device clock, captured with viser's scene
serializer (``insert_sleep`` between frames) into a ``.viser`` file. Its time is the charts'
time (``time_s`` of the series): the platform at 12.0 s in the replay is the sample at 12.0 s.

A replay is built once per recording, in a worker thread, by one viser server that only ever
records (it binds to 127.0.0.1 and nobody connects to it), one build at a time. The file is
kept beside the stored recording as ``<recording sha256>.replay<REPLAY_FORMAT>.viser``: the
recording never changes once filed, and a change to the scene or the frame rate bumps
:data:`REPLAY_FORMAT`, so a stale replay is never served.

Routes:

- ``GET /sessions/{id}/replay``: one self-contained HTML page (viser's client with the
  recording inside) that plays offline, e.g. saved and opened from disk.
- ``GET /sessions/{id}/replay.viser``: the recording alone, for the dashboard.
- ``GET /replay/viewer``: viser's client page, holding no session data, which plays the
  recording at ``?playbackPath=<url>``.

The dashboard cannot frame the HTML page from a ``blob:`` URL: a ``blob:`` document inherits
the content security policy of the page that made it, the dashboard's policy forbids inline
scripts, and viser's single-file client is inline scripts. So the session page fetches the
``.viser`` file with the therapist's token, makes a ``blob:`` URL of it, and frames the viewer
(same origin, its own policy) with that URL: no token and no patient data in any URL.
"""

from __future__ import annotations

import asyncio
import base64
import os
import threading
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Annotated

import numpy as np
import viser
from fastapi import APIRouter, FastAPI, Query, Request
from fastapi.responses import FileResponse, PlainTextResponse, RedirectResponse, Response
from numpy.typing import NDArray
from viser.infra import StateSerializer

from server.deps import Db, Id, TherapistOrAdmin
from server.models import Session
from server.routes.common import NOT_FOUND, UNAUTHORIZED
from server.routes.sessions import _session_for, exported, intact_recording, session_time
from sessions.recording import Recording, read
from webui.assets import VIEWER_CSP
from webui.scene import CAMERA_LOOK_AT, CAMERA_POSITION, PlatformScene

REPLAY_HZ = 25.0
"""Frames per second of a replay: smooth enough for ankle motion (under 2 Hz), and each
frame is about seven messages in the file."""
REPLAY_FORMAT = 1
"""Part of the cache file name: bump it when the scene or the sampling changes."""

CLIENT_HTML = Path(viser.__file__).parent / "client" / "build" / "index.html"
"""viser's packaged single-file client: the page ``as_html`` and the viewer are made of."""


def frame_indices(clock: NDArray[np.float64], drawable: NDArray[np.bool_], hz: float) -> list[int]:
    """The sample shown in each frame: the latest drawable one at or before the frame's time
    (frames every ``1/hz`` s of ``clock``, and one at the last drawable sample), each sample
    at most once."""
    usable = np.flatnonzero(drawable)
    if not len(usable):
        return []
    end = float(clock[usable[-1]])
    # The last sample closes the replay even when it falls between two frame times.
    times = np.append(np.arange(0.0, end, 1.0 / hz), end)
    at = np.searchsorted(clock[usable], times, side="right") - 1
    chosen: list[int] = usable[np.unique(at[at >= 0])].tolist()
    return chosen


class Replays:
    """Builds replays with one viser server, one build at a time, and keeps them on disk."""

    def __init__(self, hz: float = REPLAY_HZ) -> None:
        self.hz = hz
        self.builds = 0
        """Replays built by this instance (not served from disk)."""
        self._lock = threading.RLock()
        self._server: viser.ViserServer | None = None

    @staticmethod
    def path_for(source: Path, sha256: str) -> Path:
        return source.with_name(f"{sha256}.replay{REPLAY_FORMAT}.viser")

    def get(self, source: Path, sha256: str) -> Path:
        """The replay file of a stored recording, built on the first call. Blocks for the
        build: call it from a worker thread."""
        path = self.path_for(source, sha256)
        if path.is_file():
            return path
        with self._lock:
            if path.is_file():  # built while this call waited for the lock
                return path
            data = self.build(read(source))
            tmp = path.with_name(path.name + ".part")
            tmp.write_bytes(data)
            os.replace(tmp, path)
        return path

    def build(self, rec: Recording) -> bytes:
        """A ``.viser`` recording of the session's platform motion."""
        with self._lock:
            server = self._server
            if server is None:
                server = self._server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
            # The server is reused: what the last build left in its scene must not be in
            # this recording's initial state.
            server.scene.reset()
            serializer = server.get_scene_serializer()
            try:
                self._record(server, serializer, rec)
            finally:
                # Also ends the recording on failure: the reused server would otherwise
                # keep feeding a dead serializer every later build's messages.
                data = serializer.serialize()
            self.builds += 1
            return data

    def _record(
        self, server: viser.ViserServer, serializer: StateSerializer, rec: Recording
    ) -> None:
        server.gui.configure_theme(show_logo=False, show_share_button=False)
        scene = PlatformScene(server)
        s = rec.samples
        clock = session_time(s["t"])
        drawable = np.isfinite(s["pose"]).all(axis=1) & np.isfinite(s["pose_cmd"]).all(axis=1)
        # An unreadable pressure or force draws as none rather than hiding the frame.
        pressures = np.nan_to_num(s["pressures"], nan=0.0, posinf=0.0, neginf=0.0)
        wrench = np.nan_to_num(s["wrench"], nan=0.0, posinf=0.0, neginf=0.0)
        now = 0.0
        for i in frame_indices(clock, drawable, self.hz):
            serializer.insert_sleep(float(clock[i]) - now)
            now = float(clock[i])
            scene.update(s["pose"][i], s["pose_cmd"][i], pressures[i], wrench[i])

    def close(self) -> None:
        with self._lock:
            if self._server is not None:
                self._server.stop()
                self._server = None


def standalone_html(replay: bytes) -> str:
    """viser's client page with the recording inside: plays without a server.

    The same page ``StateSerializer.as_html`` makes; made here from the stored file so
    that one build serves both the dashboard and this page."""
    page = CLIENT_HTML.read_text()
    data = base64.b64encode(replay).decode("ascii")
    inject = (
        f'<script>window.__VISER_EMBED_DATA__="{data}";'
        "window.__VISER_EMBED_CONFIG__={darkMode:false};</script>"
    )
    head_end = page.index("</head>")
    return page[:head_end] + inject + page[head_end:]


@asynccontextmanager
async def _lifespan(app: FastAPI) -> AsyncIterator[None]:
    replays = Replays()
    app.state.replays = replays
    try:
        yield
    finally:
        await asyncio.to_thread(replays.close)


router = APIRouter(tags=["sessions"], responses=UNAUTHORIZED, lifespan=_lifespan)


async def _replay_file(
    request: Request, db: Db, user: TherapistOrAdmin, session_id: int
) -> tuple[Session, Path]:
    row = await _session_for(db, user, session_id)
    # Checked as every download is, and cached by the SHA-256 of the file it is made from: a
    # damaged recording is a 500, never a replay kept under the intact file's name.
    source, sha256 = await intact_recording(request, row)
    replays: Replays = request.app.state.replays
    return row, await asyncio.to_thread(replays.get, source, sha256)


@router.get(
    "/sessions/{session_id}/replay",
    response_class=Response,
    responses={
        **NOT_FOUND,
        200: {
            "content": {"text/html": {}},
            "description": "A self-contained page that plays the session's platform motion "
            "in 3D, also from a saved file. Built on the first request (seconds).",
        },
    },
    summary="The session's 3D replay as one HTML page",
)
async def replay_page(session_id: Id, request: Request, db: Db, user: TherapistOrAdmin) -> Response:
    """A file to keep: audited as the session leaving the system (``patient.export``,
    format ``replay-html``), as a session's other downloads are, and kept by no cache."""
    row, path = await _replay_file(request, db, user, session_id)
    html = await asyncio.to_thread(lambda: standalone_html(path.read_bytes()))
    await exported(db, user, row, "replay-html")
    return Response(
        html,
        media_type="text/html; charset=utf-8",
        headers={
            "Content-Security-Policy": VIEWER_CSP,
            "Cache-Control": "no-store",
            "Content-Disposition": f'inline; filename="session-{session_id}-replay.html"',
        },
    )


@router.get(
    "/sessions/{session_id}/replay.viser",
    response_class=FileResponse,
    responses={
        **NOT_FOUND,
        200: {
            "content": {"application/octet-stream": {}},
            "description": "The replay in viser's recording format, for viser's client "
            "(``?playbackPath=``). Built on the first request (seconds).",
        },
    },
    summary="The session's 3D replay as a viser recording",
)
async def replay_recording(
    session_id: Id, request: Request, db: Db, user: TherapistOrAdmin
) -> FileResponse:
    """What the session page plays: viewed, not kept, so not audited as an export (as the
    page's charts are not); still kept by no cache on the way."""
    _, path = await _replay_file(request, db, user, session_id)
    return FileResponse(
        path,
        media_type="application/octet-stream",
        filename=f"session-{session_id}.viser",
        headers={"Cache-Control": "no-store"},
    )


def _vector(v: tuple[float, float, float]) -> str:
    return ",".join(f"{x:g}" for x in v)


VIEWER_CAMERA = {
    "initialCameraPosition": _vector(CAMERA_POSITION),
    "initialCameraLookAt": _vector(CAMERA_LOOK_AT),
    "initialCameraUp": "0,0,1",
}
"""viser's client takes the recording's initial camera only when the recording is embedded
in the page; playing from ``playbackPath`` it takes these URL parameters (world frame)."""


@router.get("/replay/viewer", include_in_schema=False)
async def viewer(
    request: Request, playback_path: Annotated[str, Query(alias="playbackPath")] = ""
) -> Response:
    """viser's client, playing the recording at ``?playbackPath=``: a ``blob:`` URL only.

    A browser lets a page read only the ``blob:`` URLs its own origin made, so the viewer
    plays what the dashboard fetched with the therapist's token and nothing a link from
    elsewhere could point it at (the client runs what a recording tells it to)."""
    if not playback_path.startswith("blob:"):
        return PlainTextResponse("playbackPath must be a blob: URL made by the dashboard", 400)
    if not VIEWER_CAMERA.keys() <= request.query_params.keys():
        # The camera is set here, not by the page; a query-only reference keeps whatever
        # path prefix a proxy put in front.
        return RedirectResponse("?" + request.url.include_query_params(**VIEWER_CAMERA).query)
    return FileResponse(
        CLIENT_HTML,
        media_type="text/html",
        headers={"Content-Security-Policy": VIEWER_CSP, "Cache-Control": "no-cache"},
    )
