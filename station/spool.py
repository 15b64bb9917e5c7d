"""The station's spool directory: recorded sessions waiting for the server, and the cache.

Every session is written here first, as it runs (``<session uuid>.rec``), and deleted only
after the server has confirmed the upload with the same checksum. A file without an end
record is a session the station did not finish (killed, power lost): at start-up it is cut
back to its whole records, closed as ``interrupted`` at its last sample and queued like any
other. A finished file (its end record whole, at its end) is never cut: one that no longer
reads whole (a byte changed on the disk) is kept byte for byte in ``damaged/``, and what
still reads of it, every whole record before and after the damage, is uploaded in its place
with its end record saying what was lost (:meth:`Spool.recover_unfinished`). One station
process uses a spool at a time (:meth:`Spool.lock`).

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
import logging
import math
import os
import struct
from pathlib import Path

from sessions.private import PRIVATE_FILE, fsync_dir, private_data_dir, write_private
from sessions.recording import (
    MAGIC,
    MAX_RECORD,
    SAMPLE_DTYPE,
    End,
    Recording,
    RecordingError,
    RecordingWriter,
    RecordType,
    SessionEvent,
    decode,
    iter_records,
    recover,
)

log = logging.getLogger("ankle.station.spool")

PRESCRIPTIONS_FILE = "prescriptions.json"
LOCK_FILE = "station.lock"
"""Held locked (flock) by the station using the spool, with its process id in it."""
REFUSED_DIR = "refused"
"""Beside the sessions waiting: the ones the server refused for good."""
REASON_SUFFIX = ".reason.txt"
DAMAGED_DIR = "damaged"
"""Beside the sessions waiting: finished files that no longer read whole, kept as found."""
END_SEARCH = 1 << 16
"""Bytes from a file's end searched for its end record (one is a few hundred bytes)."""
_RECORD_HEAD = struct.Struct("<BI")
_RECORD_EXTRA = _RECORD_HEAD.size + 4  # type, length, then the payload's CRC-32


class SpoolInUse(RuntimeError):
    """Another station process holds the spool (:meth:`Spool.lock`)."""


def last_recorded(rec: Recording) -> float:
    """When a session a crash left open ended, as near as its file tells: its last sample or
    event (station clock), never before it started. Not the time it is closed, which may be
    days later (a session with 0.99 s of samples was filed as lasting 31 s)."""
    walls = [float(rec.samples["wall"][-1])] if len(rec.samples) else []
    walls += [e.wall for e in rec.events]
    return max([rec.header.started_at, *(w for w in walls if math.isfinite(w))])


def end_at_tail(data: bytes) -> int | None:
    """Where a whole, checked end record starts that ends the file exactly, or None: a
    finished session, whatever happened to the bytes before it."""
    for pos in range(len(data) - _RECORD_EXTRA, max(len(MAGIC), len(data) - END_SEARCH) - 1, -1):
        if data[pos] != RecordType.END:
            continue
        (length,) = struct.unpack_from("<I", data, pos + 1)
        if pos + _RECORD_EXTRA + length != len(data):
            continue
        records, _, rest = iter_records(MAGIC + data[pos:])
        if len(records) == 1 and not rest:
            return pos
    return None


def _whole_from(data: bytes, pos: int) -> int:
    """How many bytes from ``pos`` are whole, checked records (0: none starts there)."""
    if pos + _RECORD_EXTRA > len(data) or data[pos] not in RecordType._value2member_map_:
        return 0
    (length,) = struct.unpack_from("<I", data, pos + 1)
    if length > MAX_RECORD or pos + _RECORD_EXTRA + length > len(data):
        return 0
    _, valid, _ = iter_records(MAGIC + data[pos : pos + _RECORD_EXTRA + length])
    if valid == len(MAGIC):
        return 0  # its CRC fails
    _, valid, _ = iter_records(MAGIC + data[pos:])
    return valid - len(MAGIC)


def salvage(data: bytes) -> tuple[bytes, int]:
    """Every whole, checked record of ``data`` (a recording), damaged ones left out; and the
    number of bytes left out. After a record that fails its check, reading resumes at the
    next place a checked record starts: a byte changed on a disk spoils its record, not
    what follows it."""
    if data.startswith(MAGIC):
        _, pos, _ = iter_records(data)
    else:
        pos = min(len(data), len(MAGIC))  # its magic is what was damaged
    kept = [MAGIC, data[len(MAGIC) : pos]]
    lost = 0
    while pos < len(data):
        start = pos
        pos += 1
        while pos < len(data) and not (whole := _whole_from(data, pos)):
            pos += 1
        lost += pos - start
        if pos < len(data):
            kept.append(data[pos : pos + whole])
            pos += whole
    return b"".join(kept), lost


