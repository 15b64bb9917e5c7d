"""What a server leaves on disk is private, every answer carries the security headers, and a
clinician's number must be a number."""

from __future__ import annotations

import stat
import uuid
from pathlib import Path
from typing import Any

import pytest

from device.limits import SafetyLimits
from server.config import Settings
from server.headers import API_CSP
from tests.server.live_server import STRENGTH, Live, World, bearer, copy_seeded, running
from tests.server.test_series import recording_bytes, samples
from tests.server.test_upload_refusals import complete, put


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


@pytest.mark.asyncio
async def test_the_data_dir_is_0700_and_the_database_files_0600(
    seeded: tuple[Path, World], tmp_path: Path
) -> None:
    data_dir = tmp_path / "new" / "data"
    async with running(Settings(data_dir=data_dir)) as server:
        assert (await server.client.get("/health")).status_code == 200
        assert mode(data_dir) == 0o700
        files = sorted(data_dir.glob("ankle.db*"))
        assert {f.name for f in files} >= {"ankle.db", "ankle.db-wal", "ankle.db-shm"}
        assert {f.name: mode(f) for f in files} == {f.name: 0o600 for f in files}
    # A database made before the rule, readable by all, is brought to it on start.
    template, _ = seeded
    old = copy_seeded(template, tmp_path / "old")
    for f in old.glob("ankle.db*"):
        f.chmod(0o644)
    async with running(Settings(data_dir=old)):
        assert {mode(f) for f in old.glob("ankle.db*")} == {0o600}


@pytest.mark.asyncio
async def test_session_files_and_their_folders_are_private(live: Live, world: World) -> None:
    sid = str(uuid.uuid4())
    data = recording_bytes(sid, samples()[:500], world.s1_id, world.p1, world.rx1)
    assert await put(live, world, sid, data) == 204
    part = live.settings.data_dir / "uploads" / f"{sid}.part"
    assert mode(part) == 0o600 and mode(part.parent) == 0o700
    r = await complete(live, world, sid, data)
    assert r.status_code == 201
    filed = live.settings.data_dir / "sessions" / f"{sid}.rec"
    assert mode(filed) == 0o600 and mode(filed.parent) == 0o700
    got = await live.client.get(
        f"/sessions/{r.json()['id']}/download/csv", headers=bearer(world.t1)
    )
    assert got.status_code == 200
    exports = live.settings.data_dir / "exports"
    assert mode(exports) == 0o700
    assert {f.name: mode(f) for f in exports.iterdir()} == {
        f.name: 0o600 for f in exports.iterdir()
    }


@pytest.mark.asyncio
async def test_every_answer_has_nosniff_and_a_content_security_policy(
    live: Live, world: World
) -> None:
    sid = str(uuid.uuid4())
    data = recording_bytes(sid, samples()[:100], world.s1_id, world.p1, world.rx1)
    assert await put(live, world, sid, data) == 204
    session_id = (await complete(live, world, sid, data)).json()["id"]
    t1 = bearer(world.t1)
    answers = [
        await live.client.get("/health"),
        await live.client.get("/openapi.json"),
        await live.client.get("/patients", headers=t1),
        await live.client.get("/patients"),  # 401
        await live.client.get("/patients/999999", headers=t1),  # 404
        await live.client.post("/patients", json={"display_name": ""}, headers=t1),  # 422
        await live.client.post("/auth/login", content=b"x" * (2 * 1024 * 1024)),  # 413
        await live.client.get(f"/sessions/{session_id}/download/rec", headers=t1),
        await live.client.get(f"/sessions/{session_id}/download/csv", headers=t1),
        await live.client.get("/no/such/route"),
    ]
    assert [r.status_code for r in answers] == [200, 200, 200, 401, 404, 422, 413, 200, 200, 404]
    for r in answers:
        assert r.headers["x-content-type-options"] == "nosniff", r.url
        assert r.headers["content-security-policy"] == API_CSP, r.url
    # The bare API has no docs page: the dashboard serves it with local files.
    assert (await live.client.get("/docs")).status_code == 404


# -- numbers are numbers ---------------------------------------------------------------------


def _axis(**change: Any) -> dict[str, Any]:
    return {**STRENGTH, "axes": [{**STRENGTH["axes"][0], **change}]}


@pytest.mark.asyncio
@pytest.mark.parametrize(
    ("body", "loc"),
    [
        (_axis(stiffness=True), ["body", "axes", 0, "stiffness"]),
        (_axis(stiffness="40"), ["body", "axes", 0, "stiffness"]),
        (_axis(damping=False), ["body", "axes", 0, "damping"]),
        (_axis(damping="2.0"), ["body", "axes", 0, "damping"]),
        (_axis(center="5"), ["body", "axes", 0, "center"]),
        (_axis(rom_high=True), ["body", "axes", 0, "rom_high"]),
        ({**STRENGTH, "sets": True}, ["body", "sets"]),
        ({**STRENGTH, "repetitions": "10"}, ["body", "repetitions"]),
        ({**STRENGTH, "repetitions": 10.0}, ["body", "repetitions"]),
        ({**STRENGTH, "repetition_s": "6"}, ["body", "repetition_s"]),
        ({**STRENGTH, "rest_s": True}, ["body", "rest_s"]),
        ({**STRENGTH, "torque_limit": "60"}, ["body", "torque_limit"]),
        ({**STRENGTH, "sessions_per_week": "5"}, ["body", "sessions_per_week"]),
    ],
)
async def test_a_clinicians_number_sent_as_text_or_boolean_is_refused(
    live: Live, world: World, body: dict[str, Any], loc: list[str | int]
) -> None:
    t1 = bearer(world.t1)
    r = await live.client.post(f"/patients/{world.p1}/prescriptions", json=body, headers=t1)
    assert r.status_code == 422, r.text
    assert [e["loc"] for e in r.json()["detail"]] == [loc]
    r = await live.client.get(f"/patients/{world.p1}/prescriptions", headers=t1)
    assert len(r.json()) == 1  # the seeded one only


@pytest.mark.asyncio
async def test_integers_are_numbers_and_the_bounds_and_messages_are_kept(
    live: Live, world: World
) -> None:
    t1 = bearer(world.t1)
    url = f"/patients/{world.p1}/prescriptions"
    r = await live.client.post(url, json=_axis(stiffness=40, damping=2), headers=t1)
    assert r.status_code == 201, r.text
    assert r.json()["body"]["axes"][0]["stiffness"] == 40.0
    r = await live.client.post(url, json=_axis(stiffness=900.0), headers=t1)
    (error,) = r.json()["detail"]
    assert (r.status_code, error["msg"]) == (
        422,
        "Stiffness K on pitch must be at most 500 N·m/rad (8.73 N·m/°).",
    )
    assert (error["type"], error["ctx"]) == ("less_than_equal", {"le": 500.0})
    r = await live.client.post(url, json=_axis(damping=0.0, stiffness=400.0), headers=t1)
    (error,) = r.json()["detail"]
    assert r.status_code == 422 and error["loc"] == ["body", "axes", 0, "damping"]
    least = SafetyLimits().damping_min_at(4, 400.0)  # pitch, as the device publishes it
    assert error["msg"].startswith(f"Damping B on pitch must be at least {least:g} N·m·s/rad")
