"""The 3D replay: built once from a recording with viser's serializer, served with its viewer."""

from __future__ import annotations

import base64
import hashlib
import math
import re
import shutil
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import msgspec
import numpy as np
import pytest
import zstandard

from device.protocol.messages import DeviceMode
from server.config import Settings
from server.routes.sessions import DAMAGED
from sessions.prescription import AXIS_INDEX
from sessions.recording import SAMPLE_DTYPE, decode
from tests.server.live_server import World, bearer, running, seeded
from tests.server.test_report import exports
from tests.server.test_series import recording_bytes, upload
from webui.app import create_app
from webui.assets import VIEWER_CSP
from webui.replay import (
    CLIENT_HTML,
    REPLAY_HZ,
    VIEWER_CAMERA,
    Replays,
    frame_indices,
    standalone_html,
)

__all__ = ["seeded"]  # the seeded database fixture, shared with the server tests

HZ = 100.0
N = 2000  # 20 s
PITCH = AXIS_INDEX["pitch"]
AMPLITUDE = math.radians(12.0)


def pitch_at(t: float | np.ndarray[Any, Any]) -> Any:
    return AMPLITUDE * np.sin(2 * np.pi * 0.25 * t)


def samples() -> np.ndarray[Any, Any]:
    s = np.zeros(N, SAMPLE_DTYPE)
    s["t"] = 3.0 + np.arange(N) / HZ
    s["wall"] = 1_700_000_000.0 + np.arange(N) / HZ
    s["mode"] = int(DeviceMode.ACTIVE)
    s["pose"][:, PITCH] = pitch_at(np.arange(N) / HZ)
    s["pose_cmd"][:, PITCH] = pitch_at(np.arange(N) / HZ)
    s["pressures"] = 3e5
    s["pressures"][100:200] = np.nan  # unreadable chambers still draw
    s["pose"][1000:1010] = np.nan  # an unreadable pose is skipped, not drawn
    return s


def decode_viser(data: bytes) -> dict[str, Any]:
    """The message log of a ``.viser`` file (viser 1.x: zstd around msgpack + buffers)."""
    size = int.from_bytes(data[:8], "little")
    inner = zstandard.ZstdDecompressor().decompress(data[8:], max_output_size=size)
    head = int.from_bytes(inner[:8], "little")
    log: dict[str, Any] = msgspec.msgpack.decode(inner[8 : 8 + head])
    return log


@pytest.fixture(scope="module")
def replays() -> Iterator[Replays]:
    r = Replays()
    yield r
    r.close()


def test_a_replay_follows_the_session_on_its_clock(replays: Replays, tmp_path: Path) -> None:
    source = tmp_path / "session.rec"
    source.write_bytes(recording_bytes(str(uuid.uuid4()), samples()))
    sha = hashlib.sha256(source.read_bytes()).hexdigest()

    t0 = time.perf_counter()
    path = replays.get(source, sha)
    built_in = time.perf_counter() - t0
    assert path.parent == source.parent and sha in path.name and path.suffix == ".viser"
    assert replays.builds == 1
    # 20 s of session at 25 frames/s: about a second on this kind of machine.
    assert built_in < 10.0, built_in

    log = decode_viser(path.read_bytes())
    assert log["durationSeconds"] == pytest.approx((N - 1) / HZ, abs=1.0 / REPLAY_HZ)
    frames = [
        (t, m["wxyz"])
        for t, m in log["messages"]
        if m["type"] == "SetOrientationMessage" and m["name"] == "/platform"
    ]
    # One orientation per frame, but for the 0.1 s whose pose was unreadable.
    assert len(frames) == pytest.approx(20 * REPLAY_HZ - 0.1 * REPLAY_HZ, abs=3)
    for t, (w, _, y, _) in frames[5::97]:
        # The frame shown at replay time t is the sample at t on the charts' clock.
        assert 2 * math.atan2(y, w) == pytest.approx(pitch_at(t), abs=1e-3), t

    # Built once: the next call, and another builder, read it from disk.
    mtime = path.stat().st_mtime_ns
    assert replays.get(source, sha) == path and replays.builds == 1
    other = Replays()
    assert other.get(source, sha) == path and other.builds == 0
    assert path.stat().st_mtime_ns == mtime


def test_the_standalone_page_is_visers_client_with_the_recording_inside(
    replays: Replays,
) -> None:
    rows = samples()[:500]
    rec = decode(recording_bytes(str(uuid.uuid4()), rows))
    data = replays.build(rec)
    html = standalone_html(data)
    client = CLIENT_HTML.read_text()
    assert html.startswith(client[: client.index("</head>")])
    match = re.search(r'window\.__VISER_EMBED_DATA__="([^"]+)"', html)
    assert match is not None and base64.b64decode(match.group(1)) == data
    # The client is about 0.8 MB; 5 s of replay adds tens of kilobytes.
    assert len(html) < len(client) + 200_000


