"""The therapist reviews a real session in a real browser: the station runs the demo
prescription on the simulated device and uploads it; the session page shows the summary,
charts over the whole session and the 3D replay, and every download reads back."""

from __future__ import annotations

import csv
import functools
import hashlib
import io
import json
import re
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from email.message import Message
from pathlib import Path
from typing import Any

import httpx
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader
from playwright.sync_api import BrowserContext, Page, Route, expect

from sessions.anatomy import label
from sessions.prescription import EXERCISE_LIBRARY, ExerciseKind
from sessions.recording import decode
from tests.browser import rest
from tests.browser.a11y import assert_controls_labelled
from tests.server.test_progress_route import assessment_rows
from tests.server.test_series import recording_bytes
from tests.system.harness import System

FORMATS = ("csv", "parquet", "mcap", "json", "rec")


@contextmanager
def therapist(system: System) -> Iterator[httpx.Client]:
    """An API client signed in as the demo therapist."""
    with httpx.Client(base_url=f"{system.url}/api/v1", timeout=30.0) as client:
        yield rest.signed_in(client, system.creds, "/auth/login")


def run_one_session(system: System) -> dict[str, Any]:
    """Start the station with ``--autostart`` and wait for its session on the server."""
    system.station = system._spawn(
        "station",
        "station",
        "--device",
        system.device.link,
        "--server",
        system.station_url,
        "--spool",
        str(system.spool),
        "--autostart",
        "--page-port",
        "0",  # no patient's page: 8765 may be another station's (another test run's)
        env={"ANKLE_STATION_TOKEN": system.creds["station_token"]},
    )
    with therapist(system) as client:
        deadline = time.monotonic() + 240  # a loaded machine runs the simulation slowly
        while time.monotonic() < deadline:
            sessions = client.get("/sessions").json()
            if sessions:
                session: dict[str, Any] = sessions[0]
                return session
            assert system.station.poll() is None, system.log_tail()
            time.sleep(0.5)
    raise AssertionError(f"no session reached the server\n{system.log_tail()}")


def server_names(system: System, sid: int) -> dict[str, str]:
    """The file name the server suggests for each download, read from its Content-Disposition
    by the standard library's MIME parser (RFC 2231 included), not by the page's code."""
    token = rest.post(
        f"{system.url}/api/v1/auth/login",
        json={
            "email": system.creds["therapist_email"],
            "password": system.creds["therapist_password"],
        },
    ).json()["access_token"]
    names: dict[str, str] = {}
    for fmt in FORMATS:
        r = rest.get(
            f"{system.url}/api/v1/sessions/{sid}/download/{fmt}",
            headers={"Authorization": f"Bearer {token}"},
            timeout=60.0,
        )
        assert r.status_code == 200, r.text
        header = Message()
        header["Content-Disposition"] = r.headers["Content-Disposition"]
        name = header.get_filename()
        assert name, r.headers["Content-Disposition"]
        names[fmt] = name
    return names


def set_weight(system: System, weight_kg: float) -> None:
    """Record the demo patient's body weight, as the patient form does."""
    with therapist(system) as client:
        r = client.patch(f"/patients/{system.creds['patient_id']}", json={"weight_kg": weight_kg})
        assert r.status_code == 200, r.text


def rows_in(fmt: str, data: bytes) -> int:
    """Samples in a download, read with the library a user would open it with."""
    if fmt == "csv":
        return len(list(csv.DictReader(io.StringIO(data.decode()))))
    if fmt == "parquet":
        return int(pq.read_table(io.BytesIO(data)).num_rows)
    if fmt == "mcap":
        reader = make_reader(io.BytesIO(data))
        return sum(1 for _, ch, _ in reader.iter_messages() if ch.topic == "/telemetry")
    if fmt == "json":
        return int(json.loads(data)["summary"]["samples"])
    return len(decode(data).samples)


