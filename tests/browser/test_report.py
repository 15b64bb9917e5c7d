"""The therapist downloads the patient's report from the patient's page, in a real browser
against the real server: a period picker, the PDF and the FHIR bundle, each saved under the
server's file name and read back."""

from __future__ import annotations

import hashlib
import io
import json
import uuid
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from urllib.parse import parse_qs, urlsplit
from zoneinfo import ZoneInfo

import httpx
import numpy as np
import pytest
from playwright.sync_api import Browser, BrowserContext, Page, expect
from pypdf import PdfReader

from tests.browser.a11y import assert_controls_labelled
from tests.browser.clinic import API, Clinic, clinic, therapist
from tests.server.test_series import HZ, recording_bytes, samples

__all__ = ["clinic", "therapist"]  # fixtures (tests.browser.clinic)


def away_from_utc() -> str:
    """A time zone whose date is not UTC's now: UTC+14 from 10:00 UTC, UTC-11 before."""
    return "Pacific/Kiritimati" if datetime.now(UTC).hour >= 10 else "Pacific/Pago_Pago"


@pytest.fixture
def zone() -> str:
    return away_from_utc()


@pytest.fixture
def context(browser: Browser, zone: str) -> Iterator[BrowserContext]:
    """The therapist's browser, in a time zone whose day is not UTC's: the period's default
    is their own calendar's."""
    ctx = browser.new_context(
        viewport={"width": 1400, "height": 1000}, accept_downloads=True, timezone_id=zone
    )
    try:
        yield ctx
    finally:
        ctx.close()


def upload_a_session(clinic: Clinic, days_ago: int) -> None:
    """File a synthetic session for the demo patient, as their station would."""
    rows = samples()[:3000]  # 30 s: one upload chunk
    start = datetime.now(UTC) - timedelta(days=days_ago)
    rows["wall"] = start.timestamp() + np.arange(len(rows)) / HZ
    sid = str(uuid.uuid4())
    c = clinic.creds
    data = recording_bytes(sid, rows, c["station_id"], c["patient_id"], c["prescription_id"])
    station = {"Authorization": f"Bearer {c['station_token']}"}
    with httpx.Client(base_url=f"{clinic.url}{API}", headers=station, timeout=60) as client:
        r = client.patch(f"/uploads/{sid}", content=data, headers={"Upload-Offset": "0"})
        assert r.status_code == 204, r.text
        body = {"size": len(data), "sha256": hashlib.sha256(data).hexdigest()}
        r = client.post(f"/uploads/{sid}/complete", json=body)
        assert r.status_code == 201, r.text


def test_the_report_and_the_fhir_bundle_download_from_the_patients_page(
    clinic: Clinic, therapist: httpx.Client, page: Page, shots: Path, tmp_path: Path, zone: str
) -> None:
    upload_a_session(clinic, days_ago=5)
    pid = clinic.creds["patient_id"]
    page.goto(f"{clinic.url}/app/patients/{pid}")
    page.get_by_label("Email").fill(clinic.creds["therapist_email"])
    page.get_by_label("Password").fill(clinic.creds["therapist_password"])
    page.get_by_role("button", name="Sign in").click()
    section = page.locator(
        "section", has=page.get_by_role("heading", name="Report for the medical record")
    )
    since, until = section.get_by_label("First day"), section.get_by_label("Last day")
    today = datetime.now(ZoneInfo(zone)).date()  # the therapist's, a day from UTC's
    expect(until).to_have_value(str(today))
    expect(since).to_have_value(str(today - timedelta(days=89)))
    assert_controls_labelled(page)

    first = today - timedelta(days=30)
    since.fill(str(first))
    reference = therapist.get(f"/patients/{pid}").json()["reference"]  # the demo has one
    stem = f"report-{reference}-{first:%Y%m%d}-{today:%Y%m%d}"

    with (
        page.expect_response(lambda r: "/report.pdf" in r.url) as answer,
        page.expect_download() as got,
    ):
        section.get_by_role("button", name="Download PDF report").click()
    assert answer.value.status == 200
    assert answer.value.headers["content-type"] == "application/pdf"
    # The therapist's zone goes with their days: the report counts and prints on their clock.
    assert parse_qs(urlsplit(answer.value.url).query)["tz"] == [zone]
    pdf = got.value
    assert pdf.suggested_filename == f"{stem}.pdf"
    pdf.save_as(tmp_path / pdf.suggested_filename)
    text = " ".join(
        p.extract_text()
        for p in PdfReader(io.BytesIO((tmp_path / f"{stem}.pdf").read_bytes())).pages
    )
    assert clinic.creds["patient_name"] in text and "1 session in the period" in text
    assert f"times are in {zone} (UTC" in text, text
    expect(page.locator("#report-status")).to_contain_text(f"saved as {stem}.pdf")

    with page.expect_response(lambda r: "/fhir" in r.url) as answer, page.expect_download() as got:
        section.get_by_role("button", name="Download FHIR bundle").click()
    assert answer.value.headers["content-type"] == "application/fhir+json"
    bundle_file = got.value
    assert bundle_file.suggested_filename == f"{stem}.fhir.json"
    bundle_file.save_as(tmp_path / bundle_file.suggested_filename)
    bundle = json.loads((tmp_path / bundle_file.suggested_filename).read_text())
    assert bundle["resourceType"] == "Bundle" and len(bundle["entry"]) > 1
    page.screenshot(path=shots / "patient-report.png", full_page=True)

    # A period that ends before it starts: the server's sentence, beside the field.
    since.fill(str(today + timedelta(days=1)))
    section.get_by_role("button", name="Download PDF report").click()
    expect(page.locator('[data-error-for="query.since"]')).to_contain_text(
        "the period must start on or before the day it ends"
    )
    expect(since).to_have_attribute("aria-invalid", "true")
    page.locator("#report").screenshot(path=shots / "patient-report-error.png")

    # A period that runs into days still to come: a signed report never covers them.
    since.fill(str(first))
    until.fill("2099-12-31")
    section.get_by_role("button", name="Download PDF report").click()
    expect(page.locator('[data-error-for="query.until"]')).to_contain_text(
        "the last day (until), 2099-12-31, is still to come"
    )
    expect(page.locator("#report-status")).to_have_text("")

    # Both downloads left the system on the record; the refused one did not.
    rows = therapist.get("/audit", params={"action": "patient.export", "patient_id": pid}).json()
    assert sorted(row["new"]["format"] for row in rows) == ["fhir", "pdf"]

    # The progress filter's days are the therapist's too: the session counts on the day
    # their calendar shows it, which is not its UTC day (without tz the server counted none).
    (session,) = therapist.get("/sessions", params={"patient_id": pid}).json()
    day = datetime.fromisoformat(session["started_at"]).astimezone(ZoneInfo(zone)).date()
    page.get_by_label("From").fill(str(day))
    page.get_by_label("Until").fill(str(day))
    with page.expect_response(lambda r: "/progress?" in r.url) as answer:
        page.get_by_role("button", name="Show").click()
    assert parse_qs(urlsplit(answer.value.url).query)["tz"] == [zone]
    assert sum(e["sessions"] for e in answer.value.json()["exercises"]) == 1
