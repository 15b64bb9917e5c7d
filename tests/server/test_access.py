"""Who may call what: every route the server serves, against every kind of caller.

The routes come from the app's own OpenAPI document (the app ``ankle server`` runs: the API
with the dashboard), read at test time; ``ACCESS`` says what each identity must be answered
on each of them. A route in OpenAPI that ``ACCESS`` does not cover fails the test, with the
row to add; a row for a route that no longer exists fails too. WebSocket routes and the
routes left out of OpenAPI (pages, scripts) are not in the document: they are listed here
explicitly, and the app's own route list is checked against those lists.

The identities: ``anon`` (no token), ``wrong`` (a token nobody was given), ``station`` (s1's
token: the station of the owner's patient), ``other`` (t2, another therapist), ``admin`` and
``owner`` (t1, whose patient p1 has stations s1 and a spare, prescription rx1 and a recorded
session). Each route is called by each identity in that order, the owner last, so that a
change the owner may make happens after every other identity saw the record unchanged.
Another therapist reaching for the owner's records gets the very same 404, byte for byte,
as for a record that does not exist.
"""

from __future__ import annotations

import hashlib
import re
import uuid
from collections.abc import AsyncIterator, Callable, Mapping
from contextlib import AbstractAsyncContextManager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import pytest_asyncio
from fastapi import FastAPI
from fastapi.routing import iter_route_contexts
from starlette.routing import WebSocketRoute
from websockets.asyncio.client import connect
from websockets.exceptions import InvalidStatus

from server.config import Settings
from server.routes import API_PREFIX
from sessions.recording import SAMPLE_DTYPE
from tests.server.live_server import (
    PASSWORD,
    STRENGTH,
    Live,
    Seeds,
    Store,
    World,
    bearer,
    on_store,
    running,
)
from tests.server.test_series import recording_bytes, upload
from tests.server.ws_client import station_ws, viewer_ws, ws_url
from webui.app import create_app  # what `ankle server` runs: the API with the dashboard

IDENTITIES = ("anon", "wrong", "station", "other", "admin", "owner")
WRONG_TOKEN = "x" * 43
MISSING_ID = 999_999


@dataclass(frozen=True)
class Records:
    """What the calls name: the seeded world, a session recorded on s1, a fresh upload."""

    world: World
    session_id: int
    upload_id: str
    upload: bytes
    spare_user_id: int
    """A therapist no identity signs in as: the account the admin routes change."""

    def token(self, identity: str) -> str | None:
        if identity == "wrong":
            return WRONG_TOKEN
        return self.world.token({"other": "t2", "owner": "t1"}.get(identity, identity))


RECORD_OF: dict[str, Callable[[Records], object]] = {
    "patient_id": lambda r: r.world.p1,
    "prescription_id": lambda r: r.world.rx1,
    "station_id": lambda r: r.world.s1_id,
    "session_id": lambda r: r.session_id,
    "fmt": lambda r: "csv",
    "name": lambda r: "uPlot.iife.min.js",
    "ticket": lambda r: "t" * 43,  # made up: no ticket was issued
    "path": lambda r: "index.html",
}
"""Which record a path parameter names, unless a row says otherwise (``at``)."""


def answers(
    owner: int, admin: int, other: int, station: int = 403, anon: int = 401
) -> dict[str, int]:
    """The status each identity gets: a wrong token is always 401, as no token is; a valid
    token on a route for the other kind of caller (a station's on a therapist's route, a
    user's on a station's) is 403."""
    return {
        "anon": anon,
        "wrong": anon,
        "station": station,
        "other": other,
        "admin": admin,
        "owner": owner,
    }


PUBLIC = dict.fromkeys(IDENTITIES, 200)
ANY_USER = answers(owner=200, admin=200, other=200)
OWNER_OR_ADMIN = answers(owner=200, admin=200, other=404)
OWNER_WRITES = answers(owner=200, admin=403, other=404)
ADMIN_ONLY = answers(owner=403, admin=200, other=403)
STATION_ONLY = answers(owner=403, admin=403, other=403, station=200)


@dataclass(frozen=True)
class Call:
    """How to call one route, and what each identity must be answered."""

    expect: Mapping[str, int]
    body: Any = None
    """JSON body, or a function of the records giving it."""
    content: Callable[[Records], bytes] | None = None
    headers: Mapping[str, str] = field(default_factory=dict)
    at: Mapping[str, Callable[[Records], object]] = field(default_factory=dict)
    """Records for path parameters that do not name ``RECORD_OF``'s."""
    last: bool = False
    """Run after every other route (it ends the callers' sign-ins)."""


