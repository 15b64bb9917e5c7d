"""One viser server per watched station: the live 3D view the dashboard embeds.

viser is not ASGI, so it cannot be mounted in the FastAPI app: each view is its own
``ViserServer`` on a free port of the loopback interface (:data:`VIEW_HOST`), which no other
machine reaches. Browsers see it only through the API's port, behind a ticket
(:mod:`webui.sceneproxy`). A view is fed from the hub's newest telemetry sample at
``SCENE_HZ`` (the station sends 100 samples a second; each scene update costs about
0.25 ms) and is stopped once no therapist has watched the station for ``IDLE_S``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass, field

import viser

from server.hub import Hub
from webui.scene import PlatformScene

log = logging.getLogger("ankle.webui.live3d")

SCENE_HZ = 30.0
"""Scene updates per second: within viser's 30–60 Hz sweet spot."""
IDLE_S = 30.0
"""A view nobody has watched (no live WebSocket, no 3D client, no scene request) for this
long stops."""
VIEW_HOST = "127.0.0.1"
"""viser listens here only, whatever interface the API serves: viser checks no token."""


@dataclass(eq=False)
class LiveView:
    station_id: int
    server: viser.ViserServer
    scene: PlatformScene
    touched: float = field(default_factory=time.monotonic)
    seq: int = -1
    task: asyncio.Task[None] | None = None
    clients: int = 0
    """3D clients connected through the proxy: each keeps the view running."""

    @property
    def port(self) -> int:
        return int(self.server.get_port())


class LiveScenes:
    """The live 3D views of one server process."""

    def __init__(self, hub: Hub, hz: float = SCENE_HZ, idle_s: float = IDLE_S) -> None:
        self.hub = hub
        self.period = 1.0 / hz
        self.idle_s = idle_s
        self.views: dict[int, LiveView] = {}
        self._lock = asyncio.Lock()

    async def open(self, station_id: int) -> LiveView:
        """The station's view, started if it is not running; each call keeps it alive."""
        async with self._lock:
            view = self.views.get(station_id)
            if view is None:
                await self.hub.watch(station_id)  # its telemetry, wherever the station is
                try:
                    view = await asyncio.to_thread(self._start, station_id)
                except BaseException:
                    await self.hub.unwatch(station_id)
                    raise
                view.task = asyncio.create_task(self._feed(view), name=f"scene-{station_id}")
                self.views[station_id] = view
                log.info("3D view of station %d on port %d", station_id, view.port)
            view.touched = time.monotonic()
            return view

    @contextlib.asynccontextmanager
    async def client(self, station_id: int) -> AsyncIterator[LiveView]:
        """The station's view, kept running while a 3D client is connected to it."""
        view = await self.open(station_id)
        view.clients += 1
        try:
            yield view
        finally:
            view.clients -= 1
            view.touched = time.monotonic()

    def _start(self, station_id: int) -> LiveView:
        server = viser.ViserServer(host=VIEW_HOST, port=0, verbose=False)
        server.gui.configure_theme(show_logo=False, show_share_button=False)
        server.gui.main_panel.minimize()  # the scene, not viser's controls, fills the frame
        # viser shows its own server controls (the WebSocket address, Save Canvas, Dev
        # Settings, the scene tree) in its panel whenever the application put no GUI there,
        # and on a phone the panel is a bottom sheet that opens over the scene and ignores
        # minimize(). One element of ours, never shown, folds them behind viser's settings
        # icon: the sheet is its handle alone.
        server.gui.add_markdown("", visible=False)
        return LiveView(station_id, server, PlatformScene(server))

    async def _feed(self, view: LiveView) -> None:
        try:
            while True:
                await asyncio.sleep(self.period)
                newest = self.hub.newest(view.station_id, seen=view.seq)
                if newest is not None:
                    view.seq, t = newest
                    view.scene.update(t.pose, t.pose_cmd, t.pressures, t.wrench)
                if view.clients or self.hub.viewers.get(view.station_id):
                    view.touched = time.monotonic()
                elif time.monotonic() - view.touched > self.idle_s:
                    break
        finally:
            if self.views.get(view.station_id) is view:
                del self.views[view.station_id]
            await self.hub.unwatch(view.station_id)
            await asyncio.to_thread(view.server.stop)
            log.info("3D view of station %d stopped", view.station_id)

    async def close(self) -> None:
        for view in list(self.views.values()):
            if view.task is not None:
                view.task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await view.task
