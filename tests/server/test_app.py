"""The application as a whole: its data survives a restart; its OpenAPI is a usable document."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from server.config import Settings
from tests.server.live_server import Live, World, bearer, running


@pytest.mark.asyncio
async def test_data_and_logins_survive_a_restart(
    seeded: tuple[Path, World], tmp_path: Path
) -> None:
    template, world = seeded
    for f in template.glob("ankle.db*"):
        shutil.copy(f, tmp_path / f.name)
    t1 = bearer(world.t1)
    async with running(Settings(data_dir=tmp_path)) as first:
        r = await first.client.post("/patients", json={"display_name": "Persistent"}, headers=t1)
        patient = r.json()
    async with running(Settings(data_dir=tmp_path)) as second:
        r = await second.client.get(f"/patients/{patient['id']}", headers=t1)
        assert r.json() == patient
        health = (await second.client.get("/health")).json()
        assert health["status"] == "ok" and health["database"] is True


@pytest.mark.asyncio
async def test_two_servers_on_two_data_dirs_do_not_share_anything(
    tmp_path: Path, live: Live, world: World
) -> None:
    async with running(Settings(data_dir=tmp_path / "other")) as other:
        r = await other.client.get("/patients", headers=bearer(world.t1))
        assert r.status_code == 401


@pytest.mark.asyncio
async def test_openapi_documents_every_operation(empty: Live) -> None:
    spec = (await empty.client.get("/openapi.json")).json()
    for path, item in spec["paths"].items():
        for method, op in item.items():
            assert op.get("summary"), f"{method} {path} has no summary"
            assert op.get("tags"), f"{method} {path} has no tag"
            if path.startswith("/api/v1/") and path != "/api/v1/health":
                assert "401" in op["responses"] or "security" not in op, (method, path)
    schemas = spec["components"]["schemas"]
    stiffness = schemas["AxisPrescription"]["properties"]["stiffness"]
    assert "N·m/rad" in stiffness["description"] and "maximum" in stiffness
    assert {"UserToken", "StationToken"} <= set(spec["components"]["securitySchemes"])
