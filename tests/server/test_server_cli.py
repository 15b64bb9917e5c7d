"""Seeding from the command line: accounts and the one-machine demo."""

from __future__ import annotations

import json
import stat
from pathlib import Path

import pytest
from pydantic import ValidationError

from server.cli import CREDENTIALS_FILE, ensure_user, provision_demo, provision_demo_async
from server.config import Settings
from tests.server.live_server import bearer, login, running


def test_ensure_user_creates_once(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path)
    assert ensure_user(settings, "Boss@Clinic.test", "Boss", "admin", "violet tractor hum") is True
    assert (
        ensure_user(settings, "boss@clinic.test", "Other", "therapist", "amber cloud tide") is False
    )
    with pytest.raises(ValidationError, match="password"):
        ensure_user(settings, "short@clinic.test", "S", "admin", "123")
    with pytest.raises(ValidationError, match="too easy to guess"):
        ensure_user(settings, "weak@clinic.test", "W", "admin", "0123456789")


def test_provision_demo_is_idempotent_and_private(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, port=8765)
    first = provision_demo(settings)
    path = tmp_path / CREDENTIALS_FILE
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert first["therapist_email"] == "therapist@demo.local"
    assert first["url"] == "http://127.0.0.1:8765"
    assert provision_demo(settings) == first
    assert json.loads(path.read_text()) == {k: v for k, v in first.items() if k != "url"}
    # Without the file the secrets are new, the records are the same.
    path.unlink()
    again = provision_demo(settings)
    assert again["therapist_password"] != first["therapist_password"]
    assert again["station_token"] != first["station_token"]
    assert (again["patient_id"], again["prescription_id"]) == (
        first["patient_id"],
        first["prescription_id"],
    )


@pytest.mark.asyncio
async def test_the_demo_credentials_work(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path)
    creds = await provision_demo_async(settings)
    async with running(settings) as live:
        token = await login(live.client, creds["therapist_email"], creds["therapist_password"])
        patients = (await live.client.get("/patients", headers=bearer(token))).json()
        assert [p["id"] for p in patients] == [creds["patient_id"]]
        station = bearer(creds["station_token"])
        me = (await live.client.get("/station/me", headers=station)).json()
        assert (me["id"], me["patient_display_name"]) == (
            creds["station_id"],
            creds["patient_name"],
        )
        (rx,) = (await live.client.get("/station/prescriptions", headers=station)).json()
        assert rx["id"] == creds["prescription_id"]
        body = rx["body"]
        assert (body["exercise"], body["sets"], body["repetitions"], body["repetition_s"]) == (
            "strength",
            1,
            3,
            6.0,
        )
