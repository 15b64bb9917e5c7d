"""The prescription form when the sign-in ends under it, and when its timeline asks for a
session no recording holds, in a real browser against the server alone (no device)."""

from __future__ import annotations

import re
from pathlib import Path

import httpx
from playwright.sync_api import Page, expect

from tests.browser.clinic import API, Clinic, clinic, therapist

__all__ = ["clinic", "therapist"]  # fixtures (tests.browser.clinic)


def sign_in(page: Page, clinic: Clinic) -> None:
    page.get_by_label("Email").fill(clinic.creds["therapist_email"])
    page.get_by_label("Password").fill(clinic.creds["therapist_password"])
    page.get_by_role("button", name="Sign in").click()


def test_what_was_typed_survives_an_expired_sign_in_and_a_long_session_is_refused(
    clinic: Clinic, therapist: httpx.Client, page: Page, shots: Path
) -> None:
    pid = clinic.creds["patient_id"]
    before = therapist.get(f"/patients/{pid}/prescriptions").json()
    patient_page, form_page = f"{clinic.url}/app/patients/{pid}", f"/app/patients/{pid}/prescribe"
    page.goto(patient_page)
    sign_in(page, clinic)
    expect(page).to_have_url(patient_page)
    page.get_by_role("link", name="Prescribe an exercise").click()
    expect(page).to_have_url(f"{clinic.url}{form_page}")

    # Typed, then the sign-in ends elsewhere (signed out on another tab, or expired).
    page.get_by_label("Title").fill("Typed carefully by the therapist")
    page.get_by_label("Instructions for the patient").fill("Ten minutes of careful words.")
    page.locator("#ax-pitch-stiffness").fill("123")
    page.get_by_label("Sets", exact=True).fill("20")
    page.get_by_label("Repetitions per set").fill("100")
    page.get_by_label("Repetition time").fill("600")
    page.get_by_label("Rest between sets").fill("900")
    token = page.evaluate("sessionStorage.getItem('ankle.token')")
    r = httpx.post(f"{clinic.url}{API}/auth/logout", headers={"Authorization": f"Bearer {token}"})
    assert r.status_code == 204, r.text
    page.get_by_role("button", name="Prescribe").click()
    expect(page.get_by_role("heading", name="Sign in")).to_be_visible()
    assert page.evaluate("sessionStorage.getItem('ankle.draft')").count("Ten minutes") == 1

    # Signed in again: the form as it was typed, and a note that says so.
    sign_in(page, clinic)
    expect(page).to_have_url(f"{clinic.url}{form_page}")
    expect(page.locator("#draft-note")).to_contain_text(
        "Your sign-in had ended, so nothing was saved. What you had typed"
    )
    expect(page.get_by_label("Title")).to_have_value("Typed carefully by the therapist")
    expect(page.get_by_label("Instructions for the patient")).to_have_value(
        "Ten minutes of careful words."
    )
    expect(page.locator("#ax-pitch-stiffness")).to_have_value("123")
    expect(page.get_by_label("Sets", exact=True)).to_have_value("20")
    page.screenshot(path=shots / "prescribe-draft-restored.png", full_page=True)

    # 20 sets of 100 repetitions of 600 s with 900 s rests: 338 hours, refused beside the
    # sets with the total and the most a session may last.
    page.get_by_role("button", name="Prescribe").click()
    expect(page.locator('[data-error-for="sets"]')).to_have_text(
        "This session lasts 338 h 5 min (20 sets of 100 repetitions of 600 s, 900 s rest "
        "between sets), longer than the 2 h a session may last: fewer sets or repetitions, "
        "or shorter repetitions or rests."
    )
    expect(page.get_by_label("Sets", exact=True)).to_have_attribute("aria-invalid", "true")
    expect(page.locator("#total")).to_have_text(
        "Exercise time per session: 338 h 5 min, rests included."
    )
    page.locator("#rx section").nth(2).screenshot(path=shots / "prescribe-session-too-long.png")
    assert therapist.get(f"/patients/{pid}/prescriptions").json() == before

    page.get_by_label("Sets", exact=True).fill("2")
    page.get_by_label("Repetitions per set").fill("10")
    page.get_by_label("Repetition time").fill("6")
    page.get_by_role("button", name="Prescribe").click()
    expect(page).to_have_url(re.compile(rf"{re.escape(patient_page)}\?saved=\d+$"))
    saved = therapist.get(f"/patients/{pid}/prescriptions").json()[0]
    assert saved["body"]["title"] == "Typed carefully by the therapist"
    assert saved["body"]["axes"][0]["stiffness"] == 123
    assert page.evaluate("sessionStorage.getItem('ankle.draft')") is None

    # Back goes through the form to the patient's page, never to a sign-in form.
    page.go_back()
    expect(page).to_have_url(f"{clinic.url}{form_page}")
    expect(page.locator("#draft-note")).to_be_hidden()  # the draft was used up
    page.go_back()
    expect(page).to_have_url(patient_page)
