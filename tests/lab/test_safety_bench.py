"""`ankle bench safety --only KIND`: one fault kind's matrix, as a real command."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from tests.lab.benches import ankle_bench


def _bench(*args: str) -> subprocess.CompletedProcess[str]:
    return ankle_bench("safety", *args)


def test_only_one_kind_runs_its_four_situations_and_reports_the_fault_keys() -> None:
    done = _bench("--only", "FT-saturated", "--json")
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert result["only"] == ["FT_SATURATED"] and result["after_s"] == 0.5
    assert result["faults_total"] == 4
    assert {f["kind"] for f in result["faults"]} == {"FT_SATURATED"}
    situations = {f["scenario"] for f in result["faults"]}
    assert situations == {"holding", "exercise", "pushing", "settling"}
    assert result["faults_detected"] == 4 and result["detect_ms_max"] <= 5.0
    # Only the fault matrix ran: no healthy, boundary or K-B keys pretend to a result.
    assert "false_trips" not in result and "kb_grid_points" not in result
    assert set(result["targets_met"]) == {
        "faults_undetected",
        "detect_ms_max",
        "excursion_deg_max",
        "excursion_mm_max",
    }


def test_the_unit_without_its_calibration_allows_for_the_heaviest_seals() -> None:
    """`--uncalibrated` runs the nominal unit as the device runs without `--calibration`:
    no seal friction is taken out and no transducer zero, so the moment check allows for
    5 N of seals and 9.3 N of zeros a leg, and a 3 N m torque offset on roll or pitch (named
    in 10-52 ms on the calibrated unit) is not named: it acts as a patient's 3 N m would,
    the platform turning further (4.0 deg at most, 2.4 deg until FOLLOWING names one on
    yaw at 90-116 ms)."""
    done = _bench("--only", "ft_offset", "--json", "--uncalibrated")
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert result["calibrated"] is False and result["faults_total"] == 24
    torque = [f for f in result["faults"] if f["injected"] >= 3]
    assert not any(f["detected"] for f in torque if f["injected"] in (3, 4)), torque
    assert all(f["detect_ms"] > 50.0 for f in torque if f["detected"]), torque
    assert max(f["excursion_deg"] for f in torque) > 2.0, torque


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


def test_the_excursion_counts_from_the_fault_free_twin_until_the_loop_lets_go() -> None:
    """While the loop runs (a service warning leaves it running) the fault's platform is
    compared with the twin's at the same moment; once a trip lets go of it, with where
    the twin was then. The twin goes on exercising; its motion is not the fault's."""
    import numpy as np

    from lab.safety import excursion

    t = np.arange(10.0)[:, None]
    twin = np.hstack([t, np.zeros((10, 5))])  # x runs on with the exercise, 1 a step
    faulty = twin.copy()
    faulty[3:, 1] = 0.5  # y pushed 0.5 off at row 3, the loop still running
    faulty[6:, 0] = 6.0  # a trip at row 6: x stops where the twin was...
    faulty[8:, 1] = 2.0  # ...and then y drifts on to 2
    assert list(excursion(faulty, twin, 6)[:2]) == [0.0, 2.0]
    # Never stopped: against the twin throughout (x stood still while the twin ran on).
    assert list(excursion(faulty, twin, None)[:2]) == [3.0, 2.0]


def test_the_first_calibrated_unit_of_a_process_runs_as_every_later_one(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The unit is identified before its plant is made (identifying seeds the plant's
    random generator): made the other way round, the first rig of a process, the fault
    matrix's twin held at home, ran 0.7 mm apart from every later one, and every holding
    run's excursion carried up to 0.02 deg of it."""
    from lab import experiments, safety

    monkeypatch.setattr(experiments, "_CALIBRATIONS", {})
    runs = []
    for _ in range(2):
        rig = safety._rig("relaxed", 1)
        rig.move_legs(np.full(6, 0.5 * rig.geometry.stroke))
        runs.append(rig.run(0.3))
    np.testing.assert_array_equal(runs[0], runs[1])


def test_a_detection_counts_from_the_onset_and_never_before_it() -> None:
    """A drooping supply is a fault from where its regulator's output crosses the low
    mark; its manifold, dipping as intakes draw, may be flagged before that: 0, not a
    negative time. Never noticed is NaN; a fault with no onset counted (it never sagged
    that far) but noticed all the same is 0."""
    import math

    from lab.safety import since_onset

    assert since_onset(0.25, 0.2) == pytest.approx(0.05)
    assert since_onset(0.13, 0.19) == 0.0
    assert since_onset(0.3, math.nan) == 0.0
    assert math.isnan(since_onset(math.nan, 0.1))
