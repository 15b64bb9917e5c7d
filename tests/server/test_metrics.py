"""/metrics over real HTTP: who may read it, and that the numbers follow what happened.

A real uvicorn on the seeded database, the live links of ``test_live_audit`` (a raw station
that answers commands, a raw viewer that sends them).
"""

from __future__ import annotations

import re
from pathlib import Path

import httpx
import pytest
from pydantic import SecretStr

from server.config import Settings
from sessions import wire
from tests.server.live_server import Live, World, copy_seeded, running
from tests.server.test_live_audit import ack, station, vector, viewer

pytestmark = pytest.mark.asyncio


def sample(text: str, name: str, **labels: str) -> float:
    """The value of one series in Prometheus text, 0 if it is not there."""
    total = 0.0
    for line in text.splitlines():
        if not line.startswith(name + "{") and not line.startswith(name + " "):
            continue
        found = dict(re.findall(r'(\w+)="([^"]*)"', line.split(" ")[0]))
        if all(found.get(k) == v for k, v in labels.items()):
            total += float(line.rsplit(" ", 1)[1])
    return total


async def scrape(live: Live, **headers: str) -> httpx.Response:
    base = live.client.base_url.copy_with(path="/")
    async with httpx.AsyncClient(base_url=base) as client:
        return await client.get("/metrics", headers=headers)


async def test_requests_database_links_messages_and_commands_are_counted(
    live: Live, world: World
) -> None:
    before = (await scrape(live)).text
    assert (await live.client.get("/health")).status_code == 200
    await live.client.get("/patients/999999", headers={"Authorization": "Bearer x"})
    async with (
        station(live, world, ack, stiffness=vector(pitch=40.0)) as _,
        viewer(live, world.t1, world.s1_id) as v,
    ):
        await v.next_of(wire.TelemetryBatch)
        await v.send("m-hold", "hold")
        assert (await v.next_of(wire.CommandResult, "m-hold")).ok
        during = await scrape(live)
    assert during.status_code == 200
    assert during.headers["content-type"].startswith("text/plain")
    after = during.text
    route = {"method": "GET", "route": "/api/v1/health", "status": "200"}
    assert sample(after, "ankle_http_requests_total", **route) == (
        sample(before, "ankle_http_requests_total", **route) + 1
    )
    # a route's template, never the path with its id
    assert sample(after, "ankle_http_requests_total", route="/api/v1/patients/{patient_id}") >= 1
    assert "/patients/999999" not in after
    assert sample(after, "ankle_db_statement_seconds_count") > sample(
        before, "ankle_db_statement_seconds_count"
    )
    assert sample(after, "ankle_live_stations") == 1
    assert sample(after, "ankle_live_viewers") == 1
    assert sample(after, "ankle_live_messages_total", direction="in", peer="station") >= 1
    assert sample(after, "ankle_live_messages_total", direction="in", peer="viewer") >= 1
    assert sample(after, "ankle_live_messages_total", direction="out", peer="viewer") >= 1
    rtt = {"action": "hold", "outcome": "accepted"}
    assert sample(after, "ankle_live_command_round_trip_seconds_count", **rtt) == (
        sample(before, "ankle_live_command_round_trip_seconds_count", **rtt) + 1
    )


async def test_a_client_the_proxy_forwards_is_not_loopback(live: Live) -> None:
    # uvicorn trusts X-Forwarded-For from 127.0.0.1, as it does behind the reverse proxy
    r = await scrape(live, **{"X-Forwarded-For": "203.0.113.9"})
    assert r.status_code == 403
    assert "ANKLE_METRICS_TOKEN" in r.json()["detail"]


@pytest.mark.parametrize(
    ("header", "status"),
    [(None, 401), ("Bearer wrong", 401), ("Basic s3cret-token", 401), ("Bearer s3cret-token", 200)],
)
async def test_with_a_token_only_its_bearer_reads_metrics(
    seeded: tuple[Path, World], tmp_path: Path, header: str | None, status: int
) -> None:
    template, _ = seeded
    settings = Settings(
        data_dir=copy_seeded(template, tmp_path), metrics_token=SecretStr("s3cret-token")
    )
    async with running(settings) as live:
        headers = {"X-Forwarded-For": "203.0.113.9"}  # from afar: only the token counts
        if header is not None:
            headers["Authorization"] = header
        r = await scrape(live, **headers)
        assert r.status_code == status, r.text
        if status == 200:
            assert "ankle_http_requests_total" in r.text


async def test_made_up_methods_and_paths_add_no_series(live: Live) -> None:
    """A request line may carry any token as its method and any path: the labels must not.
    20,000 made-up methods (no token needed) once made 20,000 series, a 38 MB scrape that
    blocked the event loop 4 s; each now counts as ``other``, each path no route matched as
    ``unmatched``."""
    before = (await scrape(live)).text
    series_before = before.count("ankle_http_requests_total{")
    for i in range(40):
        r = await live.client.request(f"X{i:04d}Q", "/health")
        assert r.status_code == 405
        r = await live.client.get(f"/no-such-route-{i}")
        assert r.status_code == 404
    after = (await scrape(live)).text
    assert "X0001Q" not in after and "no-such-route" not in after
    other = {"method": "other", "route": "/api/v1/health", "status": "405"}
    assert sample(after, "ankle_http_requests_total", **other) == 40
    unmatched = {"method": "GET", "route": "unmatched", "status": "404"}
    assert sample(after, "ankle_http_requests_total", **unmatched) == (
        sample(before, "ankle_http_requests_total", **unmatched) + 40
    )
    # A few new series (those two, the scrape's own), not one per request.
    assert after.count("ankle_http_requests_total{") - series_before <= 3