NEW_USER = {
    "email": "n@clinic.test",
    "name": "N",
    "role": "therapist",
    "password": "quiet lantern ninety",
}


def upload_done(r: Records) -> dict[str, Any]:
    return {"size": len(r.upload), "sha256": hashlib.sha256(r.upload).hexdigest()}


UPLOAD = {"session_id": lambda r: r.upload_id}
SPARE_USER = {"user_id": lambda r: r.spare_user_id}

ACCESS: dict[tuple[str, str], Call] = {
    ("GET", "/health"): Call(PUBLIC),
    ("GET", "/schemas/ws"): Call(PUBLIC),
    ("GET", "/fhir/CodeSystem/session-measures"): Call(PUBLIC),  # definitions, no patient
    (
        "POST",
        "/auth/login",
    ): Call(PUBLIC, body={"email": "t1@clinic.test", "password": PASSWORD}),
    ("GET", "/auth/me"): Call(ANY_USER),
    ("POST", "/auth/password"): Call(
        ANY_USER, body={"current_password": PASSWORD, "new_password": "a brand new passphrase"}
    ),
    ("GET", "/users"): Call(ADMIN_ONLY),
    ("POST", "/users"): Call(answers(owner=403, admin=201, other=403), body=NEW_USER),
    ("POST", "/users/{user_id}/reset-password"): Call(ADMIN_ONLY, at=SPARE_USER),
    ("POST", "/users/{user_id}/deactivate"): Call(ADMIN_ONLY, at=SPARE_USER),
    ("POST", "/users/{user_id}/reactivate"): Call(ADMIN_ONLY, at=SPARE_USER),
    ("GET", "/patients"): Call(ANY_USER),
    ("GET", "/patients/attention"): Call(ANY_USER),
    ("POST", "/patients"): Call(
        answers(owner=201, admin=403, other=201), body={"display_name": "X"}
    ),
    ("GET", "/patients/{patient_id}"): Call(OWNER_OR_ADMIN),
    ("PATCH", "/patients/{patient_id}"): Call(OWNER_WRITES, body={"notes": "better"}),
    ("GET", "/patients/{patient_id}/progress"): Call(OWNER_OR_ADMIN),
    ("GET", "/exercises"): Call(ANY_USER),
    ("GET", "/exercises/limits"): Call(ANY_USER),
    ("GET", "/patients/{patient_id}/prescriptions"): Call(OWNER_OR_ADMIN),
    ("POST", "/patients/{patient_id}/prescriptions"): Call(
        answers(owner=201, admin=403, other=404), body=STRENGTH
    ),
    ("GET", "/prescriptions/{prescription_id}"): Call(OWNER_OR_ADMIN),
    ("PATCH", "/prescriptions/{prescription_id}"): Call(OWNER_WRITES, body={**STRENGTH, "sets": 2}),
    ("POST", "/prescriptions/{prescription_id}/cancel"): Call(OWNER_WRITES),
    ("POST", "/patients/{patient_id}/stations"): Call(
        answers(owner=201, admin=201, other=404), body={"name": "New"}
    ),
    ("GET", "/stations"): Call(ANY_USER),
    ("POST", "/stations/{station_id}/revoke"): Call(
        OWNER_OR_ADMIN, at={"station_id": lambda r: r.world.s1_spare_id}
    ),
    ("GET", "/stations/{station_id}/scene"): Call(OWNER_OR_ADMIN),
    ("POST", "/stations/{station_id}/scene/ticket"): Call(OWNER_OR_ADMIN),
    ("GET", "/station/me"): Call(STATION_ONLY),
    ("GET", "/station/prescriptions"): Call(STATION_ONLY),
    ("GET", "/station/progress"): Call(STATION_ONLY),
    ("GET", "/sessions"): Call(ANY_USER),
    ("GET", "/sessions/{session_id}"): Call(OWNER_OR_ADMIN),
    ("GET", "/sessions/{session_id}/download/{fmt}"): Call(OWNER_OR_ADMIN),
    ("HEAD", "/sessions/{session_id}/download/{fmt}"): Call(OWNER_OR_ADMIN),
    ("GET", "/sessions/{session_id}/series"): Call(OWNER_OR_ADMIN),
    ("GET", "/sessions/{session_id}/replay"): Call(OWNER_OR_ADMIN),
    ("GET", "/sessions/{session_id}/replay.viser"): Call(OWNER_OR_ADMIN),
    ("GET", "/patients/{patient_id}/report.pdf"): Call(OWNER_OR_ADMIN),
    ("GET", "/patients/{patient_id}/fhir"): Call(OWNER_OR_ADMIN),
    # An upload in the order a station makes one: bytes, where it stands, complete.
    ("PATCH", "/uploads/{session_id}"): Call(
        answers(owner=403, admin=403, other=403, station=204),
        content=lambda r: r.upload,
        headers={"Upload-Offset": "0"},
        at=UPLOAD,
    ),
    ("HEAD", "/uploads/{session_id}"): Call(STATION_ONLY, at=UPLOAD),
    ("POST", "/uploads/{session_id}/complete"): Call(
        answers(owner=403, admin=403, other=403, station=201), body=upload_done, at=UPLOAD
    ),
    ("GET", "/audit"): Call(ANY_USER),
    # Archiving revokes the patient's stations and freezes the record: after everything else.
    ("POST", "/patients/{patient_id}/archive"): Call(OWNER_WRITES, last=True),
    # Archiving revoked the station: its token is invalid from then on.
    ("POST", "/patients/{patient_id}/unarchive"): Call({**OWNER_WRITES, "station": 401}, last=True),
    ("POST", "/auth/logout"): Call(
        answers(owner=204, admin=204, other=204, station=401), last=True
    ),
}
"""(method, path under ``/api/v1``) → the call. Run in this order."""

