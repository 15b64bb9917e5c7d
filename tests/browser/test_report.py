"""The therapist downloads the patient's report from the patient's page, in a real browser
against the real server: a period picker, the PDF and the FHIR bundle, each saved under the
server's file name and read back."""

from __future__ import annotations

import concurrent.futures
import hashlib
import io
import json
import os
import subprocess
import sys
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from playwright.sync_api import Page, expect
from pypdf import PdfReader

from server.cli import provision_demo, wait_healthy
from server.config import Settings
from tests.browser.a11y import assert_controls_labelled
from tests.server.test_series import HZ, recording_bytes, samples
from tests.system.harness import free_port

API = "/api/v1"


@dataclass
class Clinic:
    """The server alone (``ankle server`` in a process of its own) with the demo's records:
    the report needs no device."""

    url: str
    creds: dict[str, Any]


@pytest.fixture
def therapist(clinic: Clinic) -> Iterator[httpx.Client]:
    """The demo therapist's REST client: the independent witness of what the page did."""
    with httpx.Client(base_url=f"{clinic.url}{API}", timeout=30) as client:
        r = client.post(
            "/auth/login",
            json={
                "email": clinic.creds["therapist_email"],
                "password": clinic.creds["therapist_password"],
            },
        )
        assert r.status_code == 200, r.text
        client.headers["Authorization"] = f"Bearer {r.json()['access_token']}"
        yield client


@pytest.fixture
def clinic(tmp_path: Path) -> Iterator[Clinic]:
    port = free_port()
    settings = Settings(data_dir=tmp_path / "server", port=port)
    with concurrent.futures.ThreadPoolExecutor(1) as pool:  # Playwright holds this loop
        creds = pool.submit(provision_demo, settings).result()
    env = {**os.environ, "ANKLE_DATA_DIR": str(settings.data_dir), "ANKLE_PORT": str(port)}
    with (tmp_path / "server.log").open("wb") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "ankle", "server"], env=env, stdout=log, stderr=log
        )
    url = f"http://127.0.0.1:{port}"
    try:
        wait_healthy(url, proc, timeout=60.0)
        yield Clinic(url, creds)
    finally:
        proc.terminate()
        proc.wait(30)


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
    clinic: Clinic, therapist: httpx.Client, page: Page, shots: Path, tmp_path: Path
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
    today = datetime.now(UTC).date()
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
    pdf = got.value
    assert pdf.suggested_filename == f"{stem}.pdf"
    pdf.save_as(tmp_path / pdf.suggested_filename)
    text = " ".join(
        p.extract_text()
        for p in PdfReader(io.BytesIO((tmp_path / f"{stem}.pdf").read_bytes())).pages
    )
    assert clinic.creds["patient_name"] in text and "1 session in the period" in text
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

    # Both downloads left the system on the record; the refused one did not.
    rows = therapist.get("/audit", params={"action": "patient.export", "patient_id": pid}).json()
    assert sorted(row["new"]["format"] for row in rows) == ["fhir", "pdf"]
