"""Request bodies are refused at the door: too large (413) or not text (422), before any route
or validator reads them, while the server goes on answering everyone else."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator

import httpx
import pytest

from server.errors import ERRORS_MAX, EXCERPT
from server.routes.uploads import CHUNK_MAX
from station.uploader import CHUNK
from tests.server.live_server import PASSWORD, STRENGTH, Live, World, bearer, login

MiB = 1024 * 1024


def test_the_station_chunk_fits_the_upload_limit() -> None:
    assert CHUNK < CHUNK_MAX <= CHUNK + 128 * 1024


@pytest.mark.asyncio
async def test_a_declared_length_over_the_limit_is_refused_before_the_body_is_sent(
    live: Live,
) -> None:
    """Only the headers go out: the 413 comes back without the server waiting for a byte."""
    port = live.client.base_url.port
    assert port is not None
    head = (
        "POST /api/v1/auth/login HTTP/1.1\r\nHost: 127.0.0.1\r\n"
        f"Content-Type: application/json\r\nContent-Length: {25 * MiB}\r\n\r\n"
    ).encode()
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(head)
        await writer.drain()
        answer = await asyncio.wait_for(reader.read(4096), 10)
    finally:
        writer.close()
    status_line, _, rest = answer.partition(b"\r\n")
    assert b" 413 " in status_line, answer
    body = json.loads(rest.split(b"\r\n\r\n", 1)[1])
    assert body == {
        "detail": "the request body is larger than 1 MiB (1048576 bytes), "
        "the most this route accepts"
    }


@pytest.mark.asyncio
async def test_a_25_mib_chunked_json_array_to_login_is_refused_and_health_answers_meanwhile(
    live: Live, world: World
) -> None:
    """No Content-Length: the bytes are counted as they come. Meanwhile /health answers:
    the body holds back its second half until a health poll sent after the upload began
    has come back. The server, the uploader and the poller share this test's one event
    loop, so how fast it answers says more of this process's share of a busy machine than
    of the server: the abuse benchmark (``lab/abuse.py``) times /health from a process of
    its own against a server of its own."""
    piece = b"1," * (32 * 1024)
    pieces = 25 * MiB // len(piece)
    uploading = asyncio.Event()
    answered_meanwhile = asyncio.Event()
    meanwhile: list[bool] = []

    async def array() -> AsyncIterator[bytes]:
        uploading.set()
        yield b"["
        for i in range(pieces):
            if i == pieces // 2:
                await asyncio.wait_for(answered_meanwhile.wait(), 60)
            yield piece
            await asyncio.sleep(0)
        yield b"1]"

    async def poll(base_url: str) -> list[int]:
        statuses: list[int] = []
        async with httpx.AsyncClient(base_url=base_url, timeout=30) as other:
            while not answered_meanwhile.is_set():
                sent_during_upload = uploading.is_set()
                statuses.append((await other.get("/health")).status_code)
                if sent_during_upload and not answered_meanwhile.is_set():
                    answered_meanwhile.set()
                    meanwhile.append(True)
                await asyncio.sleep(0.02)
        return statuses

    poller = asyncio.create_task(poll(str(live.client.base_url)))
    try:
        r = await live.client.post(
            "/auth/login",
            content=array(),
            headers={"Content-Type": "application/json"},
            timeout=120,
        )
    finally:
        answered_meanwhile.set()  # the poller stops even if the upload failed
        statuses = await poller
    assert r.status_code == 413
    assert "1 MiB" in r.json()["detail"]
    assert meanwhile, "no /health answer came back while the body was being sent"
    assert statuses and all(status == 200 for status in statuses), statuses
    # The route never ran: nothing was counted against anyone, and the server still works.
    assert await login(live.client, "t1@clinic.test")


@pytest.mark.asyncio
async def test_an_upload_chunk_has_its_own_limit(live: Live, world: World) -> None:
    station = bearer(world.s1)
    url = "/uploads/5b0c1d6e-8f4a-4c55-9a64-0c1f5a2e7d10"
    r = await live.client.patch(
        url, content=b"\0" * (CHUNK_MAX + 1), headers={**station, "Upload-Offset": "0"}
    )
    assert r.status_code == 413
    assert str(CHUNK_MAX) in r.json()["detail"]

    async def stream() -> AsyncIterator[bytes]:
        for _ in range(3):
            yield b"\0" * CHUNK

    r = await live.client.patch(url, content=stream(), headers={**station, "Upload-Offset": "0"})
    assert r.status_code == 413
    assert (await live.client.head(url, headers=station)).status_code == 404  # nothing held
    # A JSON route keeps the smaller limit.
    big = {"display_name": "x", "notes": "n" * (CHUNK_MAX - 100)}
    r = await live.client.post("/patients", json=big, headers=bearer(world.t1))
    assert r.status_code == 413


@pytest.mark.asyncio
async def test_a_422_quotes_only_an_excerpt_of_a_large_input(live: Live) -> None:
    r = await live.client.post("/auth/login", json={"email": "e" * 900_000, "password": PASSWORD})
    assert r.status_code == 422
    assert len(r.content) < 2000
    (error,) = r.json()["detail"]
    assert error["loc"] == ["body", "email"]
    assert error["input"] == "e" * EXCERPT + "…"

    r = await live.client.post("/auth/login", json=list(range(150_000)))
    assert r.status_code == 422 and len(r.content) < 2000
    (error,) = r.json()["detail"]
    assert error["input"].startswith("[0, 1, 2, 3") and error["input"].endswith("…")
    assert len(error["input"]) <= EXCERPT + 1

    extra = {f"field{i}": i for i in range(5000)}
    r = await live.client.post("/auth/login", json={"email": "a@b.c", "password": "p", **extra})
    detail = r.json()["detail"]
    assert r.status_code == 422 and len(detail) == ERRORS_MAX + 1
    assert detail[-1]["msg"] == f"and {5000 - ERRORS_MAX} more invalid values"
    # A small input is quoted as it is.
    r = await live.client.post("/auth/login", json={"email": ["a"], "password": "p"})
    assert r.json()["detail"][0]["input"] == ["a"]


# -- text that is not Unicode ----------------------------------------------------------------

LONE = '"\\ud800"'  # JSON text: valid JSON, but no Unicode character


@pytest.mark.asyncio
@pytest.mark.parametrize(
    ("template", "loc"),
    [
        ('{"email": %s, "password": "x"}', ["body", "email"]),
        ('{"email": "a@b.c", "password": %s}', ["body", "password"]),
        ('{"email": "a@b.c", "password": "ok\\\\", "x": [1, {"y": %s}]}', ["body", "x", 1, "y"]),
    ],
)
async def test_a_lone_surrogate_in_a_login_is_a_422_naming_the_field(
    live: Live, template: str, loc: list[str | int]
) -> None:
    r = await live.client.post(
        "/auth/login",
        content=(template % LONE).encode(),
        headers={"Content-Type": "application/json"},
    )
    assert r.status_code == 422, r.text
    (error,) = r.json()["detail"]
    assert error["loc"] == loc
    assert "lone surrogate \\ud800" in error["msg"]


@pytest.mark.asyncio
async def test_a_lone_surrogate_changes_nothing_anywhere(live: Live, world: World) -> None:
    t1 = bearer(world.t1)
    before = (await live.client.get("/patients", headers=t1)).json()
    rx_before = (await live.client.get(f"/patients/{world.p1}/prescriptions", headers=t1)).json()
    attempts = [
        ("POST", "/patients", f'{{"display_name": {LONE}}}'),
        ("POST", "/patients", '{"display_name": "ok", "notes": "a\\udc00b"}'),
        ("PATCH", f"/patients/{world.p1}", f'{{"notes": {LONE}}}'),
        ("POST", "/patients", f'{{"display_name": "ok", {LONE}: 1}}'),
        (
            "POST",
            f"/patients/{world.p1}/prescriptions",
            json.dumps({**STRENGTH, "title": "LONE"}).replace('"LONE"', LONE),
        ),
    ]
    for method, path, text in attempts:
        r = await live.client.request(
            method, path, content=text.encode(), headers={**t1, "Content-Type": "application/json"}
        )
        assert r.status_code == 422, (path, r.text)
        assert "lone surrogate" in r.json()["detail"][0]["msg"]
    assert (await live.client.get("/patients", headers=t1)).json() == before
    rx_after = (await live.client.get(f"/patients/{world.p1}/prescriptions", headers=t1)).json()
    assert rx_after == rx_before
    # A pair of surrogates is one character, and an escaped backslash is not an escape.
    for text, name in [
        ('{"display_name": "Pat \\ud83d\\ude00"}', "Pat \U0001f600"),
        ('{"display_name": "Pat \\\\ud800"}', "Pat \\ud800"),
    ]:
        r = await live.client.post(
            "/patients", content=text.encode(), headers={**t1, "Content-Type": "application/json"}
        )
        assert r.status_code == 201, r.text
        assert r.json()["display_name"] == name


UNPARSABLE = [
    pytest.param(b'{"email": "a@b.c", "password": ', "Expecting value", id="cut-off"),
    pytest.param(b'{"email": "\xff\xfe", "password": "x"}', "not utf-8 text", id="not-utf8"),
    pytest.param(b'{"email": ' + b"9" * 5000 + b"}", "more than 4300 digits", id="5000-digits"),
    pytest.param(b"[" * 1001 + b"]" * 1001, "nested too deeply", id="nested-1001"),
    pytest.param(b'{"a":' * 50000 + b"1" + b"}" * 50000, "nested too deeply", id="nested-50000"),
]


@pytest.mark.asyncio
async def test_a_surrogate_encoded_in_raw_bytes_is_a_422_naming_the_field(live: Live) -> None:
    """json reads the bytes of a UTF-16 surrogate (not UTF-8) as that surrogate; the field
    refuses it, as it does the escape."""
    r = await live.client.post(
        "/auth/login",
        content=b'{"email": "\xed\xa0\x80", "password": "x"}',
        headers={"Content-Type": "application/json"},
    )
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == ["body", "email"]


@pytest.mark.asyncio
@pytest.mark.parametrize(("body", "why"), UNPARSABLE)
async def test_every_body_that_does_not_parse_is_the_same_422(
    live: Live, world: World, body: bytes, why: str
) -> None:
    """Whatever stops a body parsing (FastAPI answered a 5,000-digit number, deep nesting
    and bytes that are not UTF-8 with a bare 400 "There was an error parsing the body"),
    every body sent as JSON is told the same sentence, with the reason beside it."""
    t1 = bearer(world.t1)
    for path, headers in (
        ("/auth/login", {"Content-Type": "application/json"}),
        ("/patients", {**t1, "Content-Type": "application/json; charset=utf-8"}),
        (f"/patients/{world.p1}/prescriptions", {**t1, "Content-Type": "application/json"}),
        (f"/stations/{world.s1_spare_id}/revoke", {**t1, "Content-Type": "application/json"}),
    ):
        r = await live.client.post(path, content=body, headers=headers)
        assert r.status_code == 422, (path, r.text)
        (error,) = r.json()["detail"]
        assert error["type"] == "json_invalid" and error["msg"] == "The request is not valid JSON."
        assert why in error["ctx"]["error"], error
    assert (await live.client.get("/patients", headers=t1)).json()[0]["display_name"] == "Pat One"


@pytest.mark.asyncio
async def test_a_body_sent_without_a_content_type_is_not_parsed_as_json(
    live: Live, world: World
) -> None:
    """FastAPI reads an untyped body as bytes: an upload's chunk sent so (binary, not
    UTF-8) is taken, and a JSON route sent one says it wants an object, not that the JSON
    is broken."""
    from tests.server.test_series import recording_bytes, samples

    sid = "3f1d7c0e-9b2a-4c5d-8e6f-7a8b9c0d1e2f"
    data = recording_bytes(sid, samples()[:200], world.s1_id, world.p1, world.rx1)
    r = await live.client.patch(
        f"/uploads/{sid}", content=data, headers={**bearer(world.s1), "Upload-Offset": "0"}
    )
    assert r.status_code == 204, r.text
    r = await live.client.post("/auth/login", content=b"[" * 5000)
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["type"] == "model_attributes_type"
