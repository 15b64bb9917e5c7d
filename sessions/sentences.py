"""Validation errors in a clinician's words: one sentence per refusal, naming the field as the
form labels it.

Pydantic says "Input should be greater than or equal to 0" about ``axes.0.damping``; a
therapist needs "Damping B on pitch must be at least 0 N·m·s/rad." This module is the one
place that turns a validation error into such a sentence. The label is the field's title in
its model (or its name in words when it has none), with "on <axis>" for a setting of one
axis; the unit is the field's ``unit`` (``json_schema_extra``), and a per-radian unit is also
said per degree. The API's 422 keeps pydantic's ``type`` and ``loc`` for programs and says
``msg`` in these words; the prescription form shows ``msg`` beside the field.

A model validator that refuses raises :class:`FieldError`, which names the field it is about
(relative to the model), so the answer points at that field rather than at the whole model.
:func:`bound_sentence` says a bound the same way whether pydantic or a validator found it,
and the API publishes the same sentences for the form to refuse with before it submits.
"""

from __future__ import annotations

import math
import typing
from collections.abc import Mapping, Sequence
from typing import Any, Literal

from pydantic import BaseModel
from pydantic.fields import FieldInfo

from sessions.text import (
    CONTROL_CHARACTER,
    DIRECTION_CONTROL,
    EMAIL_PATTERN,
    INVISIBLE_CHARACTER,
    MIXED_SCRIPTS,
    NOTHING_VISIBLE,
    STACKED_MARKS,
)

Loc = tuple[str | int, ...]
Op = Literal["ge", "gt", "le", "lt"]


class FieldError(ValueError):
    """A model validator's refusal of one field: ``loc`` is the field's path inside the model
    that raises it (``("rom_low",)``, ``("axes", 0, "damping")``), ``str()`` the sentence."""

    def __init__(self, loc: Loc, sentence: str) -> None:
        super().__init__(sentence)
        self.loc = loc


def number(value: float) -> str:
    """A number as a sentence says it: whole numbers bare, from 10 up to one decimal, smaller
    ones to three figures (22.9, 114.6, 0.698, 0.00349). An integer is said exactly, however
    large (an id's bound, 9223372036854775807, has no float that says it)."""
    if isinstance(value, int) and not isinstance(value, bool):
        return str(value)
    v = float(value)
    if not math.isfinite(v):
        return str(v)
    if abs(v) >= 10:
        v = round(v, 1)
    if v == round(v) and abs(v) < 1e15:
        return str(int(v))
    return f"{v:.1f}" if abs(v) >= 10 else f"{v:.3g}"


def quantity_parts(value: float, unit: str) -> tuple[str, str | None]:
    """``value`` with its unit, and for a per-radian unit the same per degree (else None):
    ("40 N·m/rad", "0.698 N·m/°")."""
    if not unit:
        return number(value), None
    text = f"{number(value)}{unit}" if unit.startswith("°") else f"{number(value)} {unit}"
    if unit.endswith("/rad"):
        return text, f"{number(math.radians(value))} {unit[: -len('/rad')]}/°"
    return text, None


def quantity(value: float, unit: str) -> str:
    """``value`` with its unit; a per-radian unit also per degree: "40 N·m/rad (0.698 N·m/°)"."""
    text, per_degree = quantity_parts(value, unit)
    return f"{text} ({per_degree})" if per_degree else text


_OP_WORDS: dict[Op, str] = {
    "ge": "at least",
    "gt": "above",
    "le": "at most",
    "lt": "below",
}


def bound_sentence(label: str, op: Op, bound: float, unit: str, why: str = "") -> str:
    """ "Stiffness K on pitch must be at most 500 N·m/rad (8.73 N·m/°)." with ``why`` after a
    colon when given."""
    tail = f": {why}" if why else ""
    return f"{label} must be {_OP_WORDS[op]} {quantity(bound, unit)}{tail}."


def field_label(name: str, info: FieldInfo | None, axis: str | None = None) -> str:
    """How a form labels a field: its title, else its name in words; "on <axis>" for an axis."""
    text = info.title if info is not None and info.title else name.replace("_", " ").capitalize()
    return f"{text} on {axis}" if axis else text


