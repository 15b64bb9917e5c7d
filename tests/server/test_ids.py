"""Ids: 64-bit in the store, and anything outside 1..2**63-1 refused (422 naming the
parameter) on every route, by the one type ``server.deps.Id``."""

from __future__ import annotations

import asyncio
import json
import logging
import typing
from collections.abc import Iterator
from typing import Annotated, Any

import pytest
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute, APIWebSocketRoute, iter_route_contexts
from pydantic import BaseModel, TypeAdapter, ValidationError
from sqlalchemy import text

from server.config import Settings
from server.models import ID_MAX, Patient
from sessions import wire
from tests.server.live_server import STRENGTH, Live, World, bearer
from tests.server.ws_client import closed_with, viewer_ws
from webui.app import create_app
from webui.home import messages as page

pytestmark = pytest.mark.both_stores

ABOVE_INT4 = 2**31 + 7
GOOD = ("1", str(ID_MAX))
BAD = ("0", str(ID_MAX + 1), "1.0", "+1", "1_0")
"""Out of range, or not written as a whole number: "1.0" was read as 1 (``/users/1.0``)."""


def _params(dependant: Dependant) -> list[Any]:
    """The path and query parameters of a route and of all its dependencies."""
    out = [*dependant.path_params, *dependant.query_params]
    for sub in dependant.dependencies:
        out.extend(_params(sub))
    return out


def _names_an_id(name: str) -> bool:
    return name == "id" or name.endswith("_id")


def _int_params(tmp_path: Any) -> Iterator[tuple[str, Any]]:
    """(path, parameter) for each integer path or query parameter of every route."""
    app = create_app(Settings(data_dir=tmp_path))
    for context in iter_route_contexts(app.routes):
        route, path = context.original_route, context.path_format or ""
        if not isinstance(route, APIRoute | APIWebSocketRoute):
            continue
        for param in _params(route.dependant):
            if "int" in str(param.field_info.annotation):  # not an upload's uuid, say
                yield path, param


def test_every_id_parameter_of_every_route_is_bounded(tmp_path: Any) -> None:
    checked, unbounded = [], []
    for path, param in _int_params(tmp_path):
        if not _names_an_id(param.name):
            continue
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
        ("/patients/1.0", {}, "path", "patient_id"),
        ("/sessions", {"station_id": "1.0"}, "query", "station_id"),
        ("/stations", {"patient_id": str(ID_MAX + 1)}, "query", "patient_id"),
    ],
)
async def test_an_id_out_of_range_is_a_422_naming_it(
    live: Live, world: World, path: str, params: dict[str, str], where: str, name: str
) -> None:
    r = await live.client.get(path, params=params, headers=bearer(world.t1))
    assert r.status_code == 422, r.text
    assert [where, name] in [e["loc"] for e in r.json()["detail"]]


def test_every_integer_parameter_of_every_route_stops_at_the_largest_stored(
    tmp_path: Any,
) -> None:
    """Not only ids: a page's offset reaches SQL too, where PostgreSQL's driver refused
    2**63 with a 500 (SQLite's with a 422). Every integer a path or query names is refused
    past 2**63-1 before the database is asked."""
    checked, unbounded = [], []
    for path, param in _int_params(tmp_path):
        checked.append((path, param.name))
        if not param.validate(str(ID_MAX + 1), {}, loc=("x",))[1]:
            unbounded.append((path, param.name))
    assert unbounded == []
    assert {("/api/v1/sessions", "offset"), ("/api/v1/audit", "offset")} <= set(checked)


@pytest.mark.asyncio
@pytest.mark.parametrize("path", ["/sessions", "/audit"])
async def test_an_offset_past_the_largest_stored_is_a_422_naming_it(
    live: Live, world: World, path: str
) -> None:
    for offset in (str(ID_MAX + 1), str(2**70)):
        r = await live.client.get(path, params={"offset": offset}, headers=bearer(world.t1))
        assert r.status_code == 422, r.text
        assert ["query", "offset"] in [e["loc"] for e in r.json()["detail"]]
    r = await live.client.get(path, params={"offset": str(ID_MAX)}, headers=bearer(world.t1))
    assert (r.status_code, r.json()) == (200, [])


