"""``ankle bench server`` as a user runs it: real servers, real stations and viewers, and a
real redis-server where the relay is Redis."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from typing import Any

import pytest

from lab import serverbench as bench

ARGS = ["bench", "server", "--json", "--seconds", "3", "--no-sweep", "--no-capacity"]


def _bench(*extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ankle", *ARGS, *extra],
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )


def test_a_small_run_measures_every_key() -> None:
    r = _bench("--stations", "5")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    for key, _ in bench.ROWS:
        assert key in out, key
    assert (out["processes"], out["relay"], out["store"]) == (1, "local", "sqlite")
    assert out["valid"] is True and out["invalid"] == {}
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
    assert out["redis_cpu_us_per_message"] is None  # no Redis in this run
    assert out["cross_process_latency_ms_p99"] is None  # one process: not measured
    assert out["max_stations_p99_under_50ms"] in (5, None)
    assert out["max_stations_p99_under_50ms_1proc"] is None  # --no-capacity
    assert "sweep" not in out and "capacity" not in out
    assert set(out["targets_met"]) == {t.key for t in bench.TARGETS}


def test_two_processes_on_redis_put_each_viewer_on_the_other_process() -> None:
    r = _bench("--stations", "4", "--processes", "2", "--relay", "redis")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert (out["processes"], out["relay"]) == (2, "redis")
    assert out["disconnects"] == 0 and out["commands_failed"] == 0
    # Every viewer watches a station held by the other process: what it sees crossed Redis.
    assert out["viewer_hz"] > 50
    assert out["cross_process_latency_ms_p99"] == out["telemetry_latency_ms_p99"] > 0
    assert out["commands"] > 0 and out["kb_change_to_ack_ms_p99"] > 0
    assert len(out["server_cpu_pct_per_process"]) == 2
    assert all(c > 0 for c in out["server_cpu_pct_per_process"])
    assert all(c > 0 for c in out["server_cpu_us_per_message_per_process"])
    assert out["redis_cpu_us_per_message"] > 0  # read from the bench's own redis-server


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--processes", "2"], "--relay redis"),
        (["--store", "postgres"], "--database-url"),
        (["--database-url", "postgresql+asyncpg://x@y/z"], "--store postgres"),
    ],
)
def test_options_that_cannot_run_are_refused_in_a_sentence(
    extra: list[str], words: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("ANKLE_DATABASE_URL", raising=False)
    r = _bench(*extra)
    assert r.returncode == 2
    assert words in r.stderr and "Traceback" not in r.stderr
    assert r.stdout == ""


def test_a_capacity_sweep_pins_one_server_process_to_one_core() -> None:
    if bench.split_cores() is None:
        pytest.skip("this process may not use two cores: nothing to pin")
    out = bench.run(
        stations=3,
        seconds=1.0,
        sweep=False,
        capacity=True,
        sweep_counts=(3,),
        sweep_seconds=1.0,
    )
    runs: dict[str, Any] = out["capacity"]
    assert set(runs) == set(bench.CAPACITY)
    for key in ("1proc", "1proc_redis"):
        (step,) = runs[key]["steps"]
        assert len(step["server_cores"]) == 1, key
        assert not set(step["server_cores"]) & set(step["loadgen_cores"]), key
        assert step["disconnects"] == 0
    # Read from /proc (10 ms ticks): one process publishes little to Redis in 2 s, maybe 0.
    assert runs["1proc_redis"]["steps"][0]["redis_cpu_us_per_message"] >= 0
    assert math.isnan(runs["1proc"]["steps"][0]["redis_cpu_us_per_message"])
    (two,) = runs["2proc"]["steps"]
    assert len(two["server_cores"]) > 1  # two processes are not pinned
    for key in bench.CAPACITY:
        assert out[f"max_stations_p99_under_50ms_{key}"] in (3, None)
        assert runs[key]["stopped"]  # says why it stopped, even at the top of the sweep
    if (
        out["max_stations_p99_under_50ms_1proc"]
        == 3
        == out["max_stations_p99_under_50ms_1proc_redis"]
    ):
        assert out["redis_relay_efficiency"] == 1.0
    # One process here, so the cross-process figure comes from the two-process sweep.
    assert out["cross_process_latency_ms_p99"] == two["telemetry_latency_ms_p99"] > 0
    assert "pinned" in bench.table(out)


def test_a_run_that_lost_connections_reports_no_figure_as_valid() -> None:
    window: dict[str, Any] = {key: 20.0 for key, _ in bench.ROWS}
    window.update(
        telemetry_hz_per_station=100.0,
        telemetry_skipped=0,
        commands_failed=0,
        disconnects=3,
        loadgen_cpu_pct=40.0,
        stations=100,
    )
    out = bench.summary(window, bench.Setup(), "sqlite", None, {})
    assert out["valid"] is False
    assert out["telemetry_latency_ms_p99"] is None and out["kb_change_to_ack_ms_p99"] is None
    assert out["invalid"]["telemetry_latency_ms_p99"] == "3 connections lost"
    assert out["max_stations_p99_under_50ms"] is None
    assert not out["targets_met"]["telemetry_latency_ms_p99"]
    assert "INVALID (3 connections lost)" in bench.table(out)


def test_a_short_send_rate_says_whose_fault_it_was() -> None:
    window: dict[str, Any] = {key: 20.0 for key, _ in bench.ROWS}
    window.update(
        telemetry_hz_per_station=80.0, telemetry_skipped=0, commands_failed=2, disconnects=0
    )
    window["loadgen_cpu_pct"] = 99.0
    bad = bench.problems(window)
    assert "load generator fell behind" in bad["telemetry_latency_ms_p99"]
    assert bad["hold_to_ack_ms_p99"] == "2 commands unanswered"
    assert "kb_change_to_ack_ms_p99" in bad and "telemetry_latency_ms_max" not in bad
    window["telemetry_skipped"] = 40
    assert "server did not read" in bench.problems(window)["viewer_hz"]


def test_the_table_shows_every_row_the_sweep_and_a_missing_value() -> None:
    result: dict[str, object] = {key: 1.5 for key, _ in bench.ROWS}
    result["max_stations_p99_under_50ms"] = None
    step: dict[str, Any] = dict.fromkeys(bench.STEP_KEYS, 0)
    step.update(
        stations=25,
        viewers=25,
        telemetry_hz_per_station=100.0,
        viewer_hz=48.0,
        telemetry_latency_ms_p50=6.0,
        telemetry_latency_ms_p99=12.0,
        kb_change_to_ack_ms_p99=30.0,
        hold_to_ack_ms_p99=9.0,
        disconnects=0,
        server_cpu_pct=20.0,
        server_cpu_us_per_message=180.0,
        redis_cpu_us_per_message=math.nan,
    )
    result["sweep"] = [step]
    result["sweep_stopped"] = "at 50 stations: latency p99 61 ms"
    text = bench.table(result)
    for _, label in bench.ROWS:
        assert label in text
    assert "| 25 | 25 | 100.0 | 48.0 | 6.0 | 12.0 | 30.0 | 9.0 | 0 | 20 | 180 | - |" in text
    assert "stopped at 50 stations: latency p99 61 ms" in text
    assert json.loads(json.dumps(bench.jsonable({"x": math.nan})))["x"] is None
