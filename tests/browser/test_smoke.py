"""The dashboard serves its pages and libraries, and a therapist can sign in."""

from __future__ import annotations

from pathlib import Path

from playwright.sync_api import Page, expect

from tests.browser import rest
from tests.system.harness import System


def test_vendor_libraries_are_installed_and_served(system: System) -> None:
    for name in ("uPlot.iife.min.js", "uPlot.min.css", "chart.umd.min.js"):
        r = rest.get(f"{system.url}/vendor/{name}")
        assert r.status_code == 200, (name, r.text)
        assert len(r.content) > 1_000
    assert rest.get(f"{system.url}/vendor/nothing.js").status_code == 404


def test_sign_in_wrong_then_right(system: System, page: Page, shots: Path) -> None:
    page.goto(f"{system.url}/")
    expect(page).to_have_url(f"{system.url}/app/login?next=%2Fapp%2Fpatients")
    page.get_by_label("Email").fill(system.creds["therapist_email"])
    page.get_by_label("Password").fill("not the password")
    page.get_by_role("button", name="Sign in").click()
    expect(page.get_by_role("alert")).to_contain_text("email or password")
    page.screenshot(path=shots / "login-error.png")
    page.get_by_label("Password").fill(system.creds["therapist_password"])
    page.get_by_role("button", name="Sign in").click()
    expect(page).to_have_url(f"{system.url}/app/patients")
