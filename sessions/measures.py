"""What one session measured, as a list a record can carry: the one source of the report's
and the FHIR export's numbers.

A stored session summary (:class:`sessions.summary.Summary`) holds per-axis extremes of
the angle, torques and work; a clinician's record wants *measures*: a code, a value, a UCUM
unit and, for an angle, the movement direction of this patient's foot. :func:`measures`
turns the one into the other, naming directions only through :mod:`sessions.anatomy`.

The codes form the project's own code system (``{site}/CodeSystem/session-measures``, see
:func:`system_url`), listed whole in
:data:`CODES` (generated from the axes and the direction table, so a new direction or axis
appears here by itself) and documented in ``docs/measures.md`` (a test keeps that file
equal to :func:`code_table_markdown`). A new measure (say, per-exercise metrics) is a new
entry in :data:`CODES` and a line in :func:`measures`.

Peak angles are signed in their direction: a peak plantarflexion of -3 deg means the foot
never reached neutral on that side (it stayed 3 deg dorsiflexed), as a goniometer reads.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final

from device.axes import ROTATION_AXES, RotationAxis
from sessions.anatomy import LABELS, Direction, direction_name, directions
from sessions.summary import Summary

CODE_SYSTEM_ID: Final = "session-measures"


def system_url(site: str) -> str:
    """The canonical URL of the session-measure code system under ``site``, the base of the
    running server's FHIR names (its setting ``fhir_base``: a URL under a domain the
    clinic holds; the server serves the code system there). The code system is the
    project's; its canonical URL is the site's, because no domain is the project's own
    and a canonical URL must be under one its publisher holds."""
    return f"{site.rstrip('/')}/CodeSystem/{CODE_SYSTEM_ID}"


UCUM: Final = "http://unitsofmeasure.org"

_SIDES: Final = ("right", "left", None)
"""Every side the direction table distinguishes (``both`` reads as unknown)."""


@dataclass(frozen=True)
class Code:
    """One code of the session-measure code system."""

    code: str
    display: str
    unit: str
    """UCUM code: ``deg``, ``N.m``, ``J``, ``s`` or ``{repetitions}``."""
    definition: str


@dataclass(frozen=True)
class Measure:
    """One measured value of one session."""

    code: Code
    value: float
    axis: RotationAxis | None
    direction: Direction | None
    """The direction of the patient's foot (angles only)."""

    @property
    def label(self) -> str:
        """The words a page or report shows: the direction's label, or the code's display."""
        return LABELS[self.direction] if self.direction is not None else self.code.display


def _slug(name: str) -> str:
    return name.replace("_", "-")


def _peak_code(direction: Direction) -> Code:
    words = LABELS[direction]
    return Code(
        code=f"peak-angle-{_slug(direction)}",
        display=f"Peak angle: {words[0].lower()}{words[1:]}",
        unit="deg",
        definition="The furthest the ankle moved in this direction during exercise, degrees "
        "from the platform's home pose; negative when it never passed neutral.",
    )


def _axis_codes(axis: RotationAxis) -> list[Code]:
    return [
        Code(
            f"range-of-motion-{axis}",
            f"Range of motion about the {axis} axis",
            "deg",
            f"Highest minus lowest {axis} angle during exercise, degrees.",
        ),
        Code(
            f"peak-torque-{axis}",
            f"Peak torque about the {axis} axis",
            "N.m",
            f"Largest absolute torque of the patient about the {axis} axis, N·m.",
        ),
        Code(
            f"mean-torque-{axis}",
            f"Mean torque about the {axis} axis",
            "N.m",
            f"Time-averaged absolute torque of the patient about the {axis} axis, N·m.",
        ),
        Code(
            f"work-{axis}",
            f"Work about the {axis} axis",
            "J",
            f"Positive (concentric) work the patient did on the platform about the {axis} axis, J.",
        ),
    ]


def _all_codes() -> dict[str, Code]:
    found: list[Code] = []
    for axis in ROTATION_AXES:
        for side in _SIDES:
            found += [_peak_code(d) for d in directions(axis, side)]
        found += _axis_codes(axis)
    found += [
        Code(
            "exercise-time",
            "Exercise time",
            "s",
            "Time the exercise ran (device active), s; rests, holds and faults excluded.",
        ),
        Code(
            "repetitions-completed",
            "Repetitions completed",
            "{repetitions}",
            "Repetitions finished, all sets.",
        ),
    ]
    return {c.code: c for c in found}


CODES: Final[dict[str, Code]] = _all_codes()
"""Every code of the session-measure code system, in a stable order."""


def measures(summary: Summary | Mapping[str, Any], side: str | None) -> list[Measure]:
    """The measures of one session: its stored ``summary`` (a :class:`Summary` or its JSON),
    for a patient whose affected side is ``side``. A value the summary lacks gives no
    measure."""
    s = summary if isinstance(summary, Summary) else Summary.model_validate(summary)
    out: list[Measure] = []
    for axis in ROTATION_AXES:
        a = s.axes.get(axis)
        if a is None:
            continue
        for sign, extreme in ((1, a.rom_max_deg), (-1, a.rom_min_deg)):
            if extreme is not None:
                d = direction_name(axis, sign, side)
                out.append(Measure(_peak_code(d), sign * extreme, axis, d))
        for code, value in zip(
            _axis_codes(axis),
            (a.rom_deg, a.peak_torque_nm, a.mean_torque_nm, a.work_j),
            strict=True,
        ):
            if value is not None:
                out.append(Measure(code, value, axis, None))
    out.append(Measure(CODES["exercise-time"], s.duration_s, None, None))
    out.append(Measure(CODES["repetitions-completed"], float(s.repetitions_completed), None, None))
    return out


def code_table_markdown() -> str:
    """The code system as the Markdown table of ``docs/measures.md``."""
    rows = [
        "| code | display | UCUM unit | definition |",
        "|---|---|---|---|",
        *(f"| `{c.code}` | {c.display} | `{c.unit}` | {c.definition} |" for c in CODES.values()),
    ]
    return "\n".join(rows) + "\n"
