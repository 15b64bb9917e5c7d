"""A password set here must be hard to guess: length alone (10 to 1024 characters) let in
twenty spaces, twelve zero-width spaces, "aaaaaaaaaa", "1234567890" and the account's own
e-mail address. Each is refused with zxcvbn's own advice, where a password is set: your own
change, an admin's new account, and ``ankle admin`` (the same ``UserCreate``)."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from server.schemas import UserCreate
from server.security import PASSWORD_SCORE_MIN, new_password, password_weakness
from tests.server.live_server import PASSWORD, Live, World, bearer, login

WEAK = {
    "twenty spaces": " " * 20,
    "zero-width spaces": "\u200b" * 12,
    "one letter": "a" * 10,
    "digits in a row": "1234567890",
    "own e-mail": "t1@clinic.test",
}
SAYS = {
    "twenty spaces": "nothing visible in it",
    "zero-width spaces": "nothing visible in it",
    "one letter": 'Repeats like "aaa" are easy to guess.',
    "digits in a row": "This is a top-100 common password.",
    "own e-mail": "It is made from the account's own e-mail address or name.",
}


@pytest.mark.asyncio
async def test_a_weak_new_password_is_refused_with_advice_and_changes_nothing(
    live: Live, world: World
) -> None:
    c = live.client
    token = await login(c, "t1@clinic.test")
    for name, weak in WEAK.items():
        r = await c.post(
            "/auth/password",
            json={"current_password": PASSWORD, "new_password": weak},
            headers=bearer(token),
        )
        assert r.status_code == 422, (name, r.text)
        (error,) = r.json()["detail"]
        assert error["loc"] == ["body", "new_password"], (name, error)
        assert SAYS[name] in error["msg"], (name, error)
        assert "input" not in error, "the password was echoed"
        if "visible" not in SAYS[name]:
            assert f"at least {PASSWORD_SCORE_MIN} needed" in error["msg"], error
    assert await login(c, "t1@clinic.test", PASSWORD)  # still the password it was


@pytest.mark.asyncio
async def test_a_new_account_with_a_weak_password_is_refused(live: Live, world: World) -> None:
    body = {"email": "own@clinic.test", "name": "Olga Own", "role": "therapist"}
    for weak in ("own@clinic.test", "olga own 2024", "aaaaaaaaaa"):
        r = await live.client.post(
            "/users", json={**body, "password": weak}, headers=bearer(world.admin)
        )
        assert r.status_code == 422, (weak, r.text)
        (error,) = r.json()["detail"]
        assert error["loc"] == ["body", "password"], error
        assert "too easy to guess" in error["msg"], error
    r = await live.client.get("/users", headers=bearer(world.admin))
    assert "own@clinic.test" not in r.text


def test_the_command_line_refuses_what_the_api_refuses() -> None:
    """``ankle admin create-user`` and the first admin's account validate a UserCreate."""
    with pytest.raises(ValidationError, match="nothing visible in it"):
        UserCreate(email="a@clinic.test", name="Ada", role="admin", password="\u3000" * 10)
    with pytest.raises(ValidationError, match="too easy to guess"):
        UserCreate(email="a@clinic.test", name="Ada", role="admin", password="1234567890")
    assert UserCreate(email="a@clinic.test", name="Ada", role="admin", password=PASSWORD)


def test_passwords_the_server_makes_are_strong_enough() -> None:
    inputs = ("admin@clinic.test", "Ada Admin")
    refused = [p for p in (new_password() for _ in range(300)) if password_weakness(p, inputs)]
    assert refused == []