def test_review_a_session_summary_charts_replay_and_downloads(
    system: System, page: Page, context: BrowserContext, shots: Path, tmp_path: Path
) -> None:
    session = run_one_session(system)
    sid, samples = session["id"], session["summary"]["samples"]
    assert samples > 1000  # the demo: 3 repetitions of 6 s at 100 Hz, and homing
    weight_kg = 80.0
    set_weight(system, weight_kg)

    # Sign in through the login page, which returns to the session.
    page.goto(f"{system.url}/app/sessions/{sid}")
    page.get_by_label("Email").fill(system.creds["therapist_email"])
    page.get_by_label("Password").fill(system.creds["therapist_password"])
    page.get_by_role("button", name="Sign in").click()
    expect(page).to_have_url(f"{system.url}/app/sessions/{sid}")

    # Summary.
    crumbs = page.get_by_role("navigation", name="Breadcrumbs")
    crumb = crumbs.get_by_role("link", name=system.creds["patient_name"])
    expect(crumb).to_have_attribute("href", f"/app/patients/{system.creds['patient_id']}")
    facts = page.locator("#facts")
    expect(facts).to_contain_text("3 of 3 prescribed")
    expect(facts).to_contain_text("Completed")
    expect(facts).to_contain_text(str(samples))
    pitch = page.locator("#axes tbody tr", has_text="pitch")
    expect(pitch).to_have_count(1)
    rom = session["summary"]["axes"]["pitch"]["rom_deg"]
    expect(pitch.locator("td").first).to_have_text(f"{rom:.1f}")
    expect(page.locator("#events")).to_contain_text("Repetitions done")
    expect(page.locator("#axes thead")).not_to_contain_text("Time in target")

    # The metrics that fit a strength exercise: per direction, named for the patient's side,
    # with torque per kilogram of body weight; per repetition; no tracking of a target that
    # followed the patient.
    metrics = session["summary"]["metrics"]
    assert metrics["kind"] == "strength" and metrics["tracking"] == {}
    expect(page.locator("#mx-kind")).to_contain_text("Strength")
    for sign, key in ((1, "positive"), (-1, "negative")):
        row = page.locator("#mx-directions tbody tr", has_text=label("pitch", sign, None))
        expect(row).to_have_count(1)
        peak = metrics["axes"]["pitch"][key]["peak_torque_nm"]
        cells = row.locator("td")
        expect(cells.nth(1)).to_have_text(f"{peak:.1f}")
        expect(cells.nth(2)).to_have_text(f"{peak / weight_kg:.2f}")
    reps = page.locator("#mx-repetitions tbody tr")
    expect(reps).to_have_count(2 * len(metrics["repetitions"]))
    assert len(metrics["repetitions"]) == 3
    expect(page.locator("#mx-tracking")).to_have_count(0)

    # Charts over the whole session: four uPlot canvases with a size, and lines on them.
    for chart in ("angle", "torque", "pressure", "impedance"):
        canvas = page.locator(f"#chart-{chart} canvas")
        expect(canvas).to_have_count(1)
        box = canvas.bounding_box()
        assert box is not None and box["width"] > 300 and box["height"] > 100, (chart, box)
    expect(page.locator("#series-note")).to_contain_text(f"{samples} samples")
    # The damping line is drawn apart from the stiffness line, not under it.
    k_y, b_y = page.locator("#chart-impedance").evaluate(
        """e => { const u = e.uplot; const n = u.series.length - 1;
        const last = (i) => u.data[i].findLast((v) => v != null);
        return [u.valToPos(last(1), "K"), u.valToPos(last(1 + n / 2), "B")]; }"""
    )
    assert abs(k_y - b_y) > 30, (k_y, b_y)
    legend = page.locator("#chart-angle .u-legend")
    expect(legend).to_contain_text("pitch target")

    # The 3D replay: built on first request, played by viser's viewer in the iframe.
    started = time.monotonic()
    page.get_by_role("button", name="Load 3D replay").click()
    expect(page.locator("#replay-status")).to_contain_text("Replay loaded", timeout=60_000)
    loaded_s = time.monotonic() - started
    frame = page.frame_locator("#replay")
    expect(frame.locator("canvas").first).to_be_visible(timeout=30_000)
    src = page.locator("#replay").get_attribute("src") or ""
    assert src.startswith("/api/v1/replay/viewer?playbackPath=blob%3A"), src
    viewer = next(f for f in page.frames if "/replay/viewer" in f.url)
    assert "initialCameraPosition=" in viewer.url  # the server's camera, not viser's default
    page.wait_for_timeout(2500)  # let the replay play a moment before the screenshot
    # A full page with a software-rendered WebGL frame in it is slow to capture.
    page.screenshot(path=shots / "session-review.png", full_page=True, timeout=90_000)
    assert_controls_labelled(page)

    # Every download button, read back with its own library; each holds every sample and
    # keeps the name the server gives it (with the session's date), not one the page makes.
    names = server_names(system, sid)
    for fmt in FORMATS:
        button = page.get_by_role("button", name=f"Download {fmt.upper()}", exact=False)
        with page.expect_download() as caught:
            button.click()
        download = caught.value
        assert download.suggested_filename == names[fmt], (fmt, names[fmt])
        assert re.fullmatch(rf"session-{sid}-\d{{8}}-\d{{6}}\.{fmt}", names[fmt]), names[fmt]
        data = Path(download.path()).read_bytes()
        assert rows_in(fmt, data) == samples, fmt
    expect(page.locator("#download-status")).to_contain_text(names["rec"])

    # The replay as one HTML file plays from disk, without the server.
    with page.expect_download() as caught:
        page.get_by_role("button", name="Download replay (HTML)").click()
    saved = tmp_path / caught.value.suggested_filename
    caught.value.save_as(saved)
    assert saved.name == f"session-{sid}-replay.html"
    offline = context.new_page()
    offline.goto(saved.as_uri())
    expect(offline.locator("canvas").first).to_be_visible(timeout=30_000)
    offline.close()
    print(
        f"\nsession {sid}: {samples} samples; replay built and shown in {loaded_s:.1f} s; "
        f"replay page {saved.stat().st_size / 1e6:.2f} MB"
    )