@pytest.mark.asyncio
async def test_a_damaged_recording_makes_no_replay(
    seeded: tuple[Path, World], tmp_path: Path
) -> None:
    """The replay was built from the stored file and kept under the SHA-256 the upload
    completed with: a recording cut short on disk was played (and kept) as if whole. It is
    checked as every download is: a 500 saying so, nothing built."""
    template, world = seeded
    for f in template.glob("ankle.db*"):
        shutil.copy(f, tmp_path / f.name)
    async with running(Settings(data_dir=tmp_path), create_app) as live:
        sid = await upload(live, world, samples()[:800])
        (stored,) = (tmp_path / "sessions").glob("*.rec")
        whole = stored.read_bytes()
        stored.write_bytes(whole[: len(whole) // 2])
        for path in (f"/sessions/{sid}/replay", f"/sessions/{sid}/replay.viser"):
            r = await live.client.get(path, headers=bearer(world.t1))
            assert (r.status_code, r.json()) == (500, {"detail": DAMAGED}), path
        assert live.app.state.replays.builds == 0
        assert list((tmp_path / "sessions").glob("*.viser")) == []
        stored.write_bytes(whole)  # restored from backup
        r = await live.client.get(f"/sessions/{sid}/replay.viser", headers=bearer(world.t1))
        assert r.status_code == 200 and live.app.state.replays.builds == 1


def test_frames_are_the_latest_drawable_sample_at_each_frame_time() -> None:
    clock = np.array([0.0, 0.01, 0.02, 0.05, 0.06, 0.5, 0.51])
    drawable = np.array([True, True, False, True, True, True, False])
    assert frame_indices(clock, drawable, 25.0) == [0, 1, 4, 5]
    assert frame_indices(clock, np.zeros(7, dtype=bool), 25.0) == []


@pytest.mark.asyncio
async def test_replay_routes_check_access_and_serve_one_build(
    seeded: tuple[Path, World], tmp_path: Path
) -> None:
    template, world = seeded
    for f in template.glob("ankle.db*"):
        shutil.copy(f, tmp_path / f.name)
    async with running(Settings(data_dir=tmp_path), create_app) as live:
        sid = await upload(live, world, samples()[:800])
        c, t1 = live.client, bearer(world.t1)

        r = await c.get(f"/sessions/{sid}/replay.viser", headers=t1)
        assert r.status_code == 200, r.text
        assert r.headers["content-type"] == "application/octet-stream"
        log = decode_viser(r.content)
        assert log["durationSeconds"] == pytest.approx(7.99, abs=0.05)
        cached = list((tmp_path / "sessions").glob("*.viser"))
        assert len(cached) == 1 and cached[0].read_bytes() == r.content
        assert live.app.state.replays.builds == 1

        assert r.headers["cache-control"] == "no-store"
        assert await exports(live, world) == []  # played on the page: viewed, not kept

        r = await c.get(f"/sessions/{sid}/replay", headers=t1)
        assert r.status_code == 200
        assert r.headers["content-type"].startswith("text/html")
        assert r.headers["content-security-policy"] == VIEWER_CSP
        assert r.headers["cache-control"] == "no-store"
        assert "__VISER_EMBED_DATA__" in r.text
        assert live.app.state.replays.builds == 1  # the page is made from the same build
        # A file to keep: it leaves the system, and the audit says who took it.
        (row,) = await exports(live, world)
        assert row["actor"] == f"user:{world.t1_id}" and row["entity_id"] == str(sid)
        assert row["new"] == {"format": "replay-html", "session_id": sid}

        for path in (f"/sessions/{sid}/replay", f"/sessions/{sid}/replay.viser"):
            assert (await c.get(path, headers=bearer(world.t2))).status_code == 404
            assert (await c.get(path)).status_code == 401
        assert (await c.get("/sessions/99999/replay.viser", headers=t1)).status_code == 404

        blob = {"playbackPath": "blob:http://x/1"}
        viewer = await c.get("/replay/viewer", params=blob)
        # The camera comes from the server: the first answer adds it to the address.
        assert viewer.status_code == 307
        again = httpx.URL(str(viewer.url)).join(viewer.headers["location"])
        assert again.path == viewer.url.path
        assert dict(again.params) == {**blob, **VIEWER_CAMERA}
        viewer = await c.get(again)
        assert viewer.status_code == 200
        assert viewer.headers["content-security-policy"] == VIEWER_CSP
        assert viewer.text == CLIENT_HTML.read_text()
        for elsewhere in ("https://example.org/x.viser", "data:application/octet-stream,x", ""):
            r = await c.get("/replay/viewer", params={"playbackPath": elsewhere})
            assert r.status_code == 400