def field_unit(info: FieldInfo | None) -> str:
    extra = info.json_schema_extra if info is not None else None
    unit = extra.get("unit") if isinstance(extra, dict) else None
    return unit if isinstance(unit, str) else ""


def setting_parts(model: BaseModel, name: str) -> tuple[str, str | None]:
    """A number setting of ``model`` in its field's unit as the forms and sentences write it,
    and per degree if its unit is per radian: ("40 N·m/rad", "0.698 N·m/°")."""
    return quantity_parts(getattr(model, name), field_unit(type(model).model_fields[name]))


def _models_in(annotation: Any) -> list[type[BaseModel]]:
    """The pydantic models an annotation holds (through Optional, list, Annotated)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    origin = typing.get_origin(annotation)
    if origin is None:
        return []
    found: list[type[BaseModel]] = []
    args = typing.get_args(annotation)
    if origin is typing.Annotated:
        args = args[:1]
    for a in args:
        found.extend(_models_in(a))
    return found


class _Place:
    """What a location names: the field, its label and unit (on its axis)."""

    def __init__(self, name: str, info: FieldInfo | None, axis: str | None) -> None:
        self.name = name
        self.label = field_label(name, info, axis)
        self.unit = field_unit(info)


def _place(model: type[BaseModel] | None, loc: Sequence[str | int], body: Any) -> _Place:
    """Walk ``loc`` through ``model`` (and the request ``body``, to learn which axis an entry
    of ``axes`` is) to the field it names."""
    name, info, axis = "", None, None
    node: Any = body
    for part in loc:
        if isinstance(part, int):
            node = node[part] if isinstance(node, list) and -len(node) <= part < len(node) else None
            if isinstance(node, Mapping) and isinstance(node.get("axis"), str):
                axis = node["axis"]
            continue
        name = part
        field = model.model_fields.get(part) if model is not None else None
        info = field
        node = node.get(part) if isinstance(node, Mapping) else None
        inner = _models_in(field.annotation) if field is not None else []
        model = inner[0] if inner else None
    # the entry of a list (axes.0) is labelled by its list; the axis names a setting, not itself
    on = axis if loc and isinstance(loc[-1], str) and name != "axis" and axis else None
    return _Place(name, info, on)


def _ctx_number(ctx: Mapping[str, Any], key: str) -> float | None:
    """A bound of the error's context as it was given: an integer stays exact."""
    v = ctx.get(key)
    return v if isinstance(v, int | float) and not isinstance(v, bool) else None


def _expected(ctx: Mapping[str, Any]) -> str:
    return str(ctx.get("expected", "")).replace("'", "")


def sentence(
    error: Mapping[str, Any], model: type[BaseModel] | None = None, body: Any = None
) -> tuple[Loc, str]:
    """The location (pydantic's, made more precise by a :class:`FieldError`) and the
    sentence of one validation error of ``model`` validating ``body``. The location's first
    part says where the value was (``body``, ``query``, …) when it comes from a request."""
    loc: Loc = tuple(error.get("loc", ()))
    kind = str(error.get("type", ""))
    ctx: Mapping[str, Any] = error.get("ctx") or {}
    cause = ctx.get("error")
    if isinstance(cause, FieldError):
        return loc + cause.loc, str(cause)
    request_part = loc[0] if loc and loc[0] in ("body", "query", "path", "header") else None
    inner = loc[1:] if request_part else loc
    place = _place(model if request_part in (None, "body") else None, inner, body)
    label = place.label or "The request"
    op = _BOUND_TYPES.get(kind)
    bound = _ctx_number(ctx, op) if op is not None else None
    if op is not None and bound is not None:
        return loc, bound_sentence(label, op, bound, place.unit)
    if kind in ("too_long", "too_short") and isinstance(error.get("input"), str):
        # A length checked after another validator (text cleaned, ``Line | None``) is
        # reported as a collection's: for text, its count is characters.
        kind = "string_" + kind
    if kind == "string_pattern_mismatch":
        form = PATTERN_FORMS.get(str(ctx.get("pattern", "")))
        if form is not None:
            return loc, f"{label} must be {form}."
    text = _SIMPLE.get(kind)
    if text is not None:
        words = {**ctx, "label": label, "name": place.name, "expected": _expected(ctx)}
        return loc, text.format_map(words)
    if kind == "string_too_short":
        if ctx.get("min_length") == 1:
            return loc, f"{label} is required."
        return loc, f"{label} must be at least {ctx.get('min_length')} characters long."
    if kind == "value_error":
        said = str(error.get("msg", "")).removeprefix("Value error, ")
        return loc, said[:1].upper() + said[1:] + ("" if said.endswith(".") else ".")
    return loc, f"{label}: {error.get('msg', 'not valid')}."


