"""Free text a person types: a name or a title on one line, notes or instructions on several,
and the e-mail address an account signs in with.

All typed text:

- holds no control character (NUL, escape, backspace, the C1 set) and no lone surrogate. No
  one can see one in a form or on a page, it cuts a report's line or a terminal's output,
  and PostgreSQL refuses a NUL in text outright: stored on SQLite, such a name breaks the
  day the clinic moves to PostgreSQL; sent to PostgreSQL, it was a 500. Text of several
  lines keeps its line breaks (``\\n``, ``\\r``) and tabs.
- holds no text-direction control (the embeddings, overrides and isolates, U+202A-U+202E
  and U+2066-U+2069): U+202E makes "evil" show as "live", so one name, dose or note can be
  made to read as another. The direction *marks* (LRM, RLM, ALM), which only help a
  neutral character find its side, stay in notes and instructions.

A name (a patient's, an account's, a station's) is also what a row of a list is read and
clicked by, so it

- holds no other invisible formatting character (Unicode category Cf: zero-width space, soft
  hyphen, word joiner, the direction marks, a byte-order mark) but the zero-width joiner and
  non-joiner, which Persian, Indic scripts and emoji sequences need to be spelt right;
- shows something: a letter, digit, punctuation or symbol that is drawn (not only blanks,
  combining marks, joiners or the Hangul fillers and the blank braille pattern, which are
  letters and symbols that draw nothing);
- puts at most :data:`MAX_MARKS` combining marks on one character: real text needs up to
  four (decomposed Vietnamese two, pointed Hebrew with an accent four), while a hundred
  draw a column over the rows above and below.

An e-mail address is an account's identity, so the same text must be the same account:
:func:`normal_address` is the one form addresses are stored and looked up in (NFKC, which
makes a composed and a decomposed "á" and a fullwidth "ｔ" the same text as what most
keyboards send, then lower case, as ever). A new address is refused if it holds any Cf
character (nothing invisible may make two addresses look alike) or if its local part, or
a label of its domain, mixes letters of two scripts (a Cyrillic "а" among Latin letters).
Chinese, Japanese and Korean characters count as one script there. A whole address in
another script (all Cyrillic) stays allowed, as do the internationalised addresses of
RFC 6531: refusing confusables across whole scripts needs Unicode's confusables table,
and accounts are made by an admin, who sees the address.

This module is the one check: the models a clinician writes into (``server.schemas``,
``sessions.prescription``) type their text fields with :data:`Line`, :data:`Lines` and
:func:`visible_name`; ``server.schemas.Email`` uses :func:`email_address`, sign-in
:func:`sign_in_address`, the admin command line :func:`normal_address`. Each refusal is a
422 whose type is one of the constants below and that ``sessions.sentences`` words with the
field's label.
"""

from __future__ import annotations

import re
import unicodedata
from typing import Annotated

from pydantic import AfterValidator
from pydantic_core import PydanticCustomError, PydanticKnownError

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f\ud800-\udfff]")
"""Unicode's control characters (category Cc) and lone surrogates (Cs)."""
_CONTROL_BUT_LINES = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\ud800-\udfff]")
"""The same but tab, line feed and carriage return."""
_DIRECTION = re.compile(r"[\u202a-\u202e\u2066-\u2069]")
"""Embeddings, overrides, their pop, and the isolates: what reorders whole runs of text."""
JOINERS = frozenset("\u200c\u200d")
"""Zero-width non-joiner and joiner: format characters that spell words (Persian, Indic
scripts) and emoji sequences."""
_DRAWS_NOTHING = frozenset("\u115f\u1160\u3164\uffa0\u2800")
"""Letters and symbols that draw nothing: the Hangul fillers and the blank braille pattern."""
MAX_MARKS = 4
"""The most combining marks (Mn, Me) a name may put on one character."""

EMAIL_MAX_LENGTH = 254
EMAIL_PATTERN = r"^[^@\s]+@[^@\s]+$"
_EMAIL_SHAPE = re.compile(EMAIL_PATTERN)
_EAST_ASIAN = frozenset(
    {"CJK", "IDEOGRAPHIC", "HIRAGANA", "KATAKANA", "HENTAIGANA", "HANGUL", "BOPOMOFO"}
)
"""First words of the names of Chinese, Japanese and Korean letters: one script here."""

CONTROL_CHARACTER = "control_character"
DIRECTION_CONTROL = "direction_control"
INVISIBLE_CHARACTER = "invisible_character"
NOTHING_VISIBLE = "nothing_visible"
STACKED_MARKS = "stacked_marks"
MIXED_SCRIPTS = "mixed_scripts"
"""The error types of the refusals."""


def _char(ch: str) -> str:
    """``U+202E RIGHT-TO-LEFT OVERRIDE``: what a person can look up."""
    return f"U+{ord(ch):04X} {unicodedata.name(ch, '')}".rstrip()


def _refuse(kind: str, message: str, ch: str, at: int) -> PydanticCustomError:
    return PydanticCustomError(kind, message, {"char": _char(ch), "at": at + 1})


def _refuse_control(text: str, pattern: re.Pattern[str]) -> str:
    found = pattern.search(text)
    if found is not None:
        raise PydanticCustomError(
            CONTROL_CHARACTER,
            "must not contain control characters ({char} at character {at})",
            {"char": f"U+{ord(found.group()):04X}", "at": found.start() + 1},
        )
    found = _DIRECTION.search(text)
    if found is not None:
        raise _refuse(
            DIRECTION_CONTROL,
            "must not contain text-direction controls ({char} at character {at})",
            found.group(),
            found.start(),
        )
    return text


def _refuse_invisible(text: str, allowed: frozenset[str] = frozenset()) -> None:
    for at, ch in enumerate(text):
        if unicodedata.category(ch) == "Cf" and ch not in allowed:
            raise _refuse(
                INVISIBLE_CHARACTER,
                "must not contain invisible characters ({char} at character {at})",
                ch,
                at,
            )


def one_line(text: str) -> str:
    """``text`` if it holds no control character (no line break or tab either) and no
    text-direction control."""
    return _refuse_control(text, _CONTROL)


def lines(text: str) -> str:
    """``text`` if it holds no control character but line breaks and tabs, and no
    text-direction control."""
    return _refuse_control(text, _CONTROL_BUT_LINES)


def has_visible(text: str) -> bool:
    """Whether ``text`` draws something: a letter, digit, punctuation or symbol that is not
    one of those that draw nothing (spaces, format and control characters, lone marks)."""
    return any(unicodedata.category(ch)[0] in "LNPS" and ch not in _DRAWS_NOTHING for ch in text)


def visible_name(text: str) -> str:
    """``text`` if it is a name a list can show: one line, nothing invisible but the
    joiners, something visible, at most :data:`MAX_MARKS` marks on one character."""
    one_line(text)
    _refuse_invisible(text, JOINERS)
    if not has_visible(text):
        raise PydanticCustomError(NOTHING_VISIBLE, "has nothing visible in it")
    run = 0
    for at, ch in enumerate(text):
        run = run + 1 if unicodedata.category(ch) in ("Mn", "Me") else 0
        if run > MAX_MARKS:
            base = at - run
            while at + 1 < len(text) and unicodedata.category(text[at + 1]) in ("Mn", "Me"):
                at, run = at + 1, run + 1
            raise PydanticCustomError(
                STACKED_MARKS,
                "puts {count} combining marks on character {at}, at most {most} are allowed",
                {"count": run, "at": base + 1, "most": MAX_MARKS},
            )
    return text


def normal_address(text: str) -> str:
    """The one form of an e-mail address, stored and looked up: NFKC, no surrounding blanks,
    lower case (NFKC once more: lower-casing may leave a pair that composes)."""
    return unicodedata.normalize("NFKC", unicodedata.normalize("NFKC", text).strip().lower())


def sign_in_address(text: str) -> str:
    """An address someone signs in with, in the form it is stored in; refused only for a
    control character (PostgreSQL would refuse a NUL): every stored address, made before
    the rules of :func:`email_address` or not, must still find its account."""
    _refuse_control(text, _CONTROL)
    return normal_address(text)


def _script(ch: str) -> str | None:
    """The script of a letter, by the first word of its Unicode name (Python's tables have
    no script property), or None for what is no letter of a script (digits, signs, marks,
    modifier letters)."""
    if unicodedata.category(ch) not in ("Lu", "Ll", "Lt", "Lo"):
        return None
    first = unicodedata.name(ch, "").split(" ")[0].split("-")[0]
    return "CJK" if first in _EAST_ASIAN else first


def _refuse_mixed_scripts(address: str) -> None:
    local, _, domain = address.rpartition("@")
    start = 0
    for part in (local, *domain.split(".")):
        first: str | None = None
        for i, ch in enumerate(part):
            script = _script(ch)
            if script is None:
                continue
            if first is None:
                first = script
            elif script != first:
                raise PydanticCustomError(
                    MIXED_SCRIPTS,
                    "mixes scripts in “{part}”: {char} at character {at} among {script} letters",
                    {
                        "part": part,
                        "char": _char(ch),
                        "at": start + i + 1,
                        "script": first.capitalize(),
                    },
                )
        start += len(part) + 1


def email_address(text: str) -> str:
    """A new account's address in its :func:`normal_address` form, if it is one: nothing
    invisible, at most 254 characters and one "@" once normal, one script a part."""
    _refuse_control(text, _CONTROL)
    _refuse_invisible(text)
    address = normal_address(text)
    if len(address) > EMAIL_MAX_LENGTH:
        raise PydanticKnownError("string_too_long", {"max_length": EMAIL_MAX_LENGTH})
    if not _EMAIL_SHAPE.fullmatch(address):
        raise PydanticKnownError("string_pattern_mismatch", {"pattern": EMAIL_PATTERN})
    _refuse_mixed_scripts(address)
    return address


Line = Annotated[str, AfterValidator(one_line)]
"""Text on one line: a title, an identifier someone types."""
Lines = Annotated[str, AfterValidator(lines)]
"""Text of several lines: notes, instructions."""
