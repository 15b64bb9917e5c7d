"""Every refusal of a prescription is a sentence that names the field as the form labels it.

The cases are generated from the models themselves: each bounded number of the prescription
and of an axis is tried just past each of its bounds, each text just past its length, each
choice with a value that is not one, each required field left out, so that a field added
later without a title or a unit is caught here."""

from __future__ import annotations

import math
from typing import Any

import pytest
from annotated_types import Ge, Gt, Le, Lt, MaxLen
from pydantic import BaseModel, ValidationError

from device.limits import SafetyLimits
from sessions.prescription import (
    EXERCISE_LIBRARY,
    AxisPrescription,
    ExerciseKind,
    PrescriptionBody,
    PrescriptionInput,
)
from sessions.sentences import FieldError, bound_sentence, number, quantity, sentence, setting_parts

STRENGTH: dict[str, Any] = EXERCISE_LIBRARY[ExerciseKind.STRENGTH].defaults.model_dump(mode="json")
PITCH_FLOOR = SafetyLimits().damping_min_at(4, 400.0)
"""The least damping the device publishes for pitch at K = 400."""
PYDANTIC_WORDS = ("Input should", "String should", "List should", "Value error", "Field required")


def _violations(model: type[BaseModel]) -> list[tuple[str, Any]]:
    """(field, a value it refuses) for every bound and kind of each field of ``model``."""
    out: list[tuple[str, Any]] = []
    for name, info in model.model_fields.items():
        for m in info.metadata:
            if isinstance(m, Ge | Gt):
                bound = float(m.ge if isinstance(m, Ge) else m.gt)  # type: ignore[arg-type]
                out.append((name, bound - 1.0 if isinstance(m, Ge) else bound))
            elif isinstance(m, Le | Lt):
                bound = float(m.le if isinstance(m, Le) else m.lt)  # type: ignore[arg-type]
                out.append((name, bound + 1.0))
            elif isinstance(m, MaxLen) and info.annotation is str:
                out.append((name, "x" * (m.max_length + 1)))
        if info.annotation in (float, int):
            out.append((name, "forty"))
        if name in ("exercise", "axis", "waveform"):
            out.append((name, "knee"))
        if info.is_required():
            out.append((name, ...))
    return out


def _body(where: str, field: str, value: Any) -> dict[str, Any]:
    body = {**STRENGTH, "axes": [dict(STRENGTH["axes"][0])]}
    target = body if where == "body" else body["axes"][0]
    if value is ...:
        target.pop(field)
    else:
        target[field] = value
    return body


def _label(model: type[BaseModel], field: str) -> str:
    title = model.model_fields[field].title
    assert title, f"{model.__name__}.{field} has no title: the form and the errors need one"
    return title


CASES = [
    pytest.param("body", f, v, id=f"{f}={v!r}"[:60]) for f, v in _violations(PrescriptionBody)
] + [
    pytest.param("axis", f, v, id=f"axes.0.{f}={v!r}"[:60])
    for f, v in _violations(AxisPrescription)
]


@pytest.mark.parametrize(("where", "field", "value"), CASES)
def test_each_refusal_names_the_field_as_the_form_labels_it(
    where: str, field: str, value: Any
) -> None:
    body = _body(where, field, value)
    with pytest.raises(ValidationError) as err:
        PrescriptionInput.model_validate(body)
    said = [sentence(e, PrescriptionInput, body) for e in err.value.errors()]
    model = PrescriptionBody if where == "body" else AxisPrescription
    label = _label(model, field)
    if where == "axis" and field != "axis":
        label += " on pitch"
    loc = (field,) if where == "body" else ("axes", 0, field)
    mine = [text for at, text in said if at[: len(loc)] == loc]
    assert mine, said
    for text in mine:
        assert text.startswith(label) or f"“{field}”" in text, text
        assert text.endswith("."), text
        assert not any(w in text for w in PYDANTIC_WORDS), text
        # never a field's code name (ramp_rate, rom_low); a choice lists the API's values
        assert "_" not in text.split(" must be one of ")[0], text


