"""The therapist's patient list, patient page and prescription form, in a browser against the
real system: what the pages show is checked against what the API holds."""

from __future__ import annotations

import asyncio
import concurrent.futures
import hashlib
import math
import re
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from playwright.sync_api import Locator, Page, expect

from device.limits import SafetyLimits
from sessions import wire
from sessions.recording import End, EndReason, SessionEvent
from tests.browser import rest
from tests.browser.a11y import assert_controls_labelled
from tests.server.live_server import STRENGTH
from tests.server.test_attention import recording
from tests.server.test_series import HZ, recording_bytes, samples
from tests.system.harness import System, live, next_of, short_strength

API = "/api/v1"
SESSION_S = 90.0
"""Station start, homing, a short exercise and the upload, with room for a slow machine."""


@pytest.fixture
def client(system: System) -> Iterator[httpx.Client]:
    """The demo therapist's own REST client: the independent witness of what a page did."""
    with httpx.Client(base_url=system.url, timeout=30.0) as c:
        r = c.post(
            f"{API}/auth/login",
            json={
                "email": system.creds["therapist_email"],
                "password": system.creds["therapist_password"],
            },
        )
        assert r.status_code == 200, r.text
        c.headers["Authorization"] = f"Bearer {r.json()['access_token']}"
        yield c


def get(client: httpx.Client, path: str, **params: Any) -> Any:
    r = client.get(f"{API}{path}", params=params)
    assert r.status_code == 200, r.text
    return r.json()


def sign_in(page: Page, system: System) -> None:
    page.goto(f"{system.url}/app/patients")
    page.get_by_label("Email").fill(system.creds["therapist_email"])
    page.get_by_label("Password").fill(system.creds["therapist_password"])
    page.get_by_role("button", name="Sign in").click()
    expect(page).to_have_url(f"{system.url}/app/patients")


def field(page: Page, path: str) -> Locator:
    return page.locator(f'[data-field="{path}"]')


def error_beside(page: Page, path: str) -> Locator:
    return page.locator(f'[data-error-for="{path}"]')


def test_patient_list_and_adding_a_patient(
    system: System, page: Page, client: httpx.Client, shots: Path
) -> None:
    before = get(client, "/patients")
    sign_in(page, system)
    demo = page.locator(f'tr[data-patient-id="{system.creds["patient_id"]}"]')
    expect(demo).to_contain_text(system.creds["patient_name"])
    expect(demo).to_contain_text("Offline")  # its station is provisioned but not running
    expect(demo).to_contain_text("No sessions yet")

    # A blank name and a birth year in the future: both refused, each message by its field.
    form = page.locator("#add-patient")
    form.get_by_label("Display name").fill("   ")
    form.get_by_label("Birth year").fill("3000")
    form.get_by_role("button", name="Add patient").click()
    expect(error_beside(page, "display_name")).to_have_text("Display name is required.")
    expect(error_beside(page, "birth_year")).to_have_text("Birth year 3000 is in the future.")
    expect(field(page, "display_name")).to_have_attribute("aria-invalid", "true")
    expect(field(page, "display_name")).to_be_focused()
    assert get(client, "/patients") == before, "a refused form created a patient"

    form.get_by_label("Display name").fill("R. K.")
    form.get_by_label("Reference").fill("RK-2031")
    form.get_by_label("Birth year").fill("1961")
    form.get_by_label("Affected side").select_option("left")
    # The API takes any weight within its bounds (its schema has no step): so does the page,
    # which said 72.55 did not fit its 0.1 kg step and then saved it.
    form.get_by_label("Body weight").fill("68.55")
    assert form.get_by_label("Body weight").evaluate("e => e.validity.valid")
    # A pasted link is one long word: it must wrap, not widen the page.
    notes = "Lateral sprain, grade II. Imaging: https://pacs.example/" + "A1b2C3d4E5" * 40
    form.get_by_label("Notes").fill(notes)
    form.get_by_role("button", name="Add patient").click()
    expect(page.get_by_role("status").filter(has_text="Added “R. K.”")).to_be_visible()
    expect(error_beside(page, "display_name")).to_be_empty()

    after = get(client, "/patients")
    assert len(after) == len(before) + 1
    new = after[-1]
    assert (new["display_name"], new["reference"], new["birth_year"]) == ("R. K.", "RK-2031", 1961)
    assert (new["affected_side"], new["notes"]) == ("left", notes)
    assert new["weight_kg"] == 68.55
    row = page.locator(f'tr[data-patient-id="{new["id"]}"]')
    expect(row).to_contain_text("RK-2031")
    expect(row).to_contain_text("Left")
    expect(row).to_contain_text("None provisioned")
    page.screenshot(path=shots / "patients.png", full_page=True)
    assert_controls_labelled(page)

    row.get_by_role("link", name="R. K.").click()
    expect(page).to_have_url(f"{system.url}/app/patients/{new['id']}")
    expect(page.get_by_role("heading", level=1)).to_have_text("R. K.")
    expect(page.locator("#details")).to_contain_text("Lateral sprain, grade II.")
    expect(page.locator("#details")).to_contain_text("68.5 kg")
    wide = page.evaluate("() => document.documentElement.scrollWidth - window.innerWidth")
    assert wide <= 0, f"the notes' long word widened the page by {wide} px"
    expect(page.locator("#rx-active")).to_contain_text("No active prescription")
    expect(page.locator("#history-status")).to_have_text("No sessions recorded yet.")

    # Provisioning shows the station's token once; the token is the station's own key.
    page.get_by_label("New station's place").fill("Home, kitchen")
    page.get_by_role("button", name="Provision a home station").click()
    box = page.locator("#token-box")
    expect(box).to_contain_text("shown only this once")
    token = page.get_by_label("Station token").input_value()
    (station,) = get(client, "/stations", patient_id=new["id"])
    assert station["name"] == "Home, kitchen"
    me = rest.get(f"{system.url}{API}/station/me", headers={"Authorization": f"Bearer {token}"})
    assert me.status_code == 200, me.text
    assert (me.json()["id"], me.json()["patient_id"]) == (station["id"], new["id"])
    expect(page.locator(f'li[data-station-id="{station["id"]}"]')).to_contain_text("Offline")
    page.screenshot(path=shots / "patient-provisioned.png", full_page=True)
    box.get_by_role("button", name="I have saved it: hide the token").click()
    expect(box).to_be_hidden()
    expect(page.get_by_label("Station token")).to_have_count(0)


