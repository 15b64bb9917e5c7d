"""The station's spool: what a crash leaves behind is closed, kept and uploaded."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from sessions.recording import (
    SAMPLE_DTYPE,
    DeviceInfo,
    End,
    Header,
    RecordingWriter,
    SessionEvent,
    read,
)
from station.spool import Spool


def header(session_id: str) -> Header:
    return Header(
        session_id=session_id,
        station_id=1,
        patient_id=1,
        prescription_id=1,
        prescription={},
        device=DeviceInfo(firmware="f", hardware="sim", telemetry_hz=100, home_pose=[0.0] * 6),
        software="test",
        started_at=time.time(),
    )


def row(t: float) -> tuple[object, ...]:
    z = np.zeros(1, SAMPLE_DTYPE)[0]
    names = SAMPLE_DTYPE.names or ()
    return (t, t, 3, 0, 1, 1, 1, *[z[name] for name in names[7:]])


def test_a_killed_session_is_cut_to_whole_records_and_closed_as_interrupted(
    tmp_path: Path,
) -> None:
    spool = Spool(tmp_path)
    path = spool.path("a")
    writer = RecordingWriter(path, header("a"))
    for i in range(50):
        writer.add(row(i * 0.01))
    writer.flush()
    writer.event(SessionEvent(wall=1.0, kind="rep_done"))
    for i in range(50, 80):
        writer.add(row(i * 0.01))
    writer.flush()
    size = path.stat().st_size
    os.close(writer._fd)  # killed: no end record
    with path.open("ab") as f:
        f.write(b"\x02\x00\x10\x00\x00partial")  # a record torn by the crash
    closed = spool.recover_unfinished()
    assert closed == ["a"]
    rec = read(path)
    assert not rec.damaged
    assert len(rec.samples) == 80  # every flushed sample kept
    assert np.all(np.diff(rec.samples["t"]) > 0)
    assert rec.end is not None and rec.end.reason == "interrupted"
    assert rec.end.repetitions_completed == 1
    assert path.stat().st_size > size  # the torn bytes went, the end record came


def test_a_killed_session_ends_at_its_last_sample_not_when_it_is_closed(tmp_path: Path) -> None:
    """A station off for a day after a crash files the session as it was: 0.99 s of
    samples, not a session lasting until the station came back (nor 31 s, as one was)."""
    spool = Spool(tmp_path)
    began = time.time() - 86400.0  # the station stayed off for a day
    start = header("a").model_copy(update={"started_at": began})
    writer = RecordingWriter(spool.path("a"), start)
    for i in range(100):
        writer.add(row(began + i * 0.01))  # device time and wall time alike
    writer.event(SessionEvent(wall=began + 0.5, kind="rep_done"))
    writer.flush()
    os.close(writer._fd)  # killed: no end record
    # Killed before a sample came: it ended as it started.
    RecordingWriter(spool.path("b"), header("b").model_copy(update={"started_at": began})).close()
    assert sorted(spool.recover_unfinished()) == ["a", "b"]
    ended = read(spool.path("a")).end
    assert ended is not None and ended.reason == "interrupted"
    assert ended.ended_at == began + 99 * 0.01
    ended = read(spool.path("b")).end
    assert ended is not None and ended.ended_at == began


def test_one_station_at_a_time_holds_the_spool(tmp_path: Path) -> None:
    """Two stations on one spool: the second took the first's open recording for one a crash
    left, closed and uploaded it (and the server refused it as cut off). Now a second
    `ankle station` stops at once, in one line, and leaves the spool alone."""
    spool = Spool(tmp_path / "spool")
    spool.lock()
    open_now = spool.path("running")
    writer = RecordingWriter(open_now, header("running"))
    writer.add(row(time.time()))
    writer.flush()
    before = open_now.read_bytes()
    try:
        done = subprocess.run(
            [
                sys.executable,
                "-m",
                "ankle",
                "station",
                "--device",
                "socket://127.0.0.1:9",
                "--server",
                "http://127.0.0.1:9",
                "--token",
                "t",
                "--spool",
                str(spool.dir),
                "--page-port",
                "0",
            ],
            capture_output=True,
            text=True,
            timeout=120,
            env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[2])},
        )
    finally:
        writer.close()
    assert done.returncode == 2, done
    assert done.stdout.splitlines() == [
        f"error: ankle station: the spool folder {spool.dir} is in use by another station "
        f"(process {os.getpid()}); stop it, or give this one its own --spool"
    ], done
    assert open_now.read_bytes() == before  # not closed as interrupted, not uploaded


def test_finished_sessions_are_left_alone_and_headerless_files_removed(tmp_path: Path) -> None:
    spool = Spool(tmp_path)
    with RecordingWriter(spool.path("done"), header("done")) as w:
        w.end(End(ended_at=1.0, reason="completed", sets_completed=1, repetitions_completed=3))
    before = spool.path("done").read_bytes()
    spool.path("empty").write_bytes(b"ANKL")  # killed before the header reached the disk
    assert spool.recover_unfinished() == []
    assert spool.path("done").read_bytes() == before
    assert not spool.path("empty").exists()


def test_prescriptions_cache_survives_a_restart_and_ignores_garbage(tmp_path: Path) -> None:
    Spool(tmp_path).save_prescriptions([{"id": 3}])
    assert Spool(tmp_path).load_prescriptions() == [{"id": 3}]
    (tmp_path / "prescriptions.json").write_text("{not json")
    assert Spool(tmp_path).load_prescriptions() == []


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_the_spool_and_what_it_keeps_are_the_station_accounts_alone(tmp_path: Path) -> None:
    """Folders 0700 and files 0600 whatever the umask, as the server's data: the spool, the
    cached prescriptions, the sessions and those the server refused, with their reasons."""
    old = os.umask(0o022)  # the usual default, which made 0755 folders and 0644 files
    try:
        spool = Spool(tmp_path / "station" / "spool")
        spool.save_prescriptions([{"id": 3}])
        with RecordingWriter(spool.path("s"), header("s")) as w:
            w.end(End(ended_at=1.0, reason="completed", sets_completed=1, repetitions_completed=3))
        assert mode(spool.dir) == 0o700
        assert mode(spool.dir / "prescriptions.json") == 0o600
        assert mode(spool.path("s")) == 0o600
        kept = spool.refuse(spool.path("s"), "POST …/complete: 422 not a valid recording")
    finally:
        os.umask(old)
    assert mode(kept.parent) == 0o700
    assert mode(kept) == 0o600
    assert mode(kept.parent / "s.reason.txt") == 0o600
    assert spool.refused() == {"s": "POST …/complete: 422 not a valid recording"}
    assert spool.pending() == []
    assert sorted(p.name for p in spool.dir.iterdir()) == ["prescriptions.json", "refused"]


def test_cached_prescriptions_from_before_are_made_private_on_the_next_save(
    tmp_path: Path,
) -> None:
    cache = tmp_path / "prescriptions.json"
    cache.write_text("[]")
    cache.chmod(0o644)
    Spool(tmp_path).save_prescriptions([{"id": 4}])
    assert mode(cache) == 0o600
    assert Spool(tmp_path).load_prescriptions() == [{"id": 4}]


def test_a_finished_session_damaged_on_disk_is_kept_and_not_cut_to_its_damage(
    tmp_path: Path,
) -> None:
    """One byte changed in the middle of a finished session: every file was cut back at its
    first damage and closed again, and this one went up as half a session, "interrupted".
    Now the original is kept as found, and what reads of it goes up with its own end, saying
    what was lost."""
    spool = Spool(tmp_path)
    path = spool.path("done")
    with RecordingWriter(path, header("done")) as writer:
        for block in range(10):
            for i in range(20):
                writer.add(row(block * 0.2 + i * 0.01))
            writer.flush()
            writer.event(SessionEvent(wall=1.0, kind="rep_done"))
        writer.end(
            End(ended_at=2.0, reason="completed", sets_completed=1, repetitions_completed=10)
        )
    whole = read(path)
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01  # a sample record's payload in the middle
    path.write_bytes(bytes(data))
    assert read(path).end is None  # it reads only up to the damage

    assert spool.recover_unfinished() == []  # not closed as interrupted: it was finished
    kept = tmp_path / "damaged" / "done.rec"
    assert kept.read_bytes() == bytes(data)  # the original, as found
    rec = read(path)
    assert not rec.damaged and rec.end is not None
    assert rec.end.reason == "completed" and rec.end.repetitions_completed == 10
    assert rec.end.ended_at == 2.0
    assert "damaged on the station's disk" in rec.end.text, rec.end.text
    # One block of 20 samples lost, the nine others and every event kept.
    assert len(rec.samples) == len(whole.samples) - 20
    assert [e.kind for e in rec.events] == ["rep_done"] * 10 + ["damaged"]
    # Started again, the station leaves the repaired file as it is.
    repaired = path.read_bytes()
    assert spool.recover_unfinished() == []
    assert path.read_bytes() == repaired
