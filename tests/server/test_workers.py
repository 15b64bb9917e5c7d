"""Several server processes on one store and one data directory: ``ankle server --workers``
starts them on one port, and a session filed through one is served by every other."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import httpx
import pytest
import redis

from server.cli import wait_healthy
from server.config import Settings
from tests.server.live_server import Seeds, Store, World, bearer, on_store, running
from tests.server.postgres import free_port
from tests.server.redis_server import spawned_redis
from tests.server.test_series import recording_bytes, samples
from tests.server.test_upload_refusals import complete, held, put, put_from

pytestmark = pytest.mark.both_stores


def _children(pid: int) -> set[int]:
    """The processes whose parent is ``pid`` (from /proc: no psutil needed)."""
    out = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue  # gone meanwhile
        if int(fields[1]) == pid:
            out.add(int(stat.parent.name))
    return out


def test_ankle_server_workers_share_one_port(tmp_path: Path, relay_url: str) -> None:
    port = free_port()
    log = tmp_path / "server.log"
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "ankle",
                "server",
                "--workers",
                "2",
                "--port",
                str(port),
                "--data-dir",
                str(tmp_path / "data"),
            ],
            stdout=out,
            stderr=subprocess.STDOUT,
            env=os.environ | {"ANKLE_RELAY_URL": relay_url},
        )
    try:
        url = f"http://127.0.0.1:{port}"
        wait_healthy(url, proc, timeout=120.0)
        workers = _children(proc.pid) - {proc.pid}
        # uvicorn's parent supervises; each worker is a process of its own on the one port
        # (multiprocessing may add a resource tracker beside them).
        assert len(workers) >= 2, log.read_text()
        for _ in range(20):
            assert httpx.get(f"{url}/api/v1/health", timeout=30).status_code == 200
        # /health answers once one worker serves; the other may still be starting on a
        # busy machine (it was, once, at a load of 9 on two cores).
        deadline = time.monotonic() + 120.0
        while (text := log.read_text()).count("Application startup complete.") < 2:
            assert time.monotonic() < deadline, text
            time.sleep(0.2)
        assert text.count("Application startup complete.") == 2, text
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, log.read_text()


def test_ankle_server_exits_non_zero_when_a_worker_fails_to_start(tmp_path: Path) -> None:
    """A Redis that takes one client more than the start-up check but not one per worker
    (maxclients): the second worker's hub cannot subscribe and its start-up fails. uvicorn's
    supervisor then stops every process and returned normally: ``ankle server`` exited 0,
    none serving. Now it says so in its last line and exits 1."""
    with spawned_redis(tmp_path / "redis") as (_, url):
        with redis.Redis.from_url(url) as client:
            client.config_set("maxclients", 1)  # kept once this client has gone
        out = subprocess.run(
            [sys.executable, "-m", "ankle", "server", "--workers", "2", "--port", "0"],
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
            env=os.environ
            | {"ANKLE_RELAY_URL": f"{url}/0", "ANKLE_DATA_DIR": str(tmp_path / "data")},
        )
    assert "failed to start" in out.stderr, out.stderr  # uvicorn's word: one did fail
    assert out.returncode == 1, out.stderr
    last = out.stderr.strip().splitlines()[-1]
    assert last == (
        "error: 1 of 2 server processes failed to start (the log above says why); none is serving"
    )


def test_workers_must_be_at_least_one(tmp_path: Path) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "ankle", "server", "--workers", "0", "--data-dir", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2 and "--workers must be 1 or more" in out.stderr


def test_workers_without_a_relay_are_refused(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k != "ANKLE_RELAY_URL"}
    out = subprocess.run(
        [sys.executable, "-m", "ankle", "server", "--workers", "2", "--data-dir", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert out.returncode == 2, out.stderr
    assert "needs the live relay (ANKLE_RELAY_URL" in out.stderr
    assert not (tmp_path / "ankle.db").exists()  # refused before anything was created


@pytest.mark.asyncio
async def test_a_session_uploaded_through_one_process_is_served_by_another(
    seeds: Seeds, store: Store, seeded_store: tuple[Path | str, World], tmp_path: Path
) -> None:
    """Two servers (as two worker processes would be: nothing shared but the database and
    the data directory). The upload starts on A, resumes on B, completes on A; the session
    is listed and downloaded through B."""
    template, world = seeded_store
    sid = str(uuid.uuid4())
    data = recording_bytes(sid, samples()[:3000], world.s1_id, world.p1, world.rx1)
    split = len(data) // 3
    with on_store(seeds, store, tmp_path, template) as settings:
        async with running(settings) as a, running(settings) as b:
            assert await put(a, world, sid, data[:split]) == 204
            assert await held(b, world, sid) == split
            assert await put_from(b, world, sid, data, split) == 204
            r = await complete(a, world, sid, data)
            assert r.status_code == 201, r.text
            session_id = r.json()["id"]
            r = await b.client.get("/sessions", headers=bearer(world.t1))
            assert session_id in [s["id"] for s in r.json()]
            got = await b.client.get(
                f"/sessions/{session_id}/download/rec", headers=bearer(world.t1)
            )
            assert got.status_code == 200 and got.content == data
        # Another host mounts the shared data directory elsewhere (or it was restored to a
        # new place): the session is still found, in every format.
        moved = tmp_path.with_name(tmp_path.name + "-elsewhere")
        tmp_path.rename(moved)
        try:
            url = settings.database_url.replace(str(tmp_path), str(moved))
            elsewhere = Settings(data_dir=moved, database_url=url)
            async with running(elsewhere) as c:
                t1 = bearer(world.t1)
                for fmt in ("rec", "csv"):
                    got = await c.client.get(f"/sessions/{session_id}/download/{fmt}", headers=t1)
                    assert got.status_code == 200, got.text
                r = await c.client.get(f"/sessions/{session_id}/series", headers=t1)
                assert r.status_code == 200, r.text
        finally:
            moved.rename(tmp_path)


@pytest.mark.asyncio
async def test_one_upload_sent_to_two_processes_at_once_is_taken_once(
    seeds: Seeds, store: Store, seeded_store: tuple[Path | str, World], tmp_path: Path
) -> None:
    """A station's retry landing on another process while the first attempt is still being
    written: one is taken (204), the other told the offset (409), never a 500 or a
    corrupted file."""
    template, world = seeded_store
    with on_store(seeds, store, tmp_path, template) as settings:
        async with running(settings) as a, running(settings) as b:
            for _ in range(8):
                sid = str(uuid.uuid4())
                data = recording_bytes(sid, samples()[:600], world.s1_id, world.p1, world.rx1)
                statuses = await asyncio.gather(put(a, world, sid, data), put(b, world, sid, data))
                assert sorted(statuses) == [204, 409], statuses
                assert await held(a, world, sid) == len(data)
                r = await complete(b, world, sid, data)
                assert r.status_code == 201, r.text