def test_prescribe_from_the_library_edit_and_withdraw(
    system: System, page: Page, client: httpx.Client, shots: Path
) -> None:
    r = client.post(f"{API}/patients", json={"display_name": "M. S.", "affected_side": "right"})
    assert r.status_code == 201, r.text
    patient = r.json()["id"]
    schemas = get(client, "/openapi.json")["components"]["schemas"]
    k_max = schemas["AxisPrescription"]["properties"]["stiffness"]["maximum"]
    balance = next(x for x in get(client, "/exercises") if x["kind"] == "balance")

    sign_in(page, system)
    page.goto(f"{system.url}/app/patients/{patient}")
    page.get_by_role("link", name="Prescribe an exercise").click()
    expect(page).to_have_url(f"{system.url}/app/patients/{patient}/prescribe")
    page.get_by_label("Exercise from the library").select_option("balance")
    expect(page.locator("#exercise-purpose")).to_contain_text(balance["purpose"])

    # The library's defaults fill the form, and its bounds are the API's published ones.
    roll_k, pitch = field(page, "axes.0.stiffness"), "axes.1"
    expect(page.locator("fieldset[data-axis]")).to_have_count(len(balance["defaults"]["axes"]))
    expect(roll_k).to_have_value(f"{balance['defaults']['axes'][0]['stiffness']:g}")
    expect(roll_k).to_have_attribute("max", f"{k_max:g}")
    expect(page.get_by_text("Stiffness K (N·m/rad)").first).to_be_visible()
    expect(page.get_by_text("Damping B (N·m·s/rad)").first).to_be_visible()
    # K per degree beside the per-radian value; pitch's own range, not -90..90
    expect(page.locator("#ax-roll-stiffness ~ output")).to_have_text(
        f"= {balance['defaults']['axes'][0]['stiffness'] * math.pi / 180:.3g} N·m/°"
    )
    expect(field(page, f"{pitch}.center")).to_have_attribute("max", re.compile(r"^22\.91"))
    expect(page.locator("#ax-pitch-center-range")).to_have_text("-20 to 22.9°")
    least = SafetyLimits().damping_min_at(4, 50.0)  # pitch, as the device publishes it
    expect(page.locator("#ax-pitch-damping-range")).to_contain_text(f"B ≥ {least:g} at K ≥ 50")
    # a right foot: roll above 0 is inversion, named from the API's direction table
    roll_box = page.locator('fieldset[data-axis="roll"]')
    expect(roll_box.locator("legend")).to_have_text("Roll (inversion / eversion)")
    expect(roll_box).to_contain_text("Angles above 0: Inversion (sole turned inwards).")
    expect(field(page, "sets")).to_have_value(str(balance["defaults"]["sets"]))
    torque_max = schemas["PrescriptionCreate"]["properties"]["torque_limit"]["maximum"]
    expect(field(page, "torque_limit")).to_have_attribute("max", f"{torque_max:g}")
    # Three axes at most, each once: only yaw is left to add.
    expect(page.locator("#add-axis option")).to_have_text(["Yaw (adduction / abduction)"])
    page.screenshot(path=shots / "prescribe.png", full_page=True)
    assert_controls_labelled(page)

    # Too stiff: refused before submitting, with the sentence the API publishes (and would
    # answer); then a sine that leaves the allowed pitch range, which only the API can judge:
    # its sentence appears beside the amplitude, the field it names.
    limits = get(client, "/exercises/limits", side="right")
    posts: list[str] = []
    page.on("request", lambda r: posts.append(r.url) if r.method == "POST" else None)
    roll_k.fill(f"{k_max + 100:g}")
    page.get_by_role("button", name="Prescribe").click()
    expect(error_beside(page, "axes.0.stiffness")).to_have_text(
        limits["axes"]["roll"]["fields"]["stiffness"]["above"]
    )
    expect(error_beside(page, "axes.0.stiffness")).to_contain_text(
        f"Stiffness K on roll must be at most {k_max:g} N·m/rad"
    )
    expect(roll_k).to_be_focused()
    assert posts == [], "a value past a published bound was sent"
    roll_k.fill("25")
    page.locator(f'[data-field="{pitch}.waveform"]').select_option("sine")
    field(page, f"{pitch}.amplitude").fill("40")
    field(page, f"{pitch}.frequency").fill("0.1")
    page.get_by_role("button", name="Prescribe").click()
    expect(error_beside(page, f"{pitch}.amplitude")).to_have_text(
        "The sine on pitch reaches -40 to 40°, outside the range -20 to 22.9°: lower the "
        "amplitude or move the center."
    )
    expect(error_beside(page, "axes.0.stiffness")).to_be_empty()
    assert get(client, f"/patients/{patient}/prescriptions") == []
    page.screenshot(path=shots / "prescribe-error.png", full_page=True)

    # Isometric does not render K and B: the form does not ask for them
    page.get_by_label("Exercise from the library").select_option("isometric")
    expect(page.locator("#compliance-note")).to_be_visible()
    expect(field(page, "axes.0.stiffness")).to_be_hidden()
    expect(field(page, "axes.0.damping")).to_be_hidden()
    page.screenshot(path=shots / "prescribe-isometric.png", full_page=True)
    page.get_by_label("Exercise from the library").select_option("balance")
    expect(field(page, "axes.0.stiffness")).to_be_visible()
    page.locator(f'[data-field="{pitch}.waveform"]').select_option("sine")
    field(page, f"{pitch}.frequency").fill("0.1")

    roll_k.fill("25")
    field(page, f"{pitch}.amplitude").fill("10")
    page.get_by_role("button", name="Prescribe").click()
    expect(page).to_have_url(f"{system.url}/app/patients/{patient}")
    expect(page.locator("#flash")).to_contain_text("version 1")

    (created,) = get(client, f"/patients/{patient}/prescriptions")
    assert created["version"] == 1 and created["body"]["exercise"] == "balance"
    roll, pitch_axis = created["body"]["axes"]
    assert (roll["axis"], roll["stiffness"]) == ("roll", 25.0)
    assert (pitch_axis["waveform"], pitch_axis["amplitude"]) == ("sine", 10.0)
    card = page.locator(f'article[data-prescription-id="{created["id"]}"]')
    # K and B as the form writes them: per radian and per degree (25·π/180 = 0.436).
    k_cell = card.locator("tbody tr").first.locator("td").nth(0)
    expect(k_cell).to_have_text("25 N·m/rad0.436 N·m/°")
    expect(k_cell.locator(".pt-per-degree")).to_have_text("0.436 N·m/°")
    kb = created["impedance_text"][0]
    expect(card.locator("tbody tr").first.locator("td").nth(1)).to_have_text(
        kb["damping"] + kb["damping_per_degree"]
    )
    assert kb["damping"].endswith(" N·m·s/rad") and kb["damping_per_degree"].endswith(" N·m·s/°")
    card.screenshot(path=shots / "prescription-card.png")
    expect(card).to_contain_text("Sine 0.0° ± 10.0° at 0.10 Hz")
    expect(card).to_contain_text("version 1")

    card.get_by_role("link", name=re.compile("^Edit")).click()
    expect(page).to_have_url(f"{system.url}/app/patients/{patient}/prescribe?edit={created['id']}")
    expect(roll_k).to_have_value("25")
    expect(page.get_by_label("Exercise from the library")).to_have_value("balance")
    field(page, "repetitions").fill("4")
    page.get_by_role("button", name="Save as version 2").click()
    expect(page).to_have_url(f"{system.url}/app/patients/{patient}")
    edited = get(client, f"/prescriptions/{created['id']}")
    assert (edited["version"], edited["body"]["repetitions"]) == (2, 4)
    assert edited["body"]["axes"] == created["body"]["axes"]
    expect(card).to_contain_text("version 2")
    expect(card).to_contain_text(f"{edited['body']['sets']} × 4 repetitions")

    card.get_by_role("button", name="Withdraw").click()
    card.get_by_role("button", name="Yes, withdraw").click()
    expect(page.locator("#rx-active")).to_contain_text("No active prescription")
    expect(page.locator("#rx-earlier summary")).to_have_text("Earlier prescriptions (1)")
    assert get(client, f"/prescriptions/{created['id']}")["status"] == "cancelled"


