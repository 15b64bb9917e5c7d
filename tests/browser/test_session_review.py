"""The therapist reviews a real session in a real browser: the station runs the demo
prescription on the simulated device and uploads it; the session page shows the summary,
charts over the whole session and the 3D replay, and every download reads back."""

from __future__ import annotations

import csv
import io
import json
import time
from pathlib import Path
from typing import Any

import httpx
import pyarrow.parquet as pq
from mcap.reader import make_reader
from playwright.sync_api import BrowserContext, Page, expect

from sessions.recording import decode
from tests.browser.a11y import assert_controls_labelled
from tests.system.harness import System

FORMATS = ("csv", "parquet", "mcap", "json", "rec")


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
        env={"ANKLE_STATION_TOKEN": system.creds["station_token"]},
    )
    with httpx.Client(base_url=f"{system.url}/api/v1", timeout=30.0) as client:
        r = client.post(
            "/auth/login",
            json={
                "email": system.creds["therapist_email"],
                "password": system.creds["therapist_password"],
            },
        )
        r.raise_for_status()
        client.headers["Authorization"] = f"Bearer {r.json()['access_token']}"
        deadline = time.monotonic() + 240  # a loaded machine runs the simulation slowly
        while time.monotonic() < deadline:
            sessions = client.get("/sessions").json()
            if sessions:
                session: dict[str, Any] = sessions[0]
                return session
            assert system.station.poll() is None, system.log_tail()
            time.sleep(0.5)
    raise AssertionError(f"no session reached the server\n{system.log_tail()}")


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

    # Charts over the whole session: four uPlot canvases with a size, and lines on them.
    for chart in ("angle", "torque", "pressure", "impedance"):
        canvas = page.locator(f"#chart-{chart} canvas")
        expect(canvas).to_have_count(1)
        box = canvas.bounding_box()
        assert box is not None and box["width"] > 300 and box["height"] > 100, (chart, box)
    expect(page.locator("#series-note")).to_contain_text(f"{samples} samples")
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

    # Every download button, read back with its own library; each holds every sample.
    for fmt in FORMATS:
        button = page.get_by_role("button", name=f"Download {fmt.upper()}", exact=False)
        with page.expect_download() as caught:
            button.click()
        download = caught.value
        assert download.suggested_filename == f"session-{sid}.{fmt}"
        data = Path(download.path()).read_bytes()
        assert rows_in(fmt, data) == samples, fmt
    expect(page.locator("#download-status")).to_contain_text(f"session-{sid}.rec")

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
