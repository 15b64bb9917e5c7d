"""``ankle station``'s settings: options over ANKLE_STATION_* variables over defaults; a value
refused (a hold limit that is not a time) stops it before anything starts, in one line naming
the option or the variable."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from station.cli import SettingsError, add_arguments, run, settings
from station.reasons import HOLD_LIMIT_S


def parse(*more: str, spool: Path) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_arguments(p)
    base = ["--device", "socket://127.0.0.1:9", "--server", "http://127.0.0.1:9", "--token", "t"]
    return p.parse_args([*base, "--spool", str(spool), *more])


def test_the_hold_limit_defaults_to_a_few_minutes(tmp_path: Path) -> None:
    assert settings(parse(spool=tmp_path)).hold_limit_s == HOLD_LIMIT_S == 180.0
    assert settings(parse("--hold-limit", "2.5", spool=tmp_path)).hold_limit_s == 2.5


def test_variables_set_what_the_options_leave_out(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("ANKLE_STATION_HOLD_LIMIT_S", "30")
    monkeypatch.setenv("ANKLE_STATION_BATCH_HZ", "10")
    monkeypatch.setenv("ANKLE_STATION_AUTOSTART", "true")
    config = settings(parse("--batch-hz", "5", spool=tmp_path))
    assert (config.hold_limit_s, config.batch_hz, config.autostart) == (30.0, 5.0, True)
    assert config.token == "t" and config.spool == tmp_path
    # Only the variables: a station run by systemd with an environment file.
    monkeypatch.setenv("ANKLE_STATION_DEVICE", "/dev/ttyUSB0")
    monkeypatch.setenv("ANKLE_STATION_SERVER", "https://clinic.example")
    monkeypatch.setenv("ANKLE_STATION_TOKEN", "secret")
    p = argparse.ArgumentParser()
    add_arguments(p)
    config = settings(p.parse_args([]))
    assert (config.device, config.server, config.token) == (
        "/dev/ttyUSB0",
        "https://clinic.example",
        "secret",
    )
    assert "secret" not in repr(config)


def test_a_variable_refused_is_named(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ANKLE_STATION_BATCH_HZ", "500")
    with pytest.raises(SettingsError) as refused:
        settings(parse(spool=tmp_path))
    assert str(refused.value) == (
        "--batch-hz (or ANKLE_STATION_BATCH_HZ) 500 is not a rate from 1 to 50 messages a second"
    )
    monkeypatch.delenv("ANKLE_STATION_TOKEN", raising=False)
    p = argparse.ArgumentParser()
    add_arguments(p)
    with pytest.raises(SettingsError, match=r"^--device \(or ANKLE_STATION_DEVICE\) is required"):
        settings(p.parse_args([]))


@pytest.mark.parametrize("value", ["0", "-5", "nan", "inf", "3601"])
def test_a_hold_limit_that_is_not_a_time_is_refused(
    value: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    spool = tmp_path / "spool"
    assert run(parse("--hold-limit", value, spool=spool)) == 2
    out = capsys.readouterr().out.strip().splitlines()
    assert out == [
        f"error: ankle station: --hold-limit {float(value):g} is not a time from more than 0 "
        "to 3600 s"
    ]
    assert not spool.exists()  # nothing started, nothing written
