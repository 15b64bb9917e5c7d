"""``ankle station``'s options: a hold limit that is not a time is refused before anything
starts, in one line naming the option."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from station.cli import add_arguments, run
from station.reasons import HOLD_LIMIT_S


def parse(*more: str, spool: Path) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_arguments(p)
    base = ["--device", "socket://127.0.0.1:9", "--server", "http://127.0.0.1:9", "--token", "t"]
    return p.parse_args([*base, "--spool", str(spool), *more])


def test_the_hold_limit_defaults_to_a_few_minutes(tmp_path: Path) -> None:
    assert parse(spool=tmp_path).hold_limit == HOLD_LIMIT_S == 180.0
    assert parse("--hold-limit", "2.5", spool=tmp_path).hold_limit == 2.5


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
