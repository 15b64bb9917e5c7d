"""HTTP's own answers agree with the routes and with OpenAPI: a 405's ``Allow`` lists every
method of the path, downloads answer HEAD, and OpenAPI documents the Range answers."""

from __future__ import annotations

import pytest

from tests.server.live_server import Live, World, bearer
from tests.server.test_report import TODAY, exports, rows_at
from tests.server.test_series import upload

pytestmark = pytest.mark.asyncio


async def test_a_405_allows_every_method_the_path_serves(live: Live, world: World) -> None:
    """The router answered from the first route that matched the path: ``Allow: GET`` on
    ``/patients/{id}``, which PATCH changes, and no POST on ``/patients``."""
    t1 = bearer(world.t1)
    for path, allowed in [
        (f"/patients/{world.p1}", "GET, PATCH"),
        ("/patients", "GET, POST"),
        (f"/uploads/{'0' * 8}-0000-4000-8000-{'0' * 12}", "HEAD, PATCH"),
        ("/sessions/1/download/csv", "GET, HEAD"),
    ]:
        r = await live.client.request("PUT", path, headers=t1)
        assert r.status_code == 405, (path, r.text)
        assert r.headers["allow"] == allowed, path


async def test_a_download_answers_head_with_the_headers_of_get(live: Live, world: World) -> None:
    """HEAD was a 405. It now gives the headers a GET gives, no body, and is no export."""
    session_id = await upload(live, world, rows_at(TODAY))
    t1 = bearer(world.t1)
    for fmt in ("csv", "rec"):
        url = f"/sessions/{session_id}/download/{fmt}"
        got = await live.client.get(url, headers=t1)
        audited = len(await exports(live, world))
        head = await live.client.head(url, headers=t1)
        assert head.status_code == 200, fmt
        assert head.content == b""
        for name in ("content-length", "content-type", "content-disposition", "etag"):
            assert head.headers[name] == got.headers[name], (fmt, name)
        assert head.headers["x-content-sha256"] == got.headers["x-content-sha256"]
        assert len(await exports(live, world)) == audited, "a HEAD sends no data"


async def test_openapi_documents_the_range_answers_of_a_download(live: Live) -> None:
    spec = (await live.client.get("/openapi.json")).json()
    operations = spec["paths"]["/api/v1/sessions/{session_id}/download/{fmt}"]
    assert {"get", "head"} <= set(operations)
    for op in ("get", "head"):
        assert {"200", "206", "400", "416"} <= set(operations[op]["responses"]), op
