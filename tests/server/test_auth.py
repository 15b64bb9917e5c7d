"""Logging in and out, and every way a token can be wrong."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest
from sqlalchemy import update

from server.deps import FOR_STATIONS, FOR_USERS
from server.models import AuthToken, Station, User, utcnow
from tests.server.live_server import PASSWORD, Live, World, bearer, login
from tests.server.ws_client import station_ws, welcomed

pytestmark = pytest.mark.both_stores


@pytest.mark.asyncio
async def test_login_me_logout(live: Live, world: World) -> None:
    r = await live.client.post(
        "/auth/login", json={"email": " T1@Clinic.TEST ", "password": PASSWORD}
    )
    assert r.status_code == 200
    body = r.json()
    assert body["token_type"] == "bearer"
    assert body["user"] == {**body["user"], "email": "t1@clinic.test", "role": "therapist"}
    assert "password_hash" not in body["user"]
    expires = datetime.fromisoformat(body["expires_at"])
    expected = datetime.now(UTC) + timedelta(seconds=live.settings.token_ttl_s)
    assert abs((expires - expected).total_seconds()) < 60
    token = body["access_token"]
    me = await live.client.get("/auth/me", headers=bearer(token))
    assert me.json()["id"] == world.t1_id
    assert (await live.client.post("/auth/logout", headers=bearer(token))).status_code == 204
    assert (await live.client.get("/auth/me", headers=bearer(token))).status_code == 401
    # Logging out one login leaves the user's others alone.
    assert (await live.client.get("/auth/me", headers=bearer(world.t1))).status_code == 200


@pytest.mark.asyncio
async def test_wrong_email_and_wrong_password_look_the_same(live: Live) -> None:
    answers = []
    for email, password in [
        ("nobody@clinic.test", PASSWORD),
        ("t1@clinic.test", "wrong password!"),
        ("t1@clinic.test", ""),
        ("not an email", PASSWORD),
    ] * 2:  # and the same again: repeated failures answer no differently
        r = await live.client.post("/auth/login", json={"email": email, "password": password})
        answers.append((r.status_code, r.json(), r.headers["www-authenticate"]))
    assert set(map(repr, answers)) == {repr((401, {"detail": "wrong email or password"}, "Bearer"))}
    # A few failures lock nobody out (the throttle starts later: test_throttle.py).
    await login(live.client, "t1@clinic.test")


@pytest.mark.asyncio
async def test_a_deactivated_account_cannot_log_in_or_use_its_tokens(
    live: Live, world: World
) -> None:
    async with live.sessionmaker() as db:
        await db.execute(update(User).where(User.id == world.t1_id).values(active=False))
        await db.commit()
    r = await live.client.post(
        "/auth/login", json={"email": "t1@clinic.test", "password": PASSWORD}
    )
    # The right password: told why, and whom to ask (it was "wrong email or password").
    assert (r.status_code, r.json()["detail"]) == (
        401,
        "this account is deactivated: ask your clinic's administrator to reactivate it",
    )
    # A wrong one learns nothing of the account.
    r = await live.client.post(
        "/auth/login", json={"email": "t1@clinic.test", "password": PASSWORD + "x"}
    )
    assert (r.status_code, r.json()["detail"]) == (401, "wrong email or password")
    assert (await live.client.get("/auth/me", headers=bearer(world.t1))).status_code == 401


@pytest.mark.asyncio
async def test_missing_or_malformed_tokens(live: Live, world: World) -> None:
    for authorization in [
        None,
        "",
        "Bearer",
        "Bearer not-a-token",
        "Basic dDE6Y29ycmVjdCBob3JzZQ==",
        f"Token {world.t1}",
        f"Bearer {world.t1}x",
        f"Bearer {world.t1[:-1]}",
    ]:
        headers = {} if authorization is None else {"Authorization": authorization}
        r = await live.client.get("/auth/me", headers=headers)
        assert r.status_code == 401, authorization
        assert r.headers["www-authenticate"] == "Bearer"


@pytest.mark.asyncio
async def test_an_expired_token_is_refused(live: Live, world: World) -> None:
    async with live.sessionmaker() as db:
        await db.execute(update(AuthToken).values(expires_at=utcnow() - timedelta(seconds=1)))
        await db.commit()
    r = await live.client.get("/patients", headers=bearer(world.t1))
    assert (r.status_code, r.json()) == (401, {"detail": "invalid or expired token"})


@pytest.mark.asyncio
async def test_tokens_do_not_cross_between_users_and_stations(live: Live, world: World) -> None:
    """A valid token on the other kind of caller's route is a 403 that says whose route it
    is, not a 401 calling the token invalid or expired (it is neither)."""
    r = await live.client.get("/auth/me", headers=bearer(world.s1))
    assert (r.status_code, r.json()) == (403, {"detail": FOR_USERS})
    r = await live.client.get("/patients", headers=bearer(world.s1))
    assert (r.status_code, r.json()) == (403, {"detail": FOR_USERS})
    r = await live.client.get("/station/me", headers=bearer(world.t1))
    assert (r.status_code, r.json()) == (403, {"detail": FOR_STATIONS})
    # An invalid token stays a 401 on either.
    r = await live.client.get("/patients", headers=bearer(world.s1 + "x"))
    assert (r.status_code, r.json()) == (401, {"detail": "invalid or expired token"})
    r = await live.client.get("/station/me", headers=bearer(world.t1 + "x"))
    assert (r.status_code, r.json()) == (401, {"detail": "invalid or revoked station token"})


@pytest.mark.asyncio
async def test_a_revoked_station_is_refused(live: Live, world: World) -> None:
    async with station_ws(live, world.s1) as ws:
        await welcomed(ws)
        listed = await live.client.get("/stations", headers=bearer(world.t1))
        assert {s["id"]: s["online"] for s in listed.json()}[world.s1_id] is True
        r = await live.client.post(f"/stations/{world.s1_id}/revoke", headers=bearer(world.t1))
    # The revocation closed its link: the answer says so, as the list does.
    assert (r.json()["revoked"], r.json()["online"]) == (True, False)
    listed = await live.client.get("/stations", headers=bearer(world.t1))
    assert {s["id"]: s["online"] for s in listed.json()}[world.s1_id] is False
    r = await live.client.get("/station/prescriptions", headers=bearer(world.s1))
    assert (r.status_code, r.json()) == (401, {"detail": "invalid or revoked station token"})
    async with live.sessionmaker() as db:
        station = await db.get(Station, world.s1_id)
        assert station is not None and station.revoked


@pytest.mark.sqlite_only
@pytest.mark.asyncio
async def test_tokens_are_stored_only_as_hashes(live: Live, world: World) -> None:
    raw = (live.settings.data_dir / "ankle.db").read_bytes()
    for token in (world.t1, world.t2, world.admin, world.s1, world.s2):
        assert token.encode() not in raw


@pytest.mark.asyncio
async def test_users_admin_creates_accounts(live: Live, world: World) -> None:
    admin = bearer(world.admin)
    # Ten characters are enough when they are not easy to guess.
    new = {"email": "New@Clinic.test", "name": "New", "role": "admin", "password": "kq7#Vm2!pZ"}
    r = await live.client.post("/users", json=new, headers=admin)
    assert r.status_code == 201
    assert r.json()["email"] == "new@clinic.test"
    again = await live.client.post(
        "/users", json={**new, "email": "new@clinic.test"}, headers=admin
    )
    assert again.status_code == 409
    short = await live.client.post(
        "/users", json={**new, "email": "s@c.t", "password": "x" * 9}, headers=admin
    )
    assert short.status_code == 422
    assert short.json()["detail"][0]["loc"] == ["body", "password"]
    listed = (await live.client.get("/users", headers=admin)).json()
    assert [u["email"] for u in listed] == [
        "admin@clinic.test",
        "t1@clinic.test",
        "t2@clinic.test",
        "new@clinic.test",
    ]
    # Whether a password must be changed, never the password or its hash.
    assert all("password" not in k for u in listed for k in u if k != "must_change_password")
    assert "$argon2" not in str(listed)
    await login(live.client, "new@clinic.test", new["password"])
