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

What the server answers decides what the station does next. A refusal that sending the same
bytes again cannot change (400, 413, 422, another 4xx: the file is not a valid recording, too
large…) sets the file aside in the spool's ``refused/`` folder, logged once and reported in
the station's status (``refused_uploads``), and it is sent no more. Anything that may pass
(the server or the network down, 5xx, 429, 408, a 401 or 403 until the station's token is
put right, a 404 or 409 when the server lost what it held) is tried again after a jittered
wait that doubles up to a minute.
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


RETRYABLE = frozenset({401, 403, 404, 408, 409, 429})
"""4xx answers that may change: a token put right, a server that lost an upload's bytes
(404, or 409 with its offset), a session filed meanwhile (409 to a PATCH), or a busy server.
Every other 4xx refuses the file itself, and so does a 409 to the complete step without an
offset (this session id was filed with other content); every 5xx is the server's and
passes."""


class UploadError(Exception):
    """The server refused an upload for a reason retrying will not fix."""


class UploadRetry(Exception):
    """The server did not take the upload now; the same bytes may pass later."""


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
        self.refused: dict[str, str] = spool.refused()
        """Sessions the server refused for good, set aside in the spool: id to reason."""
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
        self.refused = self.spool.refused()  # one moved back by hand is sent again
        count = 0
        for path in self.spool.pending():
            if path in self._skip:
                continue
            try:
                await self.upload(path)
            except UploadError as exc:
                kept = self.spool.refuse(path, str(exc))
                self.refused[path.stem] = str(exc)
                log.error(
                    "session %s refused by the server, kept in %s and not sent again: %s",
                    path.name,
                    kept.parent,
                    exc,
                )
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
            except (httpx.HTTPError, OSError, UploadRetry) as exc:
                if isinstance(exc, UploadRetry):
                    self.last_error = str(exc)
                else:
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
    filed_otherwise = r.status_code == 409 and r.request.method == "POST"
    if filed_otherwise and "Upload-Offset" not in r.headers:
        return UploadError(text)  # this session id was filed with other content
    if r.status_code >= 500 or r.status_code in RETRYABLE or r.status_code < 400:
        return UploadRetry(text)
    return UploadError(text)
