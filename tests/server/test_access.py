"""Who may call what: every endpoint against every kind of caller, and tenant isolation.

t1 owns patient p1 (stations s1 and a spare, prescription rx1); t2 owns p2. ``station`` is
s1's token. A therapist reaching for another therapist's records gets the very same 404 as
for a record that does not exist.
"""

from __future__ import annotations

from typing import Any

import pytest

from tests.server.live_server import STRENGTH, Live, World, bearer

# Mutating calls by the owner run last so that the others see the record unchanged.
ROLES = ("anon", "station", "t2", "admin", "t1")


def matrix(w: World) -> list[tuple[str, str, dict[str, Any] | None, dict[str, int]]]:
    """(method, path, JSON body, expected status per role)."""
    user_any = {"anon": 401, "station": 401, "t2": 200, "admin": 200, "t1": 200}
    owner_or_admin_reads = {"anon": 401, "station": 401, "t2": 404, "admin": 200, "t1": 200}
    owner_writes = {"anon": 401, "station": 401, "t2": 404, "admin": 403, "t1": 200}
    station_only = {"anon": 401, "station": 200, "t2": 401, "admin": 401, "t1": 401}
    new_user = {
        "email": "n@clinic.test",
        "name": "N",
        "role": "therapist",
        "password": "0123456789",
    }
    admin_only = {**user_any, "t1": 403, "t2": 403}
    # A wrong current password: every signed-in user may ask, nobody's password changes.
    wrong_current = {"current_password": "not the password", "new_password": "0123456789"}
    no_user = 999_999  # admins get as far as the lookup, and nothing changes
    return [
        ("GET", "/health", None, dict.fromkeys(ROLES, 200)),
        ("GET", "/auth/me", None, user_any),
        ("POST", "/auth/password", wrong_current, {**user_any, "t1": 400, "t2": 400, "admin": 400}),
        ("GET", "/users", None, admin_only),
        ("POST", "/users", new_user, {**admin_only, "admin": 201}),
        ("POST", f"/users/{no_user}/reset-password", None, {**admin_only, "admin": 404}),
        ("POST", f"/users/{no_user}/deactivate", None, {**admin_only, "admin": 404}),
        ("POST", f"/users/{no_user}/reactivate", None, {**admin_only, "admin": 404}),
        ("GET", "/patients", None, user_any),
        ("GET", "/patients?archived=true", None, user_any),
        (
            "POST",
            "/patients",
            {"display_name": "X"},
            {**user_any, "admin": 403, "t1": 201, "t2": 201},
        ),
        ("GET", f"/patients/{w.p1}", None, owner_or_admin_reads),
        ("PATCH", f"/patients/{w.p1}", {"notes": "better"}, owner_writes),
        ("GET", "/exercises", None, user_any),
        ("GET", f"/patients/{w.p1}/prescriptions", None, owner_or_admin_reads),
        ("POST", f"/patients/{w.p1}/prescriptions", STRENGTH, {**owner_writes, "t1": 201}),
        ("GET", f"/prescriptions/{w.rx1}", None, owner_or_admin_reads),
        ("PATCH", f"/prescriptions/{w.rx1}", {**STRENGTH, "sets": 2}, owner_writes),
        ("POST", f"/prescriptions/{w.rx1}/cancel", None, owner_writes),
        (
            "POST",
            f"/patients/{w.p1}/stations",
            {"name": "New"},
            {**owner_or_admin_reads, "admin": 201, "t1": 201},
        ),
        ("GET", "/stations", None, user_any),
        ("POST", f"/stations/{w.s1_spare_id}/revoke", None, owner_or_admin_reads),
        ("GET", "/station/me", None, station_only),
        ("GET", "/station/prescriptions", None, station_only),
        ("GET", "/audit", None, user_any),
        # Last: archiving p1 revokes s1 and makes the record read-only for the rows above.
        ("POST", f"/patients/{w.p1}/archive", None, owner_writes),
        ("POST", f"/patients/{w.p1}/unarchive", None, owner_writes),
    ]


