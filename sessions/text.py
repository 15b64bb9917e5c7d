"""Free text a person types: a name or a title on one line, notes or instructions on several.

Neither may hold a control character (NUL, escape, backspace, the C1 set) or a lone
surrogate. No one can see one in a form or on a page, it cuts a report's line or a terminal's
output, and PostgreSQL refuses a NUL in text outright: stored on SQLite, such a name breaks
the day the clinic moves to PostgreSQL; sent to PostgreSQL, it was a 500. Text of several
lines keeps its line breaks (``\\n``, ``\\r``) and tabs.

This module is the one check: the models a clinician writes into (``server.schemas``,
``sessions.prescription``) type their text fields with :data:`Line` and :data:`Lines`, and
the refusal is a 422 of type ``control_character`` that ``sessions.sentences`` words with
the field's label.
"""

from __future__ import annotations

import re
from typing import Annotated

from pydantic import AfterValidator
from pydantic_core import PydanticCustomError

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f\ud800-\udfff]")
"""Unicode's control characters (category Cc) and lone surrogates (Cs)."""
_CONTROL_BUT_LINES = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\ud800-\udfff]")
"""The same but tab, line feed and carriage return."""

CONTROL_CHARACTER = "control_character"
"""The error type of a refusal."""


def _refuse_control(text: str, pattern: re.Pattern[str]) -> str:
    found = pattern.search(text)
    if found is None:
        return text
    raise PydanticCustomError(
        CONTROL_CHARACTER,
        "must not contain control characters ({char} at character {at})",
        {"char": f"U+{ord(found.group()):04X}", "at": found.start() + 1},
    )


def one_line(text: str) -> str:
    """``text`` if it holds no control character (no line break or tab either)."""
    return _refuse_control(text, _CONTROL)


def lines(text: str) -> str:
    """``text`` if it holds no control character but line breaks and tabs."""
    return _refuse_control(text, _CONTROL_BUT_LINES)


Line = Annotated[str, AfterValidator(one_line)]
"""Text on one line: a name, a title, an identifier someone types."""
Lines = Annotated[str, AfterValidator(lines)]
"""Text of several lines: notes, instructions."""
