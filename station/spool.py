"""The station's spool directory: recorded sessions waiting for the server, and the cache.

Every session is written here first, as it runs (``<session uuid>.rec``), and deleted only
after the server has confirmed the upload with the same checksum. A file without an end
record is a session the station did not finish (killed, power lost): at start-up it is cut
back to its whole records, closed as ``interrupted`` at its last sample and queued like any
other. One station process uses a spool at a time (:meth:`Spool.lock`).

A session the server refuses for good (not a valid recording, too large: a 4xx that sending
it again cannot change) is moved to ``refused/`` with the server's reason beside it
(``<session uuid>.reason.txt``), and sent no more: never deleted, it is the patient's data.
Moved back into the spool, it is sent again.

The spool and everything in it are the station account's alone (folders 0700, files 0600, as
the server's data).
"""

from __future__ import annotations

import fcntl
import json
import math
import os
from pathlib import Path

from sessions.private import PRIVATE_FILE, fsync_dir, private_data_dir, write_private
from sessions.recording import End, Recording, RecordingError, RecordingWriter, recover

PRESCRIPTIONS_FILE = "prescriptions.json"
LOCK_FILE = "station.lock"
"""Held locked (flock) by the station using the spool, with its process id in it."""
REFUSED_DIR = "refused"
"""Beside the sessions waiting: the ones the server refused for good."""
REASON_SUFFIX = ".reason.txt"


class SpoolInUse(RuntimeError):
    """Another station process holds the spool (:meth:`Spool.lock`)."""


def last_recorded(rec: Recording) -> float:
    """When a session a crash left open ended, as near as its file tells: its last sample or
    event (station clock), never before it started. Not the time it is closed, which may be
    days later (a session with 0.99 s of samples was filed as lasting 31 s)."""
    walls = [float(rec.samples["wall"][-1])] if len(rec.samples) else []
    walls += [e.wall for e in rec.events]
    return max([rec.header.started_at, *(w for w in walls if math.isfinite(w))])


class Spool:
    def __init__(self, directory: Path) -> None:
        self.dir = directory
        private_data_dir(self.dir)
        self.refused_dir = self.dir / REFUSED_DIR
        self._lock_fd = -1

    def path(self, session_id: str) -> Path:
        return self.dir / f"{session_id}.rec"

    def pending(self) -> list[Path]:
        """Finished sessions not yet confirmed by the server, oldest first."""
        return sorted(self.dir.glob("*.rec"), key=lambda p: p.stat().st_mtime)

    def refuse(self, path: Path, reason: str) -> Path:
        """Set aside a session the server refused for good, with its reason; where it went."""
        private_data_dir(self.refused_dir)
        target = self.refused_dir / path.name
        write_private(self.refused_dir / (path.stem + REASON_SUFFIX), reason + "\n")
        os.replace(path, target)
        os.chmod(target, PRIVATE_FILE)  # a file put in the spool by hand may have come 0644
        fsync_dir(self.refused_dir)
        fsync_dir(self.dir)
        return target

    def refused(self) -> dict[str, str]:
        """The sessions set aside as refused: session id to the server's reason."""
        out: dict[str, str] = {}
        for path in sorted(self.refused_dir.glob("*.rec")):
            try:
                reason = (path.parent / (path.stem + REASON_SUFFIX)).read_text().strip()
            except OSError:
                reason = "refused by the server (no reason kept)"
            out[path.stem] = reason
        return out

    def recover_unfinished(self, active: set[Path] | None = None) -> list[str]:
        """Close sessions a crash left open; returns their ids. Skips ``active`` files."""
        closed: list[str] = []
        for path in self.pending():
            if active and path in active:
                continue
            try:
                rec = recover(path)
            except RecordingError:
                # Not even a header made it to disk: nothing was recorded.
                path.unlink()
                continue
            if rec.end is None:
                reps = sum(1 for e in rec.events if e.kind == "rep_done")
                sets = sum(1 for e in rec.events if e.kind == "set_done")
                with RecordingWriter(path) as writer:
                    writer.end(
                        End(
                            ended_at=last_recorded(rec),
                            reason="interrupted",
                            sets_completed=sets,
                            repetitions_completed=reps,
                            text="the station stopped before the session ended (killed, "
                            "crashed or lost power); closed when it started again",
                        )
                    )
                closed.append(rec.header.session_id)
        return closed

    def lock(self) -> None:
        """Hold the spool for this process's life: a second station on the same spool would
        take the first's open recording for one a crash left (and close, upload and lose
        it). Raises :class:`SpoolInUse` if another process holds it."""
        fd = os.open(self.dir / LOCK_FILE, os.O_RDWR | os.O_CREAT, PRIVATE_FILE)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 32).decode(errors="replace").strip()
            os.close(fd)
            who = f" (process {holder})" if holder.isdigit() else ""
            raise SpoolInUse(
                f"the spool folder {self.dir} is in use by another station{who}; stop it, "
                "or give this one its own --spool"
            ) from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._lock_fd = fd  # held, never closed: the lock ends with the process

    def save_prescriptions(self, items: list[dict[str, object]]) -> None:
        """Cache the latest prescriptions so the patient can exercise with no network."""
        write_private(self.dir / PRESCRIPTIONS_FILE, json.dumps(items))

    def load_prescriptions(self) -> list[dict[str, object]]:
        try:
            data = json.loads((self.dir / PRESCRIPTIONS_FILE).read_text())
        except (FileNotFoundError, ValueError):
            return []
        return data if isinstance(data, list) else []
