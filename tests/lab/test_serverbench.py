"""``ankle bench server`` as a user runs it: a real server, real stations and viewers."""

from __future__ import annotations

import json
import math
import subprocess
import sys

from lab import serverbench as bench

ARGS = ["bench", "server", "--json", "--stations", "5", "--seconds", "3", "--no-sweep"]


def test_a_small_run_measures_every_key() -> None:
    r = subprocess.run(
        [sys.executable, "-m", "ankle", *ARGS],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    for key, _ in bench.ROWS:
        assert key in out, key
    assert out["stations"] == 5
    assert out["viewers"] == 5
    assert out["disconnects"] == 0
    assert 0 < out["telemetry_latency_ms_p50"] <= out["telemetry_latency_ms_p99"] < 1000
    assert out["telemetry_hz_per_station"] > 50  # 100 configured
    assert 0 < out["viewer_hz"] <= bench.TELEMETRY_HZ * 1.1
    assert out["commands"] > 0 and 0 < out["kb_change_to_ack_ms_p50"] < 3000
    assert 0 < out["hold_to_ack_ms_p50"] <= out["hold_to_ack_ms_p99"] < 3000
    assert out["server_cpu_us_per_message"] > out["server_cpu_us_per_sample"] > 0
    assert out["server_cpu_pct"] > 0
    assert out["max_stations_p99_under_50ms"] in (5, None)
    assert "sweep" not in out
    assert set(out["targets_met"]) == {t.key for t in bench.TARGETS}


def test_the_table_shows_every_row_the_sweep_and_a_missing_value() -> None:
    result: dict[str, object] = {key: 1.5 for key, _ in bench.ROWS}
    result["max_stations_p99_under_50ms"] = None
    step = {
        "stations": 25,
        "viewers": 25,
        "telemetry_hz_per_station": 100.0,
        "viewer_hz": 48.0,
        "telemetry_latency_ms_p50": 6.0,
        "telemetry_latency_ms_p99": 12.0,
        "kb_change_to_ack_ms_p99": 30.0,
        "hold_to_ack_ms_p99": 9.0,
        "disconnects": 0,
        "server_cpu_pct": 20.0,
    }
    result["sweep"] = [step]
    text = bench.table(result)
    for _, label in bench.ROWS:
        assert label in text
    assert "| 25 | 25 | 100.0 | 48.0 | 6.0 | 12.0 | 30.0 | 9.0 | 0 | 20 |" in text
    assert json.loads(json.dumps(bench.jsonable({"x": math.nan})))["x"] is None
