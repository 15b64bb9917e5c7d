"""What an experiment refuses up front, what it calls invalid after it ran, and what it
credits to an injected fault: as ``ankle sim`` reports them, in process."""

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from ankle.cli import main
from device.controller import ControllerConfig
from device.geometry import AXES
from device.rig import CommandError
from lab import experiments as ex
from lab.metrics import SETTLE_HOLD_S, step_metrics


def sim(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(["sim", *args])
    out = capsys.readouterr()
    return code, out.out, out.err


def bounds_hold(message: str) -> None:
    """A refusal ``must be LOW..HIGH ..., got VALUE`` names a value outside its own bounds."""
    low, high = (float(x) for x in re.search(r"must be ([-\d.e]+)\.\.([-\d.e]+)", message).groups())  # type: ignore[union-attr]
    got = float(re.search(r"got (-?[\d.e+]+)", message).group(1))  # type: ignore[union-attr]
    assert not low <= got <= high, message


# -- a step must be measured whole ----------------------------------------------------------


def test_a_step_too_short_for_its_record_is_refused_with_the_rule(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """39 mm take at least 97.5 ms at the 0.4 m/s leg speed limit, then the settling window:
    a 0.1 s record ran, said "rise nan ms, settling nan ms" and called it valid."""
    code, out, err = sim(capsys, "step", "--mm", "39", "--duration", "0.1", "--json")
    assert code == 2 and out == ""
    assert "leg speed limit" in err and "0.597..60 s" in err, err
    bounds_hold(err)


def test_a_step_that_does_not_settle_in_its_record_is_invalid_and_its_values_null(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A 39 mm step rises in about 160 ms: 0.6 s is enough for its travel but not for
    half a second in the band after it."""
    code, out, _ = sim(capsys, "step", "--mm", "39", "--duration", "0.6", "--json")
    data = json.loads(out)
    assert code == 1 and data["valid"] is False, data
    assert "did not settle" in data["invalid_reason"], data
    assert all(data[k] is None for k in ("rise_ms", "overshoot_pct", "settling_ms")), data
    assert data["steady_error_mm"] is None


def test_an_invalid_run_still_writes_its_trace_and_a_figure_that_says_so(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """A run that tripped wrote no --csv and no --plot: the trace wanted most was the one
    withheld. Now both are written, and the verdict is on the figure."""
    out_csv, out_png = tmp_path / "step.csv", tmp_path / "step.png"
    code, out, _ = sim(
        capsys,
        "step",
        "--fault",
        "pressure_open@0.55:11",
        "--csv",
        str(out_csv),
        "--plot",
        str(out_png),
    )
    assert code == 1 and out.startswith("INVALID: tripped PRESSURE_SENSOR"), out
    rows = out_csv.read_text().splitlines()
    assert rows[0].startswith("t_s,") and len(rows) > 100
    assert out_png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_an_uncompensated_step_that_swings_through_the_band_never_settles(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Without dead-band compensation the leg swings +-0.3-0.6 mm about its target: it read
    "settling nan ms, steady-state error 0.2 mm", valid."""
    code, out, _ = sim(capsys, "step", "--no-deadband-comp")
    assert code == 1 and out.startswith("INVALID: the leg did not settle"), out


def test_settling_is_the_first_entry_into_the_band_that_lasts_its_window() -> None:
    t = np.arange(0.0, 2.0, 1e-3)
    y = np.clip(t / 0.1, 0.0, 1.0) * 10e-3  # a ramp to 10 mm in 100 ms, then rest
    y[(t > 1.5) & (t < 1.6)] += 1e-3  # a wander out of the band long after
    m = step_metrics(t, y, 0.0, 10e-3)
    assert m.measured and m.settling_ms == pytest.approx(97.0, abs=1.5)
    assert m.steady_error_mm == pytest.approx(0.0, abs=0.05) and m.overshoot_pct == 0.0
    cut = t < 0.097 + SETTLE_HOLD_S - 0.01  # ends 10 ms before the window would
    short = step_metrics(t[cut], y[cut], 0.0, 10e-3)
    assert not short.measured and math.isnan(short.settling_ms)
    never = step_metrics(t, y * 0.5, 0.0, 10e-3)
    assert not never.measured and math.isnan(never.rise_ms)


def test_settling_does_not_depend_on_how_long_the_record_goes_on() -> None:
    """Leg 2, -20 mm: the healthy leg rests 0.06 mm off, then drifts on its air to 0.36 mm
    between 10 and 18 s and is corrected at 18.3 s. Settling read 18350 ms over 20 s."""
    long = ex.step(leg=2, mm=-20.0, duration=20.0)
    short = ex.step(leg=2, mm=-20.0, duration=1.0)
    assert long.valid and short.valid
    assert long.metrics.settling_ms == short.metrics.settling_ms < 200.0
    assert long.metrics.overshoot_pct == short.metrics.overshoot_pct
    # where each record ends: corrected again by 20 s, resting at its first error by 1 s
    assert long.metrics.steady_error_mm < 0.3 and short.metrics.steady_error_mm < 0.3


# -- dynamic impedance ------------------------------------------------------------------------


def test_patient_torque_frequencies_stop_below_the_ring_guards_band() -> None:
    top = ex.IMPEDANCE_HZ_RANGE[1]
    assert top < ControllerConfig().ring_band[0]
    with pytest.raises(CommandError, match="ring guard") as exc:
        ex.check_dynamic("pitch", 50.0, 1.0, 5.0, (0.5, 5.0))
    bounds_hold(str(exc.value))


def test_the_top_patient_torque_frequency_measures_on_a_healthy_unit() -> None:
    """At 5 Hz (accepted before) the guard took the torque sine for a ring every time."""
    r = ex.impedance_dynamic("pitch", k=50.0, b=1.0, torque=5.0, hz=(2.0, ex.IMPEDANCE_HZ_RANGE[1]))
    assert r.valid and r.health.warning is None, r.health


def test_one_frequency_where_the_virtual_inertia_passes_for_stiffness_is_refused() -> None:
    """At 4.5 Hz alone K = 50 read "rendered K 20.65 (58.70 % error)", valid: the fit saw
    K - J w^2 with the device's 0.03 kg m2."""
    with pytest.raises(CommandError, match="virtual inertia") as exc:
        ex.check_dynamic("pitch", 50.0, 1.0, 5.0, (4.0,))
    assert "at most 1.45 Hz" in str(exc.value), exc.value
    with pytest.raises(CommandError, match="virtual inertia"):
        ex.check_dynamic("pitch", 50.0, 1.0, 5.0, (2.0, 2.0))  # one frequency, twice
    ex.check_dynamic("pitch", 50.0, 1.0, 5.0, (1.0,))
    ex.check_dynamic("pitch", 50.0, 1.0, 5.0, (2.0, 4.0))  # fitted with J


def test_an_invalid_dynamic_impedance_prints_no_measured_number(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, out, _ = sim(
        capsys, "impedance", "--mode", "dynamic", "--fault", "supply_droop@100", "--json"
    )
    data = json.loads(out)
    assert code == 1 and data["valid"] is False and "never struck" in data["invalid_reason"]
    for key in (
        "measured_stiffness",
        "measured_damping",
        "stiffness_error_pct",
        "damping_error",
        "damping_error_pct",
        "fits",
    ):
        assert data[key] is None, (key, data[key])


# -- what a warning is credited to ------------------------------------------------------------


def test_a_warning_is_credited_only_to_a_fault_that_struck_before_it(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The exhaust stuck open makes the device ask for service at 0.61 s; the supply
    transducer's offset (which alone it does not notice) strikes at 1.2 s and was said to
    have been answered by that warning."""
    code, out, _ = sim(
        capsys,
        "step",
        "--fault",
        "valve_stuck_open@0.6:1",
        "--fault",
        "pressure_offset@1.2:12=-0.5",
        "--json",
    )
    valve, offset = json.loads(out)["faults"]
    assert code == 1
    assert valve["noticed"].startswith("asked for service: the air of chamber 1"), valve
    assert valve["warning_names_its_part"] is True and 0 < valve["warned_ms"] <= 100, valve
    assert offset["noticed"] is None and offset["after_warning"] is True, offset
    code, out, _ = sim(
        capsys,
        "step",
        "--fault",
        "valve_stuck_open@0.6:1",
        "--fault",
        "pressure_offset@1.2:12=-0.5",
    )
    last = out.splitlines()[-1]
    assert last.endswith(
        "struck after the device had already warned; the device noticed nothing more"
    )


# -- refusals say bounds their value lies outside ----------------------------------------------


@pytest.mark.parametrize(
    ("axis", "amplitude"),
    [("pitch", 0.156), ("roll", 20.05353), ("x", 30.0), ("y", -30.0), ("x", 29.9999995)],
)
def test_a_sine_amplitude_is_checked_once_against_the_published_limits(
    axis: str, amplitude: float
) -> None:
    """x at 30 mm passed the lab's check (SafetyLimits in float64) and was refused by the
    device's (the published float32 limits, 0.029999999 m) in metres; pitch 0.156 read
    "must be 0.156..22.9 deg, got 0.156"."""
    with pytest.raises(CommandError) as exc:
        ex.check_sine(axis, amplitude, 0.5)
    bounds_hold(str(exc.value))


def test_the_largest_accepted_amplitude_is_accepted_by_the_device() -> None:
    k = AXES.index("x")
    largest = ex.largest_amplitude(k, ex._LIMITS)
    ex.check_sine("x", largest, 0.5)
    r = ex.sine("x", largest, 0.5, cycles=2)  # the device's own check takes it
    assert r.amplitude == largest


def test_a_negative_non_finite_value_reaches_the_finite_check(
    capsys: pytest.CaptureFixture[str],
) -> None:
    for args in (
        ("step", "--mm", "-inf"),
        ("sine", "--amplitude", "-inf"),
        ("step", "--mm", "-nan"),
    ):
        code, _, err = sim(capsys, *args)
        assert code == 2 and "must be finite" in err, (args, err)
    code, _, err = sim(capsys, "step", "--mm", "-1e3")
    assert code == 2 and "got -1000" in err, err
