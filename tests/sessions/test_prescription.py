"""Prescriptions are checked against anatomy and the device before they reach a patient."""

from __future__ import annotations

import math
from typing import Any

import pytest
from pydantic import ValidationError

from device.commands import check_segment_as_received
from device.geometry import DEFAULT_GEOMETRY
from device.service import TELEMETRY_HZ_MAX, ServiceConfig
from server.config import Settings
from sessions.prescription import (
    AXIS_INDEX,
    DEVICE_LIMITS,
    EXERCISE_LIBRARY,
    SESSION_S_MAX,
    SPEED_MAX_DEG_S,
    AxisPrescription,
    ExerciseKind,
    PrescriptionBody,
    PrescriptionInput,
    allowed_range_deg,
    device_segment,
)
from sessions.recording import SAMPLE_DTYPE
from sessions.sentences import FieldError


def axis(**kw: object) -> dict[str, object]:
    return {"axis": "pitch", "stiffness": 40.0, "damping": 2.0, **kw}


@pytest.mark.parametrize(
    ("kw", "needle"),
    [
        ({"stiffness": math.nan}, "finite"),
        ({"stiffness": -1.0}, "greater than or equal to 0"),
        ({"stiffness": 501.0}, "less than or equal to 500"),
        ({"damping": 51.0}, "less than or equal to 50"),
        ({"rom_high": 40.0}, "Highest angle on pitch must be at most 22.9°."),
        ({"rom_low": -30.0}, "Lowest angle on pitch must be at least -20°."),
        (
            {"waveform": "sine", "amplitude": 30.0, "frequency": 0.1},
            "The sine on pitch reaches -30 to 30°, outside the range -20 to 22.9°",
        ),
        (
            {"waveform": "sine", "amplitude": 20.0, "frequency": 2.0},
            "faster than the device allows",
        ),
        (
            {"waveform": "sine", "amplitude": 5.0},
            "Frequency on pitch must be above 0 Hz: a sine needs one.",
        ),
        ({"rom_low": 5.0, "rom_high": 5.0}, "Lowest angle on pitch (5°) must be below"),
        ({"axis": "knee"}, "roll"),
    ],
)
def test_bad_axis_values_are_refused_with_the_field_and_bound(
    kw: dict[str, object], needle: str
) -> None:
    with pytest.raises(ValidationError) as err:
        AxisPrescription.model_validate(axis(**kw))
    assert needle in str(err.value)


def test_the_allowed_range_is_the_narrower_of_anatomy_and_device() -> None:
    lo, hi = allowed_range_deg("pitch")
    assert lo == -20.0  # dorsiflexion: anatomy is narrower
    assert hi == pytest.approx(math.degrees(0.40))  # plantarflexion: the device is narrower


def test_an_axis_may_appear_once_and_totals_include_rest() -> None:
    with pytest.raises(ValidationError, match="Each axis may appear once; pitch appears"):
        PrescriptionBody.model_validate({"exercise": "strength", "axes": [axis(), axis()]})
    body = PrescriptionBody.model_validate(
        {
            "exercise": "strength",
            "axes": [axis()],
            "sets": 3,
            "repetitions": 10,
            "repetition_s": 6.0,
            "rest_s": 30.0,
        }
    )
    assert body.total_s() == 3 * 10 * 6.0 + 2 * 30.0


def _timeline(**kw: object) -> dict[str, object]:
    return {"exercise": "strength", "axes": [axis()], **kw}


def test_a_session_longer_than_two_hours_is_refused_on_the_sets_with_its_total() -> None:
    """Each count and time was within its bound, and together they asked for 338 hours,
    which no recording upload carries: refused with the total, what it is made of and the
    maximum; two hours exactly is a session."""
    with pytest.raises(ValidationError) as err:
        PrescriptionInput.model_validate(
            _timeline(sets=20, repetitions=100, repetition_s=600.0, rest_s=900.0)
        )
    (error,) = err.value.errors()
    cause = error["ctx"]["error"]
    assert isinstance(cause, FieldError) and cause.loc == ("sets",)
    assert str(cause) == (
        "This session lasts 338 h 5 min (20 sets of 100 repetitions of 600 s, 900 s rest "
        "between sets), longer than the 2 h a session may last: fewer sets or repetitions, "
        "or shorter repetitions or rests."
    )
    longest = _timeline(sets=4, repetitions=30, repetition_s=58.0, rest_s=80.0)
    assert PrescriptionInput.model_validate(longest).total_s() == SESSION_S_MAX
    # Past it by less than a second: said to the figures that tell the two apart.
    with pytest.raises(ValidationError, match=r"lasts 7200\.44 s \(1 set of 13 repetitions of "):
        PrescriptionInput.model_validate(_timeline(repetitions=13, repetition_s=553.88))
    with pytest.raises(ValidationError, match="longer than the 7200 s a session may last"):
        PrescriptionInput.model_validate(_timeline(repetitions=13, repetition_s=553.88))
    # A stored prescription loads whatever it holds.
    PrescriptionBody.model_validate(_timeline(sets=20, repetitions=100, repetition_s=600.0))


