"""The live page on one server process, its station on another: what it shows when its
process loses the relay (Redis) and gets it back, and when the station's process never
answers a HOLD.

The two servers (dashboards on one SQLite file and a real Redis) and a raw station link run
in an event loop of their own, in a thread: Playwright's sync API holds this thread's.
"""

from __future__ import annotations

import asyncio
import json
import re
import threading
import time
from collections.abc import Callable, Coroutine, Iterator
from contextlib import AsyncExitStack, ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import httpx
import pytest
import redis
from playwright.sync_api import Page, expect

from server.config import Settings
from server.hub import RELAY_LOST
from sessions import wire
from tests.browser.clinic import API
from tests.server.live_server import PASSWORD, Live, World, copy_seeded, running, seeded
from tests.server.redis_server import free_port, spawned_redis
from tests.server.ws_client import station_ws, telemetry, welcomed
from webui.app import create_app

__all__ = ["seeded"]  # a fixture shared with the server tests

T = TypeVar("T")
START_S = 60.0


class Loop:
    """An event loop running in a thread of its own."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()

    def run(self, coroutine: Coroutine[Any, Any, T]) -> T:
        return asyncio.run_coroutine_threadsafe(coroutine, self.loop).result(START_S)

    def stop(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()


@dataclass
class Apart:
    """The therapist's server (``url``), the station's, and the Redis between them."""

    url: str
    world: World
    redis_url: str
    redis_port: int
    redis: ExitStack
    """Closed, Redis is stopped; a new one may be entered in its place."""
    stop_viewing: Callable[[], None]
    """Stop the therapist's server (the page loses its server; the station streams on)."""
    start_viewing: Callable[[], None]
    """Start it again on the same port."""
    status_changes: dict[str, Any]
    """Fields the station's next statuses carry in place of an unheld exercise's."""


async def exercising(ws: Any, changes: dict[str, Any]) -> None:
    """A station running an exercise: its status (with ``changes``, which a test may make
    while it runs) every second, telemetry 25 times."""
    status = wire.StatusMsg(
        sent=time.time(),
        device_link="connected",
        device_mode="ACTIVE",
        phase="running",
        exercise="strength",
        sets=2,
        repetitions=4,
        set=1,
        rep=2,
    )
    n = 0
    while True:
        if n % 25 == 0:
            now = status.model_copy(update={**changes, "sent": time.time()})
            await ws.send(now.model_dump_json())
        await ws.send(json.dumps(telemetry(t=n * 0.04, mode="ACTIVE")))
        n += 1
        await asyncio.sleep(0.04)


@pytest.fixture
def apart(seeded: tuple[Path, World], tmp_path: Path) -> Iterator[Apart]:
    world = seeded[1]
    data_dir = copy_seeded(seeded[0], tmp_path / "data")
    redis_port, port = free_port(), free_port()
    loop = Loop()
    stack = AsyncExitStack()
    viewer = AsyncExitStack()  # the therapist's server, stopped and started on its own
    changes: dict[str, Any] = {}
    stack.push_async_exit(viewer)
    with ExitStack() as first:
        _, url = first.enter_context(spawned_redis(tmp_path / "redis", redis_port))
        base = Settings(data_dir=data_dir, relay_url=f"{url}/0", relay_lease_s=1.5)
        viewing = base.model_copy(update={"allowed_origins": [f"http://127.0.0.1:{port}"]})

        async def start_viewing() -> None:
            await viewer.enter_async_context(running(viewing, create_app, port))

        async def start() -> None:
            await start_viewing()
            b: Live = await stack.enter_async_context(running(base, create_app))
            ws = await stack.enter_async_context(station_ws(b, world.s1))
            await welcomed(ws)
            streaming = asyncio.create_task(exercising(ws, changes))
            stack.callback(streaming.cancel)

        try:
            loop.run(start())
            yield Apart(
                f"http://127.0.0.1:{port}",
                world,
                f"{url}/0",
                redis_port,
                first,
                stop_viewing=lambda: loop.run(viewer.aclose()),
                start_viewing=lambda: loop.run(start_viewing()),
                status_changes=changes,
            )
        finally:
            loop.run(stack.aclose())
            loop.stop()


