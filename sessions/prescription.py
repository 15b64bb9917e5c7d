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

from pydantic import BaseModel, ConfigDict, Field, model_validator

from device.axes import AXIS_INDEX as DEVICE_AXIS_INDEX
from device.axes import ROTATION_AXES as ROTATION_AXES  # re-exported for the server
from device.axes import RotationAxis
from device.limits import SafetyLimits, to_float32

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

_DEVICE = SafetyLimits().published()
"""The device's limits as it publishes them in its HELLO (float32)."""


def device_range_deg(axis: str) -> tuple[float, float]:
    """The device's own range of motion on one axis, degrees."""
    i = AXIS_INDEX[axis]
    return math.degrees(_DEVICE.rom_low[i]), math.degrees(_DEVICE.rom_high[i])


def allowed_range_deg(axis: str) -> tuple[float, float]:
    """Anatomical bounds and the device's range: the narrower wins."""
    lo_a, hi_a = ANATOMICAL_DEG[axis]
    lo_d, hi_d = device_range_deg(axis)
    return max(lo_a, lo_d), min(hi_a, hi_d)


STIFFNESS_MAX = _DEVICE.stiffness_max[3]
"""N·m/rad: the device's largest rotational stiffness."""
DAMPING_MAX = _DEVICE.damping_max[3]
"""N·m·s/rad: the device's largest rotational damping."""
SPEED_MAX_DEG_S = math.degrees(_DEVICE.axis_speed_max[3])
"""Fastest target motion the device accepts on a rotation axis, deg/s."""
TORQUE_LIMIT_MAX = _DEVICE.torque_limit
FORCE_LIMIT_MAX = _DEVICE.force_limit
SEGMENT_S_MAX = 600.0
"""Longest repetition (s): one device segment."""


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
# A clinician's number must arrive as a JSON number: strict fields refuse true (which lax
# mode reads as 1) and "40" (which it reads as 40), so a form or script that sends the
# wrong type is told so instead of prescribing something nobody typed. An integer is still
# a valid float; a count refuses 2.0.


class AxisPrescription(BaseModel):
    """The target and the impedance on one ankle axis."""

    model_config = _NO_NAN

    axis: Axis = Field(
        description="Ankle axis: roll (inversion/eversion), pitch "
        "(plantar/dorsiflexion) or yaw (ab-/adduction)."
    )
    stiffness: float = Field(
        strict=True,
        ge=0.0,
        le=STIFFNESS_MAX,
        description="K, N·m/rad: resistance to leaving the target.",
    )
    damping: float = Field(
        strict=True, ge=0.0, le=DAMPING_MAX, description="B, N·m·s/rad: resistance to moving fast."
    )
    waveform: Waveform = Field(
        default="hold",
        description="hold: stay at center; sine: center + amplitude·sin(2π·frequency·t); "
        "ramp: from center to ramp_end at ramp_rate, then stay.",
    )
    center: float = Field(
        strict=True, default=0.0, ge=-90.0, le=90.0, description="Degrees from home."
    )
    amplitude: float = Field(
        strict=True, default=0.0, ge=0.0, le=90.0, description="Degrees (sine)."
    )
    frequency: float = Field(strict=True, default=0.0, ge=0.0, le=7.0, description="Hz (sine).")
    ramp_end: float = Field(
        strict=True, default=0.0, ge=-90.0, le=90.0, description="Degrees (ramp)."
    )
    ramp_rate: float = Field(
        strict=True, default=0.0, ge=0.0, le=180.0, description="Degrees per second."
    )
    rom_low: float | None = Field(
        strict=True,
        default=None,
        ge=-90.0,
        le=90.0,
        description="Lowest angle allowed in this exercise, degrees; default the allowed "
        "range (anatomy and device, the narrower).",
    )
    rom_high: float | None = Field(
        strict=True, default=None, ge=-90.0, le=90.0, description="Degrees."
    )

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

    @model_validator(mode="after")
    def _within_bounds(self) -> AxisPrescription:
        lo_ok, hi_ok = allowed_range_deg(self.axis)
        if self.rom_low is not None and self.rom_low < lo_ok - 1e-9:
            raise ValueError(
                f"rom_low {self.rom_low:g} deg is below {lo_ok:.1f} deg, the lowest {self.axis} "
                "angle allowed (anatomy and device)"
            )
        if self.rom_high is not None and self.rom_high > hi_ok + 1e-9:
            raise ValueError(
                f"rom_high {self.rom_high:g} deg is above {hi_ok:.1f} deg, the highest "
                f"{self.axis} angle allowed (anatomy and device)"
            )
        lo, hi = self.limits_deg()
        if lo >= hi:
            raise ValueError(f"rom_low {lo:g} deg must be below rom_high {hi:g} deg")
        t_lo, t_hi = self.target_span_deg()
        if t_lo < lo - 1e-9 or t_hi > hi + 1e-9:
            raise ValueError(
                f"the {self.waveform} target spans {t_lo:g}..{t_hi:g} deg, outside the "
                f"{self.axis} range {lo:.1f}..{hi:.1f} deg"
            )
        speed = self.peak_speed_deg_s()
        if speed > SPEED_MAX_DEG_S:
            raise ValueError(
                f"the target moves at up to {speed:.0f} deg/s; the device allows "
                f"{SPEED_MAX_DEG_S:.0f} deg/s (lower amplitude, frequency or ramp_rate)"
            )
        if self.waveform == "sine" and self.amplitude > 0 and self.frequency <= 0:
            raise ValueError("a sine with an amplitude needs a frequency above 0 Hz")
        if self.waveform == "ramp" and self.ramp_end != self.center and self.ramp_rate <= 0:
            raise ValueError("a ramp needs a ramp_rate above 0 deg/s")
        return self


