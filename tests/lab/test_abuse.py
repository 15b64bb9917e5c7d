"""``ankle bench abuse`` as a user runs it, at a tiny size: every key measured, no 5xx."""

from __future__ import annotations

import json
import subprocess
import sys

from lab import abuse, serverbench

ARGS = [
    "bench",
    "abuse",
    "--json",
    "--bodies-10mib",
    "2",
    "--bodies-100mib",
    "1",
    "--logins",
    "12",
    "--ws-rate",
    "100",
    "--ws-seconds",
    "0.5",
    "--malformed",
    "22",
]


def test_a_small_run_measures_every_key_and_no_5xx() -> None:
    r = subprocess.run(
        [sys.executable, "-m", "ankle", *ARGS],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    for key, _ in abuse.ROWS:
        assert key in out, key
    assert set(out["targets_met"]) == {t.key for t in abuse.TARGETS}
    assert out["server_5xx"] == 0
    assert out["live_links_dropped"] == 0
    assert out["bigbody_refused"] == 3 and out["bigbody_other"] == 0
    assert out["login_flood_401"] + out["login_flood_429"] == 12
    assert out["good_login_status"] == 200 and out["good_login_ms_under_flood"] > 0
    assert out["malformed_4xx"] == 22 and out["malformed_other"] == 0
    assert out["ws_flood_sent"] >= 40
    assert out["ws_flood_closed"] == ""  # its commands stay within the link's budget
    assert out["viewer_telemetry"] > 0
    assert 0 < out["server_rss_mb_idle"] <= out["server_rss_mb_max"]
    for key in ("idle", "bigbody", "login_flood", "ws_flood", "malformed"):
        assert out[f"health_p99_ms_{key}"] > 0, key
    assert "closing the live links" in r.stderr  # the progress line


def test_the_table_shows_every_row_and_marks_a_missed_target() -> None:
    result: dict[str, object] = {key: 1.0 for key, _ in abuse.ROWS}
    result["server_5xx"] = 2
    text = abuse.table(result)
    for _, label in abuse.ROWS:
        assert label in text
    assert "| 5xx answers | 2 | = 0 | NO |" in text
    assert json.loads(json.dumps(serverbench.jsonable({"x": float("nan")})))["x"] is None
