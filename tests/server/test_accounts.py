"""Accounts with a life cycle, through a real server: change your own password, an admin
resets one, deactivates and reactivates; a printed or reset password must be changed first;
a therapist archives and unarchives a patient. Each change is audited without a secret, and
the live links it ends close within a second with the code that says why."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select
from websockets.exceptions import InvalidStatus

from server import accounts
from server.config import Settings
from server.deps import MUST_CHANGE_PASSWORD
from server.models import User
from sessions import wire
from tests.server.live_server import (
    PASSWORD,
    STRENGTH,
    Live,
    World,
    bearer,
    copy_seeded,
    login,
    running,
)
from tests.server.ws_client import close_of, closed_with, station_ws, viewer_ws, welcomed

pytestmark = pytest.mark.both_stores

CLOSE_WITHIN_S = 1.0
NEW_PASSWORD = "a new passphrase of mine"


async def rows(live: Live, world: World, action: str, n: int = 10) -> list[dict[str, Any]]:
    r = await live.client.get(
        "/audit", params={"action": action, "limit": n}, headers=bearer(world.admin)
    )
    assert r.status_code == 200, r.text
    out: list[dict[str, Any]] = r.json()
    return out


async def status_of(live: Live, token: str, path: str = "/patients") -> int:
    return (await live.client.get(path, headers=bearer(token))).status_code


async def open_then_closed(ws: Any, change: Any) -> tuple[int, str]:
    """The link is open and streaming; once ``change`` is answered, it closes within a second.

    Measured from the answer, not from the request: the request hashes a password (argon2,
    deliberately slow, slower still on a loaded machine), which is not what is tested here."""
    assert await close_of(ws, 0.3) is None, "the link closed before anything changed"
    await change()
    return await closed_with(ws, timeout=CLOSE_WITHIN_S)


def change(current: str, new: str = NEW_PASSWORD) -> dict[str, str]:
    return {"current_password": current, "new_password": new}


# --- change your own password -----------------------------------------------------------


@pytest.mark.asyncio
async def test_changing_your_password_keeps_this_login_and_ends_the_others(
    live: Live, world: World
) -> None:
    c = live.client
    this = await login(c, "t1@clinic.test")
    other = await login(c, "t1@clinic.test")

    # Refusals first: nothing changes.
    r = await c.post("/auth/password", json=change("not my password"), headers=bearer(this))
    assert r.status_code == 400, r.text
    assert "current_password" in r.json()["detail"]
    r = await c.post("/auth/password", json=change(PASSWORD, PASSWORD), headers=bearer(this))
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == ["body", "new_password"]
    assert "differ" in r.json()["detail"][0]["msg"]
    r = await c.post("/auth/password", json=change(PASSWORD, "short"), headers=bearer(this))
    assert r.status_code == 422
    assert r.json()["detail"][0]["loc"] == ["body", "new_password"]
    r = await c.post("/auth/password", json={**change(PASSWORD), "extra": 1}, headers=bearer(this))
    assert r.status_code == 422
    assert await status_of(live, other) == 200
    (failed,) = await rows(live, world, "user.password_change_failed")
    assert (failed["actor"], failed["entity_id"]) == (f"user:{world.t1_id}", str(world.t1_id))

    async with viewer_ws(live, other, world.s1_id) as ws:

        async def changed() -> None:
            r = await c.post("/auth/password", json=change(PASSWORD), headers=bearer(this))
            assert r.status_code == 200, r.text
            assert r.json()["must_change_password"] is False

        code, reason = await open_then_closed(ws, changed)
        assert code == wire.CLOSE_SIGNED_OUT, (code, reason)

    assert await status_of(live, this) == 200
    assert await status_of(live, other) == 401
    assert await status_of(live, world.t1) == 401
    bad = await c.post("/auth/login", json={"email": "t1@clinic.test", "password": PASSWORD})
    assert bad.status_code == 401
    await login(c, "t1@clinic.test", NEW_PASSWORD)

    (row,) = await rows(live, world, "user.password_change")
    assert row["actor"] == f"user:{world.t1_id}"
    assert row["old"] == {"must_change_password": False}
    # this login, `other` and the seeded one were open; two ended
    assert row["new"] == {"must_change_password": False, "other_logins_ended": 2}
    assert NEW_PASSWORD not in str(row) and PASSWORD not in str(row)


@pytest.mark.asyncio
async def test_wrong_current_passwords_count_against_the_sign_in_throttle(
    seeded: tuple[Path, World], tmp_path: Path
) -> None:
    template, world = seeded
    settings = Settings(
        data_dir=copy_seeded(template, tmp_path),
        login_account_limit="3 per 15 minutes",
        login_delay_max_s=0.0,
    )
    async with running(settings) as live:
        c = live.client
        for _ in range(3):
            r = await c.post(
                "/auth/password", json=change("guess number x"), headers=bearer(world.t1)
            )
            assert r.status_code == 400, r.text
        r = await c.post("/auth/password", json=change(PASSWORD), headers=bearer(world.t1))
        assert r.status_code == 429, r.text
        assert int(r.headers["retry-after"]) >= 1
        # The same count guards signing in to that account.
        r = await c.post("/auth/login", json={"email": "t1@clinic.test", "password": PASSWORD})
        assert r.status_code == 429


# --- an admin resets a password; must change at the next sign-in -------------------------


@pytest.mark.asyncio
async def test_a_reset_password_must_be_changed_before_anything_else(
    live: Live, world: World
) -> None:
    c = live.client
    async with viewer_ws(live, world.t1, world.s1_id) as ws:
        reset: dict[str, Any] = {}

        async def do_reset() -> None:
            r = await c.post(f"/users/{world.t1_id}/reset-password", headers=bearer(world.admin))
            assert r.status_code == 200, r.text
            reset.update(r.json())

        code, _ = await open_then_closed(ws, do_reset)
        assert code == wire.CLOSE_SIGNED_OUT
    one_time = reset["one_time_password"]
    assert len(one_time) >= 16
    assert reset["user"]["must_change_password"] is True
    assert await status_of(live, world.t1) == 401  # every login of t1 ended
    bad = await c.post("/auth/login", json={"email": "t1@clinic.test", "password": PASSWORD})
    assert bad.status_code == 401

    r = await c.post("/auth/login", json={"email": "t1@clinic.test", "password": one_time})
    assert r.status_code == 200, r.text
    assert r.json()["user"]["must_change_password"] is True
    token = r.json()["access_token"]
    for method, path, body in [
        ("GET", "/patients", None),
        ("GET", f"/patients/{world.p1}", None),
        ("POST", "/patients", {"display_name": "X"}),
        ("POST", f"/stations/{world.s1_id}/revoke", None),
        ("GET", "/exercises", None),
    ]:
        r = await c.request(method, path, json=body, headers=bearer(token))
        assert (r.status_code, r.json()["detail"]) == (403, MUST_CHANGE_PASSWORD), path
    assert "change your password" in MUST_CHANGE_PASSWORD
    me = await c.get("/auth/me", headers=bearer(token))
    assert (me.status_code, me.json()["must_change_password"]) == (200, True)
    # The live view refuses such a login at its handshake too.
    with pytest.raises(InvalidStatus) as refused:
        async with viewer_ws(live, token, world.s1_id):
            pass
    assert refused.value.response.status_code == 403

    r = await c.post("/auth/password", json=change(one_time), headers=bearer(token))
    assert (r.status_code, r.json()["must_change_password"]) == (200, False)
    assert await status_of(live, token) == 200
    async with viewer_ws(live, token, world.s1_id) as ws:
        assert await close_of(ws, 0.3) is None

    (row,) = await rows(live, world, "user.password_reset")
    assert (row["actor"], row["entity_id"]) == (
        f"user:{await admin_id(live, world)}",
        str(world.t1_id),
    )
    assert row["old"] == {"must_change_password": False}
    assert row["new"] == {"must_change_password": True, "logins_ended": 1}
    (changed,) = await rows(live, world, "user.password_change")
    assert changed["old"] == {"must_change_password": True}
    everything = str(await all_rows(live, world))
    assert one_time not in everything and NEW_PASSWORD not in everything
    assert "$argon2" not in everything


async def admin_id(live: Live, world: World) -> int:
    me = (await live.client.get("/auth/me", headers=bearer(world.admin))).json()
    return int(me["id"])


async def all_rows(live: Live, world: World) -> list[dict[str, Any]]:
    r = await live.client.get("/audit", params={"limit": 500}, headers=bearer(world.admin))
    out: list[dict[str, Any]] = r.json()
    return out


@pytest.mark.asyncio
async def test_reset_password_refusals(live: Live, world: World) -> None:
    c = live.client
    before = await all_rows(live, world)
    me = await admin_id(live, world)
    r = await c.post(f"/users/{me}/reset-password", headers=bearer(world.admin))
    assert r.status_code == 409 and "change your own" in r.json()["detail"]
    r = await c.post("/users/999999/reset-password", headers=bearer(world.admin))
    assert (r.status_code, r.json()["detail"]) == (404, "user not found")
    r = await c.post(f"/users/{world.t2_id}/reset-password", headers=bearer(world.t1))
    assert r.status_code == 403
    assert await status_of(live, world.t2) == 200
    assert await all_rows(live, world) == before


@pytest.mark.asyncio
async def test_an_account_created_without_a_password_gets_a_one_time_one(
    live: Live, world: World
) -> None:
    c = live.client
    body = {"email": "New@Clinic.test", "name": "New One", "role": "therapist"}
    r = await c.post("/users", json=body, headers=bearer(world.admin))
    assert r.status_code == 201, r.text
    created = r.json()
    assert created["must_change_password"] is True
    one_time = created["one_time_password"]
    token = await login(c, "new@clinic.test", one_time)
    assert await status_of(live, token) == 403
    r = await c.post("/auth/logout", headers=bearer(token))  # allowed, and it ends the login
    assert r.status_code == 204
    assert await status_of(live, token, "/auth/me") == 401
    (row,) = await rows(live, world, "user.create", 1)
    assert row["new"] == {
        "email": "new@clinic.test",
        "name": "New One",
        "role": "therapist",
        "must_change_password": True,
    }
    # A password the owner chose is kept as it is and answered as null.
    r = await c.post(
        "/users",
        json={**body, "email": "own@clinic.test", "password": "my own choice"},
        headers=bearer(world.admin),
    )
    assert (r.json()["one_time_password"], r.json()["must_change_password"]) == (None, False)
    assert await status_of(live, await login(c, "own@clinic.test", "my own choice")) == 200


@pytest.mark.asyncio
async def test_the_must_change_refusal_is_documented_where_it_applies(live: Live) -> None:
    doc = (await live.client.get("/openapi.json")).json()["paths"]
    assert MUST_CHANGE_PASSWORD in doc["/api/v1/patients"]["get"]["responses"]["403"]["description"]
    forbidden = doc["/api/v1/users"]["post"]["responses"]["403"]["description"]
    assert "role" in forbidden and MUST_CHANGE_PASSWORD in forbidden
    for path, method in [
        ("/api/v1/auth/me", "get"),
        ("/api/v1/auth/logout", "post"),
        ("/api/v1/auth/password", "post"),
        ("/api/v1/station/me", "get"),
    ]:
        assert "403" not in doc[path][method]["responses"], path


# --- deactivate and reactivate ----------------------------------------------------------


@pytest.mark.asyncio
async def test_deactivation_closes_the_users_live_view_within_a_second(
    live: Live, world: World
) -> None:
    c = live.client
    async with viewer_ws(live, world.t1, world.s1_id) as ws:

        async def deactivate() -> None:
            r = await c.post(f"/users/{world.t1_id}/deactivate", headers=bearer(world.admin))
            assert (r.status_code, r.json()["active"]) == (200, False), r.text

        code, reason = await open_then_closed(ws, deactivate)
    assert code == wire.CLOSE_DEACTIVATED, (code, reason)
    assert "deactivated" in reason
    assert await status_of(live, world.t1) == 401
    r = await c.post("/auth/login", json={"email": "t1@clinic.test", "password": PASSWORD})
    assert r.status_code == 401
    # Twice: nothing changes, no second row.
    r = await c.post(f"/users/{world.t1_id}/deactivate", headers=bearer(world.admin))
    assert r.status_code == 200
    (row,) = await rows(live, world, "user.deactivate")
    assert (row["old"], row["new"]) == ({"active": True}, {"active": False})

    r = await c.post(f"/users/{world.t1_id}/reactivate", headers=bearer(world.admin))
    assert (r.status_code, r.json()["active"]) == (200, True)
    # The login from before the deactivation does not come back; a new sign-in works.
    assert await status_of(live, world.t1) == 401
    assert await status_of(live, await login(c, "t1@clinic.test")) == 200
    (row,) = await rows(live, world, "user.reactivate")
    assert (row["old"], row["new"]) == ({"active": False}, {"active": True})
    assert row["actor"] == f"user:{await admin_id(live, world)}"


@pytest.mark.asyncio
async def test_an_admin_cannot_deactivate_themself_and_one_admin_always_remains(
    live: Live, world: World
) -> None:
    c = live.client
    first = await admin_id(live, world)
    r = await c.post(f"/users/{first}/deactivate", headers=bearer(world.admin))
    assert r.status_code == 409 and "your own account" in r.json()["detail"]
    r = await c.post(f"/users/{world.t2_id}/deactivate", headers=bearer(world.t1))
    assert r.status_code == 403
    r = await c.post("/users/999999/deactivate", headers=bearer(world.admin))
    assert r.status_code == 404

    r = await c.post(
        "/users",
        json={"email": "a2@clinic.test", "name": "A2", "role": "admin", "password": PASSWORD},
        headers=bearer(world.admin),
    )
    second = r.json()["id"]
    a2 = await login(c, "a2@clinic.test")
    # Two admins deactivating each other at the same moment: never both.
    answers = await asyncio.gather(
        c.post(f"/users/{second}/deactivate", headers=bearer(world.admin)),
        c.post(f"/users/{first}/deactivate", headers=bearer(a2)),
    )
    codes = [a.status_code for a in answers]
    # Never both. The one refused is refused by the last-admin rule (409) or, where the
    # other's deactivation of its very sender was committed before its token was checked,
    # as no longer signed in (401): a 401 only for the admin the other one deactivated.
    assert sorted(codes) in ([200, 409], [200, 401]), [a.text for a in answers]
    if 401 in codes:
        assert "invalid or expired token" in answers[codes.index(401)].text
    async with live.sessionmaker() as db:
        active_admins = (
            await db.execute(select(User.id).where(User.role == "admin", User.active.is_(True)))
        ).all()
    assert len(active_admins) == 1


@pytest.mark.asyncio
async def test_two_admins_deactivating_each_other_in_overlapping_transactions(
    live: Live, world: World
) -> None:
    """The same race, held open: the first deactivation is not yet committed when the
    second is asked. The second waits for it and is then refused (on PostgreSQL both went
    through while each statement counted the other admin as still active)."""
    first = await admin_id(live, world)
    r = await live.client.post(
        "/users",
        json={"email": "a3@clinic.test", "name": "A3", "role": "admin", "password": PASSWORD},
        headers=bearer(world.admin),
    )
    second = r.json()["id"]
    async with live.sessionmaker() as db1, live.sessionmaker() as db2:
        by1, target1 = await db1.get(User, first), await db1.get(User, second)
        by2, target2 = await db2.get(User, second), await db2.get(User, first)
        assert by1 and target1 and by2 and target2
        assert await accounts.set_active(db1, by1, target1, False)  # uncommitted
        racing = asyncio.create_task(accounts.set_active(db2, by2, target2, False))
        await asyncio.sleep(0.5)
        assert not racing.done(), "the second deactivation did not wait for the first"
        await db1.commit()
        with pytest.raises(accounts.AccountRefused, match="last active admin"):
            await racing
    async with live.sessionmaker() as db:
        active_admins = (
            await db.execute(select(User.id).where(User.role == "admin", User.active.is_(True)))
        ).all()
    assert [a.id for a in active_admins] == [first]


@pytest.mark.asyncio
async def test_changes_of_one_account_at_once_take_turns_and_are_audited_once_each(
    live: Live, world: World
) -> None:
    """The same deactivation (or reactivation) asked four times at once changes the account
    once: one audit row, not one per request that read it still active. Resets at once
    each see the one before: the first row's "before" is the password its owner chose,
    every later one's is the reset password the one before made."""
    c = live.client
    path = f"/users/{world.t2_id}"
    for round_ in range(1, 4):
        for verb in ("deactivate", "reactivate"):
            answers = await asyncio.gather(
                *(c.post(f"{path}/{verb}", headers=bearer(world.admin)) for _ in range(4))
            )
            assert [a.status_code for a in answers] == [200] * 4, [a.text for a in answers]
            assert {a.json()["active"] for a in answers} == {verb == "reactivate"}
            assert len(await rows(live, world, f"user.{verb}")) == round_, verb
    answers = await asyncio.gather(
        *(c.post(f"{path}/reset-password", headers=bearer(world.admin)) for _ in range(4))
    )
    assert [a.status_code for a in answers] == [200] * 4, [a.text for a in answers]
    resets = list(reversed(await rows(live, world, "user.password_reset")))
    assert [r["old"]["must_change_password"] for r in resets] == [False, True, True, True]