SHORT = short_strength("Short strength", repetitions=2)


async def run_session(system: System, token: str, prescription_id: int) -> None:
    """Start one exercise on the running station, as the live page does, and let it end."""
    ws = await live(system, token)
    try:
        deadline = time.monotonic() + SESSION_S
        while (await next_of(ws, wire.StatusMsg, SESSION_S)).device_link != "connected":
            assert time.monotonic() < deadline, "the station never reached its device"
        await ws.send(
            wire.Command(
                request_id="start", action="start", prescription_id=prescription_id
            ).model_dump_json()
        )
        result = await next_of(ws, wire.CommandResult)
        assert result.ok, result
        status = await next_of(ws, wire.StatusMsg)
        while status.phase not in ("done", "stopped", "fault"):
            status = await next_of(ws, wire.StatusMsg, deadline - time.monotonic())
        assert status.phase == "done", status
    finally:
        await ws.close()


def test_demo_patient_station_online_and_progress_charts(
    system: System, page: Page, client: httpx.Client, shots: Path
) -> None:
    patient, station = system.creds["patient_id"], system.station_id
    sign_in(page, system)
    page.goto(f"{system.url}/app/patients/{patient}")
    stations = page.locator("#stations")
    expect(stations.locator(f'li[data-station-id="{station}"]')).to_contain_text("Offline")
    expect(page.locator("#chart-progress [data-empty]")).to_contain_text("No recorded session")
    # Adherence needs no session: it says what was prescribed and that none was done.
    (demo_rx,) = get(client, f"/patients/{patient}/prescriptions")
    expect(page.locator(f"#chart-adherence-{demo_rx['id']}-canvas")).to_have_attribute(
        "aria-label",
        re.compile(
            f"This week 0 of {demo_rx['body']['sessions_per_week']} prescribed sessions completed"
        ),
    )

    system.start_station()
    badge = stations.locator(f'li[data-station-id="{station}"] .badge')
    expect(badge).to_have_text("Online", timeout=60_000)
    expect(stations.get_by_role("link", name="Watch live")).to_have_attribute(
        "href", f"/app/live/{station}"
    )

    r = client.post(f"{API}/patients/{patient}/prescriptions", json=SHORT)
    assert r.status_code == 201, r.text
    rx = r.json()["id"]
    token = str(client.headers["Authorization"]).split(" ", 1)[1]
    # In a thread: Playwright's sync API keeps an event loop running in this one.
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        try:
            pool.submit(asyncio.run, run_session(system, token, rx)).result(SESSION_S * 2)
        except Exception as e:
            # The processes' logs say why (device link, station, upload): keep them.
            raise AssertionError(f"the session did not run: {e!r}\n{system.log_tail()}") from e
    deadline = time.monotonic() + 60
    while not (sessions := get(client, "/sessions", patient_id=patient)):
        assert time.monotonic() < deadline, "the session never reached the server"
        time.sleep(0.5)
    (session,) = sessions
    pitch = session["summary"]["metrics"]["axes"]["pitch"]
    # A strength session: the target followed the patient, so no time in target.
    assert session["summary"]["axes"]["pitch"]["time_in_target_pct"] is None

    page.reload()
    row = page.locator(f'tr[data-session-id="{session["id"]}"]')
    expect(row).to_contain_text("Short strength")
    expect(row).to_contain_text("2 / 2")
    expect(row).to_contain_text("Completed")
    expect(row.get_by_role("link")).to_have_attribute("href", f"/app/sessions/{session['id']}")

    # Strength has its own chart, a line per direction named by the API's direction table,
    # drawn from the progress API; its y axis titled short enough not to be clipped.
    canvas = page.locator("#chart-strength-canvas")
    expect(canvas).to_be_visible()
    drawn = canvas.evaluate("c => Chart.getChart(c).data.datasets.map(d => [d.label, d.data])")
    assert drawn == [
        ["Plantarflexion (toes down)", [pytest.approx(pitch["positive"]["peak_torque_nm"])]],
        ["Dorsiflexion (toes up)", [pytest.approx(pitch["negative"]["peak_torque_nm"])]],
    ]
    y_title = canvas.evaluate("c => Chart.getChart(c).options.scales.y.title.text")
    assert y_title == "N·m"
    page.locator("#chart-strength summary").click()
    expect(page.locator("#chart-strength table tbody")).to_contain_text(
        f"{pitch['positive']['peak_torque_nm']:.1f}"
    )
    expect(page.locator("#progress-mdc")).to_contain_text("no ROM assessment yet")

    # Adherence per prescription: the new one has its session, the demo's none; neither
    # adds the other's sessions or prescribed counts.
    adherence = page.locator(f"#chart-adherence-{rx}-canvas")
    weekly = adherence.evaluate("c => Chart.getChart(c).data.datasets.map(d => d.data.at(-1))")
    asked = get(client, f"/prescriptions/{rx}")["body"]["sessions_per_week"]
    assert weekly == [1, 0, 0, 0, asked]  # completed, extra, ended early, missed, prescribed
    expect(adherence).to_have_attribute(
        "aria-label", re.compile(f"This week 1 of {asked} prescribed sessions completed")
    )
    expect(page.locator(f"#chart-adherence-{demo_rx['id']}-canvas")).to_have_attribute(
        "aria-label",
        re.compile(
            f"This week 0 of {demo_rx['body']['sessions_per_week']} prescribed sessions completed"
        ),
    )

    # One exercise type and a date range: the form asks the API again; a range that ends
    # before it starts is refused with the API's sentence, and the charts stay.
    page.get_by_label("Exercise type").select_option("rom_assessment")
    page.get_by_role("button", name="Show").click()
    expect(page.locator("#chart-progress [data-empty]")).to_contain_text("No recorded session")
    page.get_by_label("From").fill("2030-01-02")
    page.get_by_label("Until").fill("2030-01-01")
    page.get_by_role("button", name="Show").click()
    expect(page.locator("#progress-error")).to_contain_text("since (2030-01-02) must be before")
    page.get_by_label("From").fill("")
    page.get_by_label("Until").fill("")
    page.get_by_label("Exercise type").select_option("")
    page.get_by_role("button", name="Show").click()
    expect(page.locator("#progress-error")).to_be_hidden()
    expect(page.locator("#chart-strength-canvas")).to_be_visible()
    page.screenshot(path=shots / "patient.png", full_page=True)
    assert_controls_labelled(page)