class PrescriptionBody(BaseModel):
    """An exercise with its timeline: sets of repetitions with rest between sets."""

    model_config = _NO_NAN

    exercise: ExerciseKind
    title: str = Field(default="", max_length=120, description="Shown to the patient.")
    instructions: str = Field(
        default="", max_length=2000, description="Plain words for the patient."
    )
    axes: list[AxisPrescription] = Field(min_length=1, max_length=3)
    sets: int = Field(strict=True, default=1, ge=1, le=20)
    repetitions: int = Field(strict=True, default=10, ge=1, le=100, description="Per set.")
    repetition_s: float = Field(
        strict=True,
        default=10.0,
        ge=1.0,
        le=SEGMENT_S_MAX,
        description="Duration of one repetition, s.",
    )
    rest_s: float = Field(
        strict=True, default=30.0, ge=0.0, le=900.0, description="Rest between sets, s."
    )
    torque_limit: float = Field(
        strict=True,
        default=TORQUE_LIMIT_MAX,
        gt=0.0,
        le=TORQUE_LIMIT_MAX,
        description="N·m: the device stops if the foot's torque exceeds it.",
    )
    force_limit: float = Field(
        strict=True,
        default=FORCE_LIMIT_MAX,
        gt=0.0,
        le=FORCE_LIMIT_MAX,
        description="N: the device stops if the force on the foot plate exceeds it.",
    )
    sessions_per_week: int = Field(
        strict=True,
        default=5,
        ge=1,
        le=14,
        description="How often the patient should do this exercise; adherence is measured "
        "against it.",
    )

    @model_validator(mode="after")
    def _axes_once(self) -> PrescriptionBody:
        names = [a.axis for a in self.axes]
        if len(set(names)) != len(names):
            raise ValueError(f"each axis may appear once; got {names}")
        return self

    @model_validator(mode="after")
    def _stable(self) -> PrescriptionBody:
        """Where the platform yields, K and B must lie in the device's stable envelope."""
        if self.exercise not in COMPLIANT_KINDS:
            return self
        for a in self.axes:
            least = _DEVICE.damping_min_at(AXIS_INDEX[a.axis], a.stiffness)
            if to_float32(a.damping) < least:  # as the device receives it
                raise ValueError(
                    f"{a.axis} damping {a.damping:g} N·m·s/rad is below {least:g}, the least "
                    f"the platform renders steadily at a stiffness of {a.stiffness:g} N·m/rad: "
                    "raise the damping"
                )
        return self

    def total_s(self) -> float:
        """Exercise time including rests between sets."""
        return self.sets * self.repetitions * self.repetition_s + (self.sets - 1) * self.rest_s

    def compliant(self) -> bool:
        """Whether the platform renders K and B (yields to the patient) in this exercise."""
        return EXERCISE_LIBRARY[self.exercise].compliant


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
    axes=[_axis("roll", stiffness=15.0, damping=1.0), _axis("pitch", stiffness=15.0, damping=1.0)],
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
    axes=[_axis("pitch", stiffness=5.0, damping=0.8), _axis("roll", stiffness=5.0, damping=0.8)],
    sets=1,
    repetitions=2,
    repetition_s=15.0,
    rest_s=0.0,
    instructions="Move your foot as far as you comfortably can: toes down, up, in and out.",
)
