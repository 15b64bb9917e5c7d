"""What a therapist prescribes: an exercise from the library, per-axis settings, a timeline.

The one model the server validates, stores and sends, and the home station runs. A therapist
thinks in ankle angles, so the API speaks degrees and N·m/rad; the station converts to the
device's radians. Only the three ankle rotations are prescribed: the platform holds its home
position in x, y and z.

Sign conventions (the device's task frame, see ``device.geometry``): pitch > 0 is
plantarflexion (toes down), pitch < 0 dorsiflexion; roll > 0 lifts the foot's left edge
(inversion of a right foot, eversion of a left one); yaw > 0 turns the toes to the left.

Every limit is checked twice before it reaches a patient: here against anatomical bounds and
the device's published limits (a 422 that names the field and the bound), and again by the
device itself, which refuses anything outside its own limits.
"""

from __future__ import annotations

import math
from enum import StrEnum
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator
from pydantic.config import JsonDict

from device.axes import AXIS_INDEX as DEVICE_AXIS_INDEX
from device.axes import ROTATION_AXES as ROTATION_AXES  # re-exported for the server
from device.axes import RotationAxis
from device.commands import (
    FORCE_LIMIT_MIN,
    TORQUE_LIMIT_MIN,
    CommandError,
    check_segment_as_received,
    figures,
)
from device.geometry import DEFAULT_GEOMETRY
from device.limits import SafetyLimits, to_float32
from device.protocol import messages as msg
from device.segments import AxisPlan, build_segment
from device.waveforms import AxisTarget
from device.waveforms import Waveform as DeviceWaveform
from sessions.sentences import FieldError, bound_sentence, field_label, number
from sessions.text import lines, one_line

Axis = RotationAxis
"""A prescribed axis: one of the ankle's rotations (``device.axes``, the project's one table)."""
AXIS_INDEX: dict[str, int] = {a: DEVICE_AXIS_INDEX[a] for a in ROTATION_AXES}
"""Index of each prescribed axis in the device's 6-axis pose."""

ANATOMICAL_DEG: dict[str, tuple[float, float]] = {
    "pitch": (-20.0, 45.0),  # dorsiflexion 20 deg, plantarflexion 45 deg
    "roll": (-20.0, 20.0),  # eversion about 20 deg; inversion (30-35) capped to match it
    "yaw": (-15.0, 15.0),  # ab-/adduction of the foot at the ankle
}
"""Normal adult active ranges (AAOS), conservative: a prescription never goes past them."""

DEVICE_LIMITS = SafetyLimits().published()
"""The device's limits as it publishes them in its HELLO (float32)."""


def device_range_deg(axis: str) -> tuple[float, float]:
    """The device's own range of motion on one axis, degrees."""
    i = AXIS_INDEX[axis]
    return math.degrees(DEVICE_LIMITS.rom_low[i]), math.degrees(DEVICE_LIMITS.rom_high[i])


def allowed_range_deg(axis: str) -> tuple[float, float]:
    """Anatomical bounds and the device's range: the narrower wins."""
    lo_a, hi_a = ANATOMICAL_DEG[axis]
    lo_d, hi_d = device_range_deg(axis)
    return max(lo_a, lo_d), min(hi_a, hi_d)


STIFFNESS_MAX = DEVICE_LIMITS.stiffness_max[3]
"""N·m/rad: the device's largest rotational stiffness."""
DAMPING_MAX = DEVICE_LIMITS.damping_max[3]
"""N·m·s/rad: the device's largest rotational damping."""
SPEED_MAX_DEG_S = math.degrees(DEVICE_LIMITS.axis_speed_max[3])
"""Fastest target motion the device accepts on a rotation axis, deg/s."""
TORQUE_LIMIT_MAX = DEVICE_LIMITS.torque_limit
FORCE_LIMIT_MAX = DEVICE_LIMITS.force_limit
"""The largest torque (N·m) and force (N) limits: the device's own. The least are the
device's too (``device.commands.TORQUE_LIMIT_MIN``, ``FORCE_LIMIT_MIN``: a foot at rest
would trip a lower one), so the form publishes the bounds the device enforces."""
SEGMENT_S_MAX = 600.0
"""Longest repetition (s): one device segment."""
SLACK_DEG = 1e-9
"""Degrees an angle may pass a bound by and still be at it (the sum of two numbers typed at
the bound, e.g. center + amplitude, can land a rounding step beyond it)."""
SETS_MAX, REPETITIONS_MAX = 20, 100
"""The most sets, and repetitions per set, a prescription asks (a session's end record
counts no more: ``sessions.recording.End``)."""
SESSION_S_MAX = 2 * 3600.0
"""The longest session a prescription asks (s), rests between sets included: two hours.
Each count and time on its own is bounded, but together they reached 347 hours (20 sets of
100 repetitions of 600 s with 900 s rests), a session nobody does and no upload carries:
the station records every sample (234 bytes; 100 a second by default, 42 MB per 30 min),
and the server takes a session file of at most 512 MiB by default (``upload_max_bytes``),
about 6.4 hours; a longer one is refused and stays at the station. Two hours is thirty
times the library's longest default session (4 min), and its recording fits that limit
with room for holds and homing: a third of it at the default rate, and still under it at
the device's fastest telemetry (250 samples a second, 421 MB)."""


