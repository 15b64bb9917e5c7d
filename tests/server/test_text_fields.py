"""Control characters in what a clinician or an admin types (names, emails, references,
notes, a prescription's title and instructions, the audit log's text filters): a 422 naming
the field and the character, nothing stored, on both stores (PostgreSQL answered a NUL with
a 500). Notes and
instructions keep their line breaks and tabs."""

from __future__ import annotations

from typing import Any

import pytest

from tests.server.live_server import STRENGTH, Live, World, bearer

pytestmark = pytest.mark.both_stores


def refused(label: str, char: str, at: int) -> str:
    return (
        f"{label} must not contain control characters ({char} at character {at}): "
        "type it again without them."
    )


def cases(world: World) -> list[tuple[str, str, str, dict[str, Any], str, str]]:
    """(who, method, path, body, field, sentence) for each field a person types."""
    p1, rx = f"/patients/{world.p1}", f"/prescriptions/{world.rx1}"
    return [
        ("t1", "POST", "/patients", {"display_name": "Pat\x00One"}, "display_name",
         refused("Display name", "U+0000", 4)),
        ("t1", "POST", "/patients", {"display_name": "Pat", "reference": "R\x1b[2J"},
         "reference", refused("Reference", "U+001B", 2)),
        ("t1", "POST", "/patients", {"display_name": "Pat", "notes": "a\nb\x00"}, "notes",
         refused("Notes", "U+0000", 4)),
        ("t1", "PATCH", p1, {"display_name": "Pa\x85t"}, "display_name",
         refused("Display name", "U+0085", 3)),
        ("t1", "PATCH", p1, {"notes": "ok\x7f"}, "notes", refused("Notes", "U+007F", 3)),
        ("t1", "POST", f"{p1}/stations", {"name": "Home\x00"}, "name",
         refused("Name", "U+0000", 5)),
        ("t1", "POST", f"{p1}/prescriptions", {**STRENGTH, "title": "Toes\tup"}, "title",
         refused("Title", "U+0009", 5)),
        ("t1", "PATCH", rx, {**STRENGTH, "instructions": "Slowly.\n\x08"}, "instructions",
         refused("Instructions", "U+0008", 9)),
        ("admin", "POST", "/users",
         {"email": "x@clinic.test", "name": "N\x07", "role": "therapist"}, "name",
         refused("Name", "U+0007", 2)),
        ("admin", "POST", "/users",
         {"email": "x\x00@clinic.test", "name": "N", "role": "therapist"}, "email",
         refused("Email", "U+0000", 2)),
        ("anon", "POST", "/auth/login", {"email": "t1\x00@clinic.test", "password": "x"},
         "email", refused("Email", "U+0000", 3)),
    ]  # fmt: skip


async def everything(live: Live, world: World) -> list[Any]:
    """What any of the refused requests could have changed."""
    t1, admin = bearer(world.t1), bearer(world.admin)
    paths = [
        ("/patients", t1),
        (f"/patients/{world.p1}", t1),
        ("/stations", t1),
        (f"/patients/{world.p1}/prescriptions", t1),
        ("/users", admin),
        ("/audit", admin),
    ]
    out = []
    for path, headers in paths:
        r = await live.client.get(path, headers=headers)
        assert r.status_code == 200, (path, r.text)
        out.append(r.json())
    return out


@pytest.mark.asyncio
async def test_a_control_character_is_a_422_naming_the_field_and_changes_nothing(
    live: Live, world: World
) -> None:
    before = await everything(live, world)
    for who, method, path, body, field, sentence in cases(world):
        token = world.token(who)
        headers = bearer(token) if token else {}
        r = await live.client.request(method, path, json=body, headers=headers)
        assert r.status_code == 422, (path, field, r.status_code, r.text)
        (error,) = r.json()["detail"]
        assert (error["type"], error["loc"], error["msg"]) == (
            "control_character",
            ["body", field],
            sentence,
        ), error
    assert await everything(live, world) == before


@pytest.mark.asyncio
async def test_line_breaks_and_tabs_stay_where_text_has_several_lines(
    live: Live, world: World
) -> None:
    """The control case: the same routes take text of several lines where a field has
    them, any other character, and a pasted name's trailing line break (stripped, as ever)."""
    t1 = bearer(world.t1)
    notes = "Line one\r\nLine two\n\tindented: Zoë, Ångström, 足首 \U0001f9b6"
    r = await live.client.post(
        "/patients", json={"display_name": "Zoë Ångström\n", "notes": notes}, headers=t1
    )
    assert r.status_code == 201, r.text
    assert (r.json()["display_name"], r.json()["notes"]) == ("Zoë Ångström", notes)
    got = (await live.client.get(f"/patients/{r.json()['id']}", headers=t1)).json()
    assert got["notes"] == notes
    instructions = "Sit upright.\n\tPush the toes down slowly."
    r = await live.client.patch(
        f"/prescriptions/{world.rx1}", json={**STRENGTH, "instructions": instructions}, headers=t1
    )
    assert r.status_code == 200, r.text
    assert r.json()["body"]["instructions"] == instructions


@pytest.mark.asyncio
async def test_a_control_character_in_an_audit_filter_is_a_422(live: Live, world: World) -> None:
    """The audit log's text filters reach the database too (PostgreSQL: a 500 for a NUL)."""
    for name in ("action", "request_id"):
        r = await live.client.get(
            "/audit", params={name: "patient.update\x00"}, headers=bearer(world.admin)
        )
        assert r.status_code == 422, (name, r.text)
        (error,) = r.json()["detail"]
        label = name.replace("_", " ").capitalize()
        assert (error["loc"], error["msg"]) == (["query", name], refused(label, "U+0000", 15))
    r = await live.client.get(
        "/audit", params={"action": "patient.update"}, headers=bearer(world.admin)
    )
    assert r.status_code == 200, r.text


@pytest.mark.asyncio
async def test_text_too_long_is_counted_in_characters(live: Live, world: World) -> None:
    """A reference or an audit action filter past its length said "at most 64 allowed"
    (pydantic's words for a list, as the length is checked after the text is cleaned)."""
    t1 = bearer(world.t1)
    r = await live.client.patch(f"/patients/{world.p1}", json={"reference": "R" * 65}, headers=t1)
    assert r.status_code == 422, r.text
    (error,) = r.json()["detail"]
    assert error["msg"] == "Reference must be at most 64 characters long."
    r = await live.client.get("/audit", params={"action": "a" * 65}, headers=bearer(world.admin))
    assert r.status_code == 422, r.text
    (error,) = r.json()["detail"]
    assert error["msg"] == "Action must be at most 64 characters long."
