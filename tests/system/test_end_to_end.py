"""Prescribe → the station runs it on the simulated device → the therapist watches live and
changes K → the device ACKs → the session is recorded, uploaded, summarised, downloaded in
every format and read back."""

from __future__ import annotations

import asyncio
import csv
import hashlib
import io
import json
import time

import httpx
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader

from sessions import wire
from tests.system.harness import System, bearer, live, next_of, short_strength

STRENGTH = short_strength("End-to-end test", repetitions=2)


async def wait_session(
    client: httpx.AsyncClient, prescription_id: int, timeout: float = 60.0
) -> dict:  # type: ignore[type-arg]
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        r = await client.get("/api/v1/sessions", params={"prescription_id": prescription_id})
        assert r.status_code == 200, r.text
        if r.json():
            return dict(r.json()[0])
        await asyncio.sleep(0.5)
    raise TimeoutError("the session never reached the server")


@pytest.mark.asyncio
async def test_prescribe_run_watch_change_k_and_download(
    system: System, therapist: httpx.AsyncClient
) -> None:
    patient = system.creds["patient_id"]
    r = await therapist.post(f"/api/v1/patients/{patient}/prescriptions", json=STRENGTH)
    assert r.status_code == 201, r.text
    pid = r.json()["id"]

    system.start_station()
    ws = await live(system, bearer(therapist))
    try:
        welcome = await next_of(ws, wire.Welcome)
        assert welcome.station_id == system.station_id
        # The station is up once it reports a connected device.
        deadline = time.monotonic() + 60
        while True:
            status = await next_of(ws, wire.StatusMsg, timeout=deadline - time.monotonic())
            if status.device_link == "connected":
                break

        await ws.send(
            wire.Command(
                request_id="start-1", action="start", prescription_id=pid
            ).model_dump_json()
        )
        started = await next_of(ws, wire.CommandResult)
        assert started.request_id == "start-1" and started.ok, started

        # Live telemetry at >= 30 Hz while the exercise runs.
        deadline = time.monotonic() + 60
        while (await next_of(ws, wire.TelemetryMsg)).mode != "ACTIVE":
            assert time.monotonic() < deadline, "the exercise never started"
        t0, count, sent_ts = time.monotonic(), 0, []
        while time.monotonic() - t0 < 1.5:
            batch = await next_of(ws, wire.TelemetryBatch)
            count += len(batch)
            sent_ts.append(time.time() - batch.sent)
        rate = count / (time.monotonic() - t0)
        assert rate >= 30.0, rate
        assert sorted(sent_ts)[len(sent_ts) // 2] < 0.1  # fresh, not queued

        # A live K change: the device's own ACK comes back, then telemetry shows the new K.
        await ws.send(
            wire.Command(
                request_id="k-1", action="set_impedance", stiffness={"pitch": 80.0}
            ).model_dump_json()
        )
        result = await next_of(ws, wire.CommandResult)
        assert result.request_id == "k-1"
        assert result.ok and result.code == "", result
        assert 0 < result.rtt_ms < 1000
        deadline = time.monotonic() + 5
        k = 0.0
        while time.monotonic() < deadline and abs(k - 80.0) > 0.5:
            k = (await next_of(ws, wire.TelemetryMsg)).stiffness[4]
        assert k == pytest.approx(80.0, abs=0.5)

        # The exercise runs to its end.
        deadline = time.monotonic() + 60
        final = await next_of(ws, wire.StatusMsg)
        while final.phase not in ("done", "stopped", "fault"):
            final = await next_of(ws, wire.StatusMsg, timeout=deadline - time.monotonic())
        assert final.phase == "done", final
    finally:
        await ws.close()

    session = await wait_session(therapist, pid)
    assert session["end_reason"] == "completed"
    summary = session["summary"]
    assert summary["repetitions_completed"] == 2
    assert summary["repetitions_prescribed"] == 2
    pitch = summary["axes"]["pitch"]
    assert 3.0 < pitch["rom_deg"] < 20.0, pitch  # a 6 deg sine, partly resisted
    assert summary["events"].get("impedance", 0) >= 1

    # Every download reads back with its own library and matches its hash.
    downloads = {}
    for fmt, url in session["downloads"].items():
        r = await therapist.get(url)
        assert r.status_code == 200, (fmt, r.text[:200])
        assert hashlib.sha256(r.content).hexdigest() == r.headers["x-content-sha256"], fmt
        downloads[fmt] = r.content
    assert hashlib.sha256(downloads["rec"]).hexdigest() == session["sha256"]
    rows = list(csv.DictReader(io.StringIO(downloads["csv"].decode())))
    assert len(rows) == summary["samples"]
    assert max(float(r["pitch_deg"]) for r in rows) > 2.0
    table = pq.read_table(io.BytesIO(downloads["parquet"]))
    assert table.num_rows == summary["samples"]
    reader = make_reader(io.BytesIO(downloads["mcap"]))
    topics = {ch.topic for _, ch, _ in reader.iter_messages()}
    assert "/telemetry" in topics
    assert json.loads(downloads["json"])["summary"]["repetitions_completed"] == 2

    # The live change is in the audit log with who, old and new.
    r = await therapist.get("/api/v1/audit", params={"patient_id": patient})
    actions = {row["action"]: row for row in r.json()}
    assert "prescription.create" in actions
    change = actions["impedance.change"]
    assert change["new"]["stiffness"] == {"pitch": 80.0}
    assert change["old"]["stiffness"]["pitch"] == pytest.approx(40.0, abs=0.5)
    assert change["actor"].startswith("user:")
