"""The real station, server and simulated device: telemetry in batches reaches a viewer that
keeps up sample by sample, and the session's recording still has every sample."""

from __future__ import annotations

import asyncio
import io
import time

import httpx
import numpy as np
import pyarrow.parquet as pq
import pytest

from sessions import wire
from tests.system.harness import System, bearer, live, next_of, short_strength

DEVICE_HZ = 100  # the simulated device's default telemetry rate


def key(t: float) -> int:
    """A device time to 0.1 ms: samples are 10 ms apart, the export keeps 6 decimals."""
    return round(t * 1e4)


@pytest.mark.asyncio
async def test_every_sample_reaches_the_viewer_and_the_recording(
    system: System, therapist: httpx.AsyncClient
) -> None:
    patient = system.creds["patient_id"]
    r = await therapist.post(
        f"/api/v1/patients/{patient}/prescriptions",
        json=short_strength("Batches test", repetitions=1),
    )
    assert r.status_code == 201, r.text
    pid = r.json()["id"]
    system.start_station("--batch-hz", "20")  # 5 samples a message

    ws = await live(system, bearer(therapist))
    seen: list[float] = []
    sizes: list[int] = []
    arrivals: list[float] = []
    try:
        deadline = time.monotonic() + 60
        while (await next_of(ws, wire.StatusMsg, deadline - time.monotonic())).device_link != (
            "connected"
        ):
            pass
        start = wire.Command(request_id="start-b", action="start", prescription_id=pid)
        await ws.send(start.model_dump_json())
        deadline = time.monotonic() + 90
        phase = "idle"
        while phase not in ("done", "stopped", "fault", "interrupted"):
            message = await next_of(ws, object, deadline - time.monotonic())
            if isinstance(message, wire.TelemetryBatch):
                seen.extend(s.t for s in message.samples())
                sizes.append(len(message))
                arrivals.append(time.monotonic())
            elif isinstance(message, wire.StatusMsg):
                phase = message.phase
            elif isinstance(message, wire.CommandResult):
                assert message.ok, message
        assert phase == "done", phase
        # The status goes before telemetry: the session's last samples are still on the way.
        last = max(seen)
        while max(seen) < last + 0.5:
            message = await next_of(ws, wire.TelemetryBatch, deadline - time.monotonic())
            seen.extend(s.t for s in message.samples())
    finally:
        await ws.close()

    # Batches of the configured size, and more than 30 fresh samples a second.
    assert sorted(sizes)[len(sizes) // 2] == DEVICE_HZ // 20, sizes[:50]
    span = arrivals[-1] - arrivals[0]
    assert len(seen) / span > 30.0, (len(seen), span)

    # The session's recording, uploaded and downloaded: every sample the device sent.
    deadline = time.monotonic() + 60
    while not (
        r := await therapist.get("/api/v1/sessions", params={"prescription_id": pid})
    ).json():
        assert time.monotonic() < deadline, "the session never reached the server"
        await asyncio.sleep(0.2)
    session = r.json()[0]
    parquet = await therapist.get(session["downloads"]["parquet"])
    assert parquet.status_code == 200
    recorded = pq.read_table(io.BytesIO(parquet.content)).column("time_s").to_numpy()
    steps = np.diff(recorded)
    assert len(recorded) == session["summary"]["samples"] > 3 * DEVICE_HZ
    assert steps.max() < 1.5 / DEVICE_HZ, f"the recording misses samples: {steps.max():.4f} s"

    # Each one of them reached the viewer, once and in order.
    assert seen == sorted(seen) and len(set(seen)) == len(seen)
    missing = {key(t) for t in recorded} - {key(t) for t in seen}
    assert not missing, f"{len(missing)} of {len(recorded)} samples never reached the viewer"