class Spool:
    def __init__(self, directory: Path) -> None:
        self.dir = directory
        private_data_dir(self.dir)
        self.refused_dir = self.dir / REFUSED_DIR
        self.damaged_dir = self.dir / DAMAGED_DIR
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

    def free_bytes(self) -> int:
        """Bytes free for the station's account on the spool's disk."""
        st = os.statvfs(self.dir)
        return st.f_bavail * st.f_frsize

    def recover_unfinished(self, active: set[Path] | None = None) -> list[str]:
        """Close sessions a crash left open; returns their ids. Skips ``active`` files.

        Only a file with no end record is cut back to its whole records (what a killed writer
        left): one whose end record is whole was finished, and a record that fails its check
        before it is damage on the disk, not a crash. Cutting it there, as every file once
        was, filed a finished session as interrupted at the damage (half of it, for one byte).
        Such a file is kept as found in ``damaged/`` and every record that still reads is
        uploaded in its place, the end saying what was lost (:meth:`_repair`): the least
        lost, and the therapist told."""
        closed: list[str] = []
        for path in self.pending():
            if active and path in active:
                continue
            try:
                data = path.read_bytes()
            except OSError as exc:
                log.error("cannot read the session file %s: %s; left as it is", path, exc)
                continue
            tail = end_at_tail(data)
            if tail is not None:
                self._check_finished(path, data, tail)
                continue
            try:
                rec = recover(path)
            except RecordingError:
                if salvage(data)[0] != MAGIC:
                    # Records, but no header to read them by: kept, never deleted.
                    self._set_aside(path, "its header record cannot be read")
                    continue
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

    def _check_finished(self, path: Path, data: bytes, tail: int) -> None:
        """Leave a finished file that reads whole as it is; repair one that does not."""
        try:
            rec = decode(data)
        except ValueError:
            rec = None
        if rec is not None and rec.end is not None and not rec.damaged:
            return
        try:
            self._repair(path, data, tail)
        except (ValueError, OSError) as exc:
            self._set_aside(path, f"it does not read whole, and could not be repaired: {exc}")

    def _repair(self, path: Path, data: bytes, tail: int) -> None:
        """Keep a finished file that no longer reads whole in ``damaged/``, as found, and put
        what still reads in its place: its whole records, then a ``damaged`` event and its
        own end record, whose text says what was lost."""
        kept, lost = salvage(data[:tail])
        if lost == 0:
            raise RecordingError("nothing damaged was found before its end record")
        records, _, _ = iter_records(MAGIC + data[tail:])
        end = End.model_validate_json(records[0][1])
        rec = decode(kept)  # RecordingError if its header is what was damaged
        hz = rec.header.device.telemetry_hz
        about = f" (about {lost / (hz * SAMPLE_DTYPE.itemsize):.1f} s of samples)" if hz else ""
        said = (
            f"the recording was damaged on the station's disk: {lost} bytes{about} could "
            "not be read and are left out; the station keeps the file as it was found"
        )
        end = end.model_copy(update={"text": "; ".join(t for t in (end.text, said) if t)})
        tmp = path.with_name(path.name + ".repair")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, PRIVATE_FILE)
        try:
            os.write(fd, kept)
        finally:
            os.close(fd)
        with RecordingWriter(tmp) as writer:
            writer.event(
                SessionEvent(
                    wall=end.ended_at,
                    kind="damaged",
                    by="station",
                    detail={"text": said, "bytes_lost": lost},
                )
            )
            writer.end(end)
        original = self._keep_damaged(path)
        os.replace(tmp, path)
        fsync_dir(self.dir)
        log.error(
            "session %s: %s; what reads of it is uploaded, the original kept in %s",
            path.stem,
            said,
            original,
        )

    def _keep_damaged(self, path: Path) -> Path:
        """A copy of ``path`` as it is now, in ``damaged/`` (a second name, not a copy)."""
        private_data_dir(self.damaged_dir)
        target = self.damaged_dir / path.name
        target.unlink(missing_ok=True)  # left by a repair a crash cut short
        os.link(path, target)
        fsync_dir(self.damaged_dir)
        return target

    def _set_aside(self, path: Path, why: str) -> None:
        """Move a file that cannot be uploaded to ``damaged/``, with why beside it."""
        private_data_dir(self.damaged_dir)
        target = self.damaged_dir / path.name
        write_private(self.damaged_dir / (path.stem + REASON_SUFFIX), why + "\n")
        os.replace(path, target)
        fsync_dir(self.damaged_dir)
        fsync_dir(self.dir)
        log.error("session file %s set aside in %s: %s", path.name, self.damaged_dir, why)

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
