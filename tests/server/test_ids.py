"""Ids: 64-bit in the store, and anything outside 1..2**63-1 refused (422 naming the
parameter) on every route, by the one type ``server.deps.Id``."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute, APIWebSocketRoute, iter_route_contexts
from sqlalchemy import text

from server.config import Settings
from server.models import ID_MAX, Patient
from tests.server.live_server import STRENGTH, Live, World, bearer
from webui.app import create_app

pytestmark = pytest.mark.both_stores

ABOVE_INT4 = 2**31 + 7
GOOD = ("1", str(ID_MAX))
BAD = ("0", str(ID_MAX + 1))


def _params(dependant: Dependant) -> list[Any]:
    """The path and query parameters of a route and of all its dependencies."""
    out = [*dependant.path_params, *dependant.query_params]
    for sub in dependant.dependencies:
        out.extend(_params(sub))
    return out


def _names_an_id(name: str) -> bool:
    return name == "id" or name.endswith("_id")


def test_every_id_parameter_of_every_route_is_bounded(tmp_path: Any) -> None:
    app = create_app(Settings(data_dir=tmp_path))
    checked, unbounded = [], []
    for context in iter_route_contexts(app.routes):
        route, path = context.original_route, context.path_format or ""
        if not isinstance(route, APIRoute | APIWebSocketRoute):
            continue
        for param in _params(route.dependant):
            if not _names_an_id(param.name) or param.field_info.annotation is None:
                continue
            if "int" not in str(param.field_info.annotation):
                continue  # an upload's uuid, say
            checked.append((path, param.name))
            # As the route validates it: the bounds pass, one past either is an error.
            verdicts = [not param.validate(v, {}, loc=("x",))[1] for v in GOOD + BAD]
            if verdicts != [True] * len(GOOD) + [False] * len(BAD):
                unbounded.append((path, param.name))
    assert unbounded == []
    # The walk does find them: the patient's, the session's, the live view's.
    paths = {path for path, _ in checked}
    assert {"/api/v1/patients/{patient_id}", "/ws/live/{station_id}"} <= paths
    assert ("/api/v1/sessions", "station_id") in checked
    assert len(checked) >= 25


@pytest.mark.asyncio
@pytest.mark.parametrize(
    ("path", "params", "where", "name"),
    [
        ("/patients/0", {}, "path", "patient_id"),
        ("/patients/-3", {}, "path", "patient_id"),
        (f"/patients/{ID_MAX + 1}", {}, "path", "patient_id"),
        (f"/sessions/{2**70}/series", {}, "path", "session_id"),
        ("/sessions", {"station_id": "0"}, "query", "station_id"),
        ("/stations", {"patient_id": str(ID_MAX + 1)}, "query", "patient_id"),
    ],
)
async def test_an_id_out_of_range_is_a_422_naming_it(
    live: Live, world: World, path: str, params: dict[str, str], where: str, name: str
) -> None:
    r = await live.client.get(path, params=params, headers=bearer(world.t1))
    assert r.status_code == 422, r.text
    assert [where, name] in [e["loc"] for e in r.json()["detail"]]


@pytest.mark.asyncio
@pytest.mark.parametrize(
    ("value", "sentence"),
    [
        (str(ID_MAX + 1), f"Session id must be at most {ID_MAX}."),
        ("0", "Session id must be at least 1."),
    ],
)
async def test_an_id_out_of_range_is_refused_with_the_exact_bound(
    live: Live, world: World, value: str, sentence: str
) -> None:
    """The bound is said as the integer it is (2**63-1), not as the float nearest to it."""
    r = await live.client.get(f"/sessions/{value}/download/csv", headers=bearer(world.t1))
    assert r.status_code == 422, r.text
    (error,) = r.json()["detail"]
    assert (error["loc"], error["msg"]) == (["path", "session_id"], sentence)


@pytest.mark.asyncio
async def test_the_largest_id_is_an_ordinary_404(live: Live, world: World) -> None:
    for id_ in (ABOVE_INT4, ID_MAX):
        r = await live.client.get(f"/patients/{id_}", headers=bearer(world.t1))
        assert r.status_code == 404, r.text


@pytest.mark.asyncio
async def test_records_with_ids_past_two_to_the_31_work(live: Live, world: World) -> None:
    """A patient whose id int4 cannot hold, its station, prescription and audit rows."""
    async with live.sessionmaker() as db:
        db.add(Patient(id=ABOVE_INT4, therapist_id=world.t1_id, display_name="Big Id"))
        await db.commit()
    t1 = bearer(world.t1)
    r = await live.client.get(f"/patients/{ABOVE_INT4}", headers=t1)
    assert r.status_code == 200 and r.json()["id"] == ABOVE_INT4
    r = await live.client.post(f"/patients/{ABOVE_INT4}/stations", json={"name": "h"}, headers=t1)
    assert r.status_code == 201, r.text
    station = r.json()["id"]
    r = await live.client.post(f"/patients/{ABOVE_INT4}/prescriptions", json=STRENGTH, headers=t1)
    assert r.status_code == 201, r.text
    r = await live.client.get("/stations", params={"patient_id": ABOVE_INT4}, headers=t1)
    assert [s["id"] for s in r.json()] == [station]
    r = await live.client.get("/audit", params={"patient_id": ABOVE_INT4}, headers=t1)
    assert r.status_code == 200 and len(r.json()) >= 2


@pytest.mark.asyncio
async def test_new_ids_count_on_past_two_to_the_31(live: Live, world: World, store: str) -> None:
    """The ids the database hands out go on past int4 too (on PostgreSQL its sequences
    are 64-bit; SQLite's rowid always was)."""
    async with live.sessionmaker() as db:
        if store == "postgres":
            await db.execute(text(f"ALTER SEQUENCE patients_id_seq RESTART WITH {ABOVE_INT4}"))
        else:
            db.add(Patient(id=ABOVE_INT4 - 1, therapist_id=world.t1_id, display_name="Last"))
        await db.commit()
    r = await live.client.post("/patients", json={"display_name": "Next"}, headers=bearer(world.t1))
    assert r.status_code == 201, r.text
    assert r.json()["id"] == ABOVE_INT4
