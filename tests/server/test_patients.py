"""Patients: what a therapist may write and how a partial update behaves."""

from __future__ import annotations

import asyncio
from datetime import UTC, datetime
from typing import Any

import pytest

from tests.server.live_server import Live, World, bearer

pytestmark = pytest.mark.both_stores


@pytest.mark.asyncio
async def test_create_then_patch_only_the_given_fields(live: Live, world: World) -> None:
    t1 = bearer(world.t1)
    r = await live.client.post(
        "/patients",
        json={
            "display_name": "  J. D.  ",
            "reference": "CL-7",
            "birth_year": 1950,
            "affected_side": "both",
            "weight_kg": 72.5,
            "notes": "post-fracture",
        },
        headers=t1,
    )
    assert r.status_code == 201
    created = r.json()
    assert created["weight_kg"] == 72.5
    assert (created["display_name"], created["therapist_id"]) == ("J. D.", world.t1_id)
    r = await live.client.patch(
        f"/patients/{created['id']}",
        json={"reference": None, "notes": "walking", "weight_kg": 70},
        headers=t1,
    )
    updated = r.json()
    assert updated == {
        **created,
        "reference": None,
        "notes": "walking",
        "weight_kg": 70.0,
        "updated_at": updated["updated_at"],
    }
    assert updated["updated_at"] > created["updated_at"]
    again = await live.client.get(f"/patients/{created['id']}", headers=t1)
    assert again.json() == updated


INVALID: list[tuple[dict[str, Any], list[str], str]] = [
    ({"display_name": None}, ["body", "display_name"], "Display name cannot be empty."),
    ({"display_name": ""}, ["body", "display_name"], "Display name is required."),
    (
        {"birth_year": datetime.now(UTC).year + 1},
        ["body", "birth_year"],
        f"Birth year {datetime.now(UTC).year + 1} is in the future.",
    ),
    ({"birth_year": 1800}, ["body", "birth_year"], "Birth year must be at least 1900."),
    (
        {"affected_side": "middle"},
        ["body", "affected_side"],
        "Affected side must be one of left, right or both.",
    ),
    ({"therapist_id": 2}, ["body", "therapist_id"], "“therapist_id” is not a field here."),
    ({"weight_kg": 5}, ["body", "weight_kg"], "Body weight must be at least 10 kg."),
    ({"weight_kg": 1000}, ["body", "weight_kg"], "Body weight must be at most 400 kg."),
    ({"weight_kg": "heavy"}, ["body", "weight_kg"], "Body weight must be a number."),
]


@pytest.mark.asyncio
async def test_invalid_updates_are_refused(live: Live, world: World) -> None:
    t1 = bearer(world.t1)
    before = (await live.client.get(f"/patients/{world.p1}", headers=t1)).json()
    for body, loc, msg in INVALID:
        r = await live.client.patch(f"/patients/{world.p1}", json=body, headers=t1)
        assert r.status_code == 422, body
        assert (r.json()["detail"][0]["loc"], r.json()["detail"][0]["msg"]) == (loc, msg), body
    assert (await live.client.get(f"/patients/{world.p1}", headers=t1)).json() == before


@pytest.mark.asyncio
async def test_two_edits_at_once_are_applied_in_turn_and_audited_as_stored(
    live: Live, world: World
) -> None:
    """Two changes of one patient at the same moment: each is applied in turn, and each
    audit row's old value is what the other had stored (the log replays to the record)."""
    t1 = bearer(world.t1)
    path = f"/patients/{world.p1}"
    for round_ in range(4):
        wanted = {f"first {round_}", f"second {round_}"}
        answers = await asyncio.gather(
            *(live.client.patch(path, json={"notes": n}, headers=t1) for n in sorted(wanted))
        )
        assert [a.status_code for a in answers] == [200, 200], [a.text for a in answers]
        assert {a.json()["notes"] for a in answers} == wanted
    stored = (await live.client.get(path, headers=t1)).json()
    r = await live.client.get(
        "/audit", params={"patient_id": world.p1, "action": "patient.update"}, headers=t1
    )
    rows = list(reversed(r.json()))
    assert len(rows) == 8
    notes = ""
    for row in rows:
        assert row["old"] == {"notes": notes}, rows
        notes = row["new"]["notes"]
    assert notes == stored["notes"]
