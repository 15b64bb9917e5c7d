"""``ankle admin`` as an operator runs it on a fresh install: real processes on a real data
directory, then a real server that signs the new accounts in."""

from __future__ import annotations

import os
import re
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
from sqlalchemy import select

from server.cli import ensure_user
from server.config import Settings
from server.deps import MUST_CHANGE_PASSWORD
from server.models import AuditEntry
from tests.server.live_server import bearer, login, running

ONE_TIME = re.compile(r"^One-time password: (\S+)$", re.MULTILINE)
RESET = re.compile(r"^New one-time password for .*: (\S+)$", re.MULTILINE)


def admin(data_dir: Path, *args: str, stdin: str | None = None) -> subprocess.CompletedProcess[str]:
    """``ankle admin ...`` with the data directory from the usual setting."""
    return subprocess.run(
        [sys.executable, "-m", "ankle", "admin", *args],
        env={**os.environ, "ANKLE_DATA_DIR": str(data_dir)},
        input=stdin,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


@pytest.mark.asyncio
async def test_the_first_admin_of_a_fresh_install_must_change_the_printed_password(
    tmp_path: Path,
) -> None:
    made = admin(
        tmp_path,
        *("create-user", "--email", "Boss@Clinic.test", "--name", "Bo Boss", "--role", "admin"),
    )
    assert made.returncode == 0, made.stderr
    assert "Created admin Bo Boss <boss@clinic.test>" in made.stdout
    match = ONE_TIME.search(made.stdout)
    assert match, made.stdout
    printed = match.group(1)
    assert len(printed) >= 16

    async with running(Settings(data_dir=tmp_path)) as live:
        c = live.client
        r = await c.post("/auth/login", json={"email": "boss@clinic.test", "password": printed})
        assert r.status_code == 200, r.text
        assert r.json()["user"]["must_change_password"] is True
        token = r.json()["access_token"]
        r = await c.get("/users", headers=bearer(token))
        assert (r.status_code, r.json()["detail"]) == (403, MUST_CHANGE_PASSWORD)
        r = await c.post(
            "/auth/password",
            json={"current_password": printed, "new_password": "the boss's own passphrase"},
            headers=bearer(token),
        )
        assert r.status_code == 200, r.text
        r = await c.get("/users", headers=bearer(token))
        assert r.status_code == 200
        assert [u["email"] for u in r.json()] == ["boss@clinic.test"]

        # Forgotten: the operator resets it; the server's open login ends with it.
        done = admin(tmp_path, "reset-password", "--email", "BOSS@clinic.test")
        assert done.returncode == 0, done.stderr
        match = RESET.search(done.stdout)
        assert match, done.stdout
        reset = match.group(1)
        assert (await c.get("/auth/me", headers=bearer(token))).status_code == 401
        bad = await c.post(
            "/auth/login",
            json={"email": "boss@clinic.test", "password": "the boss's own passphrase"},
        )
        assert bad.status_code == 401
        token = await login(c, "boss@clinic.test", reset)
        assert (await c.get("/users", headers=bearer(token))).status_code == 403

        async with live.sessionmaker() as db:
            audit = (await db.execute(select(AuditEntry).order_by(AuditEntry.id))).scalars().all()
    actions = [(a.action, a.actor) for a in audit if a.action.startswith("user.")]
    assert actions == [
        ("user.create", "system"),
        ("user.password_change", "user:1"),
        ("user.password_reset", "system"),
    ]
    everything = str([(a.old, a.new) for a in audit])
    assert printed not in everything and reset not in everything and "argon2" not in everything


@pytest.mark.asyncio
async def test_a_password_given_on_stdin_is_the_owners_and_needs_no_change(
    tmp_path: Path,
) -> None:
    r = admin(
        tmp_path,
        "create-user",
        "--email",
        "t@clinic.test",
        "--name",
        "Thera",
        "--role",
        "therapist",
        "--password-stdin",
        stdin="chosen by me, 2024\n",
    )
    assert r.returncode == 0, r.stderr
    assert "One-time password" not in r.stdout
    async with running(Settings(data_dir=tmp_path)) as live:
        token = await login(live.client, "t@clinic.test", "chosen by me, 2024")
        assert (await live.client.get("/patients", headers=bearer(token))).status_code == 200


@pytest.mark.parametrize(
    ("args", "stdin", "needle"),
    [
        (
            ["create-user", "--email", "taken@clinic.test", "--name", "X", "--role", "admin"],
            None,
            "exists",
        ),
        (
            [
                "create-user",
                "--email",
                "n@clinic.test",
                "--name",
                "X",
                "--role",
                "admin",
                "--password-stdin",
            ],
            "short\n",
            "password",
        ),
        (
            [
                "create-user",
                "--email",
                "n@clinic.test",
                "--name",
                "X",
                "--role",
                "admin",
                "--password-stdin",
            ],
            "",
            "no password",
        ),
        (
            ["create-user", "--email", "not an email", "--name", "X", "--role", "admin"],
            None,
            "email",
        ),
        (
            ["create-user", "--email", "n@clinic.test", "--name", " ", "--role", "admin"],
            None,
            "name",
        ),
        (
            ["create-user", "--email", "n@clinic.test", "--name", "X", "--role", "boss"],
            None,
            "--role",
        ),
        (["create-user", "--email", "n@clinic.test", "--role", "admin"], None, "--name"),
        (["reset-password", "--email", "nobody@clinic.test"], None, "no user"),
        (["delete-user", "--email", "taken@clinic.test"], None, "invalid choice"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_changes_nothing(
    tmp_path: Path, args: list[str], stdin: str | None, needle: str
) -> None:
    settings = Settings(data_dir=tmp_path)
    ensure_user(settings, "taken@clinic.test", "Taken", "therapist", "taken but strong passphrase")
    r = admin(tmp_path, *args, stdin=stdin)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    assert needle in lines[0]
    assert r.stdout == ""
    with sqlite3.connect(tmp_path / "ankle.db") as db:
        users = db.execute("SELECT count(*) FROM users").fetchone()
        rows = db.execute("SELECT count(*) FROM audit_log").fetchone()
    assert (users, rows) == ((1,), (1,))


@pytest.mark.parametrize("email", ["", "not an email", "two@at@signs"])
def test_an_address_that_is_not_one_is_refused_in_words(tmp_path: Path, email: str) -> None:
    """The API's sentence after the option that gave it, not pydantic's words around the
    address's regular expression ("String should match pattern '^[^@\\s]+@[^@\\s]+$'")."""
    r = admin(tmp_path, "create-user", "--email", email, "--name", "X", "--role", "admin")
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert r.stderr.strip() == (
        "error: --email: Email must be an email address such as name@clinic.example: one @ "
        "with text on each side, and no spaces."
    )
