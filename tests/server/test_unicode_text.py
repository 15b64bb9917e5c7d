"""Unicode in what people type. One e-mail address is one account whatever form of it a
keyboard sends (NFKC, lower case): creating it again is a 409, signing in works with any
form, on the API and on the command line. An address or a name that could pass for
another, hide, or draw over its neighbours (invisible format characters, text-direction
controls, mixed scripts in an address, nothing visible, a column of combining marks) is a
422 naming the field and the character, and nothing is stored. Stored addresses are made
normal by migration 0005 and still sign in. Both stores."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pytest
from alembic import command
from sqlalchemy import Connection, text

from server.accounts import EMAIL_TAKEN
from server.cli import AdminError, create_user_async, ensure_user_async, reset_password_async
from server.config import Settings
from server.db import alembic_config, create_engine, head_revision, migrate, migration_sql
from tests.server.live_server import (
    PASSWORD,
    STRENGTH,
    Live,
    Seeds,
    World,
    bearer,
    on_store,
    running,
)
from tests.server.test_text_fields import everything

pytestmark = pytest.mark.both_stores

COMPOSED = "t\u00e1@clinic.test"
DECOMPOSED = "ta\u0301@clinic.test"
FULLWIDTH = "\uff54\u00e1\uff20\uff43\uff4c\uff49\uff4e\uff49\uff43\uff0e\uff54\uff45\uff53\uff54"
"""ｔá＠ｃｌｉｎｉｃ．ｔｅｓｔ: what a keyboard left in full-width mode sends."""


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


def mixed(part: str, char: str, at: int) -> str:
    return (
        f"Email mixes scripts in “{part}” ({char} at character {at} among Latin letters), so "
        "it could pass for another address: type it in one script."
    )


async def sign_in(live: Live, email: str) -> int:
    """The id of the account ``email`` signs in to."""
    r = await live.client.post("/auth/login", json={"email": email, "password": PASSWORD})
    assert r.status_code == 200, (email, r.text)
    user_id: int = r.json()["user"]["id"]
    return user_id


def account(email: str, name: str = "Therapist a") -> dict[str, Any]:
    return {"email": email, "name": name, "role": "therapist", "password": PASSWORD}


@pytest.mark.asyncio
async def test_one_address_is_one_account_whatever_form_the_keyboard_sends(
    live: Live, world: World
) -> None:
    admin = bearer(world.admin)
    r = await live.client.post("/users", json=account(DECOMPOSED), headers=admin)
    assert r.status_code == 201, r.text
    created = r.json()["id"]
    assert r.json()["email"] == COMPOSED  # stored in its one form
    for same in (COMPOSED, "T\u00c1@CLINIC.TEST", FULLWIDTH, f" {DECOMPOSED} "):
        r = await live.client.post("/users", json=account(same), headers=admin)
        assert (r.status_code, r.json()["detail"]) == (409, EMAIL_TAKEN), (same, r.text)
    for form in (COMPOSED, DECOMPOSED, "TA\u0301@Clinic.Test", FULLWIDTH):
        assert await sign_in(live, form) == created, form
    # An account made before (seeded as t1@clinic.test) is found by any form too.
    assert await sign_in(live, "\uff54\uff11@clinic.test") == world.t1_id
    users = (await live.client.get("/users", headers=admin)).json()
    assert [u["id"] for u in users if u["name"] == "Therapist a"] == [created]

    # The command line: the same account, whichever form the operator types.
    with pytest.raises(AdminError, match=EMAIL_TAKEN):
        await create_user_async(live.settings, FULLWIDTH, "Other", "therapist", None)
    assert not await ensure_user_async(live.settings, DECOMPOSED, "Other", "admin", PASSWORD)
    user, _ = await reset_password_async(live.settings, DECOMPOSED)
    assert user.id == created


@pytest.mark.asyncio
async def test_an_address_that_could_pass_for_another_is_a_422(live: Live, world: World) -> None:
    admin = bearer(world.admin)
    before = await everything(live, world)
    cases = [
        ("t1@clinic.test\u200b", "invisible_character",
         invisible("Email", "U+200B ZERO WIDTH SPACE", 15)),
        ("t1@clinic.test\u00ad", "invisible_character",
         invisible("Email", "U+00AD SOFT HYPHEN", 15)),
        ("t\u20601@clinic.test", "invisible_character",
         invisible("Email", "U+2060 WORD JOINER", 2)),
        ("t1@clinic\u202e.test", "direction_control",
         direction("Email", "U+202E RIGHT-TO-LEFT OVERRIDE", 10)),
        ("t\u0430@clinic.test", "mixed_scripts",
         mixed("t\u0430", "U+0430 CYRILLIC SMALL LETTER A", 2)),
        ("t1@cl\u0456nic.test", "mixed_scripts",
         mixed("cl\u0456nic", "U+0456 CYRILLIC SMALL LETTER BYELORUSSIAN-UKRAINIAN I", 6)),
    ]  # fmt: skip
    for email, kind, sentence in cases:
        r = await live.client.post("/users", json=account(email), headers=admin)
        assert r.status_code == 422, (email, r.text)
        (error,) = r.json()["detail"]
        assert (error["type"], error["loc"], error["msg"]) == (
            kind,
            ["body", "email"],
            sentence,
        ), error
    assert await everything(live, world) == before
    # One script a part is not refused: all Cyrillic, or Japanese kanji with kana.
    for email in ("\u0438\u0432\u0430\u043d@clinic.test", "山田たろう@clinic.test"):
        r = await live.client.post("/users", json=account(email, "Other"), headers=admin)
        assert (r.status_code, r.json().get("email")) == (201, email), r.text
        assert await sign_in(live, email) == r.json()["id"]


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


def _downgrade(connection: Connection, revision: str) -> None:
    config = alembic_config()
    config.attributes["connection"] = connection
    command.downgrade(config, revision)


async def _legacy_accounts(settings: Settings) -> dict[str, int]:
    """Accounts as the code before migration 0005 stored them (lower-cased only), in a
    database set back to revision 0004: name -> id."""
    engine = create_engine(settings)
    try:
        await migrate(engine)
        ids = {}
        for who in ("decomposed", "fullwidth", "plain", "lookalike"):
            await ensure_user_async(settings, f"{who}@clinic.test", who, "therapist", PASSWORD)
        stored = {
            "decomposed": DECOMPOSED,
            "fullwidth": "\uff54\uff42@clinic.test",  # ｔｂ
            "plain": "plain@clinic.test",
            "lookalike": "\uff50\uff4c\uff41\uff49\uff4e@clinic.test",  # ｐｌａｉｎ
        }
        async with engine.begin() as connection:
            for who, email in stored.items():
                await connection.execute(
                    text("UPDATE users SET email = :email WHERE name = :who"),
                    {"email": email, "who": who},
                )
                ids[who] = (
                    await connection.execute(
                        text("SELECT id FROM users WHERE name = :who"), {"who": who}
                    )
                ).scalar_one()
            # Back to revision 0004 the way alembic goes back (the tables of later
            # revisions dropped), the accounts kept as the old code stored them.
            await connection.run_sync(_downgrade, "0004_patient_weight")
        return ids
    finally:
        await engine.dispose()


@pytest.mark.asyncio
async def test_stored_addresses_are_made_normal_and_still_sign_in(
    fresh: Settings, caplog: pytest.LogCaptureFixture
) -> None:
    ids = await _legacy_accounts(fresh)
    engine = create_engine(fresh)
    try:
        with caplog.at_level(logging.WARNING, logger="ankle.server.migrations"):
            await migrate(engine)
        async with engine.connect() as connection:
            rows = await connection.execute(text("SELECT name, email FROM users"))
            stored: dict[str, str] = dict(rows.all())
    finally:
        await engine.dispose()
    assert {who: stored[who] for who in ids} == {
        "decomposed": COMPOSED,
        "fullwidth": "tb@clinic.test",
        "plain": "plain@clinic.test",
        # Its normal form is the other account's: left as it was, and said.
        "lookalike": "\uff50\uff4c\uff41\uff49\uff4e@clinic.test",
    }
    (warning,) = [r.getMessage() for r in caplog.records if r.name == "ankle.server.migrations"]
    assert f"account {ids['lookalike']}'s address" in warning
    assert f"signing in with either reaches account {ids['plain']}" in warning
    async with running(fresh) as live:
        for form in (DECOMPOSED, COMPOSED):
            assert await sign_in(live, form) == ids["decomposed"]
        for form in ("\uff54\uff42@clinic.test", "tb@clinic.test"):
            assert await sign_in(live, form) == ids["fullwidth"]
        assert await sign_in(live, "\uff50\uff4c\uff41\uff49\uff4e@clinic.test") == ids["plain"]


@pytest.mark.asyncio
async def test_the_printed_sql_stops_where_only_python_can_rewrite_an_address(
    seeds: Seeds, tmp_path: Path
) -> None:
    """``ankle db sql`` cannot print the rewrite: on PostgreSQL its script refuses to run
    while a stored address needs it, and runs once none does."""
    with on_store(seeds, "postgres", tmp_path) as settings:
        await _legacy_accounts(settings)
        database = settings.database_url.rsplit("/", 1)[1]
        script = migration_sql(settings.database_url, "0004_patient_weight")
        with pytest.raises(RuntimeError, match="rewritten by `ankle db upgrade`"):
            seeds.cluster.psql(script, database)
        version = "SELECT version_num FROM alembic_version"
        assert seeds.cluster.psql(version, database).strip() == "0004_patient_weight"
        seeds.cluster.psql("DELETE FROM users WHERE email IS NOT NFKC NORMALIZED", database)
        seeds.cluster.psql(script, database)
        assert seeds.cluster.psql(version, database).strip() == head_revision()
