"""Accounts in the dashboard, in a browser against the real system: the first admin made by
``ankle admin`` changes the printed password before anything else and manages accounts; a
therapist edits, archives and revokes from the patient's page. What the pages did is
checked through the API, the independent witness."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from playwright.sync_api import Page, expect

from tests.browser import rest
from tests.browser.a11y import assert_controls_labelled
from tests.system.harness import System

API = "/api/v1"
DEADLINE_S = 60.0
NEW_PASSWORD = "the boss's own passphrase"
BOSS = ("--email", "boss@clinic.test", "--name", "Bo Boss", "--role", "admin")


def sign_in_api(system: System, email: str, password: str) -> httpx.Response:
    return rest.post(
        f"{system.url}{API}/auth/login", json={"email": email, "password": password}, timeout=30
    )


SignedIn = Callable[[str, str], httpx.Client]


@pytest.fixture
def as_user(system: System) -> Iterator[SignedIn]:
    """A REST client signed in as someone: the independent witness of what a page did."""
    opened: list[httpx.Client] = []

    def sign_in(email: str, password: str) -> httpx.Client:
        r = sign_in_api(system, email, password)
        assert r.status_code == 200, r.text
        client = httpx.Client(
            base_url=f"{system.url}{API}",
            headers={"Authorization": f"Bearer {r.json()['access_token']}"},
            timeout=30,
        )
        opened.append(client)
        return client

    yield sign_in
    for client in opened:
        client.close()


def eventually(check: Callable[[], Any], what: str) -> Any:
    deadline = time.monotonic() + DEADLINE_S
    while True:
        value = check()
        if value:
            return value
        assert time.monotonic() < deadline, f"not within {DEADLINE_S} s: {what}"
        time.sleep(0.2)


def sign_in(page: Page, system: System, email: str, password: str) -> None:
    page.goto(f"{system.url}/app/patients")
    page.get_by_label("Email").fill(email)
    page.get_by_label("Password").fill(password)
    page.get_by_role("button", name="Sign in").click()


def test_a_printed_password_is_changed_first_then_accounts_are_managed(
    system: System, page: Page, shots: Path, as_user: SignedIn
) -> None:
    made = subprocess.run(
        [sys.executable, "-m", "ankle", "admin", "create-user", *BOSS],
        env={**os.environ, "ANKLE_DATA_DIR": str(system.data_dir / "server")},
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    printed = re.search(r"One-time password: (\S+)", made.stdout)
    assert printed, made.stdout

    sign_in(page, system, "boss@clinic.test", printed.group(1))
    expect(page).to_have_url(f"{system.url}/app/password?next=%2Fapp%2Fpatients")
    expect(page.get_by_text("given to you by an administrator")).to_be_visible()
    # Another page of the dashboard sends such a user back here.
    page.goto(f"{system.url}/app/accounts")
    expect(page).to_have_url(f"{system.url}/app/password?next=%2Fapp%2Faccounts")
    assert_controls_labelled(page)
    page.screenshot(path=shots / "password-must-change.png", full_page=True)

    page.get_by_label("Current password").fill("not the printed one")
    page.get_by_label("New password", exact=True).fill(NEW_PASSWORD)
    page.get_by_label("New password again").fill(NEW_PASSWORD + "!")
    page.get_by_role("button", name="Change password").click()
    expect(page.locator('[data-error-for="repeat_password"]')).to_contain_text("not the same")
    page.get_by_label("New password again").fill(NEW_PASSWORD)
    page.get_by_role("button", name="Change password").click()
    expect(page.locator('[data-error-for="current_password"]')).to_contain_text("current_password")
    expect(page.get_by_label("Current password")).to_be_focused()
    page.screenshot(path=shots / "password-error.png", full_page=True)
    assert sign_in_api(system, "boss@clinic.test", NEW_PASSWORD).status_code == 401

    page.get_by_label("Current password").fill(printed.group(1))
    page.get_by_role("button", name="Change password").click()
    expect(page).to_have_url(f"{system.url}/app/accounts")
    boss = as_user("boss@clinic.test", NEW_PASSWORD)
    assert boss.get("/auth/me").json()["must_change_password"] is False

    # The accounts page: the demo therapist and the admin (you).
    therapist = system.creds["therapist_email"]
    demo_row = page.locator("tr", has_text=therapist)
    expect(demo_row).to_contain_text("Active")
    expect(page.locator("tr", has_text="boss@clinic.test")).to_contain_text("(you)")
    page.get_by_label("Name").fill("Nora Nurse")
    page.get_by_label("Email").fill("nora@clinic.test")
    page.get_by_role("button", name="Add account").click()
    box = page.locator("#secret-box")
    expect(box).to_contain_text("shown only this once")
    first = page.get_by_label("One-time password").input_value()
    r = sign_in_api(system, "nora@clinic.test", first)
    assert r.status_code == 200 and r.json()["user"]["must_change_password"] is True
    nora_row = page.locator("tr", has_text="nora@clinic.test")
    expect(nora_row).to_contain_text("Must change password")
    assert_controls_labelled(page)
    page.screenshot(path=shots / "accounts.png", full_page=True)
    box.get_by_role("button", name="I have saved it: hide the password").click()
    expect(box).to_be_hidden()

    # Reset Nora's password: a new one is shown once, the first stops working.
    nora_row.get_by_role("button", name="Reset the password of Nora Nurse").click()
    nora_row.get_by_role("button", name="Yes, reset").click()
    expect(box).to_contain_text("One-time password for Nora Nurse")
    second = page.get_by_label("One-time password").input_value()
    assert second != first
    assert sign_in_api(system, "nora@clinic.test", first).status_code == 401
    assert sign_in_api(system, "nora@clinic.test", second).status_code == 200
    box.get_by_role("button", name="I have saved it: hide the password").click()

    # Deactivate the demo therapist, with a confirmation; then reactivate.
    demo = as_user(therapist, system.creds["therapist_password"])
    demo_row.get_by_role("button", name=re.compile("^Deactivate")).click()
    expect(demo_row).to_contain_text("cannot sign in")
    assert_controls_labelled(page)
    page.screenshot(path=shots / "accounts-deactivate.png", full_page=True)
    demo_row.get_by_role("button", name="Yes, deactivate").click()
    expect(demo_row).to_contain_text("Deactivated")
    assert demo.get("/auth/me").status_code == 401
    assert sign_in_api(system, therapist, system.creds["therapist_password"]).status_code == 401
    demo_row.get_by_role("button", name=re.compile("^Reactivate")).click()
    demo_row.get_by_role("button", name="Yes, reactivate").click()
    expect(demo_row).to_contain_text("Active")
    assert sign_in_api(system, therapist, system.creds["therapist_password"]).status_code == 200
    actions = [row["action"] for row in boss.get("/audit", params={"limit": 20}).json()]
    for action in ("user.create", "user.password_reset", "user.deactivate", "user.reactivate"):
        assert action in actions


def test_revoke_a_station_edit_and_archive_from_the_patients_page(
    system: System, page: Page, shots: Path, as_user: SignedIn
) -> None:
    therapist = as_user(system.creds["therapist_email"], system.creds["therapist_password"])
    patient, station = system.creds["patient_id"], system.station_id
    system.start_station()
    eventually(
        lambda: therapist.get("/stations", params={"patient_id": patient}).json()[0]["online"],
        "the demo station comes online",
    )

    sign_in(page, system, system.creds["therapist_email"], system.creds["therapist_password"])
    expect(page).to_have_url(f"{system.url}/app/patients")
    page.goto(f"{system.url}/app/patients/{patient}")
    row = page.locator(f'li[data-station-id="{station}"]')
    expect(row).to_contain_text("Online")
    row.get_by_role("button", name="Revoke the station “Demo station”").click()
    expect(row).to_contain_text("stops streaming at once")
    assert_controls_labelled(page)
    page.screenshot(path=shots / "patient-revoke.png", full_page=True)
    row.get_by_role("button", name="Yes, revoke").click()
    expect(row).to_contain_text("Revoked")
    expect(row.get_by_role("button", name=re.compile("Revoke"))).to_have_count(0)
    expect(page.locator("#flash")).to_contain_text("is revoked")
    eventually(
        lambda: not therapist.get("/stations", params={"patient_id": patient}).json()[0]["online"],
        "the revoked station's link is closed",
    )
    (listed,) = therapist.get("/stations", params={"patient_id": patient}).json()
    assert listed["revoked"] is True
    r = rest.get(
        f"{system.url}{API}/station/me",
        headers={"Authorization": f"Bearer {system.creds['station_token']}"},
        timeout=30,
    )
    assert r.status_code == 401

    # Edit the details: a refused value beside its field, then saved.
    page.get_by_role("button", name="Edit details").click()
    form = page.locator("#edit-patient")
    form.get_by_label("Display name").fill(" ")
    form.get_by_role("button", name="Save details").click()
    name_error = page.locator('[data-error-for="display_name"]')
    expect(name_error).to_have_text("Display name is required.")
    form.get_by_label("Display name").fill("D. P.")
    form.get_by_label("Notes").fill("Moved to the second floor.")
    assert_controls_labelled(page)
    form.get_by_role("button", name="Save details").click()
    expect(page.get_by_role("heading", level=1)).to_have_text("D. P.")
    expect(page.locator("#details")).to_contain_text("Moved to the second floor.")
    saved = therapist.get(f"/patients/{patient}").json()
    assert (saved["display_name"], saved["notes"]) == ("D. P.", "Moved to the second floor.")

    # Archive, with a confirmation that says what happens.
    page.get_by_role("button", name="Archive patient").click()
    expect(page.locator("#details-actions")).to_contain_text("withdrawn")
    page.get_by_role("button", name="Yes, archive").click()
    expect(page.locator("#archived-note")).to_contain_text("read-only")
    expect(page.locator("#flash")).to_contain_text("1 prescription withdrawn")
    expect(page.get_by_role("link", name="Prescribe an exercise")).to_be_hidden()
    expect(page.get_by_role("button", name="Edit details")).to_have_count(0)
    page.screenshot(path=shots / "patient-archived.png", full_page=True)
    archived = therapist.get(f"/patients/{patient}").json()
    assert archived["archived_at"] is not None
    rx = therapist.get(f"/patients/{patient}/prescriptions").json()
    assert {p["status"] for p in rx} == {"cancelled"}

    page.goto(f"{system.url}/app/patients")
    expect(page.locator(f'tr[data-patient-id="{patient}"]')).to_have_count(0)
    page.get_by_role("link", name="Archived patients").click()
    expect(page.locator(f'tr[data-patient-id="{patient}"]')).to_contain_text("D. P.")