JSON_INVALID = "The request is not valid JSON."
"""What a body that does not parse as JSON is told, whatever stopped it (``server.guard``)."""

SHA256_HEX = r"^[0-9a-fA-F]{64}$"
"""A SHA-256 as hex digits, in either case (``sha256sum`` writes lower, some tools upper)."""
PATTERN_FORMS: dict[str, str] = {
    SHA256_HEX: "64 hexadecimal digits (0-9 and a-f)",
    EMAIL_PATTERN: "an email address such as name@clinic.example: one @ with text on each "
    "side, and no spaces",
}
"""What a text a pattern checks must be, in words, for each pattern the API uses; a
pattern not named here is quoted as it is."""

_BOUND_TYPES: dict[str, Op] = {
    "greater_than_equal": "ge",
    "greater_than": "gt",
    "less_than_equal": "le",
    "less_than": "lt",
}
_SIMPLE: dict[str, str] = {
    "missing": "{label} is required.",
    "string_too_long": "{label} must be at most {max_length} characters long.",
    "too_short": "{label}: at least {min_length} required.",
    "too_long": "{label}: at most {max_length} allowed.",
    "float_type": "{label} must be a number.",
    "float_parsing": "{label} must be a number.",
    "int_type": "{label} must be a whole number.",
    "int_parsing": "{label} must be a whole number.",
    "int_from_float": "{label} must be a whole number.",
    "finite_number": "{label} must be a finite number.",
    "bool_type": "{label} must be true or false.",
    "bool_parsing": "{label} must be true or false.",
    "string_type": "{label} must be text.",
    "list_type": "{label} must be a list.",
    "model_type": "{label} must be an object of named fields.",
    "dict_type": "{label} must be an object of named fields.",
    "model_attributes_type": "{label} must be an object of named fields.",
    "literal_error": "{label} must be one of {expected}.",
    "enum": "{label} must be one of {expected}.",
    "extra_forbidden": "“{name}” is not a field here.",
    "string_pattern_mismatch": "{label} is not in the expected form: it must match the "
    "regular expression {pattern}.",
    "json_invalid": JSON_INVALID,
    "datetime_parsing": "{label} must be a date and time (ISO 8601).",
    "datetime_type": "{label} must be a date and time (ISO 8601).",
    "datetime_from_date_parsing": "{label} must be a date and time (ISO 8601).",
    CONTROL_CHARACTER: "{label} must not contain control characters ({char} at character "
    "{at}): type it again without them.",
    DIRECTION_CONTROL: "{label} must not contain text-direction controls ({char} at character "
    "{at}): they make text show in another order than it is written. Type it again without "
    "them.",
    INVISIBLE_CHARACTER: "{label} must not contain invisible characters ({char} at character "
    "{at}): type it again without them.",
    NOTHING_VISIBLE: "{label} has nothing visible in it (only blanks, invisible characters or "
    "combining marks): type letters or digits.",
    STACKED_MARKS: "{label} puts {count} combining marks on character {at}, which draws over "
    "the lines around it: at most {most} are allowed on one character. Type it again without "
    "the extra marks.",
    MIXED_SCRIPTS: "{label} mixes scripts in “{part}” ({char} at character {at} among "
    "{script} letters), so it could pass for another address: type it in one script.",
}


__all__ = [
    "JSON_INVALID",
    "PATTERN_FORMS",
    "SHA256_HEX",
    "FieldError",
    "bound_sentence",
    "field_label",
    "field_unit",
    "number",
    "quantity",
    "sentence",
]
