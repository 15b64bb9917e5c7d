"""What a prescription may ask, published for the form: each field's bounds with the sentence
the API refuses a value past them with, each axis's allowed range, the device's stable
stiffness–damping envelope, and the directions of each axis for the patient's side.

Nothing here is a second copy of a rule: the bounds are read from the model's fields
(:mod:`sessions.prescription`), the ranges from ``allowed_range_deg`` (anatomy and the
device's published limits), the envelope from the limits the device publishes in its HELLO,
the sentences from :func:`sessions.sentences.bound_sentence` (what the 422 says), and the
directions from :func:`sessions.anatomy.direction_table`. The form refuses a value outside a
published bound with the published sentence before it submits; every other rule (a sine's
span, the envelope at a given K) the server checks and answers beside the field.
"""

from __future__ import annotations

from annotated_types import Ge, Gt, Le, Lt
from pydantic import BaseModel, Field
from pydantic.fields import FieldInfo

from device.limits import SafetyLimits
from sessions.anatomy import direction_table
from sessions.prescription import (
    AXIS_INDEX,
    DEVICE_LIMITS,
    ROTATION_AXES,
    AxisPrescription,
    PrescriptionBody,
    allowed_range_deg,
)
from sessions.sentences import bound_sentence, field_label, field_unit

ANGLE_FIELDS = ("center", "ramp_end", "rom_low", "rom_high")
"""Axis settings that are angles: bounded by the axis's allowed range."""


class FieldBounds(BaseModel):
    """One number field's bounds and what the API says when a value is past one."""

    label: str = Field(description="The field as the form labels it, e.g. 'Stiffness K on pitch'.")
    unit: str = Field(description="Its unit as the form shows it ('' for a count).")
    min: float | None = Field(description="Lowest value accepted (see min_exclusive).")
    min_exclusive: bool = Field(description="The lowest accepted value is above min, not min.")
    max: float | None = Field(description="Highest value accepted.")
    below: str | None = Field(description="The API's sentence for a value under min.")
    above: str | None = Field(description="The API's sentence for a value over max.")


class EnvelopeBand(BaseModel):
    """From this stiffness up to the next band's, damping must be at least damping_min."""

    stiffness_from: float = Field(description="N·m/rad.")
    damping_min: float = Field(description="N·m·s/rad.")


class AxisLimits(BaseModel):
    axis: str
    range_deg: tuple[float, float] = Field(
        description="Lowest and highest angle a prescription may reach, degrees: anatomy and "
        "the device's range, the narrower."
    )
    envelope: list[EnvelopeBand] = Field(
        description="The device's stable K–B envelope on this axis, as its HELLO publishes it: "
        "where the platform yields (strength, flexibility, balance, ROM assessment), B must be "
        "at least damping_min of the band K falls in."
    )
    directions: dict[str, str] = Field(
        description="positive, negative (direction names) and positive_label, negative_label "
        "(how a page labels them) for the patient's side."
    )
    fields: dict[str, FieldBounds] = Field(description="Each number setting of this axis.")


class PrescriptionLimits(BaseModel):
    """Everything a prescription form shows before it submits."""

    side: str | None = Field(description="The affected side the directions are named for.")
    axes: dict[str, AxisLimits]
    fields: dict[str, FieldBounds] = Field(description="The timeline's and safety's numbers.")


def _bounds(info: FieldInfo) -> tuple[float | None, bool, float | None]:
    lo: float | None = None
    hi: float | None = None
    exclusive = False
    for m in info.metadata:
        if isinstance(m, Ge):
            lo = float(m.ge)  # type: ignore[arg-type]
        elif isinstance(m, Gt):
            lo, exclusive = float(m.gt), True  # type: ignore[arg-type]
        elif isinstance(m, Le):
            hi = float(m.le)  # type: ignore[arg-type]
        elif isinstance(m, Lt):
            hi = float(m.lt)  # type: ignore[arg-type]
    return lo, exclusive, hi


def field_bounds(
    name: str,
    info: FieldInfo,
    axis: str | None = None,
    span: tuple[float, float] | None = None,
) -> FieldBounds:
    """A field's published bounds; ``span`` narrows them (an angle's allowed range)."""
    lo, exclusive, hi = _bounds(info)
    if span is not None:
        lo, exclusive, hi = span[0], False, span[1]
    label, unit = field_label(name, info, axis), field_unit(info)
    return FieldBounds(
        label=label,
        unit=unit,
        min=lo,
        min_exclusive=exclusive,
        max=hi,
        below=None if lo is None else bound_sentence(label, "gt" if exclusive else "ge", lo, unit),
        above=None if hi is None else bound_sentence(label, "le", hi, unit),
    )


def _number_fields(model: type[BaseModel]) -> dict[str, FieldInfo]:
    return {
        name: info
        for name, info in model.model_fields.items()
        if any(isinstance(m, Ge | Gt | Le | Lt) for m in info.metadata)
    }


def axis_limits(axis: str, side: str | None, device: SafetyLimits) -> AxisLimits:
    span = allowed_range_deg(axis)
    i = AXIS_INDEX[axis]
    return AxisLimits(
        axis=axis,
        range_deg=span,
        envelope=[
            EnvelopeBand(stiffness_from=k, damping_min=device.damping_min[3 * i + band])
            for band, k in enumerate(device.envelope_stiffness)
        ],
        directions=direction_table(side)[axis],
        fields={
            name: field_bounds(name, info, axis, span if name in ANGLE_FIELDS else None)
            for name, info in _number_fields(AxisPrescription).items()
        },
    )


def prescription_limits(side: str | None) -> PrescriptionLimits:
    """The limits a prescription form shows for a patient whose affected side is ``side``."""
    return PrescriptionLimits(
        side=side,
        axes={axis: axis_limits(axis, side, DEVICE_LIMITS) for axis in ROTATION_AXES},
        fields={
            name: field_bounds(name, info)
            for name, info in _number_fields(PrescriptionBody).items()
        },
    )