@pytest.mark.asyncio
@pytest.mark.parametrize(
    ("value", "sentence"),
    [
        (str(ID_MAX + 1), f"Session id must be at most {ID_MAX}."),
        ("0", "Session id must be at least 1."),
        ("1.0", "Session id must be a whole number."),
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


def _wire_models() -> set[type[BaseModel]]:
    """Every model a live link's message holds, at any depth."""
    found: set[type[BaseModel]] = set()

    def walk(annotation: Any) -> None:
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            if annotation not in found:
                found.add(annotation)
                for info in annotation.model_fields.values():
                    walk(info.annotation)
            return
        for arg in typing.get_args(annotation):
            walk(arg)

    for union in (wire.StationUp, wire.StationDown, wire.ViewerUp, wire.ViewerDown):
        walk(union)
    for union in (page.PageAction, page.PageMessage):  # the patient's page, at the station
        walk(union)
    return found


OFFLINE_PATIENT = ("Welcome", "patient_id")
"""A viewer's welcome names patient 0 while its station is offline."""
DEVICE_COUNTERS = {"segment_id"}
"""Numbers the device counts itself (0: no segment), which name no record of the store."""


def test_every_id_field_of_every_live_message_is_bounded() -> None:
    """One rule for ids on the live links and the patient's page, as on the routes:
    1..2**63-1, JSON integers. A Start of prescription 2**70 from the patient's page made a
    Command the live link's rule refuses, raised inside the page's link, and closed it."""
    checked, unbounded = [], []
    for model in _wire_models():
        for name, info in model.model_fields.items():
            if not _names_an_id(name) or "int" not in str(info.annotation):
                continue
            if name in DEVICE_COUNTERS:
                continue
            checked.append((model.__name__, name))
            # The field as the model reads it (an ``Id | None`` carries its rule inside).
            form: Any = (
                Annotated[(info.annotation, *info.metadata)] if info.metadata else info.annotation
            )
            field: TypeAdapter[Any] = TypeAdapter(form)
            low = 0 if (model.__name__, name) == OFFLINE_PATIENT else 1
            verdicts = []
            for value in (low, ID_MAX, low - 1, ID_MAX + 1, True):
                try:
                    field.validate_json(json.dumps(value))
                    verdicts.append(True)
                except ValidationError:
                    verdicts.append(False)
            if verdicts != [True, True, False, False, False]:  # ``true`` is no id
                unbounded.append((model.__name__, name, verdicts))
    assert unbounded == []
    assert {("Command", "prescription_id"), ("StatusMsg", "prescription_id")} <= set(checked)
    assert {("PrescriptionItem", "id"), ("PrescriptionItem", "patient_id")} <= set(checked)
    assert {("Start", "prescription_id"), ("Exercise", "id")} <= set(checked)


@pytest.mark.asyncio
@pytest.mark.parametrize("prescription_id", [2**70, ID_MAX + 1, 0])
async def test_a_start_of_an_id_out_of_range_closes_the_view_naming_it(
    live: Live, world: World, prescription_id: int, caplog: pytest.LogCaptureFixture
) -> None:
    """Invalid input, refused as such: the view is closed as malformed (1007), naming the
    field and its bound, with no error logged and no audit row. A Start of prescription
    2**70 went to the database, whose driver could not send it, and came back as the
    database not answering (AUDIT, "try again"), logged at ERROR."""
    command = {
        "type": "command",
        "request_id": "huge",
        "action": "start",
        "prescription_id": prescription_id,
    }
    async with viewer_ws(live, world.t1, world.s1_id) as ws:
        await asyncio.wait_for(ws.recv(), 15)  # welcome
        await ws.send(json.dumps(command))
        code, reason = await closed_with(ws, timeout=15)
    bound = "at least 1" if prescription_id < 1 else f"at most {ID_MAX}"
    assert (code, reason) == (wire.CLOSE_MALFORMED, f"command.prescription_id: must be {bound}")
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR] == []
    r = await live.client.get("/audit", params={"request_id": "huge"}, headers=bearer(world.admin))
    assert r.status_code == 200 and r.json() == [], r.text