def sign_in(page: Page) -> None:
    page.get_by_label("Email").fill("t1@clinic.test")
    page.get_by_label("Password").fill(PASSWORD)
    page.get_by_role("button", name="Sign in").click()


def open_live(page: Page, apart: Apart, station_id: int) -> None:
    page.add_init_script("localStorage.setItem('ankle.live.scene', 'off')")  # not tested here
    page.goto(f"{apart.url}/app/live/{station_id}")
    if page.get_by_label("Email").count():
        sign_in(page)
    expect(page).to_have_url(f"{apart.url}/app/live/{station_id}")


def test_the_live_page_says_when_its_server_lost_the_station_s_server(
    page: Page, apart: Apart, tmp_path: Path
) -> None:
    open_live(page, apart, apart.world.s1_id)
    expect(page.locator("#st-link")).to_have_text("station online")
    expect(page.locator("#st-doing")).to_have_text("exercising")
    expect(page.locator("#st-mode")).to_have_text("ACTIVE")

    apart.redis.close()  # Redis gone: this page's server cannot reach the station's
    expect(page.locator("#st-link")).to_have_text("station not reachable")
    expect(page.locator("#st-doing")).to_have_text(f"unknown: {RELAY_LOST}")
    expect(page.locator("#st-mode")).to_have_text("–")
    page.get_by_role("button", name="HOLD").click()
    # In words (the code stays in data-code for programs), never "refused, OFFLINE:".
    expect(page.locator("#ack")).to_contain_text("HOLD: not done: this server cannot")
    expect(page.locator("#ack")).to_have_attribute("data-code", "OFFLINE")

    apart.redis.enter_context(spawned_redis(tmp_path / "redis", apart.redis_port))
    expect(page.locator("#st-link")).to_have_text("station online")
    expect(page.locator("#st-doing")).to_have_text("exercising")
    expect(page.locator("#st-mode")).to_have_text("ACTIVE")


def test_the_live_page_says_when_the_station_s_server_never_answers(
    page: Page, apart: Apart
) -> None:
    """The spare station is named held by a server process that never answers (as one that
    died is until its lease runs out): the HOLD ends in TIMEOUT, not "waiting" for good."""
    station_id = apart.world.s1_spare_id
    with redis.Redis.from_url(apart.redis_url) as client:
        client.set(f"ankle:station:{station_id}", "a-process-that-died", px=120_000)
    open_live(page, apart, station_id)
    expect(page.locator("#st-link")).to_have_text("station online")
    page.get_by_role("button", name="HOLD").click()
    expect(page.locator("#ack")).to_contain_text(
        "HOLD: no answer: the station's server did not answer within 3 s"
    )


def test_the_live_page_says_what_is_unknown_when_it_loses_its_server(
    page: Page, apart: Apart
) -> None:
    """Cut off from its server, the page shows the patient's state as unknown, with the last
    known and when, not "exercising" and ACTIVE as if they were news; back, as it is now."""
    open_live(page, apart, apart.world.s1_id)
    doing, mode = page.locator("#st-doing"), page.locator("#st-mode")
    expect(doing).to_have_text("exercising")
    expect(mode).to_have_text("ACTIVE")

    apart.stop_viewing()
    expect(page.locator("#st-link")).to_contain_text("server connection lost")
    expect(doing).to_have_text(
        re.compile(
            r"^unknown: the connection to the server is lost "
            r"\(last known at \d{1,2}:\d{2}:\d{2}(\s?[AP]M)?: exercising\)$"
        )
    )
    expect(mode).to_have_text("–")
    expect(page.locator("#st-pose")).to_have_text("–")

    apart.start_viewing()  # the page tries again by itself, within 10 s
    expect(doing).to_have_text("exercising", timeout=30_000)
    expect(mode).to_have_text("ACTIVE")


