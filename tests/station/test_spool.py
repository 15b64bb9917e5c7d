"""The station's spool: what a crash leaves behind is closed, kept and uploaded."""

from __future__ import annotations

import os
import stat
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
