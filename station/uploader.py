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

What the server answers decides what the station does next, by one table (:data:`ANSWERS`,
then the status): a refusal that sending the same bytes again cannot change (400, 413, 422,
another 4xx: the file is not a valid recording, too large…) sets the file aside in the spool's
``refused/`` folder, logged once and reported in the station's status (``refused_uploads``),
and it is sent no more. A server whose copy of the bytes did not match the station's file at
``complete`` (a checksum mismatch: a fault of the network or of the server's storage, not of
the recording) has discarded its copy: the same file is sent again from its start, up to
:data:`RESENDS` times after jittered waits, then kept pending for :data:`RESEND_PAUSE_S` and
said so; it is never refused for that. Anything else that may pass (the server or the network
down, 5xx, 429, 408, a 401 or 403 until the station's token is put right, a 404 or 409 when
the server lost what it held) is tried again after a jittered wait that doubles up to a
minute. A session file the station cannot read itself is named as such, not as the server's.
"""

from __future__ import annotations

import asyncio
import contextlib
import enum
import hashlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
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
RESENDS = 3
"""New uploads of the same file after the server's copy did not match it, each after a
jittered wait (:data:`RETRY_FIRST_S` doubling): a fault of the server's storage or of the
network that repeats past this is not cured by sending again at once."""
RESEND_PAUSE_S = 600.0
"""How long a file whose copies kept not matching waits, kept in the spool, before it is sent
again (the station's next start sends it at once)."""


class Next(enum.Enum):
    """What the station does with a session file after the server's answer."""

    RETRY = "retry"
    """The same bytes may pass later: sent again after a jittered wait."""
    RESEND = "resend"
    """The server discarded its copy (not the station's bytes): a new upload of the file."""
    REFUSE = "refuse"
    """The file itself is refused: set aside in ``refused/``, sent no more."""


@dataclass(frozen=True)
class Answer:
    """One row of :data:`ANSWERS`: an answer that matches every field given is ``next``."""

    next: Next
    status: int | None = None
    method: str | None = None
    code: str | None = None
    """The answer's ``code`` field, for programs (servers that send one)."""
    text: str | None = None
    """How the answer's ``detail`` begins (servers that send no ``code``)."""
    offset: bool | None = None
    """Whether the answer carries ``Upload-Offset``."""

    def matches(self, status: int, method: str, code: str, detail: str, offset: bool) -> bool:
        return (
            (self.status is None or self.status == status)
            and (self.method is None or self.method == method)
            and (self.code is None or self.code == code)
            and (self.text is None or detail.startswith(self.text))
            and (self.offset is None or self.offset == offset)
        )


ANSWERS: tuple[Answer, ...] = (
    # The server's bytes were not the station's file (or were gone): it discarded them.
    Answer(Next.RESEND, code="upload_corrupted"),
    # The same, from a server that answers it 422 without a code.
    Answer(Next.RESEND, status=422, method="POST", text="checksum mismatch"),
    # A 409 to complete without an offset: this session id was filed with other content.
    Answer(Next.REFUSE, status=409, method="POST", offset=False),
)
"""Answers whose status alone does not say what to do, first match wins; any other answer
is decided by its status (:func:`classify`). A new answer of the server is one row here."""


class UploadError(Exception):
    """The server refused an upload for a reason retrying will not fix."""


class UploadRetry(Exception):
    """The server did not take the upload now; the same bytes may pass later."""


class UploadResend(UploadRetry):
    """The server discarded its copy of the file: a new upload of the same file may pass."""


class SpoolFileError(Exception):
    """A session file in the spool cannot be read by the station itself."""


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
        self.kept_back: dict[str, str] = {}
        """Sessions whose copies on the server kept not matching the file: id to why, while
        they wait (:data:`RESEND_PAUSE_S`) in the spool."""
        self._resends: dict[str, int] = {}
        self._back_until: dict[str, float] = {}
        self._wake = asyncio.Event()
        self._skip: set[Path] = set()
        self._held: set[Path] = set()
        self.on_uploaded: Callable[[], None] = lambda: None
        """Called after each session the server has taken whole."""

    @property
    def client(self) -> httpx.AsyncClient:
        """The station's HTTP client to the server, with its token."""
        return self._client

    def skip(self, path: Path | None) -> None:
        """Do not upload this file yet (the session being recorded)."""
        self._skip = ({path} if path else set()) | self._held

    def hold(self, path: Path) -> None:
        """Do not upload this file while the station runs: a session whose end record could
        not be written (its disk full), closed from what it holds at the next start. Sent
        now, it was refused as cut off."""
        self._held.add(path)
        self._skip.add(path)

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
            if path in self._skip or self._kept_back(path.stem):
                continue
            try:
                await self.upload(path)
            except UploadResend as exc:
                if self._resend(path.stem, str(exc)):
                    raise
                continue
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
            except OSError as exc:
                if not path.exists():
                    continue  # gone meanwhile (moved aside by hand): nothing to send
                raise SpoolFileError(
                    f"cannot read the session file {path}: {exc.strerror or exc}; it stays "
                    "in the spool and is tried again"
                ) from exc
            self._resends.pop(path.stem, None)
            path.unlink()
            self.uploaded.append(path.stem)
            self.on_uploaded()
            count += 1
        return count

    def _resend(self, session_id: str, why: str) -> bool:
        """The server discarded its copy of this session; whether to send it again after
        the retry wait (True), or to keep it back for :data:`RESEND_PAUSE_S` (False)."""
        n = self._resends.get(session_id, 0) + 1
        if n <= RESENDS:
            self._resends[session_id] = n
            log.warning(
                "session %s: the server's copy did not match this station's file (%s); "
                "sending the file again from its start (%d of %d)",
                session_id,
                why,
                n,
                RESENDS,
            )
            return True
        self._resends.pop(session_id, None)
        self._back_until[session_id] = time.monotonic() + RESEND_PAUSE_S
        said = (
            f"the server's copy of session {session_id} did not match this station's file "
            f"{RESENDS + 1} times in a row (the network or the server's storage is at fault, "
            f"not the recording): it is kept here and sent again in {RESEND_PAUSE_S / 60:g} "
            "minutes"
        )
        self.kept_back[session_id] = said
        log.error("%s; the server said: %s", said, why)
        return False

    def _kept_back(self, session_id: str) -> bool:
        until = self._back_until.get(session_id)
        if until is None:
            return False
        if time.monotonic() < until:
            return True
        del self._back_until[session_id]
        self.kept_back.pop(session_id, None)
        return False

    async def run(self, period: float = 5.0) -> None:
        """Keep uploading: at start, when woken (a session ended) and every ``period``."""
        backoff = Backoff(RETRY_FIRST_S, RETRY_MAX_S)
        while True:
            try:
                await self.upload_all()
                self.last_error = "; ".join(self.kept_back.values())
                backoff.reset()
                wait = period
            except (httpx.HTTPError, OSError, UploadRetry, SpoolFileError) as exc:
                if isinstance(exc, UploadRetry | SpoolFileError):
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


def classify(r: httpx.Response) -> tuple[Next, str]:
    """What to do after the server's answer ``r`` (:data:`ANSWERS`, then its status), and
    the answer in words."""
    code, detail = "", r.text
    try:
        body = r.json()
    except ValueError:
        body = None
    if isinstance(body, dict):
        code = str(body.get("code") or "")
        detail = str(body.get("detail", r.text))
    method = r.request.method
    text = f"{method} {r.request.url.path}: {r.status_code} {detail}"
    offset = "Upload-Offset" in r.headers
    for answer in ANSWERS:
        if answer.matches(r.status_code, method, code, detail, offset):
            return answer.next, text
    if r.status_code >= 500 or r.status_code in RETRYABLE or r.status_code < 400:
        return Next.RETRY, text
    return Next.REFUSE, text


def _error(r: httpx.Response) -> Exception:
    next_, text = classify(r)
    if next_ is Next.RESEND:
        return UploadResend(text)
    if next_ is Next.RETRY:
        return UploadRetry(text)
    return UploadError(text)