WEBSOCKETS: dict[str, dict[str, bool]] = {
    "/ws/station": {**dict.fromkeys(IDENTITIES, False), "station": True},
    "/ws/live/{station_id}": {**dict.fromkeys(IDENTITIES, False), "admin": True, "owner": True},
    # The 3D view: a ticket in the path opens it, never a bearer token (a made-up ticket here).
    "/scene/{ticket}": dict.fromkeys(IDENTITIES, False),
}
"""WebSocket route → whether each identity's handshake is accepted (else HTTP 403)."""

UNLISTED: dict[str, int] = {
    "/api/v1/openapi.json": 200,
    "/api/v1/docs": 200,
    "/api/v1/replay/viewer": 400,  # plays only a blob: URL the dashboard made
    "/": 307,
    "/favicon.ico": 200,
    "/app": 307,
    "/app/": 307,
    "/app/login": 200,
    "/app/patients": 200,
    "/app/patients/{patient_id}": 200,
    "/app/patients/{patient_id}/prescribe": 200,
    "/app/live/{station_id}": 200,
    "/app/sessions/{session_id}": 200,
    "/vendor/{name}": 200,
    "/static/js/axes.js": 200,
    "/app/accounts": 200,
    "/app/password": 200,
    # The 3D view's proxy: nothing without a ticket (a made-up one here).
    "/scene": 403,
    "/scene/": 403,
    "/scene/{ticket}": 403,
    "/scene/{ticket}/{path:path}": 403,
    # Prometheus: loopback callers only (this test's client is one), tests/server/test_metrics.py
    "/metrics": 200,
}
"""GET routes left out of OpenAPI → what a caller without a token gets: pages and scripts
that carry no record (each page asks the API, with the therapist's token, for what it
shows). ``/static`` is a folder of files, not a route."""


def operations(app: FastAPI) -> list[tuple[str, str]]:
    """Every (method, path under API_PREFIX) in the app's OpenAPI document."""
    out = []
    for path, item in app.openapi()["paths"].items():
        assert path.startswith(API_PREFIX), f"{path} is outside {API_PREFIX}"
        for method in item:
            if method in {"get", "put", "post", "patch", "delete", "head", "options"}:
                out.append((method.upper(), path.removeprefix(API_PREFIX)))
    return out


def parameters(path: str) -> list[str]:
    return re.findall(r"{(\w+)(?::\w+)?}", path)


def concrete(path: str, call: Call | None, records: Records | None) -> str:
    """``path`` with each parameter replaced by the record it names (None: a missing id)."""
    values = {}
    for name in parameters(path):
        if records is None:
            values[name] = {"fmt": "csv", "path": "index.html"}.get(name, str(MISSING_ID))
            continue
        chosen = (call.at if call else {}).get(name) or RECORD_OF.get(name)
        assert chosen is not None, f"{path}: say which record {{{name}}} names (Call(at=...))"
        values[name] = str(chosen(records))
    return re.sub(r"{(\w+)(?::\w+)?}", lambda m: values[m.group(1)], path)


