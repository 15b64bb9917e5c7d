"""`ankle bench safety --only KIND`: one fault kind's matrix, as a real command."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest


def _bench(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ankle", "bench", "safety", *args],
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )


def test_only_one_kind_runs_its_three_situations_and_reports_the_fault_keys() -> None:
    done = _bench("--only", "FT-saturated", "--json")
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert result["only"] == ["FT_SATURATED"] and result["after_s"] == 0.5
    assert result["faults_total"] == 3
    assert {f["kind"] for f in result["faults"]} == {"FT_SATURATED"}
    assert {f["scenario"] for f in result["faults"]} == {"holding", "exercise", "pushing"}
    assert result["faults_detected"] == 3 and result["detect_ms_max"] <= 5.0
    # Only the fault matrix ran: no healthy, boundary or K-B keys pretend to a result.
    assert "false_trips" not in result and "kb_grid_points" not in result
    assert set(result["targets_met"]) == {
        "faults_undetected",
        "detect_ms_max",
        "excursion_deg_max",
        "excursion_mm_max",
    }


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (("--only", "leg_frozen"), "unknown kind 'leg_frozen'; kinds: supply_loss"),
        (("--only", "leg_stuck", "--after", "0"), "--after: 0 outside 0.1..10"),
    ],
)
def test_a_wrong_kind_or_watch_time_is_one_line_and_exit_2(
    args: tuple[str, ...], says: str
) -> None:
    done = _bench(*args)
    assert done.returncode == 2 and done.stdout == ""
    assert says in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr
