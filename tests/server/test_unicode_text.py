"""Unicode in the text people type: a name that could hide, read as another, or draw over
its neighbours (invisible format characters, text-direction controls, nothing visible, a
column of combining marks), and a text-direction control in any typed text, is a 422 naming
the field and the character, and nothing is stored. Both stores."""

from __future__ import annotations

from typing import Any

import pytest

from tests.server.live_server import PASSWORD, STRENGTH, Live, World, bearer
from tests.server.test_text_fields import everything

pytestmark = pytest.mark.both_stores


def invisible(label: str, char: str, at: int) -> str:
    return (
        f"{label} must not contain invisible characters ({char} at character {at}): "
        "type it again without them."
    )


def direction(label: str, char: str, at: int) -> str:
    return (
        f"{label} must not contain text-direction controls ({char} at character {at}): they "
        "make text show in another order than it is written. Type it again without them."
    )


def nothing_visible(label: str) -> str:
    return (
        f"{label} has nothing visible in it (only blanks, invisible characters or combining "
        "marks): type letters or digits."
    )


def account(email: str, name: str = "Therapist a") -> dict[str, Any]:
    return {"email": email, "name": name, "role": "therapist", "password": PASSWORD}


def name_cases(world: World) -> list[tuple[str, str, str, dict[str, Any], str, str, str]]:
    """(who, method, path, body, field, type, sentence) for each refused name or text."""
    p1, rx = f"/patients/{world.p1}", f"/prescriptions/{world.rx1}"
    return [
        ("t1", "POST", "/patients", {"display_name": "\u200b"}, "display_name",
         "invisible_character", invisible("Display name", "U+200B ZERO WIDTH SPACE", 1)),
        ("t1", "POST", "/patients", {"display_name": "\u202eevil\u202c Smith"}, "display_name",
         "direction_control", direction("Display name", "U+202E RIGHT-TO-LEFT OVERRIDE", 1)),
        ("t1", "POST", "/patients", {"display_name": "Pat e" + "\u0301" * 114 + "x"},
         "display_name", "stacked_marks",
         "Display name puts 114 combining marks on character 5, which draws over the lines "
         "around it: at most 4 are allowed on one character. Type it again without the "
         "extra marks."),
        ("t1", "PATCH", p1, {"display_name": "\u0301\u0301"}, "display_name",
         "nothing_visible", nothing_visible("Display name")),
        ("t1", "PATCH", p1, {"display_name": "Ann\u00ad"}, "display_name",
         "invisible_character", invisible("Display name", "U+00AD SOFT HYPHEN", 4)),
        ("t1", "POST", f"{p1}/stations", {"name": "\u3164"}, "name", "nothing_visible",
         nothing_visible("Name")),
        ("t1", "POST", f"{p1}/stations", {"name": "\u200d\u200c"}, "name", "nothing_visible",
         nothing_visible("Name")),
        ("admin", "POST", "/users", account("new@clinic.test", "Ann\u2066"), "name",
         "direction_control", direction("Name", "U+2066 LEFT-TO-RIGHT ISOLATE", 4)),
        ("admin", "POST", "/users", account("new@clinic.test", "A\u200eB"), "name",
         "invisible_character", invisible("Name", "U+200E LEFT-TO-RIGHT MARK", 2)),
        # Free text: only the direction controls.
        ("t1", "POST", "/patients", {"display_name": "Pat", "notes": "Take 10\u202e mg"},
         "notes", "direction_control", direction("Notes", "U+202E RIGHT-TO-LEFT OVERRIDE", 8)),
        ("t1", "POST", "/patients", {"display_name": "Pat", "reference": "R\u202a1"},
         "reference", "direction_control",
         direction("Reference", "U+202A LEFT-TO-RIGHT EMBEDDING", 2)),
        ("t1", "POST", f"{p1}/prescriptions", {**STRENGTH, "title": "\u2067Toes up"}, "title",
         "direction_control", direction("Title", "U+2067 RIGHT-TO-LEFT ISOLATE", 1)),
        ("t1", "PATCH", rx, {**STRENGTH, "instructions": "Slowly.\n\u202d5 then 10"},
         "instructions", "direction_control",
         direction("Instructions", "U+202D LEFT-TO-RIGHT OVERRIDE", 9)),
    ]  # fmt: skip


@pytest.mark.asyncio
async def test_a_name_that_hides_reverses_or_draws_over_its_rows_is_a_422(
    live: Live, world: World
) -> None:
    before = await everything(live, world)
    for who, method, path, body, field, kind, sentence in name_cases(world):
        token = world.token(who)
        assert token is not None
        r = await live.client.request(method, path, json=body, headers=bearer(token))
        assert r.status_code == 422, (path, field, r.status_code, r.text)
        (error,) = r.json()["detail"]
        assert (error["type"], error["loc"], error["msg"]) == (
            kind,
            ["body", field],
            sentence,
        ), error
    assert await everything(live, world) == before


@pytest.mark.asyncio
async def test_names_and_notes_of_real_scripts_are_kept_as_typed(live: Live, world: World) -> None:
    """The control case: the joiners Persian, Devanagari and emoji need, marks as decomposed
    Vietnamese and pointed Hebrew use them, and in notes what only notes may hold."""
    t1 = bearer(world.t1)
    notes = "Zero\u200bwidth, \u05e9\u05dc\u05d5\u05dd\u200f (5), e" + "\u0301" * 10
    for display_name in (
        "\u0645\u0647\u200c\u0633\u0627",  # Persian, with a zero-width non-joiner
        "\u0915\u094d\u200d\u0937",  # Devanagari, a half form by the zero-width joiner
        "Pat \U0001f469\u200d\U0001f9b0",  # an emoji sequence
        "Nguye\u0323\u0302n",  # decomposed Vietnamese: two marks on one letter
        "\u05e9\u05c1\u05bc\u05b8\u05a3",  # shin: dot, dagesh, vowel, accent (4 marks)
    ):
        r = await live.client.post(
            "/patients", json={"display_name": display_name, "notes": notes}, headers=t1
        )
        assert r.status_code == 201, (display_name, r.text)
        got = (await live.client.get(f"/patients/{r.json()['id']}", headers=t1)).json()
        assert (got["display_name"], got["notes"]) == (display_name, notes)
    r = await live.client.post(
        f"/patients/{world.p1}/stations", json={"name": "Home \u0915\u094d\u200d"}, headers=t1
    )
    assert (r.status_code, r.json().get("name")) == (201, "Home \u0915\u094d\u200d"), r.text