@pytest.mark.parametrize(
    ("axis", "loc", "needle"),
    [
        ({"rom_low": -30.0}, "rom_low", "Lowest angle on pitch must be at least -20°."),
        ({"rom_high": 40.0}, "rom_high", "Highest angle on pitch must be at most 22.9°."),
        ({"rom_low": 5.0, "rom_high": 5.0}, "rom_low", "Lowest angle on pitch (5°) must be below"),
        ({"center": 30.0}, "center", "Center on pitch must be at most 22.9°."),
        (
            {"waveform": "ramp", "ramp_end": -25.0, "ramp_rate": 5.0},
            "ramp_end",
            "Ramp end on pitch must be at least -20°.",
        ),
        (
            {"waveform": "ramp", "ramp_end": 10.0},
            "ramp_rate",
            "Ramp rate on pitch must be above 0°/s: a ramp to another angle needs one.",
        ),
        (
            {"waveform": "sine", "amplitude": 30.0, "frequency": 0.1},
            "amplitude",
            "The sine on pitch reaches -30 to 30°, outside the range -20 to 22.9°",
        ),
        (
            {"waveform": "sine", "amplitude": 20.0, "frequency": 2.0},
            "frequency",
            "The target on pitch moves at up to 251.3°/s, faster than the device allows",
        ),
        (
            {"waveform": "sine", "amplitude": 5.0},
            "frequency",
            "Frequency on pitch must be above 0 Hz: a sine needs one.",
        ),
        (
            {"stiffness": 400.0, "damping": 0.0},
            "damping",
            f"Damping B on pitch must be at least {PITCH_FLOOR:g} N·m·s/rad "
            f"({PITCH_FLOOR * math.pi / 180:.3g} N·m·s/°): the least "
            "the platform renders steadily at a stiffness of 400 N·m/rad.",
        ),
    ],
)
def test_a_rule_across_fields_points_at_the_field_to_change(
    axis: dict[str, Any], loc: str, needle: str
) -> None:
    body = {**STRENGTH, "axes": [{**STRENGTH["axes"][0], **axis}]}
    with pytest.raises(ValidationError) as err:
        PrescriptionInput.model_validate(body)
    (error,) = err.value.errors()
    at, text = sentence(error, PrescriptionInput, body)
    assert at == ("axes", 0, loc)
    assert text.startswith(needle), text


@pytest.mark.parametrize("kind", [ExerciseKind.ISOMETRIC, ExerciseKind.PASSIVE_ROM])
@pytest.mark.parametrize("field", ["stiffness", "damping"])
def test_an_exercise_that_does_not_yield_refuses_k_and_b_but_stored_ones_load(
    kind: ExerciseKind, field: str
) -> None:
    body = EXERCISE_LIBRARY[kind].defaults.model_dump(mode="json")
    PrescriptionInput.model_validate(body)  # its own defaults: K = B = 0
    body["axes"][0][field] = 3.0
    with pytest.raises(ValidationError) as err:
        PrescriptionInput.model_validate(body)
    at, text = sentence(err.value.errors()[0], PrescriptionInput, body)
    assert at == ("axes", 0, field)
    assert "is not used in" in text and EXERCISE_LIBRARY[kind].name in text
    # a prescription stored before this rule still loads as the station runs it
    assert getattr(PrescriptionBody.model_validate(body).axes[0], field) == 3.0


def test_the_same_axis_twice_is_said_once() -> None:
    body = {**STRENGTH, "axes": [STRENGTH["axes"][0], STRENGTH["axes"][0]]}
    with pytest.raises(ValidationError) as err:
        PrescriptionInput.model_validate(body)
    at, text = sentence(err.value.errors()[0], PrescriptionInput, body)
    assert (at, text) == (("axes",), "Each axis may appear once; pitch appears more than once.")


def test_numbers_and_units_read_as_a_clinician_writes_them() -> None:
    assert [number(v) for v in (500.0, 22.918, 114.59, 0.2, 0.6000000238, -20.0)] == [
        "500",
        "22.9",
        "114.6",
        "0.2",
        "0.6",
        "-20",
    ]
    assert quantity(300.0, "N·m/rad") == f"300 N·m/rad ({number(math.radians(300))} N·m/°)"
    assert quantity(22.9, "°") == "22.9°"
    assert bound_sentence("Sets", "ge", 1, "") == "Sets must be at least 1."
    axis = AxisPrescription(axis="roll", stiffness=12.5, damping=0.8)
    assert setting_parts(axis, "stiffness") == ("12.5 N·m/rad", "0.218 N·m/°")
    assert setting_parts(axis, "damping") == ("0.8 N·m·s/rad", "0.014 N·m·s/°")
    assert setting_parts(axis, "center") == ("0°", None)


def test_a_field_error_keeps_its_sentence_and_place() -> None:
    e = FieldError(("rom_low",), "Lowest angle on pitch must be at least -20°.")
    loc, text = sentence({"type": "value_error", "loc": ("body", "axes", 1), "ctx": {"error": e}})
    assert loc == ("body", "axes", 1, "rom_low") and text == str(e)
