"""Session exports made in processes of their own, one at a time per file however many ask.

Made in a thread of the server, an export held the interpreter's lock (the GIL) for seconds
on end while Arrow handed over a block of messages and the MCAP writer framed them one by
one: a 2 h session at 250 Hz (1.8 M samples) took 120 s and froze the whole server for 11 s,
long enough for every live WebSocket to be closed for a missed heartbeat and for ``/health``
to report the database down; at 100 Hz (720 k samples) the loop stood still 2-4 s. In a
process of its own an export takes a core, never the event loop, and gives its memory back
to the system when it ends.

Each export is a fresh ``spawn`` process (no copy of the server's threads, sockets or
database connections), at a lower priority, that reads the recording, writes the export to
its file block by block and hands back only its SHA-256. Starting one costs about a second
of imports, against the seconds to minutes of a long session's export, and each is made
once and kept. :class:`ExportWorkers` runs at most ``workers`` at once; requests for the same
file share one making; past ``queue_max`` files made or waiting, a request is refused with a
503 and ``Retry-After``. An export that outlives ``timeout_s`` is killed, and one whose
process ends without an answer (killed, out of memory) is a 503 saying so: never a request
left hanging.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import multiprocessing
import os
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from pathlib import Path

from fastapi import HTTPException

log = logging.getLogger(__name__)

EXPORT_NICE = 10
"""How much lower than the server an export process runs (Linux nice): on a machine of two
cores, the server's own work comes first."""

BUSY = (
    "the server is already making {count} session downloads: try again in a minute; this one "
    "has not been started"
)
TOO_LONG = (
    "making this download took longer than {seconds:g} s and was stopped: the server is busy "
    "or the session very long; try again later, or download the recording (rec)"
)
STOPPED = "the process making this download stopped before it finished ({why}): try again"
FAILED = "this download could not be made; the server's log says why"

RETRY_AFTER_S = 60


def _lower_priority() -> None:
    with contextlib.suppress(OSError):
        os.nice(EXPORT_NICE)


def _work(answer: Connection, source: str, fmt: str, path: str) -> None:
    """In the export process: write the export, answer ``("ok", sha256)`` or the error."""
    _lower_priority()
    # Imported here, in the child: the server process never needs the exporters itself.
    from sessions.export import write_export
    from sessions.recording import read

    try:
        digest = write_export(read(Path(source)), fmt, Path(path))
    except Exception as exc:
        # Short: a pipe holds some kilobytes, and a child blocked on a long send never ends.
        answer.send(("error", f"{type(exc).__name__}: {exc}"[:1000]))
    else:
        answer.send(("ok", digest))
    finally:
        answer.close()


def _remove_partial(path: Path) -> None:
    """What a process that was killed or died was writing, under its temporary name (see
    :func:`sessions.export.write_export`); a whole export is only ever renamed into place."""
    for partial in path.parent.glob(f".{path.name}.*.tmp"):
        partial.unlink(missing_ok=True)


def _answer(receive: Connection) -> tuple[str, str] | None:
    """What the process sent before it ended; None if it ended without a word."""
    try:
        if receive.poll():
            status, value = receive.recv()
            return str(status), str(value)
    except (EOFError, OSError):
        pass
    return None


class ExportWorkers:
    """Exports off the server's event loop and out of its memory (see the module)."""

    def __init__(self, workers: int, queue_max: int, timeout_s: float) -> None:
        self.workers = workers
        self.queue_max = queue_max
        self.timeout_s = timeout_s
        self._slots = asyncio.Semaphore(workers)
        self._making: dict[Path, asyncio.Future[str]] = {}
        self._running: set[BaseProcess] = set()
        self._ctx = multiprocessing.get_context("spawn")

    @property
    def pids(self) -> list[int]:
        """Process ids of the exports being made now."""
        return [p.pid for p in self._running if p.pid is not None]

    async def make(self, source: Path, fmt: str, path: Path) -> str:
        """Write the export of ``source`` in ``fmt`` to ``path``; its SHA-256. A request for a
        file already being made waits for that making rather than starting another."""
        making = self._making.get(path)
        if making is None:
            if len(self._making) >= self.queue_max:
                raise HTTPException(
                    503,
                    BUSY.format(count=len(self._making)),
                    headers={"Retry-After": str(RETRY_AFTER_S)},
                )
            making = asyncio.ensure_future(self._make(source, fmt, path))
            self._making[path] = making
            making.add_done_callback(lambda done: self._done(path, done))
        # Shielded: a client that goes away does not stop what others (and the cache) wait for.
        return await asyncio.shield(making)

    def _done(self, path: Path, done: asyncio.Future[str]) -> None:
        if self._making.get(path) is done:
            del self._making[path]
        if not done.cancelled():
            done.exception()  # retrieved, so that nobody waiting left is never logged as lost

    async def _make(self, source: Path, fmt: str, path: Path) -> str:
        async with self._slots:
            receive, send = self._ctx.Pipe(duplex=False)
            process = self._ctx.Process(
                target=_work,
                args=(send, str(source), fmt, str(path)),
                name=f"export-{fmt}",
                daemon=True,
            )
            try:
                await asyncio.to_thread(process.start)
                self._running.add(process)
                send.close()  # the child holds the other end: it ends when the child does
                await asyncio.to_thread(process.join, self.timeout_s)
                if process.is_alive():
                    process.kill()
                    await asyncio.to_thread(process.join)
                    _remove_partial(path)
                    log.error("export %s of %s killed after %g s", fmt, source, self.timeout_s)
                    raise HTTPException(
                        503,
                        TOO_LONG.format(seconds=self.timeout_s),
                        headers={"Retry-After": str(RETRY_AFTER_S)},
                    )
                answer = _answer(receive)
            finally:
                self._running.discard(process)
                if process.is_alive():  # cancelled while waiting (the server stopping)
                    process.kill()
                    _remove_partial(path)
                receive.close()
                send.close()
        if answer is None:
            _remove_partial(path)
            why = f"exit code {process.exitcode}"
            log.error("export %s of %s: its process ended without an answer (%s)", fmt, source, why)
            raise HTTPException(503, STOPPED.format(why=why), headers={"Retry-After": "5"})
        status, value = answer
        if status != "ok":
            log.error("export %s of %s failed: %s", fmt, source, value)
            raise HTTPException(500, FAILED)
        return value

    def close(self) -> None:
        """Stop the exports being made (the server is stopping): their files are never kept
        partial, each being written under a temporary name until whole."""
        for process in list(self._running):
            with contextlib.suppress(Exception):
                process.kill()
