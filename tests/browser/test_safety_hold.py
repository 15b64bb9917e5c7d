"""A safety hold in real browsers: the device's watchdog holds the exercise when the station
stalls. The patient's page says so in plain words, with what to do, and never offers
Continue; the therapist's live view, opened after the hold began, says why and until when;
nobody resumes, and the exercise ends by itself at the station's limit."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import httpx
from playwright.sync_api import BrowserContext, Page, expect

from tests.browser import rest
from tests.browser.test_live import sign_in, therapist_token
from tests.browser.test_patient_page import uploaded_session, wait_for_page
from tests.system.harness import System
from tests.system.test_hold import STALL_S, stall

MINUTE_MS = 60_000
LIMIT_S = 30
"""Long enough to sign in and open the live view while held; short enough to wait out."""
TITLE = "Ankle strength, held"
BODY: dict[str, Any] = {
    "exercise": "strength",
    "title": TITLE,
    "axes": [{"axis": "pitch", "stiffness": 40.0, "damping": 2.0}],
    "sets": 1,
    "repetitions": 3,
    "repetition_s": 8.0,
    "rest_s": 0.0,
    "instructions": "Push your foot against the plate, down and up.",
}


def test_a_safety_hold_is_told_apart_from_a_pause_and_ends_by_itself(
    system: System, context: BrowserContext, page: Page, shots: Path
) -> None:
    token = therapist_token(system)
    auth = {"Authorization": f"Bearer {token}"}
    r = rest.patch(
        f"{system.url}/api/v1/prescriptions/{system.creds['prescription_id']}",
        json=BODY,
        headers=auth,
    )
    assert r.status_code == 200, r.text
    system.start_station("--hold-limit", str(LIMIT_S))
    wait_for_page(system)

    page.goto(system.page_url)
    todo, platform = page.locator("#todo"), page.locator("#platform")
    expect(platform).to_have_text("The platform is ready", timeout=MINUTE_MS)
    page.get_by_role("button", name=f"Start {TITLE}").click()
    # While it runs, the one instruction on the page is the therapist's.
    expect(todo).to_contain_text(BODY["instructions"], timeout=MINUTE_MS)
    expect(platform).to_have_text("The platform is moving with you", timeout=MINUTE_MS)

    stall(system, STALL_S)
    expect(todo).to_contain_text(
        "The platform stopped to keep you safe: it lost contact with this computer for a "
        "moment. Keep your foot still. Your therapist has been told and can carry on; if "
        "not, the exercise ends by itself in",
        timeout=30_000,
    )
    expect(todo).to_contain_text("Press STOP to end it now.")
    expect(todo).not_to_contain_text("Continue")
    expect(todo).not_to_contain_text("Paused")
    expect(page.get_by_role("button", name="Continue")).to_have_count(0)
    expect(page.locator("#pause")).to_be_hidden()
    expect(page.locator("#pause-help")).to_have_text(
        "Only your therapist can carry on after this stop."
    )
    expect(page.get_by_role("button", name="STOP")).to_be_enabled()
    page.screenshot(path=shots / "patient-safety-hold.png")

    # The therapist opens the live view only now, and sees why the device holds.
    live = context.new_page()
    live.add_init_script("localStorage.setItem('ankle.live.scene', 'off')")  # spare a core
    sign_in(live, system, f"/app/live/{system.station_id}")
    why = live.locator("#why")
    expect(why).to_contain_text("Held for", timeout=30_000)
    expect(why).to_contain_text("the device's watchdog held the platform")
    expect(why).to_contain_text("Unless resumed, the exercise ends at")
    expect(live.locator("#st-trip")).to_contain_text("held: the device's watchdog")
    live.screenshot(path=shots / "live-safety-hold.png", full_page=True)

    # Nobody resumes: the station ends the exercise and the platform goes home.
    expect(todo).to_have_text(
        "The exercise ended because the platform was stopped for too long. You can start "
        "again when you are ready, or call your therapist.",
        timeout=2 * MINUTE_MS,
    )
    expect(platform).to_have_text("The platform is ready", timeout=MINUTE_MS)
    expect(why).to_contain_text(f"longer than the {LIMIT_S} s limit", timeout=30_000)
    live.screenshot(path=shots / "live-interrupted.png", full_page=True)

    with httpx.Client(base_url=system.url, headers=auth, timeout=30.0) as client:
        session = uploaded_session(client, system.creds["patient_id"])
    assert session["end_reason"] == "interrupted", session
    assert "the device's watchdog held the platform" in session["summary"]["end_text"]
    # The session review says why it ended.
    live.goto(f"{system.url}/app/sessions/{session['id']}")
    expect(live.locator("#facts")).to_contain_text("Interrupted")
    expect(live.locator("#end-text")).to_have_text(session["summary"]["end_text"])
    expect(live.locator("#end-text")).to_contain_text(f"longer than the {LIMIT_S} s limit")