def coverage(ops: list[tuple[str, str]]) -> str:
    """What ACCESS lacks or has too many of against the OpenAPI operations ``ops``."""
    missing = [op for op in ops if op not in ACCESS]
    stale = [op for op in ACCESS if op not in ops]
    problems = []
    if missing:
        rows = "\n".join(
            f"    {op!r}: Call(answers(owner=..., admin=..., other=..., station=403)),"
            for op in missing
        )
        problems.append(
            "routes in OpenAPI with no row in ACCESS (tests/server/test_access.py): add each, "
            "with the status every identity must get (and body=, at= if the call needs "
            f"them):\n{rows}"
        )
    if stale:
        problems.append(f"rows in ACCESS for routes that no longer exist: remove {stale}")
    return "\n".join(problems)


def test_the_table_covers_exactly_the_routes_in_openapi(tmp_path: Path) -> None:
    """Fails for a new route until its row says who may call it."""
    problems = coverage(operations(create_app(Settings(data_dir=tmp_path))))
    assert not problems, problems


def test_websocket_and_unlisted_routes_are_listed(tmp_path: Path) -> None:
    """Routes OpenAPI does not show must be listed here, or they would escape the matrix."""
    app = create_app(Settings(data_dir=tmp_path))
    websockets: set[str] = set()
    unlisted: set[str] = set()
    for context in iter_route_contexts(app.routes):
        if context.path is None:  # a mount: /static, a folder of files
            continue
        if isinstance(context.route, WebSocketRoute):
            websockets.add(context.path)
        elif getattr(context.route, "include_in_schema", True) is False:
            unlisted.add(context.path)
    assert websockets == set(WEBSOCKETS), (
        f"WebSocket routes {sorted(websockets ^ set(WEBSOCKETS))} differ from WEBSOCKETS: "
        "list each with the identities whose handshake is accepted"
    )
    assert unlisted == set(UNLISTED), (
        f"routes left out of OpenAPI {sorted(unlisted ^ set(UNLISTED))} differ from UNLISTED: "
        "list each with what a caller without a token gets"
    )


@pytest_asyncio.fixture
async def served(
    seeds: Seeds, store: Store, seeded_store: tuple[Path | str, World], tmp_path: Path
) -> AsyncIterator[Live]:
    """``ankle server``'s app (API and dashboard) on a private copy of the seeded database."""
    with on_store(seeds, store, tmp_path, seeded_store[0]) as settings:
        async with running(settings, create_app) as server:
            yield server


def short_recording() -> np.ndarray[Any, Any]:
    rows = np.zeros(300, SAMPLE_DTYPE)
    rows["t"] = np.arange(300) / 100.0
    rows["wall"] = 1_700_000_000.0 + rows["t"]
    return rows


@pytest_asyncio.fixture
async def records(served: Live, world: World) -> Records:
    session_id = await upload(served, world, short_recording())
    upload_id = str(uuid.uuid4())
    data = recording_bytes(upload_id, short_recording(), world.s1_id, world.p1, world.rx1)
    spare = await served.client.post(
        "/users",
        json={**NEW_USER, "email": "spare@clinic.test", "name": "Spare"},
        headers=bearer(world.admin),
    )
    assert spare.status_code == 201, spare.text
    return Records(world, session_id, upload_id, data, spare.json()["id"])


async def call(
    client: httpx.AsyncClient, method: str, path: str, call: Call, r: Records, token: str | None
) -> httpx.Response:
    body = call.body(r) if callable(call.body) else call.body
    return await client.request(
        method,
        path,
        json=body,
        content=call.content(r) if call.content else None,
        headers={**call.headers, **(bearer(token) if token else {})},
    )


