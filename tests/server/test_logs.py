"""ANKLE_LOG_FORMAT=json: a real ``ankle server`` writes one JSON object a line, with the
request id on an HTTP request's lines and a link id on a live link's."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import httpx
import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from server.cli import wait_healthy
from tests.processes import free_port, stop


def _serve(tmp_path: Path, log_format: str | None) -> tuple[subprocess.Popen[bytes], str, Path]:
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("ANKLE_")}
    if log_format is not None:
        env["ANKLE_LOG_FORMAT"] = log_format
    log = tmp_path / "server.log"
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "ankle", "server", "--data-dir", "data", "--port", str(port)],
            cwd=tmp_path,
            env=env,
            # text: uvicorn's access lines go to stdout; json: every log line to stderr, and
            # stdout keeps only the start-up banner
            stdout=out if log_format is None else subprocess.DEVNULL,
            stderr=out,
        )
    url = f"http://127.0.0.1:{port}"
    wait_healthy(url, proc, timeout=120)
    return proc, url, log


def test_json_lines_carry_request_and_link_ids(tmp_path: Path) -> None:
    proc, url, log = _serve(tmp_path, "json")
    try:
        given = httpx.get(f"{url}/api/v1/health", headers={"X-Request-ID": "probe-1234abcd"})
        assert given.headers["x-request-id"] == "probe-1234abcd"
        made = httpx.get(f"{url}/api/v1/patients")
        assert made.status_code == 401
        assert re.fullmatch(r"[0-9a-f]{32}", made.headers["x-request-id"])
        odd = httpx.get(f"{url}/api/v1/health", headers={"X-Request-ID": "bad id\twith tab"})
        assert odd.headers["x-request-id"] != "bad id\twith tab"  # a new one, not an echo
        with pytest.raises(InvalidStatus):
            connect(f"{url.replace('http', 'ws')}/ws/station", open_timeout=10).close()
    finally:
        stop(proc)
    lines: list[dict[str, Any]] = [
        json.loads(line) for line in log.read_text().splitlines() if line.strip()
    ]  # every line is one JSON object, or this fails
    assert all({"time", "level", "logger", "message"} <= set(line) for line in lines)

    def one(pattern: str) -> dict[str, Any]:
        found = [line for line in lines if re.search(pattern, line["message"])]
        assert found, f"no line matching {pattern!r} in {[x['message'] for x in lines]}"
        return found[0]

    access = [line for line in lines if line["logger"] == "uvicorn.access"]
    assert access and all(line["request_id"] for line in access)
    ids = {line["request_id"] for line in access}
    assert {"probe-1234abcd", made.headers["x-request-id"]} <= ids
    assert one(r"GET /api/v1/patients HTTP.* 401")["request_id"] == made.headers["x-request-id"]
    link = one(r"WebSocket /ws/station")
    assert re.fullmatch(r"[0-9a-f]{16}", link["link_id"]) and link["request_id"] is None


def test_text_stays_the_default(tmp_path: Path) -> None:
    proc, url, log = _serve(tmp_path, None)
    try:
        assert "x-request-id" in httpx.get(f"{url}/api/v1/health").headers
    finally:
        stop(proc)
    text = log.read_text()
    assert "GET /api/v1/health" in text and not text.lstrip().startswith("{")


def test_an_unknown_log_format_is_refused_naming_the_setting(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("ANKLE_")}
    env["ANKLE_LOG_FORMAT"] = "xml"
    done = subprocess.run(
        [sys.executable, "-m", "ankle", "server", "--data-dir", "data", "--port", "0"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2
    assert done.stderr.splitlines() == ["error: ANKLE_LOG_FORMAT: Input should be 'text' or 'json'"]
