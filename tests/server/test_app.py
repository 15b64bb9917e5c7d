"""The application as a whole: its data survives a restart; its OpenAPI is a usable document."""

from __future__ import annotations

import shutil
import subprocess
import sys
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


GC_PROBE = """
import asyncio, gc, sys
from server.app import GC_YOUNG_THRESHOLD, create_app
from server.config import Settings
from tests.server.live_server import running

async def main() -> None:
    async with running(Settings(data_dir=sys.argv[1], gc_freeze=sys.argv[2] == "on")):
        print(gc.get_freeze_count(), gc.get_threshold()[0], GC_YOUNG_THRESHOLD)

asyncio.run(main())
"""


@pytest.mark.parametrize("freeze", ["on", "off"])
def test_a_started_server_freezes_its_start_up_out_of_the_collectors_reach(
    tmp_path: Path, freeze: str
) -> None:
    """In a process of its own: the freeze is for the whole interpreter, and this one runs
    hundreds of servers (tests/conftest.py turns it off here)."""
    root = Path(__file__).resolve().parents[2]
    done = subprocess.run(
        [sys.executable, "-c", GC_PROBE, str(tmp_path), freeze],
        capture_output=True,
        text=True,
        cwd=root,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    frozen, young, wanted = (int(v) for v in done.stdout.split())
    if freeze == "on":
        assert frozen > 10_000 and young == wanted  # modules, routes, tables, the hub
    else:
        assert frozen == 0 and young == 700  # CPython's own
