"""Resumable, idempotent upload of recorded sessions to the server.

The protocol (served by ``server/routes/uploads.py``), keyed by the session's UUID:
- ``HEAD /api/v1/uploads/{id}``: how many bytes the server holds (``Upload-Offset``) and
  whether the session is already complete (``Upload-Complete: 1``).
- ``PATCH /api/v1/uploads/{id}`` with ``Upload-Offset: n``: append bytes at ``n``; the server
  writes them to disk before answering, so an answered chunk is never asked for again. A
  wrong offset gets 409 with the server's offset, and the upload continues from there.
- ``POST /api/v1/uploads/{id}/complete`` with the size and SHA-256 of the whole file: the
  server checks both and the recording itself, then files the session. Repeating it returns
  the same session, so a station killed between the answer and deleting its copy uploads
  nothing twice.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx

from station.backoff import Backoff
from station.spool import Spool

log = logging.getLogger("ankle.station.upload")
CHUNK = 1 << 20
"""Bytes per PATCH: small enough to resend cheaply on a poor home connection."""


RETRY_FIRST_S = 2.0
RETRY_MAX_S = 60.0
"""Retries of a failed upload wait a jittered 0..2 s, 0..4 s, … up to 60 s (station/backoff.py)."""


class UploadError(Exception):
    """The server refused an upload for a reason retrying will not fix."""


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()


class Uploader:
    def __init__(
        self, server: str, token: str, spool: Spool, client: httpx.AsyncClient | None = None
    ) -> None:
        self.spool = spool
        self._client = client or httpx.AsyncClient(
            base_url=server, headers={"Authorization": f"Bearer {token}"}, timeout=30.0
        )
        self.uploaded: list[str] = []
        self.last_error = ""
        self._wake = asyncio.Event()
        self._skip: set[Path] = set()
        self.on_uploaded: Callable[[], None] = lambda: None
        """Called after each session the server has taken whole."""

    @property
    def client(self) -> httpx.AsyncClient:
        """The station's HTTP client to the server, with its token."""
        return self._client

    def skip(self, path: Path | None) -> None:
        """Do not upload this file yet (the session being recorded)."""
        self._skip = {path} if path else set()

    def wake(self) -> None:
        self._wake.set()

    def pending(self) -> int:
        return sum(1 for p in self.spool.pending() if p not in self._skip)

    async def upload(self, path: Path) -> dict[str, Any]:
        """Upload one finished session file; returns the server's session record."""
        session_id = path.stem
        url = f"/api/v1/uploads/{session_id}"
        size = path.stat().st_size
        head = await self._client.head(url)
        if head.status_code not in (200, 404):
            raise _error(head)
        offset = int(head.headers.get("Upload-Offset", "0")) if head.status_code == 200 else 0
        if head.headers.get("Upload-Complete") != "1":
            with path.open("rb") as f:
                while offset < size:
                    f.seek(offset)
                    chunk = f.read(CHUNK)
                    r = await self._client.patch(
                        url,
                        content=chunk,
                        headers={
                            "Upload-Offset": str(offset),
                            "Content-Type": "application/offset+octet-stream",
                        },
                    )
                    if r.status_code == 409 and "Upload-Offset" in r.headers:
                        offset = int(r.headers["Upload-Offset"])
                        continue
                    if r.status_code >= 300:
                        raise _error(r)
                    offset = int(r.headers["Upload-Offset"])
        done = await self._client.post(
            f"{url}/complete", json={"size": size, "sha256": sha256_file(path)}
        )
        if done.status_code >= 300:
            raise _error(done)
        return dict(done.json())

    async def upload_all(self) -> int:
        """Upload every finished session; delete each local copy once confirmed."""
        count = 0
        for path in self.spool.pending():
            if path in self._skip:
                continue
            try:
                await self.upload(path)
            except UploadError as exc:
                self.last_error = str(exc)
                log.error("upload of %s refused: %s", path.name, exc)
                continue
            path.unlink()
            self.uploaded.append(path.stem)
            self.on_uploaded()
            count += 1
        return count

    async def run(self, period: float = 5.0) -> None:
        """Keep uploading: at start, when woken (a session ended) and every ``period``."""
        backoff = Backoff(RETRY_FIRST_S, RETRY_MAX_S)
        while True:
            try:
                await self.upload_all()
                self.last_error = ""
                backoff.reset()
                wait = period
            except (httpx.HTTPError, OSError) as exc:
                self.last_error = f"server unreachable ({type(exc).__name__})"
                wait = backoff.next()
                log.info("upload failed: %s; retrying in %.2f s", self.last_error, wait)
            self._wake.clear()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(wait):  # not wait_for: see ServerLink
                    await self._wake.wait()

    async def aclose(self) -> None:
        await self._client.aclose()


def _error(r: httpx.Response) -> Exception:
    try:
        detail = r.json().get("detail", r.text)
    except ValueError:
        detail = r.text
    text = f"{r.request.method} {r.request.url.path}: {r.status_code} {detail}"
    if r.status_code >= 500 or r.status_code == 429:
        return httpx.HTTPStatusError(text, request=r.request, response=r)
    return UploadError(text)