def duration_words(seconds: float) -> str:
    """A duration as a sentence says it, to the second: "2 h", "347 h 45 min", "4 min 30 s"."""
    whole = round(seconds)
    parts = [(whole // 3600, "h"), (whole // 60 % 60, "min"), (whole % 60, "s")]
    said = [f"{n} {unit}" for n, unit in parts if n]
    return " ".join(said) or "0 s"


def plus_zero(value: object) -> object:
    """-0.0 as 0.0 (a number is stored, shown and sent as the therapist means it); anything
    else unchanged."""
    return value + 0.0 if isinstance(value, float) else value


def _said(value: float, bound: float) -> tuple[str, str]:
    """``value`` and ``bound`` as a sentence says them (:func:`number`), or with the figures
    that keep them apart when rounding would not (``device.commands.figures``): a sine
    reaching 22.929° is not said to reach 22.9°, outside a range up to 22.9°."""
    texts = number(value), number(bound)
    shown = float(texts[0]), float(texts[1])
    if (shown[0] > shown[1]) == (value > bound) and (shown[0] < shown[1]) == (value < bound):
        return texts
    said, top = figures(value, bound, digits=4)
    return said, top


class ExerciseKind(StrEnum):
    """The exercise library (Girone et al., the Rutgers Ankle's clinical protocols)."""

    STRENGTH = "strength"
    """Resistive: the patient moves the foot against the prescribed stiffness and damping."""
    FLEXIBILITY = "flexibility"
    """Range of motion, active-assisted: the platform moves slowly to the ends of the
    prescribed range while yielding a little to the patient."""
    PASSIVE_ROM = "passive_rom"
    """Passive range of motion: the platform moves a relaxed foot; it does not yield."""
    ISOMETRIC = "isometric"
    """The platform holds still and stiff; the patient pushes; torque is what counts."""
    BALANCE = "balance"
    """Low stiffness in roll and pitch: the patient keeps the platform level."""
    ROM_ASSESSMENT = "rom_assessment"
    """Nearly free platform: the patient moves as far as they can; the range is recorded."""


COMPLIANT_KINDS = frozenset(
    {
        ExerciseKind.STRENGTH,
        ExerciseKind.FLEXIBILITY,
        ExerciseKind.BALANCE,
        ExerciseKind.ROM_ASSESSMENT,
    }
)
"""Exercises in which the platform yields to the foot (renders K and B); in the others it
holds or moves the foot and does not give way."""

Waveform = Literal["hold", "sine", "ramp"]

_NO_NAN = ConfigDict(allow_inf_nan=False, extra="forbid")
_DEG: JsonDict = {"unit": "°"}
# A clinician's number must arrive as a JSON number: strict fields refuse true (which lax
# mode reads as 1) and "40" (which it reads as 40), so a form or script that sends the
# wrong type is told so instead of prescribing something nobody typed. An integer is still
# a valid float; a count refuses 2.0.


class AxisPrescription(BaseModel):
    """The target and the impedance on one ankle axis."""

    model_config = _NO_NAN

    axis: Axis = Field(
        title="Axis",
        description="Ankle axis: roll (inversion/eversion), pitch "
        "(plantar/dorsiflexion) or yaw (ab-/adduction).",
    )
    stiffness: float = Field(
        strict=True,
        ge=0.0,
        le=STIFFNESS_MAX,
        title="Stiffness K",
        description="K, N·m/rad: resistance to leaving the target.",
        json_schema_extra={"unit": "N·m/rad"},
    )
    damping: float = Field(
        strict=True,
        ge=0.0,
        le=DAMPING_MAX,
        title="Damping B",
        description="B, N·m·s/rad: resistance to moving fast.",
        json_schema_extra={"unit": "N·m·s/rad"},
    )
    waveform: Waveform = Field(
        default="hold",
        title="Target motion",
        description="hold: stay at center; sine: center + amplitude·sin(2π·frequency·t); "
        "ramp: from center to ramp_end at ramp_rate, then stay.",
    )
    center: float = Field(
        strict=True,
        default=0.0,
        ge=-90.0,
        le=90.0,
        title="Center",
        description="Degrees from home.",
        json_schema_extra=_DEG,
    )
    amplitude: float = Field(
        strict=True,
        default=0.0,
        ge=0.0,
        le=90.0,
        title="Amplitude",
        description="Degrees (sine).",
        json_schema_extra=_DEG,
    )
    frequency: float = Field(
        strict=True,
        default=0.0,
        ge=0.0,
        le=7.0,
        title="Frequency",
        description="Hz (sine).",
        json_schema_extra={"unit": "Hz"},
    )
    ramp_end: float = Field(
        strict=True,
        default=0.0,
        ge=-90.0,
        le=90.0,
        title="Ramp end",
        description="Degrees (ramp).",
        json_schema_extra=_DEG,
    )
    ramp_rate: float = Field(
        strict=True,
        default=0.0,
        ge=0.0,
        le=SPEED_MAX_DEG_S,
        title="Ramp rate",
        description="Degrees per second (ramp); the device's fastest target motion at most.",
        json_schema_extra={"unit": "°/s"},
    )
    rom_low: float | None = Field(
        strict=True,
        default=None,
        ge=-90.0,
        le=90.0,
        title="Lowest angle",
        description="Lowest angle allowed in this exercise, degrees; default the allowed "
        "range (anatomy and device, the narrower).",
        json_schema_extra=_DEG,
    )
    rom_high: float | None = Field(
        strict=True,
        default=None,
        ge=-90.0,
        le=90.0,
        title="Highest angle",
        description="Highest angle allowed in this exercise, degrees; default the allowed range.",
        json_schema_extra=_DEG,
    )

    _plus_zero = field_validator("*", mode="after")(plus_zero)

    def _label(self, field: str) -> str:
        return field_label(field, type(self).model_fields[field], self.axis)

    def limits_deg(self) -> tuple[float, float]:
        lo, hi = allowed_range_deg(self.axis)
        return (
            lo if self.rom_low is None else self.rom_low,
            hi if self.rom_high is None else self.rom_high,
        )

    def target_span_deg(self) -> tuple[float, float]:
        """Lowest and highest angle the target waveform reaches."""
        if self.waveform == "sine":
            return self.center - self.amplitude, self.center + self.amplitude
        if self.waveform == "ramp":
            return min(self.center, self.ramp_end), max(self.center, self.ramp_end)
        return self.center, self.center

    def peak_speed_deg_s(self) -> float:
        if self.waveform == "sine":
            return 2.0 * math.pi * self.frequency * self.amplitude
        if self.waveform == "ramp":
            return self.ramp_rate
        return 0.0

    def target_inside(self) -> bool:
        """The target waveform stays within :meth:`limits_deg` (as degrees are compared)."""
        t_lo, t_hi = self.target_span_deg()
        lo, hi = self.limits_deg()
        return t_lo >= lo - SLACK_DEG and t_hi <= hi + SLACK_DEG

    def speed_allowed(self) -> bool:
        """The target moves no faster than the device allows (as degrees are compared)."""
        return self.peak_speed_deg_s() <= SPEED_MAX_DEG_S + SLACK_DEG

    def _in_range(self, field: str, lo: float, hi: float) -> None:
        value = getattr(self, field)
        if value is None:
            return
        if value < lo - SLACK_DEG:
            raise FieldError((field,), bound_sentence(self._label(field), "ge", lo, "°"))
        if value > hi + SLACK_DEG:
            raise FieldError((field,), bound_sentence(self._label(field), "le", hi, "°"))

    @model_validator(mode="after")
    def _within_bounds(self) -> AxisPrescription:
        lo_ok, hi_ok = allowed_range_deg(self.axis)
        self._in_range("rom_low", lo_ok, hi_ok)
        self._in_range("rom_high", lo_ok, hi_ok)
        lo, hi = self.limits_deg()
        if lo >= hi:
            raise FieldError(
                ("rom_high" if self.rom_low is None else "rom_low",),
                f"{self._label('rom_low')} ({number(lo)}°) must be below the highest angle "
                f"({number(hi)}°).",
            )
        self._in_range("center", lo, hi)
        if self.waveform == "ramp":
            self._in_range("ramp_end", lo, hi)
        if not self.target_inside():
            t_lo, t_hi = self.target_span_deg()
            (reach_lo, low), (reach_hi, high) = _said(t_lo, lo), _said(t_hi, hi)
            raise FieldError(
                ("amplitude",),
                f"The sine on {self.axis} reaches {reach_lo} to {reach_hi}°, outside the "
                f"range {low} to {high}°: lower the amplitude or move the center.",
            )
        if not self.speed_allowed():  # a sine's (a ramp's rate has its own bound)
            speed, top = _said(self.peak_speed_deg_s(), SPEED_MAX_DEG_S)
            raise FieldError(
                ("frequency",),
                f"The target on {self.axis} moves at up to {speed}°/s, faster than the device "
                f"allows ({top}°/s): lower the amplitude or the frequency.",
            )
        if self.waveform == "sine" and self.amplitude > 0 and self.frequency <= 0:
            raise FieldError(
                ("frequency",),
                bound_sentence(self._label("frequency"), "gt", 0, "Hz", "a sine needs one"),
            )
        if self.waveform == "ramp" and self.ramp_end != self.center and self.ramp_rate <= 0:
            raise FieldError(
                ("ramp_rate",),
                bound_sentence(
                    self._label("ramp_rate"), "gt", 0, "°/s", "a ramp to another angle needs one"
                ),
            )
        return self


class PrescriptionBody(BaseModel):
    """An exercise with its timeline: sets of repetitions with rest between sets."""

    model_config = _NO_NAN

    exercise: ExerciseKind = Field(title="Exercise")
    title: str = Field(
        default="", max_length=120, title="Title", description="Shown to the patient."
    )
    instructions: str = Field(
        default="",
        max_length=2000,
        title="Instructions",
        description="Plain words for the patient.",
    )
    axes: list[AxisPrescription] = Field(min_length=1, max_length=3, title="Axes")
    sets: int = Field(strict=True, default=1, ge=1, le=SETS_MAX, title="Sets")
    repetitions: int = Field(
        strict=True,
        default=10,
        ge=1,
        le=REPETITIONS_MAX,
        title="Repetitions per set",
        description="Per set.",
    )
    repetition_s: float = Field(
        strict=True,
        default=10.0,
        ge=1.0,
        le=SEGMENT_S_MAX,
        title="Repetition time",
        description="Duration of one repetition, s.",
        json_schema_extra={"unit": "s"},
    )
    rest_s: float = Field(
        strict=True,
        default=30.0,
        ge=0.0,
        le=900.0,
        title="Rest between sets",
        description="Rest between sets, s.",
        json_schema_extra={"unit": "s"},
    )
    torque_limit: float = Field(
        strict=True,
        default=TORQUE_LIMIT_MAX,
        ge=TORQUE_LIMIT_MIN,
        le=TORQUE_LIMIT_MAX,
        title="Torque limit",
        description="N·m: the device stops if the foot's torque exceeds it.",
        json_schema_extra={"unit": "N·m"},
    )
    force_limit: float = Field(
        strict=True,
        default=FORCE_LIMIT_MAX,
        ge=FORCE_LIMIT_MIN,
        le=FORCE_LIMIT_MAX,
        title="Force limit",
        description="N: the device stops if the force on the foot plate exceeds it.",
        json_schema_extra={"unit": "N"},
    )
    sessions_per_week: int = Field(
        strict=True,
        default=5,
        ge=1,
        le=14,
        title="Sessions per week",
        description="How often the patient should do this exercise; adherence is measured "
        "against it.",
    )

    _plus_zero = field_validator("*", mode="after")(plus_zero)

    @model_validator(mode="after")
    def _axes_once(self) -> PrescriptionBody:
        names = [a.axis for a in self.axes]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise FieldError(
                ("axes",), f"Each axis may appear once; {', '.join(twice)} appears more than once."
            )
        return self

    @model_validator(mode="after")
    def _stable(self) -> PrescriptionBody:
        """Where the platform yields, K and B must lie in the device's stable envelope."""
        if self.exercise not in COMPLIANT_KINDS:
            return self
        for i, a in enumerate(self.axes):
            # K and B as the device receives them (float32), looked up as it looks them up
            # (device.commands): 4.9999999 reaches it as 5, where the envelope asks 0.8.
            axis = AXIS_INDEX[a.axis]
            stiffness = to_float32(a.stiffness)
            least = DEVICE_LIMITS.damping_min_at(axis, stiffness)
            if to_float32(a.damping) < least:
                raise FieldError(
                    ("axes", i, "damping"),
                    bound_sentence(
                        a._label("damping"),
                        "ge",
                        least,
                        "N·m·s/rad",
                        "the least the platform renders steadily at a stiffness of "
                        f"{_envelope_stiffness(axis, stiffness)} N·m/rad",
                    ),
                )
        return self

    def total_s(self) -> float:
        """Exercise time including rests between sets."""
        return self.sets * self.repetitions * self.repetition_s + (self.sets - 1) * self.rest_s

    def compliant(self) -> bool:
        """Whether the platform renders K and B (yields to the patient) in this exercise."""
        return EXERCISE_LIBRARY[self.exercise].compliant


def _envelope_stiffness(axis: int, stiffness: float) -> str:
    """``stiffness`` (float32) as a sentence about the envelope says it: rounded as every
    number is (:func:`number`), unless the rounded value asks another least damping than
    ``stiffness`` does (4.9999995 said as 5, where the published envelope asks 0.8 instead
    of 1): then with the figures that tell it from the band's edge ("4.9999995")."""
    said = number(stiffness)
    if DEVICE_LIMITS.damping_min_at(axis, float(said)) == DEVICE_LIMITS.damping_min_at(
        axis, stiffness
    ):
        return said
    return np.format_float_positional(np.float32(stiffness), trim="-")


def _unused_by_waveform(a: AxisPrescription) -> list[tuple[str, str]]:
    """The settings of ``a`` its target motion does not render, each with why: a hold stays
    at its center, a sine moves only with an amplitude and a ramp only to another angle.
    Their bounds are checked only where they are used, so a hold took and stored an
    amplitude of 60° at 7 Hz and a ramp to -20° at 100°/s, and a sine of amplitude 0 took
    5 Hz: numbers on the record that nothing renders."""
    sine, ramp = ("amplitude", "frequency"), ("ramp_end", "ramp_rate")
    if a.waveform == "hold":
        return [(f, "a hold stays at its center") for f in sine + ramp]
    if a.waveform == "sine":
        moves = "a sine moves about its center by its amplitude at its frequency"
        unused = [(f, moves) for f in ramp]
        if a.amplitude == 0:
            unused.append(("frequency", "a sine of amplitude 0 stays at its center"))
        return unused
    unused = [(f, "a ramp moves from its center to its end at its rate") for f in sine]
    if a.ramp_end == a.center:
        unused.append(("ramp_rate", "a ramp that ends at its center stays there"))
    return unused


class PrescriptionInput(PrescriptionBody):
    """A prescription as a therapist writes it (new, or a new version). Besides the body's
    checks, an exercise in which the platform does not yield (isometric, passive range of
    motion) takes no stiffness or damping: a K or B there would be a number on the record
    that nothing renders, so it is refused rather than silently kept; so is a setting of a
    target motion that does not use it (:func:`_unused_by_waveform`). The title and the
    instructions hold no control characters (``sessions.text``). Stored prescriptions are
    read back as :class:`PrescriptionBody` and load whatever they hold."""

    _title_one_line = field_validator("title")(one_line)
    _instructions_text = field_validator("instructions")(lines)

    @model_validator(mode="after")
    def _only_used_settings(self) -> PrescriptionInput:
        for i, a in enumerate(self.axes):
            for field, why in _unused_by_waveform(a):
                if getattr(a, field) != 0:
                    raise FieldError(
                        ("axes", i, field),
                        f"{a._label(field)} is not used: {why}, so leave it at 0.",
                    )
        if self.exercise in COMPLIANT_KINDS:
            return self
        name = EXERCISE_LIBRARY[self.exercise].name
        for i, a in enumerate(self.axes):
            for field in ("stiffness", "damping"):
                if getattr(a, field) != 0:
                    raise FieldError(
                        ("axes", i, field),
                        f"{a._label(field)} is not used in “{name}”: the platform does not "
                        "give way in this exercise, so leave it at 0.",
                    )
        return self

    @model_validator(mode="after")
    def _session_fits(self) -> PrescriptionInput:
        """The whole session, rests included, no longer than :data:`SESSION_S_MAX`. Said of
        the sets, the first of the timeline's fields, with every number it is made of."""
        total = self.total_s()
        if total <= SESSION_S_MAX:
            return self
        sets = f"{self.sets} set{'s' if self.sets != 1 else ''}"
        reps = f"{self.repetitions} repetition{'s' if self.repetitions != 1 else ''}"
        rests = (
            f", {number(self.rest_s)} s rest between sets"
            if self.sets > 1 and self.rest_s > 0
            else ""
        )
        said, most = duration_words(total), duration_words(SESSION_S_MAX)
        if round(total) <= SESSION_S_MAX:  # to the second it reads as the maximum: 7200.4 s
            said, most = (f"{text} s" for text in figures(total, SESSION_S_MAX))
        raise FieldError(
            ("sets",),
            f"This session lasts {said} ({sets} of {reps} of {number(self.repetition_s)} s"
            f"{rests}), longer than the {most} a session may last: fewer sets or "
            "repetitions, or shorter repetitions or rests.",
        )

    @model_validator(mode="after")
    def _device_accepts(self) -> PrescriptionInput:
        """The device's own check of a repetition's segment, on the values as it receives
        them (float32, radians) and against the limits it publishes: whatever the bounds
        above let through, a prescription the device would refuse at its start is refused
        here, beside the field. (A torque limit of 1e-300 N·m reaches the device as 0.)"""
        segment = device_segment(
            DEVICE_LIMITS,
            1,
            self,
            {a.axis: a.stiffness for a in self.axes},
            {a.axis: a.damping for a in self.axes},
        )
        try:
            check_segment_as_received(segment, DEVICE_LIMITS, DEFAULT_GEOMETRY)
        except CommandError as exc:
            raise self._device_refusal(exc) from None
        return self

    def _device_refusal(self, exc: CommandError) -> FieldError:
        """The device's refusal of this prescription's segment, said of the field it is about."""
        why = f"the platform refuses it as it receives it (in single precision): {exc}."
        top = {"duration": "repetition_s", "force_limit": "force_limit"}
        top["torque_limit"] = "torque_limit"
        if exc.field in top:
            name = top[exc.field]
            label = field_label(name, PrescriptionBody.model_fields[name])
            return FieldError((name,), f"{label}: {why}")
        for i, a in enumerate(self.axes):
            if exc.axis == AXIS_INDEX[a.axis] and exc.field in AxisPrescription.model_fields:
                return FieldError(("axes", i, exc.field), f"{a._label(exc.field)}: {why}")
        if exc.amount is not None:
            return FieldError(("axes",), self._together(exc.field == "center", *exc.amount))
        return FieldError(("axes",), f"The platform refuses these targets together: {exc}.")

    def _together(self, reach: bool, need: float, bound: float) -> str:
        """The device's refusal of targets each within its own bounds but not all at once
        (``device.commands.check_reachable``: a leg's length, ``reach``; else
        ``check_planned_leg_speed``: a leg's speed), said as a therapist acts on it: which
        axes combine, how far past the platform they go, and what to lower. The device's
        own sentence names a leg and "what they may plan", which nobody prescribing can
        change: a corner hold (roll 20°, pitch 22.9°, yaw 15°, each inside its range) needs
        leg 2 at 102.071 mm of 95."""
        if reach:
            axes = [a for a in self.axes if a.target_span_deg() != (0.0, 0.0)]
        else:
            axes = [a for a in self.axes if a.peak_speed_deg_s() > 0]
        axes = axes or list(self.axes)
        names = [a.axis for a in axes]
        said = names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"
        waves = {a.waveform for a in axes}
        if reach:
            mm, top = _said(need, bound)
            lower = (["lower the amplitude"] if "sine" in waves else []) + [
                "move the center" + (" or the ramp end" if "ramp" in waves else "") + " nearer 0°"
            ]
            verb = "reach"
            what = (
                f"beyond what the platform can do (a leg would need {mm} mm where its travel "
                f"ends at {top} mm)"
            )
        else:
            speed, top = _said(need, bound)
            lower = ["lower the amplitude or the frequency"] if "sine" in waves else []
            lower += ["lower the ramp rate"] if "ramp" in waves else []
            verb = "move"
            what = (
                f"faster than the platform can (a leg at up to {speed} m/s, above the {top} "
                "m/s it may be asked for)"
            )
        fix = " or ".join(lower)
        if len(names) == 1:
            return f"The target on {said} {verb}s {what}: {fix}."
        return (
            f"{said[0].upper()}{said[1:]} together {verb} {what}, though each is within its "
            f"own bounds: {fix} on one of them."
        )


_WAVEFORM = {"hold": DeviceWaveform.HOLD, "sine": DeviceWaveform.SINE, "ramp": DeviceWaveform.RAMP}


def device_segment(
    device: msg.DeviceHello | SafetyLimits,
    segment_id: int,
    body: PrescriptionBody,
    stiffness: dict[str, float],
    damping: dict[str, float],
) -> msg.StartSegment:
    """The device segment of one repetition: the prescription in the device's units (radians)
    with the K and B given, its ranges of motion and limits; unprescribed axes hold home
    within the device's own range (``device``: its HELLO, or the limits it publishes)."""
    low, high = list(device.rom_low), list(device.rom_high)
    plans: dict[str, AxisPlan] = {}
    compliant = body.compliant()
    for a in body.axes:
        lo, hi = a.limits_deg()
        i = AXIS_INDEX[a.axis]
        low[i], high[i] = math.radians(lo), math.radians(hi)
        if a.waveform == "sine":
            top = device.axis_speed_max[i]
            center, amplitude, frequency = _sine_as_received(a, low[i], high[i], top)
        else:
            center, amplitude = math.radians(a.center), math.radians(a.amplitude)
            frequency = a.frequency
        plans[a.axis] = AxisPlan(
            waveform=_WAVEFORM[a.waveform],
            center=center,
            amplitude=amplitude,
            frequency=frequency,
            ramp_end=math.radians(a.ramp_end),
            ramp_rate=math.radians(a.ramp_rate),
            stiffness=stiffness[a.axis],
            damping=damping[a.axis],
            compliant=compliant,
        )
    return build_segment(
        device,
        segment_id,
        body.repetition_s,
        plans,
        rom_low=tuple(low),
        rom_high=tuple(high),
        force_limit=body.force_limit,
        torque_limit=body.torque_limit,
    )


SINE_STEPS_MAX = 4
"""Float32 steps a sine's amplitude or frequency is taken in by at most, past the room the
rounded numbers leave (:func:`_sine_as_received`): one is ever needed."""


def _sine_as_received(
    a: AxisPrescription, low: float, high: float, speed_max: float
) -> tuple[float, float, float]:
    """The centre, amplitude (radians) and frequency of a sine the model accepted in degrees,
    such that the device accepts them too as it receives them (each a float32 on its own,
    checked as ``device.commands.check_axis_targets`` does): inside ``low..high`` and no
    faster than ``speed_max`` (rad/s). Rounded one by one, a sine spanning the range exactly
    (pitch -20 to 22.918°: centre 1.459°, amplitude 21.459°) reached the device a step beyond
    both ends (-0.3490659..0.40000002 rad in -0.3490658..0.40000001), and one at the top
    speed peaked at 2.00000002 rad/s over 2: refused, though every bound the model states
    held. The centre is kept inside the range, and the amplitude, then the frequency, taken
    in by the float32 steps that cost (under 1e-5° and 1e-6 Hz). A sine the model refuses is
    not adjusted."""
    center, amplitude = math.radians(a.center), math.radians(a.amplitude)
    if not a.target_inside() or not a.speed_allowed():
        return center, amplitude, a.frequency
    lo, hi, top = to_float32(low), to_float32(high), to_float32(speed_max)
    c = min(max(to_float32(center), lo), hi)
    amp = np.float32(min(to_float32(amplitude), c - lo, hi - c))

    def sine(amp: np.float32, hz: np.float32) -> AxisTarget:  # the device's own arithmetic
        return AxisTarget(DeviceWaveform.SINE, c, float(amp), float(hz))

    for _ in range(SINE_STEPS_MAX):
        t_lo, t_hi = sine(amp, np.float32(0.0)).extent()
        if t_lo >= lo and t_hi <= hi:
            break
        amp = np.nextafter(amp, np.float32(0.0))
    hz = np.float32(a.frequency)
    if amp > 0:
        hz = np.float32(min(float(hz), top / (2.0 * math.pi * float(amp))))
    for _ in range(SINE_STEPS_MAX):
        if sine(amp, hz).peak_speed() <= top:
            break
        hz = np.nextafter(hz, np.float32(0.0))
    return c, float(amp), float(hz)


class ExerciseTemplate(BaseModel):
    """One entry of the exercise library: what it is for and sensible defaults."""

    kind: ExerciseKind
    name: str
    purpose: str
    compliant: bool = Field(description="The platform yields to the foot (renders K, B).")
    defaults: PrescriptionBody


def _axis(axis: Axis, **kw: float | str) -> AxisPrescription:
    return AxisPrescription.model_validate({"axis": axis, **kw})


EXERCISE_LIBRARY: dict[ExerciseKind, ExerciseTemplate] = {}


def _template(kind: ExerciseKind, name: str, purpose: str, **body: object) -> None:
    EXERCISE_LIBRARY[kind] = ExerciseTemplate(
        kind=kind,
        name=name,
        purpose=purpose,
        compliant=kind in COMPLIANT_KINDS,
        defaults=PrescriptionBody.model_validate({"exercise": kind, "title": name, **body}),
    )


_template(
    ExerciseKind.STRENGTH,
    "Strength (resistive)",
    "Push the foot down and pull it up against the platform's springiness.",
    axes=[_axis("pitch", stiffness=40.0, damping=2.0)],
    sets=3,
    repetitions=10,
    repetition_s=6.0,
    rest_s=30.0,
    instructions="Push your toes down as far as is comfortable, then bring them up. Slowly.",
)
_template(
    ExerciseKind.FLEXIBILITY,
    "Flexibility (range of motion)",
    "The platform slowly takes the foot towards the ends of its range and back.",
    axes=[
        _axis("pitch", stiffness=60.0, damping=3.0, waveform="sine", amplitude=12.0, frequency=0.1)
    ],
    sets=2,
    repetitions=5,
    repetition_s=10.0,
    rest_s=20.0,
    instructions="Relax and let the platform move your foot. Help it along if you can.",
)
_template(
    ExerciseKind.PASSIVE_ROM,
    "Passive range of motion",
    "The platform moves a relaxed foot through its range; it does not give way.",
    axes=[
        _axis("pitch", stiffness=0.0, damping=0.0, waveform="sine", amplitude=10.0, frequency=0.1)
    ],
    sets=1,
    repetitions=6,
    repetition_s=10.0,
    rest_s=0.0,
    instructions="Keep your foot relaxed on the platform.",
)
_template(
    ExerciseKind.ISOMETRIC,
    "Isometric",
    "The platform holds still; the patient pushes against it without moving.",
    axes=[_axis("pitch", stiffness=0.0, damping=0.0)],
    sets=3,
    repetitions=5,
    repetition_s=5.0,
    rest_s=20.0,
    instructions="Push your toes down against the platform and hold. It will not move.",
)
_template(
    ExerciseKind.BALANCE,
    "Balance",
    "A soft platform in roll and pitch: keep it level.",
    axes=[_axis("roll", stiffness=15.0, damping=1.3), _axis("pitch", stiffness=15.0, damping=1.0)],
    sets=2,
    repetitions=3,
    repetition_s=20.0,
    rest_s=30.0,
    instructions="Keep the platform level. Small, steady corrections.",
)
_template(
    ExerciseKind.ROM_ASSESSMENT,
    "Range of motion assessment",
    "A nearly free platform: move as far as you can in each direction; the range is recorded.",
    axes=[_axis("pitch", stiffness=5.0, damping=0.8), _axis("roll", stiffness=5.0, damping=1.3)],
    sets=1,
    repetitions=2,
    repetition_s=15.0,
    rest_s=0.0,
    instructions="Move your foot as far as you comfortably can: toes down, up, in and out.",
)
