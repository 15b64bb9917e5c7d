"""The patient's page in a real browser: the station serves it, the simulated patient's foot
(a scripted push in pitch) flies the plane, the patient starts by keyboard, pauses, carries
on and stops, and the game's score reaches the therapist in the uploaded session."""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from playwright.sync_api import Page, expect

from tests.browser.a11y import assert_controls_labelled
from tests.browser.rest import signed_in
from tests.system.harness import System

MINUTE_MS = 60_000
INSTRUCTIONS = "Push your toes down as far as is comfortable, then bring them up. Slowly."
BODY: dict[str, Any] = {
    "exercise": "strength",
    "title": "Ankle strength",
    "instructions": INSTRUCTIONS,
    "axes": [{"axis": "pitch", "stiffness": 40.0, "damping": 2.0}],
    "sets": 2,
    "repetitions": 2,
    "repetition_s": 5.0,
    "rest_s": 6.0,
}


@pytest.fixture
def therapist(system: System) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=system.url, timeout=30.0) as client:
        yield signed_in(client, system.creds, "/api/v1/auth/login")


def wait_for_page(system: System, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while True:
        try:
            if httpx.get(system.page_url, timeout=2.0).status_code == 200:
                return
        except httpx.TransportError:
            pass
        if system.station is not None and system.station.poll() is not None:
            raise AssertionError("the station exited:\n" + system.log_tail())
        assert time.monotonic() < deadline, "the page never answered:\n" + system.log_tail()
        time.sleep(0.2)


def uploaded_session(client: httpx.Client, patient: int, timeout: float = 60.0) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        r = client.get("/api/v1/sessions", params={"patient_id": patient})
        assert r.status_code == 200, r.text
        if r.json():
            return r.json()[0]
        time.sleep(0.5)
    raise AssertionError("the session never reached the server")


def test_the_patient_exercises_plays_pauses_and_stops(
    system: System, therapist: httpx.Client, page: Page, shots: Path
) -> None:
    client = therapist
    # The therapist's prescription for today: two short sets with a rest between them.
    r = client.patch(f"/api/v1/prescriptions/{system.creds['prescription_id']}", json=BODY)
    assert r.status_code == 200, r.text
    system.start_station()
    wait_for_page(system)

    page.goto(system.page_url)
    expect(page).to_have_title("Your ankle exercises")
    expect(page.get_by_role("heading", name="Ankle strength")).to_be_visible()
    expect(page.get_by_text(INSTRUCTIONS)).to_have_count(0)  # until it is what to do now
    expect(page.get_by_text("2 sets of 2 repetitions, about 1 minute.")).to_be_visible()
    connection, platform, todo = (
        page.locator("#connection"),
        page.locator("#platform"),
        page.locator("#todo"),
    )
    expect(connection).to_have_text("Connected to your therapist", timeout=MINUTE_MS)
    expect(platform).to_have_text("The platform is ready", timeout=MINUTE_MS)
    expect(todo).to_have_text("Put your foot on the plate, then press Start when you are ready.")
    stop = page.get_by_role("button", name="STOP")
    expect(stop).to_be_visible()
    expect(stop).to_be_enabled()
    # Every control has a name a screen reader can say.
    for button in page.get_by_role("button").all():
        label = button.get_attribute("aria-label") or button.inner_text()
        assert label.strip(), button
    page.screenshot(path=shots / "patient-ready.png")

    # Keyboard only: the first Tab reaches today's Start button.
    page.keyboard.press("Tab")
    start = page.get_by_role("button", name="Start Ankle strength")
    expect(start).to_be_focused()
    page.keyboard.press("Enter")
    expect(todo).to_have_text(INSTRUCTIONS, timeout=MINUTE_MS)
    expect(page.get_by_text(INSTRUCTIONS)).to_have_count(1)  # one instruction at a time
    expect(platform).to_have_text("The platform is moving with you")
    expect(page.locator("#sets")).to_have_text("2")
    expect(page.locator("#reps")).to_have_text("2")
    expect(start).to_be_hidden()  # while it runs, only what to do now and the game show

    # The foot flies the plane: its angle changes and gates are judged.
    foot = page.locator("#foot")
    expect(foot).to_contain_text("Your foot:")
    first = foot.inner_text()
    expect(foot).not_to_have_text(first, timeout=10_000)
    expect(page.locator("#gates")).not_to_have_text("0", timeout=20_000)
    expect(page.locator("#done")).to_have_text("1", timeout=MINUTE_MS)
    page.screenshot(path=shots / "patient-game.png")
    assert_controls_labelled(page)

    # A rest between the sets, counted down.
    expect(page.locator("#rest")).to_be_visible(timeout=MINUTE_MS)
    expect(page.locator("#rest")).to_contain_text("Rest: next set in")
    expect(todo).to_have_text("Rest and relax your foot. The next set starts by itself.")
    seconds = int(page.locator("#rest-seconds").inner_text())
    assert 0 < seconds <= 6
    expect(page.locator("#done")).to_have_text("2")
    page.screenshot(path=shots / "patient-rest.png")
    expect(page.locator("#rest-seconds")).not_to_have_text(str(seconds), timeout=5_000)

    # The second set: pause, then carry on from the keyboard.
    expect(todo).to_have_text(INSTRUCTIONS, timeout=MINUTE_MS)
    expect(page.locator("#set")).to_have_text("2")
    pause = page.get_by_role("button", name="Pause")
    pause.click()
    expect(todo).to_have_text("Paused. Press Continue when you are ready.")
    expect(platform).to_have_text("The platform is holding still")
    carry_on = page.get_by_role("button", name="Continue")
    expect(carry_on).to_be_visible()
    page.screenshot(path=shots / "patient-paused.png")
    carry_on.focus()
    page.keyboard.press("Space")
    expect(todo).to_have_text(INSTRUCTIONS)
    expect(platform).to_have_text("The platform is moving with you")

    stop.click()
    # The answer shows for a few seconds; the platform may take longer to settle.
    expect(page.locator("#feedback")).to_contain_text("Stopped.")
    expect(todo).to_have_text(
        "The exercise was stopped. You can start again when you are ready.", timeout=MINUTE_MS
    )
    expect(start).to_be_enabled(timeout=MINUTE_MS)
    expect(page.locator("#game-note")).to_have_text(
        "Game over. Your score is saved with today's exercise."
    )
    expect(page.locator("#set")).to_have_text("–")  # no current set once it has ended
    score = int(page.locator("#score").inner_text())
    gates = int(page.locator("#gates").inner_text())
    assert gates >= 1
    page.screenshot(path=shots / "patient-stopped.png")
    page.set_viewport_size({"width": 820, "height": 1180})  # a tablet held upright
    page.screenshot(path=shots / "patient-stopped-tablet.png")

    # The therapist sees the stop and the game in the uploaded session.
    session = uploaded_session(client, system.creds["patient_id"])
    # The session counts in the patient's own progress as soon as the server has it.
    expect(page.locator("#mine")).to_contain_text(
        "1 exercise session in the last 7 days. A good start!", timeout=MINUTE_MS
    )
    page.screenshot(path=shots / "patient-progress.png")
    summary = session["summary"]
    assert session["end_reason"] == "stopped", session
    assert summary["events"]["game_score"] == gates
    assert summary["game"] == {"games": 1, "score": score, "gates": gates, "missed": gates - score}
    assert summary["events"]["hold"] == 1 and summary["events"]["resume"] == 1
    r = client.get(session["downloads"]["json"])
    assert r.status_code == 200
    events = r.json()["events"]
    last = [e for e in events if e["kind"] == "game_score"][-1]
    assert last["by"] == "patient"
    assert (last["detail"]["score"], last["detail"]["gates"]) == (score, gates)

    # The therapist's server goes away: the patient is told, in words, that nothing is lost.
    page.set_viewport_size({"width": 1400, "height": 1000})
    system.stop_servers()
    expect(connection).to_have_text(
        "Working offline — your session is saved and will be sent later", timeout=30_000
    )
    expect(platform).to_have_text("The platform is ready")
    page.screenshot(path=shots / "patient-offline.png")
    # And the station itself: the page says so and keeps trying.
    system.stop(system.station)
    expect(connection).to_have_text(
        "This page has lost contact with your station. Trying again…", timeout=30_000
    )
    expect(start).to_be_disabled()


SCREENS = {"desktop": (1400, 900), "laptop": (1280, 720), "tablet-portrait": (768, 1024)}
PHONES = {"phone": (375, 667), "phone-sideways": (667, 375)}
"""Screens on which, during an exercise, the game and STOP share a phone's little height
(stacked, the controls took 41 % of it and the game was below the fold)."""
CONTROLS_SHARE_MAX = 0.2
"""The most of a phone's height the Pause and STOP bar takes (it takes 10 % upright, 19 %
sideways)."""
TARGET_PX = 44
"""The least width and height of STOP: WCAG 2.5.5's target size, in CSS pixels."""
IN_VIEW = """(selector) => {
  const el = document.querySelector(selector);
  const r = el.getBoundingClientRect();
  const controls = document.querySelector("footer.controls");
  // Above the controls, or one of them.
  const floor = controls.contains(el) ? innerHeight : controls.getBoundingClientRect().top;
  const hit = document.elementFromPoint(r.left + r.width / 2, r.top + r.height / 2);
  return {
    top: r.top, bottom: r.bottom, left: r.left, right: r.right, height: r.height,
    width: innerWidth, viewport: innerHeight, floor,
    hit: hit !== null && (hit === el || el.contains(hit)),
    hitName: hit === null ? null : hit.outerHTML.slice(0, 80),
  };
}"""


def in_view(box: dict[str, Any]) -> bool:
    return bool(
        box["top"] >= 0
        and box["left"] >= 0
        and box["right"] <= box["width"]
        and box["bottom"] <= box["floor"] <= box["viewport"]
        and box["hit"]
    )


def assert_in_view(page: Page, selector: str, screen: str, timeout: float = 10.0) -> None:
    """Wholly on the screen, above the controls, and not covered at its centre (the page
    lays itself out again after a resize: give it until ``timeout``)."""
    deadline = time.monotonic() + timeout
    while not in_view(box := page.evaluate(IN_VIEW, selector)):
        assert time.monotonic() < deadline, f"{selector} at {screen}: {box}"
        time.sleep(0.2)


def test_start_the_game_and_stop_are_in_view_on_every_screen(
    system: System, therapist: httpx.Client, page: Page, shots: Path
) -> None:
    # Ten repetitions (50 s): still running while every screen is looked at.
    body = {**BODY, "sets": 1, "repetitions": 10, "rest_s": 0.0}
    r = therapist.patch(f"/api/v1/prescriptions/{system.creds['prescription_id']}", json=body)
    assert r.status_code == 200, r.text
    system.start_station()
    wait_for_page(system)
    page.goto(system.page_url)
    start = page.get_by_role("button", name="Start Ankle strength")
    expect(start).to_be_enabled(timeout=MINUTE_MS)
    mine = page.locator("#mine")  # the patient's own progress, asked of the server
    expect(mine).to_contain_text("Your first exercise starts your progress here.", timeout=30_000)
    for screen, (width, height) in SCREENS.items():
        page.set_viewport_size({"width": width, "height": height})
        page.screenshot(path=shots / f"patient-{screen}-ready.png")
        for selector in ("button.start", "#game-canvas", "#stop", "#todo"):
            assert_in_view(page, selector, screen)
        # The game is a game, not a strip: at least a third of the screen's height.
        assert page.evaluate(IN_VIEW, "#game-canvas")["height"] >= height / 3, screen

    start.click()
    todo = page.locator("#todo")
    expect(todo).to_have_text(INSTRUCTIONS, timeout=MINUTE_MS)
    expect(page.locator("#progress")).to_be_visible()
    for screen, (width, height) in SCREENS.items():
        page.set_viewport_size({"width": width, "height": height})
        page.screenshot(path=shots / f"patient-{screen}-running.png")
        for selector in ("#game-canvas", "#stop", "#todo"):
            assert_in_view(page, selector, screen)
        # One instruction at a time: the therapist's words, once, in "what to do now".
        expect(page.get_by_text(INSTRUCTIONS)).to_have_count(1)
    # The bar as it stands through the exercise: "Starting." under the buttons is gone after
    # a few seconds.
    expect(page.locator("#feedback")).to_be_empty()
    for screen, (width, height) in PHONES.items():
        page.set_viewport_size({"width": width, "height": height})
        page.screenshot(path=shots / f"patient-{screen}-running.png")
        for selector in ("#game-canvas", "#stop", "#todo"):
            assert_in_view(page, selector, screen)
        controls = page.locator("footer.controls").bounding_box()
        stop = page.locator("#stop").bounding_box()
        assert controls is not None and stop is not None
        assert controls["height"] <= CONTROLS_SHARE_MAX * height, (screen, controls)
        assert stop["width"] >= TARGET_PX and stop["height"] >= TARGET_PX, (screen, stop)
        assert page.evaluate(IN_VIEW, "#game-canvas")["height"] >= height / 4, screen
    page.get_by_role("button", name="STOP").click()
    expect(todo).to_have_text(
        "The exercise was stopped. You can start again when you are ready.", timeout=MINUTE_MS
    )


SUPPLY_LOW_WORDS = "The platform's air supply is low: check that the compressor is on"


@pytest.mark.parametrize("device_args", [("--fault", "supply_droop@0")], ids=["compressor-off"])
def test_a_low_air_supply_is_on_the_platform_light_not_ready(
    system: System, page: Page, shots: Path
) -> None:
    """The compressor is off from the start (the regulator sags to 3.5 bar, under the
    device's low mark): the platform's light warns of it instead of "ready", agreeing with
    the station's notice under it, and no exercise offers to start (the station would
    refuse it with the same sentence: tests/station/test_patient_page.py)."""
    system.start_station()
    wait_for_page(system)
    page.goto(system.page_url)
    platform = page.locator("#platform")
    expect(platform).to_have_text(SUPPLY_LOW_WORDS, timeout=MINUTE_MS)
    expect(platform).to_have_attribute("data-level", "warn")
    expect(page.locator("#message")).to_contain_text("air supply is low")
    page.screenshot(path=shots / "patient-supply-low.png")

    start = page.locator("button.start").first  # the demo's own prescription
    expect(start).to_be_disabled()
    # ...and nothing asks the patient to press it.
    expect(page.locator("#todo")).to_contain_text("You can start once the air is back")
    expect(page.locator("#todo")).not_to_contain_text("press Start")
    expect(platform).to_have_text(SUPPLY_LOW_WORDS)


LINK_LOST = "The exercise ended because the station lost its connection to the platform."


def test_after_a_lost_platform_link_the_page_says_when_to_start_again(
    system: System, therapist: httpx.Client, page: Page, shots: Path
) -> None:
    """The device stands still mid-exercise (SIGSTOP) longer than the station waits for it:
    the exercise ends. Once the platform answers again and is home, the page used to go on
    saying to wait until the platform is connected; it says it is connected again and that
    the patient can start again."""
    r = therapist.patch(f"/api/v1/prescriptions/{system.creds['prescription_id']}", json=BODY)
    assert r.status_code == 200, r.text
    system.start_station()
    wait_for_page(system)
    page.goto(system.page_url)
    todo, platform = page.locator("#todo"), page.locator("#platform")
    expect(platform).to_have_text("The platform is ready", timeout=MINUTE_MS)
    page.get_by_role("button", name="Start Ankle strength").click()
    expect(todo).to_have_text(INSTRUCTIONS, timeout=MINUTE_MS)
    os.kill(system.device.pid, signal.SIGSTOP)
    try:
        expect(todo).to_contain_text(LINK_LOST, timeout=MINUTE_MS)
        expect(todo).to_contain_text("once the platform is connected")
    finally:
        os.kill(system.device.pid, signal.SIGCONT)
    expect(todo).to_have_text(
        f"{LINK_LOST} It is connected again: you can start again when you are ready, or call"
        " your therapist.",
        timeout=MINUTE_MS,
    )
    expect(platform).to_have_text("The platform is ready")
    expect(page.get_by_role("button", name="Start Ankle strength")).to_be_enabled()
    page.screenshot(path=shots / "patient-link-back.png")