# (Content-Disposition, the name the page saves under); None: the page's own fallback.
DISPOSITIONS = [
    ('attachment; filename="session-7-20260301-101500.csv"', "session-7-20260301-101500.csv"),
    ("attachment; filename=plain.csv", "plain.csv"),
    (
        'attachment; filename="fallback.pdf"; '
        "filename*=UTF-8''Bericht%20J%C3%BCrgen%20%E2%82%AC.pdf",
        "Bericht Jürgen €.pdf",
    ),
    ("attachment; filename*=utf-8''r%C3%A9sum%C3%A9.json", "résumé.json"),
    ('attachment; filename="week 9; \\left\\.csv"', "week 9; left.csv"),
    ('attachment; filename="../../etc/passwd"', "passwd"),
    ("attachment; filename*=UTF-8''%E0%A4%A.csv; filename=\"ok.csv\"", "ok.csv"),
    ("attachment", None),
    ("", None),
]


def fulfil(route: Route, headers: dict[str, str], body: str) -> None:
    route.fulfill(status=200, headers=headers, body=body)


def test_a_download_takes_its_name_from_content_disposition(system: System, page: Page) -> None:
    """The page's download helper in a real browser: each header above is served at the
    browser's network boundary for a path of the page's own origin, and the file is saved
    under the name the header gives (the page's fallback only when it gives none)."""
    page.goto(f"{system.url}/app/login")
    for n, (header, expected) in enumerate(DISPOSITIONS):
        path = f"/api/v1/test-download/{n}"
        body = f"file {n}"

        headers = {"Content-Type": "application/octet-stream"}
        if header:
            headers["Content-Disposition"] = header
        page.route(f"**{path}", functools.partial(fulfil, headers=headers, body=body))
        with page.expect_download() as caught:
            saved = page.evaluate(
                """async ([path, n]) => {
                    const { download } = await import("/static/js/api.js");
                    return download(path.replace("/api/v1", ""), `fallback-${n}.bin`);
                }""",
                [path, n],
            )
        name = expected or f"fallback-{n}.bin"
        assert caught.value.suggested_filename == name, (header, caught.value.suggested_filename)
        assert saved == name, (header, saved)
        assert Path(caught.value.path()).read_text() == body


