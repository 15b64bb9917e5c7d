"""`ankle bench shutwatch`: the valves watched while shut and while released, as a command."""

from __future__ import annotations

import json
import subprocess

import pytest

from tests.lab.benches import ankle_bench


def _bench(*args: str) -> subprocess.CompletedProcess[str]:
    return ankle_bench("shutwatch", *args)


def test_every_fault_is_named_on_its_chamber_and_no_healthy_release_is_stopped() -> None:
    done = _bench("--builds", "0", "--hold", "2", "--json")
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    faults = result["faults"]
    # held: 28 faults; an exercise's hold: 36; released 0, 0.5 and 1 s in: 10 each; both feet.
    assert result["faults_total"] == len(faults) == 2 * (28 + 36 + 3 * 10)
    assert {f["situation"] for f in faults} == {
        "held",
        "exercise+hold",
        "released+0",
        "released+0.5",
        "released+1",
    }
    unnamed = [f for f in faults if not f["named"]]
    assert not unnamed, unnamed
    assert result["faults_named"] == result["faults_total"]
    # Counted from the injection; a fault the exercise tripped on already, 0 at the hold.
    assert all(f["detect_ms"] > 0.0 for f in faults if f["situation"] != "exercise+hold")
    assert all(f["detect_ms"] >= 0.0 for f in faults)
    # The healthy part: the library x both feet on the nominal unit, none stopped.
    assert result["healthy_runs"] >= 10 and result["false_stops"] == 0, result["false"]
    assert len(result["release_own_motion"]) == 8
    worst = max(faults, key=lambda f: f["shift_mm"])
    assert result["excursion_mm_max"] == worst["shift_mm"]
    over = [f for f in faults if f["tilt_deg"] > 2.0 or f["shift_mm"] > 3.0]
    assert result["over_targets"] == len(over)


@pytest.mark.parametrize(
    ("args", "says"),
    [(("--builds", "-1"), "--builds: -1 outside 0..10000"), (("--hold", "0"), "--hold: 0")],
)
def test_a_wrong_count_or_hold_is_one_line_and_exit_2(args: tuple[str, ...], says: str) -> None:
    done = _bench(*args)
    assert done.returncode == 2 and done.stdout == ""
    assert says in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr
