"""The therapist's live view in a real browser against the real system.

Sign in, open the demo station's live page, start the demo exercise from it, and see: what
the patient is doing first, the engineering detail under a closed "Technical" disclosure
that remembers being opened, telemetry moving the charts and the 3D view (the viser scene's
platform pose changes), the 3D card collapsing when turned off (remembered too), a K change
acknowledged by the device and then in force, and one made during HOLD that says it applies
on Resume and is in force after it.
"""

from __future__ import annotations

import io
import re
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from PIL import Image
from playwright.sync_api import Page, ViewportSize, expect

from server.cli import demo_prescription
from tests.browser import rest
from tests.browser.a11y import assert_controls_labelled
from tests.system.harness import STACKS, System

SHOT_MS = 60_000
"""Screenshots of the live page, whose 3D view is WebGL drawn in software by headless
chromium: on a busy machine (the whole suite on two cores) one took over the default 15 s."""


def sign_in(page: Page, system: System, path: str) -> None:
    page.goto(f"{system.url}{path}")
    page.get_by_label("Email").fill(system.creds["therapist_email"])
    page.get_by_label("Password").fill(system.creds["therapist_password"])
    page.get_by_role("button", name="Sign in").click()
    expect(page).to_have_url(f"{system.url}{path}", timeout=30_000)


def therapist_token(system: System) -> str:
    r = rest.post(
        f"{system.url}/api/v1/auth/login",
        json={
            "email": system.creds["therapist_email"],
            "password": system.creds["therapist_password"],
        },
    )
    r.raise_for_status()
    return str(r.json()["access_token"])


def scene(system: System, token: str) -> dict[str, object]:
    r = rest.get(
        f"{system.url}/api/v1/stations/{system.station_id}/scene",
        headers={"Authorization": f"Bearer {token}"},
    )
    r.raise_for_status()
    body: dict[str, object] = r.json()
    return body


def dark_share(png: bytes) -> float:
    """The share of the middle of a screenshot that is darker than light grey."""
    image = Image.open(io.BytesIO(png)).convert("L")
    w, h = image.size
    middle = image.crop((w // 4, h // 3, 3 * w // 4, 5 * h // 6))
    counts = middle.histogram()  # pixels per grey level
    return sum(counts[:150]) / sum(counts)


SCREEN_S = 90.0
"""How long the 3D view may take to show a pose on screen: each screenshot of it waits for
software WebGL, several seconds apiece while the whole suite loads two cores."""

BROWSER_SCENE = """() => {
    const viewer = window.__viserMutable;
    const platform = viewer?.nodeRefFromName?.["/platform"];
    const canvas = viewer?.canvas;
    const gl = canvas?.getContext("webgl2");
    return {
        platform: platform ? [...platform.quaternion.toArray(), ...platform.position.toArray()]
            : null,
        queued: viewer?.messageQueue?.length ?? null,
        webgl_lost: gl ? gl.isContextLost() : null,
        visibility: document.visibilityState,
    };
}"""
"""What viser's client in the 3D view's frame holds (it publishes its state for tests): the
platform as three.js draws it (quaternion and position), messages not yet applied, whether
the WebGL context was lost."""


def browser_scene(page: Page) -> dict[str, object]:
    handle = page.locator("#scene").element_handle()
    frame = handle.content_frame() if handle is not None else None
    assert frame is not None, "the 3D view's frame is not loaded"
    state: dict[str, object] = frame.evaluate(BROWSER_SCENE)
    return state


def status(page: Page) -> str:
    """What the page says about the device, for a failure's message: the mode, what the
    patient is doing, and the why-banner (a hold's or fault's reason, and since when)."""
    parts = {
        "mode": "#st-mode",
        "doing": "#st-doing",
        "why": "#why",
        "station": "#st-message",
        "ack": "#ack",
    }
    return "; ".join(f"{k} {page.locator(css).inner_text()!r}" for k, css in parts.items())


def watchdog_held(page: Page) -> bool:
    """The device held because the station's frames stopped for longer than its watchdog: on
    a loaded machine this can happen to a station nothing is wrong with."""
    why = page.locator("#st-trip").inner_text()
    held = page.locator("#st-mode").inner_text() == "HOLD"
    return held and "the device's watchdog held the platform" in why


def wait_for(
    page: Page,
    done: Callable[[], bool],
    what: str,
    timeout: float = 30.0,
    account: Callable[[], str] | None = None,
) -> None:
    """Wait until ``done()``, resuming (at most three times) a hold by the device's watchdog;
    fail with ``what``, the page's account of the device and ``account()`` if given. Any
    other hold, a fault or an end fails at the deadline with its reason in the message."""
    deadline = time.monotonic() + timeout
    resumed = 0
    while not done():
        if time.monotonic() >= deadline:
            more = f"; {account()}" if account is not None else ""
            pytest.fail(f"{what} within {timeout:g} s: {status(page)}{more}")
        if watchdog_held(page) and resumed < 3:
            resumed += 1
            print(f"resuming a hold by the watchdog: {status(page)}")  # shown if the test fails
            page.get_by_role("button", name="Resume").click()
            expect(page.locator("#st-mode")).not_to_have_text("HOLD", timeout=10_000)
        page.wait_for_timeout(200)


def hold_mid_repetition(page: Page, tries: int = 3) -> None:
    """Press HOLD until it lands in a repetition and the device holds. Each repetition is a
    segment of its own: a HOLD that lands between two (the device READY at home, on a busy
    machine for up to a second while the station sends the next) holds the exercise back,
    "held" and READY, with nothing for the device to hold; the therapist resumes and holds
    again."""
    mode = page.locator("#st-mode")
    for _ in range(tries):
        page.get_by_role("button", name="HOLD").click()
        expect(page.locator("#ack")).to_contain_text("HOLD: acknowledged by the device")
        expect(mode).to_have_text(re.compile("^(HOLD|READY)$"))
        if mode.inner_text() == "HOLD":
            return
        expect(page.locator("#st-doing")).to_contain_text("held")  # the run waits
        print(f"HOLD landed between two repetitions: {status(page)}")  # shown on failure
        page.get_by_role("button", name="Resume").click()
        expect(page.locator("#ack")).to_contain_text("Resume: acknowledged by the device")
        expect(mode).to_have_text("ACTIVE")
    pytest.fail(f"HOLD never landed in a repetition in {tries} tries: {status(page)}")


def long_prescription(system: System, token: str) -> int:
    """The demo strength exercise with 30 repetitions (3 min): long enough to watch and
    adjust. 10 (60 s) ended before the test's HOLD on a busy machine, where software WebGL
    screenshots and watchdog holds had taken the minute."""
    auth = {"Authorization": f"Bearer {token}"}
    body = demo_prescription().model_dump(mode="json") | {"repetitions": 30, "title": "Live test"}
    r = rest.post(
        f"{system.url}/api/v1/patients/{system.creds['patient_id']}/prescriptions",
        json=body,
        headers=auth,
    )
    assert r.status_code == 201, r.text
    return int(r.json()["id"])


# On both stacks: with two server processes the page and its 3D view are on the process the
# station is not connected to.
@pytest.mark.parametrize("stack", STACKS, indirect=True, ids=STACKS)
def test_live_view_start_watch_change_k_and_hold(system: System, page: Page, shots: Path) -> None:
    # While its 3D view draws (software WebGL) the page answers late on a loaded machine:
    # its actions (a click, a choice in a list) wait as long as its screenshots.
    page.set_default_timeout(SHOT_MS)
    token = therapist_token(system)
    rx = long_prescription(system, token)
    system.start_station()
    sign_in(page, system, f"/app/live/{system.station_id}")
    expect(page.locator("#st-link")).to_have_text("station online", timeout=30_000)
    expect(page.locator("#st-device")).to_have_text("connected", timeout=60_000)

    # The 3D view loads first: its client is the page's heaviest part.
    frame = page.frame_locator("#scene")
    expect(frame.locator("canvas").first).to_be_visible(timeout=30_000)

    # Start the prescription from the page.
    page.get_by_label("Prescription to start").select_option(str(rx))
    page.get_by_role("button", name="Start", exact=True).click()
    expect(page.locator("#st-link")).to_have_text("station online")
    expect(page.locator("#ack")).to_contain_text("Start: accepted", timeout=30_000)

    # Clinical status first; the engineering detail waits, closed, under "Technical".
    def exercising() -> bool:
        return page.locator("#st-mode").inner_text() == "ACTIVE" and bool(
            re.fullmatch("exercising|resting.*", page.locator("#st-doing").inner_text())
        )

    wait_for(page, exercising, "the platform ACTIVE and the patient exercising")
    expect(page.locator("#st-pose")).to_have_text(re.compile(r"^pitch -?\d+\.\d°$"))
    expect(page.locator("#st-torque")).to_have_text(re.compile(r"^pitch -?\d+\.\d N·m$"))
    technical = page.locator("#technical")
    expect(technical).not_to_have_attribute("open", re.compile(".*"))
    for detail in ("#st-overruns", "#st-frames", "#st-rate", "#chart-pressure"):
        expect(page.locator(detail)).to_be_hidden()
    page.screenshot(path=shots / "live-technical-closed.png", full_page=True, timeout=SHOT_MS)
    technical.locator("summary").click()
    expect(page.locator("#st-overruns")).to_be_visible()
    expect(page.locator("#st-scene")).to_contain_text("through this server")
    pressure = page.locator("#chart-pressure canvas")
    expect(pressure).to_be_visible()
    box = pressure.bounding_box()
    assert box is not None and box["width"] > 300, box  # sized when opened, not at 0 width

    # Telemetry arrives at the live view's rate and moves the charts.
    expect(page.locator("#st-rate")).to_have_text(
        re.compile(r"^([3-9]\d|\d{3,}) samples/s$"), timeout=10_000
    )
    chart = page.locator("#chart-angle canvas")
    before = chart.screenshot()
    # Each wait resumes a hold by the device's watchdog (a host stall of 200 ms on a busy
    # machine): a held platform stands still, and so do the charts and the 3D view.
    wait_for(page, lambda: chart.screenshot() != before, "the angle chart did not move")

    # The 3D view: the scene's platform pose follows telemetry, and the browser draws it.
    first = scene(system, token)

    def moved() -> bool:
        second = scene(system, token)
        return int(str(second["updates"])) > int(str(first["updates"])) + 10 and (
            first["platform_wxyz"],
            first["platform_position"],
        ) != (second["platform_wxyz"], second["platform_position"])

    wait_for(page, moved, "the scene's platform did not follow telemetry")
    # In the browser: the 3D client applies the poses it receives to the platform it draws...
    iframe = page.locator("#scene")
    held = browser_scene(page)
    assert held["platform"] is not None and held["webgl_lost"] is False, held
    wait_for(
        page,
        lambda: browser_scene(page)["platform"] != held["platform"],
        "the browser's 3D view did not receive the platform's poses",
        account=lambda: f"{browser_scene(page)}",
    )
    # ...and they change what is on screen.
    shots_taken: list[str] = []

    def redrawn() -> bool:
        t0 = time.monotonic()
        changed = iframe.screenshot(timeout=SHOT_MS) != pixels
        shots_taken.append(f"{time.monotonic() - t0:.1f} s")
        return changed

    pixels = iframe.screenshot(timeout=SHOT_MS)
    wait_for(
        page,
        redrawn,
        "the 3D view did not change on screen",
        timeout=SCREEN_S,
        account=lambda: f"screenshots taken in {', '.join(shots_taken)}; {browser_scene(page)}",
    )
    page.screenshot(path=shots / "live.png", full_page=True, timeout=SHOT_MS)
    assert_controls_labelled(page)

    # Software WebGL costs a core: with it off, the station, device and server on this
    # machine keep their timing for the rest of the test (the device holds if the station
    # misses its watchdog).
    page.get_by_label("Show the 3D view").uncheck()
    expect(iframe).to_be_hidden()
    # Both choices are remembered on this computer: "Technical" stays open, the 3D view off,
    # its card one line rather than a large empty panel.
    card = page.locator("#scene-card")
    page.reload()
    expect(page.locator("#st-link")).to_have_text("station online", timeout=30_000)
    expect(page.locator("#technical")).to_have_attribute("open", "")
    expect(page.get_by_label("Show the 3D view")).not_to_be_checked()
    expect(iframe).to_be_hidden()
    box = card.bounding_box()
    assert box is not None and box["height"] < 100, box
    assert page.locator("#scene").get_attribute("src") in (None, "about:blank")
    page.locator("#technical summary").click()  # closed again for the screenshots below
    expect(page.locator("#technical")).not_to_have_attribute("open", re.compile(".*"))
    page.screenshot(path=shots / "live-3d-off.png", full_page=True, timeout=SHOT_MS)

    # A stiffness beyond the published limit is caught beside the field and never sent.
    k = page.get_by_label("pitch stiffness K, N·m/rad")
    k.fill("9999")
    page.get_by_role("button", name="Send change").click()
    expect(page.locator('[data-error-for="stiffness.pitch"]')).to_contain_text("from 0 to 500")
    expect(page.locator("#kb-ack")).to_have_text("")
    page.screenshot(path=shots / "live-k-error.png", timeout=SHOT_MS)

    # A K change from 40 to 80: the device's answer, then 80 in force.
    k.fill("80")
    page.get_by_role("button", name="Send change").click()
    expect(page.locator("#kb-ack")).to_contain_text(
        re.compile(r"acknowledged by the device|applies"), timeout=10_000
    )
    # On a busy machine the station may miss the device's watchdog, and the device
    # holds: the change is then in force once the therapist resumes (never before).
    in_force = page.locator("#kb-now-pitch")

    def k_80() -> bool:
        if watchdog_held(page):  # held before it took effect: still 40 until Resume
            assert "40.0 ·" in in_force.inner_text(), in_force.inner_text()
        return in_force.inner_text().startswith("80.0 ·")

    wait_for(page, k_80, "K 80 in force")
    expect(page.locator("#st-rtt")).to_contain_text("ms")

    # HOLD reaches the device, and the device's mode changes on the page.
    hold_mid_repetition(page)
    expect(page.locator("#st-doing")).to_contain_text("held")

    # A change while held (80 to 60): the device renders 80 until Resume, and the page says so.
    k.fill("60")
    page.get_by_role("button", name="Send change").click()
    expect(page.locator("#kb-ack")).to_contain_text("applies on Resume", timeout=10_000)
    now = page.locator("#kb-now-pitch")
    expect(now).to_contain_text(re.compile(r"→ K 60\.0 · B 2\.00 on Resume$"))
    assert now.inner_text().startswith("80.0 ·"), now.inner_text()
    page.screenshot(path=shots / "live-hold.png", full_page=True, timeout=SHOT_MS)
    page.get_by_role("button", name="Resume").click()
    expect(page.locator("#ack")).to_contain_text("Resume: acknowledged by the device")
    wait_for(page, lambda: now.inner_text().startswith("60.0 ·"), "K 60 in force after Resume")
    expect(now).not_to_contain_text("on Resume")


def test_the_3d_view_comes_through_the_api_port(system: System, page: Page, shots: Path) -> None:
    """viser's page and WebSocket are reached on the API's own port behind a ticket; the
    browser asks no other port for anything, and the scene draws."""
    requests: list[str] = []
    sockets: list[str] = []
    page.on("request", lambda r: requests.append(r.url))
    page.on("websocket", lambda ws: sockets.append(ws.url))
    sign_in(page, system, f"/app/live/{system.station_id}")

    iframe = page.locator("#scene")
    frame = page.frame_locator("#scene")
    expect(frame.locator("canvas").first).to_be_visible(timeout=60_000)
    src = str(iframe.get_attribute("src"))
    assert re.fullmatch(r"/scene/[A-Za-z0-9_-]{43}/", src), src
    # The scene arrives over viser's WebSocket through the proxy, and is drawn: the platform
    # and legs darken the middle of an otherwise light frame.
    expect(frame.get_by_text("Connected")).to_be_visible(timeout=60_000)
    deadline = time.monotonic() + 60.0
    while dark_share(iframe.screenshot(timeout=SHOT_MS)) < 0.02:
        assert time.monotonic() < deadline, "the 3D view drew no platform"
        page.wait_for_timeout(250)
    iframe.screenshot(path=shots / "live-3d.png", timeout=SHOT_MS)

    api = f"127.0.0.1:{system.port}"
    elsewhere = [
        u for u in requests + sockets if not u.startswith(("data:", "blob:")) and api not in u
    ]
    assert not elsewhere, elsewhere
    assert f"ws://{api}{src.rstrip('/')}" in sockets
    # The same address without the ticket's rights is refused.
    r = rest.get(f"{system.url}/scene/{'A' * 43}/")
    assert r.status_code == 403 and "ticket" in r.json()["detail"]


PHONE: ViewportSize = {"width": 375, "height": 667}


def test_on_a_phone_every_page_fits_and_the_3d_view_is_the_scene_alone(
    system: System, page: Page, shots: Path
) -> None:
    """At 375 px every dashboard page was 490 px wide: the header's name, "Change password" and
    "Sign out" ran past its dark bar (white on the light page) and tables and grids kept
    their desktop widths. The live page's 3D view opened viser's own panel over the scene
    (the WebSocket address, Save Canvas, Dev Settings, the scene tree)."""
    page.set_viewport_size(PHONE)
    pid = system.creds["patient_id"]
    sign_in(page, system, "/app/patients")
    for path in (
        "/app/patients",
        f"/app/patients/{pid}",
        f"/app/patients/{pid}/prescribe",
        "/app/password",
        f"/app/live/{system.station_id}",
    ):
        page.goto(f"{system.url}{path}")
        expect(page.locator("header#top a.brand")).to_be_visible()
        page.wait_for_load_state("networkidle")
        width = page.evaluate("document.documentElement.scrollWidth")
        assert width <= PHONE["width"], (path, width)
        bar = page.locator("header#top").bounding_box()
        assert bar is not None
        for name in ("Change password", "Sign out"):
            box = page.locator("header#top").get_by_text(name, exact=True).bounding_box()
            assert box is not None, (path, name)
            inside = (
                box["x"] >= bar["x"]
                and box["x"] + box["width"] <= bar["x"] + bar["width"]
                and box["y"] + box["height"] <= bar["y"] + bar["height"]
            )
            assert inside, (path, name, box, bar)
    page.screenshot(path=shots / "phone-live.png", full_page=True, timeout=SHOT_MS)

    frame = page.frame_locator("#scene")
    expect(frame.locator("canvas").first).to_be_visible(timeout=60_000)
    expect(frame.get_by_text("Connected")).to_be_visible(timeout=60_000)
    for dev in ("Dev Settings", "Scene tree", "Save Canvas"):
        expect(frame.get_by_text(dev, exact=True)).to_be_hidden()
    page.locator("#scene").screenshot(path=shots / "phone-live-3d.png", timeout=SHOT_MS)
