"""The patient's own progress, kept from the server for their page (``GET
/api/v1/station/progress``): asked when the station connects, after each upload, and every few
minutes. Without a server the page shows the last one it had, or none."""

from __future__ import annotations

import asyncio
import contextlib
import logging

import httpx
from pydantic import ValidationError

from sessions.home_progress import HomeProgress

log = logging.getLogger("ankle.station.progress")
REFRESH_S = 300.0
"""Asked again this often even when nothing was uploaded (the week moves on)."""


class ProgressWatch:
    def __init__(self, client: httpx.AsyncClient, connected: asyncio.Event) -> None:
        self._client = client
        self._connected = connected
        self._wake = asyncio.Event()
        self.latest: HomeProgress | None = None

    def wake(self) -> None:
        self._wake.set()

    async def run(self, refresh_s: float = REFRESH_S) -> None:
        while True:
            await self._connected.wait()
            self._wake.clear()
            await self.ask()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(refresh_s):
                    await self._wake.wait()

    async def ask(self) -> None:
        try:
            r = await self._client.get("/api/v1/station/progress")
            r.raise_for_status()
            self.latest = HomeProgress.model_validate_json(r.content)
        except (httpx.HTTPError, OSError, ValidationError) as exc:
            log.warning("cannot get the patient's progress: %s", exc)
