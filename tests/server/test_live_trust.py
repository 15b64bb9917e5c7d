"""Live links follow their credentials: when trust ends, the open link ends within a second,
with the close code that says why (``sessions.wire.CLOSE_*``).

A real uvicorn on a private copy of the seeded database and raw ``websockets`` clients, as a
browser and a station would hold them. Each test also checks that the link was open and
streaming before the change, so a link refused from the start cannot pass.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest
from sqlalchemy import update
from websockets.asyncio.client import ClientConnection

from server.config import Settings
from server.models import Patient, User
from sessions import wire
from tests.server.live_server import PASSWORD, Live, World, bearer, copy_seeded, login, running
from tests.server.ws_client import close_of, closed_with, station_ws, viewer_ws, welcomed

CLOSE_WITHIN_S = 1.0
"""What the issue asks: the link is gone within a second of the change."""


async def _still_open(ws: ClientConnection, seconds: float = 0.3) -> None:
    assert await close_of(ws, seconds) is None, "the link closed before anything changed"


@pytest.mark.asyncio
async def test_logout_closes_the_views_opened_with_that_login_only(
    live: Live, world: World
) -> None:
    token = await login(live.client, "t1@clinic.test")
    async with (
        viewer_ws(live, token, world.s1_id) as ended,
        viewer_ws(live, world.t1, world.s1_id) as other,
    ):
        await _still_open(ended)
        began = time.monotonic()
        r = await live.client.post("/auth/logout", headers=bearer(token))
        assert r.status_code == 204, r.text
        code, reason = await closed_with(ended, timeout=CLOSE_WITHIN_S)
        assert time.monotonic() - began <= CLOSE_WITHIN_S
        assert code == wire.CLOSE_SIGNED_OUT, (code, reason)
        assert "sign in again" in reason
        # The same therapist's other login keeps its view.
        await _still_open(other)


@pytest.mark.asyncio
async def test_a_view_closes_when_its_sign_in_expires(
    seeded: tuple[Path, World], tmp_path: Path
) -> None:
    template, world = seeded
    settings = Settings(data_dir=copy_seeded(template, tmp_path), token_ttl_s=2)
    async with running(settings) as live:
        r = await live.client.post(
            "/auth/login", json={"email": "t1@clinic.test", "password": PASSWORD}
        )
        assert r.status_code == 200, r.text
        token = r.json()["access_token"]
        opened = time.monotonic()
        async with viewer_ws(live, token, world.s1_id) as ws:
            await _still_open(ws, 0.5)
            code, reason = await closed_with(ws, timeout=2 + CLOSE_WITHIN_S)
            assert code == wire.CLOSE_EXPIRED, (code, reason)
            assert "expired" in reason
            # Not before its time: the login lasted its 2 s less the login's own round trip.
            assert time.monotonic() - opened >= 1.0


@pytest.mark.asyncio
async def test_a_revoked_station_link_closes_at_once(live: Live, world: World) -> None:
    async with station_ws(live, world.s1) as ws:
        await welcomed(ws)
        await _still_open(ws)
        r = await live.client.post(f"/stations/{world.s1_id}/revoke", headers=bearer(world.t1))
        assert r.status_code == 200, r.text
        code, _ = await closed_with(ws, timeout=CLOSE_WITHIN_S)
        assert code == wire.CLOSE_REVOKED


@pytest.mark.asyncio
@pytest.mark.parametrize(
    ("change", "code"),
    [("deactivate", wire.CLOSE_DEACTIVATED), ("reassign", wire.CLOSE_NO_ACCESS)],
)
async def test_a_change_made_in_the_database_is_caught_by_the_periodic_recheck(
    seeded: tuple[Path, World], tmp_path: Path, change: str, code: int
) -> None:
    """Changes that bypass this process (a database edit, another server) are caught by the
    background re-check, here every 0.3 s."""
    template, world = seeded
    settings = Settings(data_dir=copy_seeded(template, tmp_path), live_recheck_s=0.3)
    async with running(settings) as live, viewer_ws(live, world.t1, world.s1_id) as ws:
        await _still_open(ws, 0.5)
        async with live.sessionmaker() as db:
            if change == "deactivate":
                await db.execute(update(User).where(User.id == world.t1_id).values(active=False))
            else:
                await db.execute(
                    update(Patient).where(Patient.id == world.p1).values(therapist_id=world.t2_id)
                )
            await db.commit()
        got, reason = await closed_with(ws, timeout=0.3 + CLOSE_WITHIN_S + 2.0)
        assert got == code, (got, reason)


@pytest.mark.asyncio
async def test_rechecks_in_a_burst_share_passes_and_close_each_link_once(
    live: Live, world: World
) -> None:
    """Fifty concurrent re-checks (a burst of logouts) leave the good links open."""
    async with (
        viewer_ws(live, world.t1, world.s1_id) as a,
        viewer_ws(live, world.admin, world.s2_id) as b,
    ):
        await asyncio.gather(*(live.app.state.hub.recheck() for _ in range(50)))
        await _still_open(a)
        await _still_open(b)
