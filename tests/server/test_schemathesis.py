"""Property-based API tests generated from the server's OpenAPI document.

Schemathesis makes requests from each operation's schema, valid and invalid, and sends them
to a real server process (``ankle server`` on a copy of the seeded database; its log, with
any traceback, is ``server.log`` in its data directory). The document is the app's own,
loaded at import so that each operation is a test, and checked to be exactly what the
running server serves at ``/api/v1/openapi.json``. Every answer must not be a server error
and must match the schema published for its status code.

Each call carries the token its operation is meant for: the home station's (of the second
therapist's patient, so that a fuzzed ``POST /stations/{id}/revoke`` cannot cut it off)
for the station's routes, the admin's for account management, the first therapist's for
the rest; ``POST /auth/logout`` gets a token of its own. About 12 examples per operation:
under 30 s in all.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import requests
import schemathesis
from hypothesis import HealthCheck, Phase, settings
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (
    response_schema_conformance,
    status_code_conformance,
)

from server.cli import wait_healthy
from tests.server.live_server import PASSWORD, World
from webui.app import create_app  # what `ankle server` runs: the API with the dashboard

SQLITE_INT_MAX = 2**63 - 1
"""Integer ids and offsets beyond SQLite's 64-bit range are a known server error (see
``test_ids_beyond_sqlite_range_are_not_server_errors``); they are left out of the
generated requests so that the fuzzing finds what is new."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Served:
    def __init__(self, url: str, proc: subprocess.Popen[bytes], log: Path) -> None:
        self.url = url
        self.proc = proc
        self.log = log


@pytest.fixture(scope="module")
def served(
    seeded: tuple[Path, World], tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Served]:
    """``ankle server`` in its own process, on a private copy of the seeded database."""
    template, _ = seeded
    data_dir = tmp_path_factory.mktemp("schemathesis")
    for f in template.glob("ankle.db*"):
        shutil.copy(f, data_dir / f.name)
    port = free_port()
    log = data_dir / "server.log"
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "ankle", "server"],
            env={**os.environ, "ANKLE_DATA_DIR": str(data_dir), "ANKLE_PORT": str(port)},
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    try:
        url = f"http://127.0.0.1:{port}"
        wait_healthy(url, proc, timeout=30.0)
        yield Served(url, proc, log)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


schema = schemathesis.openapi.from_dict(create_app().openapi(), config=schemathesis.Config())
"""The document the server publishes (``test_the_served_schema_is_the_one_tested`` checks
that the running server serves exactly this), loaded at import so that pytest gets one test
per operation."""


@pytest.fixture(scope="module")
def http(served: Served) -> Iterator[requests.Session]:
    with requests.Session() as session:
        yield session


def _token(case: schemathesis.Case[Any], world: World, http: requests.Session, url: str) -> str:
    operation = case.operation
    security = operation.definition.raw.get("security") or []
    if any("StationToken" in s for s in security):
        return world.s2
    if operation.path == "/api/v1/users":
        return world.admin
    if operation.path == "/api/v1/auth/logout":
        r = http.post(
            f"{url}/api/v1/auth/login", json={"email": "t1@clinic.test", "password": PASSWORD}
        )
        assert r.status_code == 200, r.text
        return str(r.json()["access_token"])
    return world.t1


@schema.parametrize()
@settings(
    max_examples=12,
    phases=[Phase.explicit, Phase.generate],
    suppress_health_check=list(HealthCheck),
    deadline=None,
)
def test_api_answers_within_its_schema_and_never_500(
    case: schemathesis.Case[Any], world: World, served: Served, http: requests.Session
) -> None:
    token = _token(case, world, http, served.url)
    case.call_and_validate(
        base_url=served.url,
        session=http,
        headers={"Authorization": f"Bearer {token}"},
        checks=[not_a_server_error, response_schema_conformance],
        timeout=10,
    )


def test_ids_beyond_sqlite_range_are_not_server_errors(
    world: World, served: Served, http: requests.Session
) -> None:
    big = SQLITE_INT_MAX + 1
    auth = {"Authorization": f"Bearer {world.t1}"}
    calls = [
        ("GET", f"/patients/{big}"),
        ("GET", f"/patients/{big}/prescriptions"),
        ("GET", f"/prescriptions/{big}"),
        ("POST", f"/prescriptions/{big}/cancel"),
        ("POST", f"/stations/{big}/revoke"),
        ("GET", f"/stations?patient_id={big}"),
        ("GET", f"/sessions/{big}"),
        ("GET", f"/sessions?offset={big}"),
        ("GET", f"/audit?patient_id={big}"),
    ]
    status = {
        f"{method} {path}": http.request(
            method, f"{served.url}/api/v1{path}", headers=auth, timeout=10
        ).status_code
        for method, path in calls
    }
    assert all(code < 500 for code in status.values()), status


def test_the_served_schema_is_the_one_tested(served: Served, http: requests.Session) -> None:
    r = http.get(f"{served.url}/api/v1/openapi.json", timeout=10)
    assert r.status_code == 200
    assert r.json() == schema.raw_schema


def test_upload_refusals_are_documented(
    world: World, served: Served, http: requests.Session
) -> None:
    """The upload routes' own refusals (not a UUID, not a recording, no such upload) come
    with a status and a body the OpenAPI document lists, so that a station written from the
    schema can read them; fuzzing rarely makes a valid UUID with garbage bytes."""
    known = "0b7c3c52-8b8e-4a4c-9f3e-2f1f3b1d2a10"
    auth = {"Authorization": f"Bearer {world.s2}"}
    offset = {"Upload-Offset": "0"}
    complete = {"size": 9, "sha256": "0" * 64}
    calls: list[tuple[str, str, str, dict[str, Any], int]] = [
        ("HEAD", "/uploads/{session_id}", known, {}, 404),
        ("HEAD", "/uploads/{session_id}", "not-a-uuid", {}, 422),
        ("PATCH", "/uploads/{session_id}", "not-a-uuid", {"data": b"x", "headers": offset}, 422),
        ("PATCH", "/uploads/{session_id}", known, {"data": b"garbage", "headers": offset}, 422),
        ("POST", "/uploads/{session_id}/complete", "not-a-uuid", {"json": complete}, 422),
        ("POST", "/uploads/{session_id}/complete", known, {"json": complete}, 404),
    ]
    checks = [not_a_server_error, status_code_conformance, response_schema_conformance]
    for method, path, session_id, kwargs, expected in calls:
        operation = schema["/api/v1" + path][method]
        headers = {**auth, **kwargs.pop("headers", {})}
        url = f"{served.url}/api/v1{path.format(session_id=session_id)}"
        r = http.request(method, url, headers=headers, timeout=10, **kwargs)
        assert r.status_code == expected, (method, url, r.status_code, r.text)
        case = operation.Case(path_parameters={"session_id": session_id}, headers=headers)
        case.validate_response(r, checks=checks)