def patient_with_station(client: httpx.Client, name: str, side: str) -> tuple[int, int, str]:
    """A new patient of the demo therapist with a home station: (patient, station, token)."""
    r = client.post(f"{API}/patients", json={"display_name": name, "affected_side": side})
    assert r.status_code == 201, r.text
    patient: int = r.json()["id"]
    r = client.post(f"{API}/patients/{patient}/stations", json={"name": "Home"})
    assert r.status_code == 201, r.text
    return patient, r.json()["id"], r.json()["token"]


def _upload(system: System, token: str, data: bytes, sid: str) -> int:
    """File a recording as a station does, with the station's own token."""
    station = {"Authorization": f"Bearer {token}"}
    r = rest.patch(
        f"{system.url}{API}/uploads/{sid}",
        content=data,
        headers={**station, "Upload-Offset": "0"},
        timeout=30.0,
    )
    assert r.status_code == 204, r.text
    body = {"size": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    r = rest.post(
        f"{system.url}{API}/uploads/{sid}/complete", json=body, headers=station, timeout=30.0
    )
    assert r.status_code == 201, r.text
    session_id: int = r.json()["id"]
    return session_id


def test_needs_attention_links_to_where_it_happened(
    system: System, page: Page, client: httpx.Client, shots: Path
) -> None:
    patient, station, token = patient_with_station(client, "A. T.", "left")
    r = client.post(f"{API}/patients/{patient}/prescriptions", json=STRENGTH)
    assert r.status_code == 201, r.text
    rx = r.json()["id"]
    started = time.time() - 7200
    ids = {}
    cases: list[tuple[str, EndReason, list[tuple[str, str]]]] = [
        ("fault", "fault", [("fault", "device")]),
        ("held", "stopped", [("hold", "patient")]),
    ]
    for name, reason, events in cases:
        sid = str(uuid.uuid4())
        end = End(ended_at=started + 2, reason=reason, sets_completed=0, repetitions_completed=2)
        evs = [
            SessionEvent(wall=started + 1, kind=k, by=by, detail={"text": "valve 3 stuck"})
            for k, by in events
        ]
        data = recording(sid, station, patient, rx, started, end, evs)
        ids[name] = _upload(system, token, data, sid)
        started += 600

    sign_in(page, system)
    items = page.locator(f'#attention li[data-patient-id="{patient}"]')
    expect(items.filter(has_text="Fault")).to_have_count(1)
    expect(items.filter(has_text="Fault")).to_contain_text("valve 3 stuck")
    expect(items.filter(has_text="Held")).to_contain_text("The exercise was held once.")
    expect(items.filter(has_text="Ended early")).to_contain_text("2 of 30 repetitions")
    assert_controls_labelled(page)
    page.screenshot(path=shots / "patients-attention.png", full_page=True)
    items.filter(has_text="Fault").get_by_role("link", name="Review the session").click()
    expect(page).to_have_url(f"{system.url}/app/sessions/{ids['fault']}")


def test_progress_is_in_the_first_screen_of_a_tablet_held_upright(
    system: System, page: Page, client: httpx.Client, shots: Path
) -> None:
    """768 x 1024: the progress charts come right after the patient's details, two side by
    side, so however many prescriptions the patient has, the first chart starts on the first
    screen."""
    patient, station, token = patient_with_station(client, "T. P.", "right")
    rxs = []
    for title in ("Strength, morning", "Strength, evening", "Strength, weekend"):
        r = client.post(
            f"{API}/patients/{patient}/prescriptions", json={**STRENGTH, "title": title}
        )
        assert r.status_code == 201, r.text
        rxs.append(r.json()["id"])
    started = time.time() - 3 * 86_400
    for _ in range(2):
        sid = str(uuid.uuid4())
        rows = samples()[:3000]  # 30 s: one upload request
        rows["wall"] = started + np.arange(len(rows)) / HZ
        _upload(system, token, recording_bytes(sid, rows, station, patient, rxs[0]), sid)
        started += 86_400

    sign_in(page, system)
    page.set_viewport_size({"width": 768, "height": 1024})
    page.goto(f"{system.url}/app/patients/{patient}")
    expect(page.locator("#chart-strength-canvas")).to_be_visible()
    expect(page.locator(".pt-rx")).to_have_count(3)
    first = page.locator("#chart-strength").bounding_box()
    beside = page.locator(f"#chart-adherence-{rxs[0]}").bounding_box()
    assert first is not None and beside is not None
    assert first["y"] >= 0 and first["y"] + 200 <= 1024, first  # its top and title in view
    # The width is used: the next chart sits beside the first, not under it.
    assert beside["y"] == pytest.approx(first["y"], abs=2)
    assert beside["x"] >= first["x"] + first["width"]
    # The prescriptions, below, still fit their cards: no sideways scrolling.
    tables = page.locator(".pt-rx .pt-scroll")
    for i in range(tables.count()):
        sizes = tables.nth(i).evaluate("e => [e.scrollWidth, e.clientWidth]")
        assert sizes[0] <= sizes[1], sizes
    page.screenshot(path=shots / "patient-tablet-portrait.png")
