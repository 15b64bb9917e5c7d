"""A setting that cannot work, or a database that cannot be reached, is one line naming the
setting and what is wrong, exit 2 (a bad setting) or 1 (the database away): not a
traceback of hundreds of lines from the driver, uvicorn or ``int()``."""

from __future__ import annotations

import socket
import threading
from pathlib import Path

import pytest

from ankle.cli import main

COMMANDS = {
    "server": ["server"],
    "db current": ["db", "current"],
    "db upgrade": ["db", "upgrade"],
    "admin create-user": [
        "admin",
        "create-user",
        "--email",
        "a@clinic.test",
        "--name",
        "A",
        "--role",
        "admin",
    ],
}


def closed_port() -> int:
    """A local port nothing listens on (bound, then let go)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
    return port


def refused(argv: list[str]) -> int:
    """``main(argv)``'s exit code. It must refuse at once: a regression that starts serving
    instead fails the test after a minute, where called here it would hang the run."""
    codes: list[int] = []
    raised: list[BaseException] = []

    def run() -> None:
        try:
            codes.append(main(argv))
        except BaseException as exc:  # handed to the test below
            raised.append(exc)

    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(60.0)
    assert not worker.is_alive(), f"`ankle {' '.join(argv)}` did not refuse within 60 s"
    if raised:
        raise raised[0]
    return codes[0]


def one_line(capsys: pytest.CaptureFixture[str]) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert "Traceback" not in captured.err + captured.out
    return lines[0]


@pytest.mark.parametrize("command", COMMANDS)
def test_a_database_that_cannot_be_reached_is_one_line_and_exit_1(
    command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    url = f"postgresql+asyncpg://ankle:s3cret@127.0.0.1:{closed_port()}/ankle"
    with pytest.MonkeyPatch.context() as env:
        env.setenv("ANKLE_DATABASE_URL", url)
        env.setenv("ANKLE_DATA_DIR", str(tmp_path))
        assert refused(COMMANDS[command]) == 1
    line = one_line(capsys)
    assert line.startswith("error: cannot open the database (ANKLE_DATABASE_URL: PostgreSQL")
    assert "s3cret" not in line  # the line reaches a log


@pytest.mark.parametrize(
    ("name", "value", "says"),
    [
        ("ANKLE_DATABASE_URL", "mysql://ankle:s3cret@db/ankle", "mysql scheme is not a database"),
        ("ANKLE_DATABASE_URL", "postgresql://ankle:s3cret@db/ankle", "postgresql+asyncpg://"),
        ("ANKLE_PORT", "abc", "valid integer"),
        ("ANKLE_PORT", "70000", "65535"),
        ("ANKLE_ALLOWED_ORIGINS", "notjson", 'not JSON; a list is written as JSON, such as ["'),
        ("ANKLE_ALLOWED_ORIGINS", '["*"]', '"*" is not an origin'),
        ("ANKLE_DATA_DIR", "/dev/null", "/dev/null is a file, not a directory"),
        ("ANKLE_DATA_DIR", "/dev/null/ankle", "/dev/null is a file, not a directory"),
        ("ANKLE_PUBLIC_URL", "garbage", "'garbage' is not a base URL"),
    ],
)
@pytest.mark.parametrize("command", COMMANDS)
def test_a_setting_that_cannot_work_is_one_line_naming_it_and_exit_2(
    command: str,
    name: str,
    value: str,
    says: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.MonkeyPatch.context() as env:
        env.setenv("ANKLE_DATA_DIR", str(tmp_path))
        env.setenv(name, value)
        assert refused(COMMANDS[command]) == 2
    line = one_line(capsys)
    assert line.startswith(f"error: {name}: "), line
    assert says in line and "s3cret" not in line
    assert line.count("ANKLE_") == 1, line  # no other setting blamed (one derived from it)


def test_a_relay_that_cannot_be_reached_is_one_line_and_exit_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.MonkeyPatch.context() as env:
        env.setenv("ANKLE_DATA_DIR", str(tmp_path))
        env.setenv("ANKLE_RELAY_URL", f"redis://:s3cret@127.0.0.1:{closed_port()}/0")
        assert refused(["server", "--port", "0"]) == 1
    line = one_line(capsys)
    assert line.startswith("error: cannot reach the relay (ANKLE_RELAY_URL: Redis at 127.0.0.1:")
    assert "s3cret" not in line


def test_a_schema_not_current_without_migrating_is_one_line_and_exit_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.MonkeyPatch.context() as env:
        env.setenv("ANKLE_DATA_DIR", str(tmp_path))
        env.setenv("ANKLE_MIGRATE_ON_START", "false")
        assert refused(["server", "--port", "0"]) == 1
    line = one_line(capsys)
    assert line.startswith("error: the database's schema is at revision none (empty)"), line
    assert line.endswith("run `ankle db upgrade` (or set ANKLE_MIGRATE_ON_START=true)")