def test_rom_assessments_trials_and_progress_with_mdc(
    system: System, page: Page, shots: Path
) -> None:
    """Three ROM assessments of two trials each, uploaded as a station does: the review page
    lists the trials per direction; the patient's progress draws them against the baseline,
    with the MDC95 they give and the last change flagged as beyond it."""
    creds = system.creds
    now = time.time()
    history = [
        (now - 20 * 86_400, [(20.0, 10.0), (22.0, 12.0)]),
        (now - 13 * 86_400, [(21.0, 11.0), (23.0, 13.0)]),
        (now - 6 * 86_400, [(25.0, 10.0), (27.0, 12.0)]),
    ]
    station = {"Authorization": f"Bearer {creds['station_token']}"}
    with therapist(system) as client:
        body = EXERCISE_LIBRARY[ExerciseKind.ROM_ASSESSMENT].defaults.model_dump(mode="json")
        r = client.post(f"/patients/{creds['patient_id']}/prescriptions", json=body)
        assert r.status_code == 201, r.text
        rx = r.json()["id"]
        ids = []
        for k, (at, trials) in enumerate(history):
            sid = str(uuid.uuid4())
            trial_rows = assessment_rows(trials)
            if k == len(history) - 1:  # the last assessment's link stalled 5 s at its end
                trial_rows["t"][-10:] += 5.0
                trial_rows["wall"][-10:] += 5.0
            data = recording_bytes(
                sid,
                trial_rows,
                system.station_id,
                int(creds["patient_id"]),
                rx,
                repetitions=1,
                kind=ExerciseKind.ROM_ASSESSMENT,
                started_at=at,
            )
            r = client.patch(
                f"/uploads/{sid}", content=data, headers={**station, "Upload-Offset": "0"}
            )
            assert r.status_code == 204, r.text
            done = {"size": len(data), "sha256": hashlib.sha256(data).hexdigest()}
            r = client.post(f"/uploads/{sid}/complete", json=done, headers=station)
            assert r.status_code == 201, r.text
            ids.append(r.json()["id"])
        side = client.get(f"/patients/{creds['patient_id']}").json()["affected_side"]

    page.goto(f"{system.url}/app/sessions/{ids[-1]}")
    page.get_by_label("Email").fill(creds["therapist_email"])
    page.get_by_label("Password").fill(creds["therapist_password"])
    page.get_by_role("button", name="Sign in").click()
    expect(page.locator("#mx-kind")).to_contain_text("Range of motion assessment")
    rows = page.locator("#mx-trials tbody tr")
    expect(rows).to_have_count(2)
    head = page.locator("#mx-trials thead")
    expect(head).to_contain_text("Plantarflexion (toes down)")
    # Roll is named for the patient's side, through the one table of directions.
    expect(head).to_contain_text(label("roll", 1, side))
    expect(head).to_contain_text(label("roll", -1, side))
    expect(rows.nth(0)).to_contain_text("25.0")
    expect(rows.nth(1)).to_contain_text("27.0")
    expect(page.locator("#mx-tracking")).to_have_count(0)
    # Samples missing are said beside the samples' count, not left to read as whole.
    expect(page.locator("#gaps")).to_have_text(
        "(1 gap in the telemetry, 5 s missing: the numbers leave that time out)"
    )
    page.screenshot(path=shots / "session-review-rom.png", full_page=False)

    page.goto(f"{system.url}/app/patients/{creds['patient_id']}")
    chart = page.locator("#chart-rom_assessment")
    expect(chart).to_contain_text("a real change (beyond MDC95 3.9°)")
    expect(page.locator("#progress-mdc")).to_contain_text("3.9° (6 trials in 3 assessments)")
    # Roll is prescribed but never moved: no "MDC95 0.0°", and no change judged against it.
    never = "not measurable: never moved this way in 6 trials"
    expect(page.locator("#progress-mdc")).to_contain_text(f"{label('roll', 1, side)} {never}")
    expect(chart).to_contain_text(f"not judged, MDC95 {never}")
    expect(page.locator("#progress-mdc")).not_to_contain_text(" 0.0°")
    drawn = page.locator("#chart-rom_assessment-canvas").evaluate(
        """(c, name) => Chart.getChart(c).data.datasets
        .filter(d => d.label === name).map(d => [d.data, d.pointRadius])[0]""",
        label("pitch", 1, side),
    )
    values, radii = drawn
    assert values == pytest.approx([21.0, 22.0, 26.0], abs=1e-4)  # the device's float32
    assert radii[2] > radii[1] == radii[0]  # only the change beyond the MDC95 is marked
    # The baselines are drawn, dotted, but not listed in the legend: the plot keeps its height.
    legend, datasets, plot_h = page.locator("#chart-rom_assessment-canvas").evaluate(
        """c => { const ch = Chart.getChart(c);
        return [ch.legend.legendItems.map(i => i.text), ch.data.datasets.map(d => d.label),
                ch.chartArea.height]; }"""
    )
    assert f"{label('pitch', 1, side)}: baseline" in datasets
    assert legend == [d for d in datasets if not d.endswith(": baseline")] and len(legend) == 4
    assert plot_h >= 120, plot_h
    expect(chart).to_contain_text("Dotted lines: the baselines.")
    page.locator("#chart-rom_assessment summary").click()
    expect(page.locator("#chart-rom_assessment table")).to_contain_text("+5.0° real change")
    chart.screenshot(path=shots / "progress-rom.png")
