"""Prescriptions over the API: the library, validation at the door, versions, the hub."""

from __future__ import annotations

import asyncio
import json
from typing import Any

import pytest

from sessions.prescription import (
    AXIS_INDEX,
    DEVICE_LIMITS,
    STIFFNESS_MAX,
    ExerciseKind,
    PrescriptionBody,
)
from sessions.sentences import bound_sentence
from tests.server.live_server import STRENGTH, Live, World, bearer

pytestmark = pytest.mark.both_stores


def with_pitch(**changes: Any) -> dict[str, Any]:
    """The strength defaults with the pitch axis changed."""
    return {**STRENGTH, "axes": [{**STRENGTH["axes"][0], **changes}]}


def as_json(body: dict[str, Any], **raw: str) -> str:
    """``body`` as JSON text, with ``@name`` placeholders replaced by raw JSON tokens."""
    text = json.dumps(body)
    for name, token in raw.items():
        text = text.replace(f'"@{name}"', token)
    return text


AXIS = ["body", "axes", 0]
INVALID = [
    pytest.param(
        as_json(with_pitch(stiffness="@x"), x="NaN"),
        [*AXIS, "stiffness"],
        "Stiffness K on pitch must be a finite number.",
        id="nan",
    ),
    pytest.param(
        as_json(with_pitch(damping="@x"), x="Infinity"),
        [*AXIS, "damping"],
        "Damping B on pitch must be a finite number.",
        id="infinity",
    ),
    pytest.param(
        as_json(with_pitch(stiffness=-1.0)),
        [*AXIS, "stiffness"],
        "Stiffness K on pitch must be at least 0 N·m/rad (0 N·m/°).",
        id="negative-stiffness",
    ),
    pytest.param(
        as_json(with_pitch(stiffness=1e9)),
        [*AXIS, "stiffness"],
        f"Stiffness K on pitch must be at most {STIFFNESS_MAX:g} N·m/rad (8.73 N·m/°).",
        id="oversized-stiffness",
    ),
    pytest.param(
        as_json({**STRENGTH, "repetitions": 10_000}),
        ["body", "repetitions"],
        "Repetitions per set must be at most 100.",
        id="oversized-repetitions",
    ),
    pytest.param(
        as_json(with_pitch(rom_high=40.0)),
        [*AXIS, "rom_high"],
        "Highest angle on pitch must be at most 22.9°.",
        id="rom-beyond-anatomy-and-device",
    ),
    pytest.param(
        as_json({**STRENGTH, "torque_limit": 1e-300}),
        ["body", "torque_limit"],
        "Torque limit must be at least 2 N·m.",
        id="torque-limit-below-the-devices-least",
    ),
    pytest.param(
        as_json({**STRENGTH, "force_limit": 1e-300}),
        ["body", "force_limit"],
        "Force limit must be at least 60 N.",
        id="force-limit-below-the-devices-least",
    ),
    pytest.param(
        as_json({**STRENGTH, "surprise": 1}),
        ["body", "surprise"],
        "“surprise” is not a field here.",
        id="unknown-field",
    ),
]


async def _snapshot(live: Live, world: World) -> tuple[Any, Any]:
    rx = await live.client.get(f"/patients/{world.p1}/prescriptions", headers=bearer(world.t1))
    log = await live.client.get("/audit", headers=bearer(world.admin))
    return rx.json(), log.json()


@pytest.mark.asyncio
@pytest.mark.parametrize(("text", "loc", "msg"), INVALID)
async def test_an_invalid_prescription_is_a_422_that_changes_nothing(
    live: Live, world: World, text: str, loc: list[Any], msg: str
) -> None:
    before = await _snapshot(live, world)
    headers = {**bearer(world.t1), "Content-Type": "application/json"}
    for method, path in [
        ("POST", f"/patients/{world.p1}/prescriptions"),
        ("PATCH", f"/prescriptions/{world.rx1}"),
    ]:
        r = await live.client.request(method, path, content=text, headers=headers)
        assert r.status_code == 422, r.text
        errors = r.json()["detail"]
        assert any(e["loc"] == loc and msg in e["msg"] for e in errors), errors
    assert await _snapshot(live, world) == before


@pytest.mark.asyncio
async def test_the_exercise_library(live: Live, world: World) -> None:
    r = await live.client.get("/exercises", headers=bearer(world.t1))
    library = r.json()
    assert [e["kind"] for e in library] == [k.value for k in ExerciseKind]
    for entry in library:
        PrescriptionBody.model_validate(entry["defaults"])