def test_the_live_k_and_b_form_refuses_what_the_browser_cannot_read(
    page: Page, apart: Apart
) -> None:
    """A K typed past the largest number (1e400) reads as an empty field: it is refused
    beside the field, not dropped while B alone is sent; a refusal clears the line that
    answered the form before."""
    open_live(page, apart, apart.world.s1_id)
    expect(page.locator("#st-link")).to_have_text("station online")
    form, ack = page.locator("#kb-form"), page.locator("#kb-ack")

    form.get_by_role("button", name="Send change").click()
    expect(ack).to_have_text("Enter a stiffness or damping to send.")
    k = page.get_by_label("pitch stiffness K, N·m/rad")
    k.click()
    page.keyboard.type("1e400")
    page.get_by_label("pitch damping B, N·m·s/rad").fill("3")
    form.get_by_role("button", name="Send change").click()
    expect(page.locator('[data-error-for="stiffness.pitch"]')).to_contain_text("from 0 to 500")
    expect(k).to_have_attribute("aria-invalid", "true")
    expect(ack).to_have_text("")  # not "sent, waiting for the device…": nothing was sent


def test_signed_out_the_live_page_says_so_clears_the_stale_state_and_offers_sign_in(
    page: Page, apart: Apart, shots: Path
) -> None:
    """Signed out from elsewhere (the page's token, POST /auth/logout): the page said "server
    connection lost" and "the connection to the server is lost", kept the red "Held for ..."
    banner counting as if current, and left HOLD, Resume, Stop, Start and Send enabled to
    answer "not sent, the connection to the server is down", with no way to sign in again."""
    apart.status_changes["hold"] = wire.HoldInfo(
        code="therapist",
        text="the therapist pressed HOLD",
        by="therapist:1",
        since=time.time(),
        patient_may_resume=False,
    )
    open_live(page, apart, apart.world.s1_id)
    banner, trip = page.locator("#why"), page.locator("#st-trip")
    expect(banner).to_contain_text("Held for")
    expect(trip).to_have_text("held: the therapist pressed HOLD")  # not "none; held: ..."
    buttons = [
        page.get_by_role("button", name=name, exact=True)
        for name in ("HOLD", "Resume", "Stop exercise", "Start", "Send change")
    ]
    for button in buttons:
        expect(button).to_be_enabled()

    token = page.evaluate("sessionStorage.getItem('ankle.token')")
    r = httpx.post(f"{apart.url}{API}/auth/logout", headers={"Authorization": f"Bearer {token}"})
    assert r.status_code == 204, r.text
    expect(page.locator("#st-link")).to_have_text("signed out")
    expect(page.locator("#st-doing")).to_have_text("unknown: signed out")
    expect(banner).to_be_hidden()
    expect(trip).to_have_text("–")
    for stale in ("#st-mode", "#st-exercise", "#st-uploads", "#kb-now-pitch"):
        expect(page.locator(stale)).to_have_text("–")
    for button in buttons:
        expect(button).to_be_disabled()
    expect(page.get_by_label("pitch stiffness K, N·m/rad")).to_be_disabled()
    expect(page.locator("#page-error")).to_contain_text("You were signed out.")
    page.wait_for_timeout(2000)  # the page's once-a-second refresh must not bring them back
    expect(banner).to_be_hidden()
    expect(page.locator("#st-link")).to_have_text("signed out")
    page.screenshot(path=str(shots / "live-signed-out.png"), full_page=True)

    page.get_by_role("link", name="Sign in again").click()
    sign_in(page)
    expect(page).to_have_url(f"{apart.url}/app/live/{apart.world.s1_id}")
    expect(page.locator("#st-link")).to_have_text("station online")
    expect(banner).to_contain_text("Held for")
    for button in buttons:
        expect(button).to_be_enabled()