def test_the_longest_session_s_recording_fits_the_default_upload_limit() -> None:
    """What SESSION_S_MAX rests on: a recording of a session that long, sampled at the
    device's fastest telemetry, is still smaller than the server takes by default; at the
    default rate, under a third of it."""
    limit = Settings.model_fields["upload_max_bytes"].default
    per_second = SAMPLE_DTYPE.itemsize
    assert SESSION_S_MAX * per_second * TELEMETRY_HZ_MAX < limit
    assert 3 * SESSION_S_MAX * per_second * ServiceConfig().telemetry_hz < limit


def test_the_library_covers_the_clinical_exercises_with_valid_defaults() -> None:
    assert {k.value for k in EXERCISE_LIBRARY} == {
        "strength",
        "flexibility",
        "passive_rom",
        "isometric",
        "balance",
        "rom_assessment",
    }
    for template in EXERCISE_LIBRARY.values():
        PrescriptionBody.model_validate(template.defaults.model_dump())


def test_minus_zero_is_zero() -> None:
    """-0.0 is stored, shown and sent as 0.0."""
    body = PrescriptionInput.model_validate(
        {
            "exercise": "strength",
            "axes": [{"axis": "pitch", "stiffness": -0.0, "damping": 2.0, "center": -0.0}],
        }
    )
    assert str(body.axes[0].stiffness) == "0.0" and str(body.axes[0].center) == "0.0"


def _sine(axis_name: str, center: float, amplitude: float, frequency: float) -> dict[str, object]:
    body = EXERCISE_LIBRARY[ExerciseKind.FLEXIBILITY].defaults.model_dump(mode="json")
    body["axes"][0].update(axis=axis_name, center=center, amplitude=amplitude, frequency=frequency)
    return body


@pytest.mark.parametrize("axis_name", ["pitch", "roll", "yaw"])
def test_a_sine_at_the_edges_of_the_range_or_the_speed_is_what_the_device_accepts(
    axis_name: str,
) -> None:
    """The range is published in degrees and the device checks radians in single precision:
    a sine the model accepts reaching an end of the range exactly (the whole pitch range,
    -20 to 22.918°, was refused by the device's check: -0.3490659..0.40000002 rad outside
    -0.3490658..0.40000001), or moving exactly at the top speed, is accepted by both, and
    reaches the device no more than a rounding step from what was prescribed."""
    lo, hi = allowed_range_deg(axis_name)
    sines = [((lo + hi) / 2, (hi - lo) / 2)]
    for k in range(1, 40):
        center = lo + (hi - lo) * k / 40
        sines.append((center, min(center - lo, hi - center)))
    for center, amplitude in sines:
        for frequency in (0.05, SPEED_MAX_DEG_S / (2 * math.pi * amplitude)):
            body = PrescriptionInput.model_validate(
                _sine(axis_name, center, amplitude, min(frequency, 7.0))
            )
            segment = device_segment(DEVICE_LIMITS, 1, body, {axis_name: 60.0}, {axis_name: 3.0})
            check_segment_as_received(segment, DEVICE_LIMITS, DEFAULT_GEOMETRY)
            i = AXIS_INDEX[axis_name]
            assert math.degrees(segment.center[i]) == pytest.approx(center, abs=1e-5)
            assert math.degrees(segment.amplitude[i]) == pytest.approx(amplitude, abs=1e-5)
            assert segment.frequency[i] == pytest.approx(min(frequency, 7.0), abs=1e-6)


def _field(error: Any) -> tuple[object, ...]:
    """The path of the field a refusal is about, as the server reports it."""
    cause = error.get("ctx", {}).get("error")
    return (*error["loc"], *(cause.loc if isinstance(cause, FieldError) else ()))


def test_a_sine_past_the_range_or_the_speed_is_refused_in_degrees_on_its_field() -> None:
    lo, hi = allowed_range_deg("pitch")
    center, amplitude = (lo + hi) / 2, (hi - lo) / 2 + 0.01
    with pytest.raises(ValidationError) as err:
        PrescriptionInput.model_validate(_sine("pitch", center, amplitude, 0.05))
    (error,) = err.value.errors()
    assert _field(error) == ("axes", 0, "amplitude"), error
    # Said with the figures that keep the reach outside the range, in degrees.
    assert "reaches -20.01 to 22.9283°, outside the range -20 to 22.92°" in error["msg"], error
    frequency = SPEED_MAX_DEG_S / (2 * math.pi * 10.0) * 1.00003
    with pytest.raises(ValidationError) as err:
        PrescriptionInput.model_validate(_sine("pitch", 0.0, 10.0, frequency))
    (error,) = err.value.errors()
    assert _field(error) == ("axes", 0, "frequency"), error
    assert "moves at up to 114.595°/s, faster than the device allows (114.59°/s)" in error["msg"]