@pytest.mark.asyncio
async def test_create_update_cancel(
    live: Live, world: World, monkeypatch: pytest.MonkeyPatch
) -> None:
    hub = live.app.state.hub
    nudged: list[int] = []
    original = hub.prescriptions_changed

    async def record(station_id: int) -> None:
        nudged.append(station_id)
        await original(station_id)

    monkeypatch.setattr(hub, "prescriptions_changed", record)
    t1 = bearer(world.t1)
    body = with_pitch(stiffness=25.0, rom_low=-10.0, rom_high=20.0)
    r = await live.client.post(f"/patients/{world.p1}/prescriptions", json=body, headers=t1)
    assert r.status_code == 201
    rx = r.json()
    assert (rx["status"], rx["version"], rx["created_by"]) == ("active", 1, world.t1_id)
    assert rx["body"]["axes"][0]["stiffness"] == 25.0
    # K and B as the form writes them, per radian and per degree (25·π/180 = 0.436).
    assert rx["impedance_text"] == [
        {
            "axis": "pitch",
            "stiffness": "25 N·m/rad",
            "stiffness_per_degree": "0.436 N·m/°",
            "damping": "2 N·m·s/rad",
            "damping_per_degree": "0.0349 N·m·s/°",
        }
    ]
    assert rx["total_s"] == PrescriptionBody.model_validate(body).total_s()
    assert sorted(nudged) == [world.s1_id, world.s1_spare_id]

    # Revoked stations are not told; the therapist's edit bumps the version.
    await live.client.post(f"/stations/{world.s1_spare_id}/revoke", headers=t1)
    nudged.clear()
    r = await live.client.patch(f"/prescriptions/{rx['id']}", json={**body, "sets": 2}, headers=t1)
    assert (r.json()["version"], r.json()["body"]["sets"]) == (2, 2)
    assert nudged == [world.s1_id]
    # The same body again is no change: no new version, no audit row.
    r = await live.client.patch(f"/prescriptions/{rx['id']}", json={**body, "sets": 2}, headers=t1)
    assert r.json()["version"] == 2

    station = bearer(world.s1)
    active = (await live.client.get("/station/prescriptions", headers=station)).json()
    assert [p["id"] for p in active] == [world.rx1, rx["id"]]

    r = await live.client.post(f"/prescriptions/{rx['id']}/cancel", headers=t1)
    assert r.json()["status"] == "cancelled"
    active = (await live.client.get("/station/prescriptions", headers=station)).json()
    assert [p["id"] for p in active] == [world.rx1]
    for method, path in [
        ("POST", f"/prescriptions/{rx['id']}/cancel"),
        ("PATCH", f"/prescriptions/{rx['id']}"),
    ]:
        r = await live.client.request(method, path, json=body, headers=t1)
        assert (r.status_code, r.json()["detail"]) == (
            409,
            "the prescription is cancelled; write a new one instead",
        )
    listed = await live.client.get(
        f"/patients/{world.p1}/prescriptions?status=cancelled", headers=t1
    )
    assert [p["id"] for p in listed.json()] == [rx["id"]]


@pytest.mark.asyncio
async def test_two_edits_at_once_are_two_versions_audited_as_stored(
    live: Live, world: World
) -> None:
    """Two saves of one prescription at the same moment: each is applied in turn, as its
    own version, and the audit log replays exactly to what is stored (neither save lost, no
    version given out twice)."""
    t1 = bearer(world.t1)
    path = f"/prescriptions/{world.rx1}"
    for round_ in range(4):
        wanted = (20 + 2 * round_, 21 + 2 * round_)
        answers = await asyncio.gather(
            *(
                live.client.patch(path, json={**STRENGTH, "repetitions": n}, headers=t1)
                for n in wanted
            )
        )
        assert [a.status_code for a in answers] == [200, 200], [a.text for a in answers]
        got = sorted((a.json()["version"], a.json()["body"]["repetitions"]) for a in answers)
        assert got[1][0] == got[0][0] + 1, got
        assert sorted(n for _, n in got) == list(wanted)
        stored = (await live.client.get(path, headers=t1)).json()
        assert (stored["version"], stored["body"]["repetitions"]) == got[1]
    r = await live.client.get(
        "/audit", params={"patient_id": world.p1, "action": "prescription.update"}, headers=t1
    )
    rows = [e for e in reversed(r.json()) if e["entity_id"] == str(world.rx1)]
    assert len(rows) == 8
    version, repetitions = 1, STRENGTH["repetitions"]
    for row in rows:
        assert row["old"] == {"version": version, "body": {"repetitions": repetitions}}, rows
        version, repetitions = row["new"]["version"], row["new"]["body"]["repetitions"]
    assert (version, repetitions) == (stored["version"], stored["body"]["repetitions"])
    assert version == 1 + 8


@pytest.mark.asyncio
async def test_two_cancellations_at_once_withdraw_once(live: Live, world: World) -> None:
    """The second of two cancellations at once finds the prescription withdrawn: a 409, and
    one audit row."""
    t1 = bearer(world.t1)
    answers = await asyncio.gather(
        *(live.client.post(f"/prescriptions/{world.rx1}/cancel", headers=t1) for _ in range(2))
    )
    assert sorted(a.status_code for a in answers) == [200, 409], [a.text for a in answers]
    r = await live.client.get(
        "/audit", params={"patient_id": world.p1, "action": "prescription.cancel"}, headers=t1
    )
    assert [e["entity_id"] for e in r.json()] == [str(world.rx1)]


@pytest.mark.asyncio
async def test_damping_below_the_stable_least_names_the_field_and_its_value(
    live: Live, world: World
) -> None:
    """A refusal a model-wide check makes about one field (here the stable envelope) points
    at that field: its loc, its value as input, and the whole sentence, bound included."""
    least = DEVICE_LIMITS.damping_min_at(AXIS_INDEX["pitch"], 40.0)
    assert least > 0
    r = await live.client.post(
        f"/patients/{world.p1}/prescriptions",
        json=with_pitch(stiffness=40.0, damping=0.0),
        headers=bearer(world.t1),
    )
    assert r.status_code == 422, r.text
    (error,) = r.json()["detail"]
    expected = bound_sentence(
        "Damping B on pitch",
        "ge",
        least,
        "N·m·s/rad",
        "the least the platform renders steadily at a stiffness of 40 N·m/rad",
    )
    assert error["loc"] == [*AXIS, "damping"]
    assert error["input"] == 0.0
    assert error["msg"] == expected
    assert error["ctx"] == {"error": expected}