@pytest.mark.asyncio
async def test_every_endpoint_for_every_role(live: Live, world: World) -> None:
    wrong = []
    for method, path, body, expected in matrix(world):
        for role in ROLES:
            token = world.token(role)
            headers = bearer(token) if token else {}
            r = await live.client.request(method, path, json=body, headers=headers)
            if r.status_code != expected[role]:
                wrong.append(f"{method} {path} as {role}: {r.status_code}, not {expected[role]}")
            if r.status_code == 401:
                assert r.headers["www-authenticate"] == "Bearer"
    assert not wrong, "\n".join(wrong)


ELSEWHERE: list[tuple[str, str, dict[str, Any] | None]] = [
    ("GET", "/patients/{p}", None),
    ("PATCH", "/patients/{p}", {"notes": "x"}),
    ("GET", "/patients/{p}/prescriptions", None),
    ("POST", "/patients/{p}/prescriptions", STRENGTH),
    ("POST", "/patients/{p}/stations", {"name": "x"}),
    ("GET", "/prescriptions/{rx}", None),
    ("PATCH", "/prescriptions/{rx}", STRENGTH),
    ("POST", "/prescriptions/{rx}/cancel", None),
    ("POST", "/stations/{s}/revoke", None),
    ("POST", "/patients/{p}/archive", None),
    ("POST", "/patients/{p}/unarchive", None),
]


@pytest.mark.asyncio
async def test_someone_elses_record_is_indistinguishable_from_none(
    live: Live, world: World
) -> None:
    """t1 asking for t2's patient, prescription or station, and for ids that do not exist."""
    for method, template, body in ELSEWHERE:
        others = template.format(p=world.p2, rx=world.rx2, s=world.s2_id)
        missing = template.format(p=999_999, rx=999_999, s=999_999)
        a = await live.client.request(method, others, json=body, headers=bearer(world.t1))
        b = await live.client.request(method, missing, json=body, headers=bearer(world.t1))
        assert a.status_code == b.status_code == 404, (method, template)
        assert a.json() == b.json()
        assert a.headers["content-length"] == b.headers["content-length"]


@pytest.mark.asyncio
async def test_lists_show_only_the_callers_patients(live: Live, world: World) -> None:
    async def ids(path: str, who: str) -> set[int]:
        r = await live.client.get(path, headers=bearer(world.token(who) or ""))
        assert r.status_code == 200
        return {row["id"] for row in r.json()}

    assert await ids("/patients", "t1") == {world.p1}
    assert await ids("/patients", "t2") == {world.p2}
    assert await ids("/patients", "admin") == {world.p1, world.p2}
    assert await ids("/stations", "t1") == {world.s1_id, world.s1_spare_id}
    assert await ids("/stations", "t2") == {world.s2_id}
    assert await ids("/stations", "admin") == {world.s1_id, world.s1_spare_id, world.s2_id}
    # Filtering by someone else's patient yields nothing rather than their stations.
    assert await ids(f"/stations?patient_id={world.p2}", "t1") == set()


@pytest.mark.asyncio
async def test_a_station_sees_only_its_own_patient(live: Live, world: World) -> None:
    me = (await live.client.get("/station/me", headers=bearer(world.s1))).json()
    assert me == {
        "id": world.s1_id,
        "name": "Home of Pat One",
        "patient_id": world.p1,
        "patient_display_name": "Pat One",
    }
    rx = (await live.client.get("/station/prescriptions", headers=bearer(world.s2))).json()
    assert [p["id"] for p in rx] == [world.rx2]
    assert rx[0]["body"]["exercise"] == "strength"


@pytest.mark.asyncio
async def test_station_last_seen_and_online(live: Live, world: World) -> None:
    before = (await live.client.get("/stations", headers=bearer(world.t1))).json()
    assert all(s["last_seen_at"] is None and s["online"] is False for s in before)
    await live.client.get("/station/me", headers=bearer(world.s1))
    after = {
        s["id"]: s for s in (await live.client.get("/stations", headers=bearer(world.t1))).json()
    }
    assert after[world.s1_id]["last_seen_at"] is not None
    assert after[world.s1_spare_id]["last_seen_at"] is None