@pytest.mark.asyncio
async def test_the_last_active_admin_is_never_deactivated(live: Live, world: World) -> None:
    """The rule behind the API's: even asked by an admin who is no longer active (a race the
    API cannot otherwise show), the last active admin stays."""
    async with live.sessionmaker() as db:
        first = (
            await db.execute(select(User).where(User.email == "admin@clinic.test"))
        ).scalar_one()
        gone = User(
            email="gone@clinic.test", name="Gone", role="admin", password_hash="x", active=False
        )
        db.add(gone)
        await db.flush()
        with pytest.raises(accounts.AccountRefused, match="last active admin"):
            await accounts.set_active(db, gone, first, active=False)
        await db.rollback()
    assert await status_of(live, world.admin) == 200
    # A therapist can be deactivated by the one active admin.
    async with live.sessionmaker() as db:
        first = (
            await db.execute(select(User).where(User.email == "admin@clinic.test"))
        ).scalar_one()
        t2 = await db.get(User, world.t2_id)
        assert t2 is not None
        assert await accounts.set_active(db, first, t2, active=False) is True
        await db.commit()
    assert await status_of(live, world.t2) == 401


# --- archive a patient ------------------------------------------------------------------


@pytest.mark.asyncio
async def test_archiving_a_patient_revokes_their_stations_and_freezes_the_record(
    live: Live, world: World
) -> None:
    c, t1 = live.client, bearer(world.t1)
    # Not another therapist (their patient does not exist for them), nor an admin (read-only).
    for who, refused in ((world.t2, 404), (world.admin, 403)):
        r = await c.post(f"/patients/{world.p1}/archive", headers=bearer(who))
        assert r.status_code == refused, r.text
    async with station_ws(live, world.s1) as ws:
        await welcomed(ws)
        done: dict[str, Any] = {}

        async def archive() -> None:
            r = await c.post(f"/patients/{world.p1}/archive", headers=t1)
            assert r.status_code == 200, r.text
            done.update(r.json())

        code, _ = await open_then_closed(ws, archive)
        assert code == wire.CLOSE_REVOKED
    assert done["archived_at"] is not None
    assert sorted(done["stations_revoked"]) == sorted([world.s1_id, world.s1_spare_id])
    assert done["prescriptions_cancelled"] == [world.rx1]

    # Read-only and out of the default list, but still there to read.
    listed = (await c.get("/patients", headers=t1)).json()
    assert [p["id"] for p in listed] == []
    archived = (await c.get("/patients", params={"archived": "true"}, headers=t1)).json()
    assert [p["id"] for p in archived] == [world.p1]
    assert (await c.get(f"/patients/{world.p1}", headers=t1)).status_code == 200
    admin_list = (await c.get("/patients", headers=bearer(world.admin))).json()
    assert [p["id"] for p in admin_list] == [world.p2]
    for method, path, body in [
        ("PATCH", f"/patients/{world.p1}", {"notes": "x"}),
        ("POST", f"/patients/{world.p1}/prescriptions", STRENGTH),
        ("POST", f"/patients/{world.p1}/stations", {"name": "Again"}),
        ("PATCH", f"/prescriptions/{world.rx1}", {**STRENGTH, "sets": 2}),
    ]:
        r = await c.request(method, path, json=body, headers=t1)
        assert r.status_code == 409, (path, r.text)
        assert "archived" in r.json()["detail"] and "unarchive" in r.json()["detail"], path
    r = await c.get("/station/me", headers=bearer(world.s1))
    assert r.status_code == 401
    stations = (await c.get("/stations", params={"patient_id": world.p1}, headers=t1)).json()
    assert all(s["revoked"] for s in stations)
    rx = (await c.get(f"/prescriptions/{world.rx1}", headers=t1)).json()
    assert rx["status"] == "cancelled"

    actor = f"user:{world.t1_id}"
    (row,) = await rows(live, world, "patient.archive")
    assert (row["actor"], row["patient_id"]) == (actor, world.p1)
    assert (row["old"], row["new"]) == ({"archived": False}, {"archived": True})
    revoked = await rows(live, world, "station.revoke")
    assert sorted(int(r["entity_id"]) for r in revoked) == sorted(done["stations_revoked"])
    assert all(r["new"] == {"revoked": True, "because": "patient.archive"} for r in revoked)
    (cancelled,) = await rows(live, world, "prescription.cancel")
    assert cancelled["new"] == {"status": "cancelled", "because": "patient.archive"}

    # Twice changes nothing.
    again = (await c.post(f"/patients/{world.p1}/archive", headers=t1)).json()
    assert (again["stations_revoked"], again["prescriptions_cancelled"]) == ([], [])
    assert len(await rows(live, world, "patient.archive")) == 1

    # Unarchived: editable again; what archiving ended stays ended.
    r = await c.post(f"/patients/{world.p1}/unarchive", headers=t1)
    assert (r.status_code, r.json()["archived_at"]) == (200, None)
    r = await c.patch(f"/patients/{world.p1}", json={"notes": "back"}, headers=t1)
    assert r.status_code == 200
    assert [p["id"] for p in (await c.get("/patients", headers=t1)).json()] == [world.p1]
    assert (await c.get("/station/me", headers=bearer(world.s1))).status_code == 401
    (row,) = await rows(live, world, "patient.unarchive")
    assert (row["old"], row["new"]) == ({"archived": True}, {"archived": False})
    (update_row,) = await rows(live, world, "patient.update")
    assert (update_row["old"], update_row["new"]) == ({"notes": ""}, {"notes": "back"})


@pytest.mark.asyncio
async def test_the_patient_list_filter_takes_only_a_boolean(live: Live, world: World) -> None:
    r = await live.client.get("/patients", params={"archived": "maybe"}, headers=bearer(world.t1))
    assert r.status_code == 422
    assert r.json()["detail"][0]["loc"] == ["query", "archived"]
