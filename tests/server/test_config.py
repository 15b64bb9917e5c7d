"""Settings: defaults that follow from other settings, and ANKLE_* variables."""

from __future__ import annotations

from pathlib import Path

import pytest

from server.config import Settings, SettingsError, load_settings


def test_defaults_follow_data_dir_and_port(tmp_path: Path) -> None:
    s = Settings(data_dir=tmp_path, port=8123)
    assert s.database_url == f"sqlite+aiosqlite:///{tmp_path}/ankle.db"
    assert s.allowed_origins == ["http://127.0.0.1:8123", "http://localhost:8123"]
    assert s.public_url == "http://127.0.0.1:8123"
    assert s.fhir_base == "http://127.0.0.1:8123/api/v1/fhir"  # where it serves its own
    assert s.token_ttl_s == 12 * 3600
    assert s.upload_max_bytes == 512 * 1024 * 1024


def test_explicit_values_win_and_a_wildcard_host_is_published_as_loopback() -> None:
    s = Settings(
        host="0.0.0.0",
        database_url="sqlite+aiosqlite:///elsewhere.db",
        allowed_origins=["https://clinic.example"],
    )
    assert s.public_url == "http://127.0.0.1:8000"
    assert s.database_url == "sqlite+aiosqlite:///elsewhere.db"
    assert s.allowed_origins == ["https://clinic.example"]
    # None (from code that builds settings from a dict) means "derive it", like unset.
    derived = Settings.model_validate({"database_url": None}).database_url
    assert derived.endswith("ankle-data/ankle.db")


def test_environment_variables(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("ANKLE_DATA_DIR", str(tmp_path))
    monkeypatch.setenv("ANKLE_PORT", "9001")
    monkeypatch.setenv("ANKLE_TOKEN_TTL_S", "60")
    monkeypatch.setenv("ANKLE_PUBLIC_URL", "https://ankle.clinic.example")
    s = Settings()
    assert (s.data_dir, s.port, s.token_ttl_s) == (tmp_path, 9001, 60)
    assert s.database_url == f"sqlite+aiosqlite:///{tmp_path}/ankle.db"
    assert s.allowed_origins == [
        "https://ankle.clinic.example",
        "http://127.0.0.1:9001",
        "http://localhost:9001",
    ]
    assert s.public_url == "https://ankle.clinic.example"


def test_out_of_range_values_are_refused() -> None:
    with pytest.raises(ValueError, match="port"):
        Settings(port=70000)
    with pytest.raises(ValueError, match="token_ttl_s"):
        Settings(token_ttl_s=0)


def test_a_public_address_behind_a_proxy_is_an_allowed_origin() -> None:
    s = Settings(port=8000, public_url="https://rehab.clinic.example/")
    assert s.allowed_origins == [
        "https://rehab.clinic.example",
        "http://127.0.0.1:8000",
        "http://localhost:8000",
    ]
    # An explicit list is taken as it is.
    assert Settings(
        public_url="https://a.example", allowed_origins=["https://b.example"]
    ).allowed_origins == ["https://b.example"]


def test_the_relay_is_redis_or_nothing() -> None:
    assert Settings().relay_url == ""
    assert Settings(relay_url="redis://cache:6379/2").relay_url == "redis://cache:6379/2"
    with pytest.raises(ValueError, match="relay_url") as refused:
        Settings(relay_url="http://cache:6379")
    assert "redis://host:port/db" in str(refused.value)
    # The line reaches the log: the scheme is named, the URL and its password are not.
    with pytest.raises(SettingsError) as refused_line:
        load_settings(relay_url="https://ops:s3cret@cache:6379/0")
    assert str(refused_line.value).startswith("ANKLE_RELAY_URL: https scheme is not a relay")
    assert "s3cret" not in str(refused_line.value)
    with pytest.raises(ValueError, match="relay_lease_s"):
        Settings(relay_lease_s=0)


def test_the_fhir_names_are_under_the_clinics_own_base_url() -> None:
    behind = Settings(public_url="https://rehab.clinic.example/")
    assert behind.fhir_base == "https://rehab.clinic.example/api/v1/fhir"
    own = Settings(fhir_base="https://records.clinic.example/fhir/")
    assert own.fhir_base == "https://records.clinic.example/fhir"
    for bad in ("records.clinic.example/fhir", "urn:ankle", "https://x.example/fhir?a=1"):
        with pytest.raises(ValueError, match="is not a base URL"):
            Settings(fhir_base=bad)
