"""Prescriptions are checked against anatomy and the device before they reach a patient."""

from __future__ import annotations

import math

import pytest
from pydantic import ValidationError

from sessions.prescription import (
    EXERCISE_LIBRARY,
    AxisPrescription,
    PrescriptionBody,
    PrescriptionInput,
    allowed_range_deg,
)


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