def _strength(*axes: dict[str, object]) -> dict[str, object]:
    body = EXERCISE_LIBRARY[ExerciseKind.STRENGTH].defaults.model_dump(mode="json")
    body["axes"] = [axis(**a) for a in axes]
    return body


def _refusal(body: dict[str, object]) -> tuple[tuple[object, ...], str]:
    with pytest.raises(ValidationError) as err:
        PrescriptionInput.model_validate(body)
    (error,) = err.value.errors()
    return _field(error), str(error["msg"])


@pytest.mark.parametrize(
    ("axes", "said"),
    [
        (  # a corner hold: each angle inside its range, leg 2 at 102.071 mm of 95
            [
                {"axis": "roll", "center": 20.0},
                {"axis": "pitch", "center": 22.9},
                {"axis": "yaw", "center": 15.0},
            ],
            "Roll, pitch and yaw together reach beyond what the platform can do (a leg would "
            "need 102.1 mm where its travel ends at 95 mm), though each is within its own "
            "bounds: move the center nearer 0° on one of them.",
        ),
        (  # each sine within its speed, leg 1 planned at 0.321919 m/s of 0.256
            [
                {"axis": "roll", "waveform": "sine", "amplitude": 10.0, "frequency": 1.8},
                {"axis": "pitch", "waveform": "sine", "amplitude": 10.0, "frequency": 1.8},
            ],
            "Roll and pitch together move faster than the platform can (a leg at up to 0.322 "
            "m/s, above the 0.256 m/s it may be asked for), though each is within its own "
            "bounds: lower the amplitude or the frequency on one of them.",
        ),
    ],
)
def test_targets_refused_together_say_which_axes_and_what_to_lower(
    axes: list[dict[str, object]], said: str
) -> None:
    """The device refuses these in its own words ("these targets together need leg 2 at
    49.5071..102.071 mm", "...above the 0.256 m/s they may plan", after "as it receives it
    (in single precision)"): the prescription says which axes combine and what to lower."""
    where, msg = _refusal(_strength(*axes))
    assert where == ("axes",)
    assert msg == f"Value error, {said}"


@pytest.mark.parametrize(
    ("kw", "field", "why"),
    [
        ({"amplitude": 60.0}, "amplitude", "Amplitude on pitch is not used: a hold stays at"),
        ({"frequency": 7.0}, "frequency", "Frequency on pitch is not used: a hold stays at"),
        ({"ramp_end": -20.0}, "ramp_end", "Ramp end on pitch is not used: a hold stays at"),
        ({"ramp_rate": 100.0}, "ramp_rate", "Ramp rate on pitch is not used: a hold stays at"),
        (
            {"waveform": "sine", "amplitude": 0.0, "frequency": 5.0},
            "frequency",
            "Frequency on pitch is not used: a sine of amplitude 0 stays at its center",
        ),
        (
            {"waveform": "sine", "amplitude": 5.0, "frequency": 0.5, "ramp_end": -20.0},
            "ramp_end",
            "Ramp end on pitch is not used: a sine moves about its center by its amplitude",
        ),
        (
            {"waveform": "ramp", "ramp_end": 10.0, "ramp_rate": 5.0, "amplitude": 60.0},
            "amplitude",
            "Amplitude on pitch is not used: a ramp moves from its center to its end",
        ),
        (
            {"waveform": "ramp", "center": 5.0, "ramp_end": 5.0, "ramp_rate": 100.0},
            "ramp_rate",
            "Ramp rate on pitch is not used: a ramp that ends at its center stays there",
        ),
    ],
)
def test_a_setting_the_target_motion_does_not_use_is_refused_on_its_field(
    kw: dict[str, object], field: str, why: str
) -> None:
    """A strength hold took and stored an amplitude of 60° at 7 Hz and a ramp to -20° at
    100°/s (past every bound, none checked where unused), and a sine of amplitude 0 at 5 Hz."""
    where, msg = _refusal(_strength({"axis": "pitch", **kw}))
    assert where == ("axes", 0, field)
    assert msg.startswith(f"Value error, {why}") and msg.endswith(", so leave it at 0."), msg
    # The same target is taken with the unused setting at 0.
    PrescriptionInput.model_validate(_strength({"axis": "pitch", **kw, field: 0.0}))