@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_every_route_answers_every_identity_as_the_table_says(
    served: Live, records: Records
) -> None:
    ops = operations(served.app)
    problems = coverage(ops)
    assert not problems, problems
    ordered = sorted(ops, key=lambda op: (ACCESS[op].last, list(ACCESS).index(op)))
    client, wrong = served.client, []
    for method, template in ordered:
        row = ACCESS[(method, template)]
        path = concrete(template, row, records)
        for identity in IDENTITIES:
            token = records.token(identity)
            r = await call(client, method, path, row, records, token)
            if r.status_code != row.expect[identity]:
                wrong.append(
                    f"{method} {template} as {identity}: {r.status_code}, not "
                    f"{row.expect[identity]} ({r.text[:120]})"
                )
            if r.status_code == 401 and r.headers.get("www-authenticate") != "Bearer":
                wrong.append(f"{method} {template} as {identity}: 401 without WWW-Authenticate")
            if identity == "other" and row.expect["other"] == 404:
                # Someone else's record is indistinguishable from none at all.
                none = await call(
                    client, method, concrete(template, row, None), row, records, token
                )
                if (none.status_code, none.content) != (r.status_code, r.content):
                    wrong.append(
                        f"{method} {template}: another's record answers {r.status_code} "
                        f"{r.content!r}, a missing one {none.status_code} {none.content!r}"
                    )
    assert not wrong, "\n".join(wrong)


@pytest.mark.asyncio
async def test_every_websocket_handshake_is_refused_but_to_whom_the_table_says(
    served: Live, records: Records
) -> None:
    wrong = []
    for template, accepted in WEBSOCKETS.items():
        for identity in IDENTITIES:
            token = records.token(identity) or ""
            opened: AbstractAsyncContextManager[object]
            if template == "/ws/station":
                opened = station_ws(served, token)
            elif template == "/ws/live/{station_id}":
                opened = viewer_ws(served, token, records.world.s1_id)
            else:
                made_up = template.format(ticket="t" * 43)
                opened = connect(ws_url(served, made_up), additional_headers=bearer(token))
            try:
                async with opened:
                    got = True
            except InvalidStatus as exc:
                got = False
                if exc.response.status_code != 403:
                    wrong.append(f"{template} as {identity}: HTTP {exc.response.status_code}")
            if got != accepted[identity]:
                wrong.append(f"{template} as {identity}: {'accepted' if got else 'refused'}")
    assert not wrong, "\n".join(wrong)


@pytest.mark.asyncio
async def test_routes_outside_openapi_show_nothing_without_a_token(
    served: Live, records: Records
) -> None:
    root = f"http://127.0.0.1:{served.client.base_url.port}"
    async with httpx.AsyncClient(base_url=root) as client:
        got = {
            path: (await client.get(concrete(path, None, records))).status_code for path in UNLISTED
        }
    assert got == UNLISTED


# -- what the lists hold ------------------------------------------------------------------------
@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_lists_show_only_the_callers_patients(live: Live, world: World) -> None:
    async def ids(path: str, who: str) -> set[int]:
        r = await live.client.get(path, headers=bearer(world.token(who) or ""))
        assert r.status_code == 200
        return {row["id"] for row in r.json()}

    assert await ids("/patients", "t1") == {world.p1}
    assert await ids("/patients", "t2") == {world.p2}
    assert await ids("/patients", "admin") == {world.p1, world.p2}
    assert await ids("/stations", "t1") == {world.s1_id, world.s1_spare_id}
    assert await ids("/stations", "t2") == {world.s2_id}
    assert await ids("/stations", "admin") == {world.s1_id, world.s1_spare_id, world.s2_id}
    # Filtering by someone else's patient yields nothing rather than their stations.
    assert await ids(f"/stations?patient_id={world.p2}", "t1") == set()


@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_a_station_sees_only_its_own_patient(live: Live, world: World) -> None:
    me = (await live.client.get("/station/me", headers=bearer(world.s1))).json()
    assert me == {
        "id": world.s1_id,
        "name": "Home of Pat One",
        "patient_id": world.p1,
        "patient_display_name": "Pat One",
    }
    rx = (await live.client.get("/station/prescriptions", headers=bearer(world.s2))).json()
    assert [p["id"] for p in rx] == [world.rx2]
    assert rx[0]["body"]["exercise"] == "strength"


@pytest.mark.both_stores
@pytest.mark.asyncio
async def test_station_last_seen_and_online(live: Live, world: World) -> None:
    before = (await live.client.get("/stations", headers=bearer(world.t1))).json()
    assert all(s["last_seen_at"] is None and s["online"] is False for s in before)
    await live.client.get("/station/me", headers=bearer(world.s1))
    after = {
        s["id"]: s for s in (await live.client.get("/stations", headers=bearer(world.t1))).json()
    }
    assert after[world.s1_id]["last_seen_at"] is not None
    assert after[world.s1_spare_id]["last_seen_at"] is None
