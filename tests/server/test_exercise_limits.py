"""What a prescription may ask is published before it is asked, in the words the API refuses
with: ranges per axis, the device's stable envelope, directions for the patient's side."""

from __future__ import annotations

import re
from typing import Any

import numpy as np
import pytest

from device.limits import SafetyLimits
from sessions.prescription import allowed_range_deg
from tests.server.live_server import STRENGTH, Live, World, bearer

pytestmark = pytest.mark.both_stores


def _pitch(**changes: Any) -> dict[str, Any]:
    return {**STRENGTH, "axes": [{**STRENGTH["axes"][0], **changes}]}


@pytest.mark.asyncio
async def test_ranges_envelope_and_directions_are_published(live: Live, world: World) -> None:
    r = await live.client.get("/exercises/limits?side=left", headers=bearer(world.t1))
    assert r.status_code == 200, r.text
    limits = r.json()
    pitch = limits["axes"]["pitch"]
    assert pitch["range_deg"] == list(allowed_range_deg("pitch"))
    assert pitch["range_deg"][0] == -20.0 and round(pitch["range_deg"][1], 1) == 22.9
    assert (pitch["fields"]["center"]["min"], pitch["fields"]["center"]["max"]) == tuple(
        pitch["range_deg"]
    )
    device = SafetyLimits().published()  # what the device's HELLO carries
    for i, axis in enumerate(("roll", "pitch", "yaw")):
        bands = limits["axes"][axis]["envelope"]
        assert [b["stiffness_from"] for b in bands] == list(device.envelope_stiffness)
        assert [b["damping_min"] for b in bands] == list(device.damping_min[9 + 3 * i : 12 + 3 * i])
    assert limits["axes"]["roll"]["directions"]["positive"] == "eversion"  # a left foot
    right = (await live.client.get("/exercises/limits?side=right", headers=bearer(world.t1))).json()
    assert right["axes"]["roll"]["directions"]["positive"] == "inversion"
    unknown = (await live.client.get("/exercises/limits", headers=bearer(world.t1))).json()
    assert unknown["axes"]["roll"]["directions"]["positive_label"] == "Platform's left edge up"
    # the library keeps its shape
    library = (await live.client.get("/exercises", headers=bearer(world.t1))).json()
    assert isinstance(library, list) and library[0]["kind"] == "strength"


@pytest.mark.asyncio
@pytest.mark.parametrize(
    ("body", "loc", "where", "which"),
    [
        (_pitch(stiffness=501.0), ["axes", 0, "stiffness"], ("pitch", "stiffness"), "above"),
        (_pitch(damping=-1.0), ["axes", 0, "damping"], ("pitch", "damping"), "below"),
        (_pitch(center=30.0), ["axes", 0, "center"], ("pitch", "center"), "above"),
        (_pitch(rom_low=-25.0), ["axes", 0, "rom_low"], ("pitch", "rom_low"), "below"),
        ({**STRENGTH, "sets": 0}, ["sets"], (None, "sets"), "below"),
        ({**STRENGTH, "torque_limit": 0.0}, ["torque_limit"], (None, "torque_limit"), "below"),
    ],
)
async def test_the_published_sentence_is_the_one_the_api_refuses_with(
    live: Live,
    world: World,
    body: dict[str, Any],
    loc: list[Any],
    where: tuple[str | None, str],
    which: str,
) -> None:
    t1 = bearer(world.t1)
    limits = (await live.client.get("/exercises/limits", headers=t1)).json()
    axis, field = where
    published = (limits["axes"][axis]["fields"] if axis else limits["fields"])[field][which]
    r = await live.client.post(f"/patients/{world.p1}/prescriptions", json=body, headers=t1)
    assert r.status_code == 422, r.text
    (error,) = r.json()["detail"]
    assert error["loc"] == ["body", *loc]
    assert error["msg"] == published
    assert error["type"]  # the machine-readable kind stays for API clients


@pytest.mark.asyncio
async def test_isometric_k_and_b_are_refused_with_a_sentence(live: Live, world: World) -> None:
    t1 = bearer(world.t1)
    body = {**_pitch(stiffness=40.0, damping=2.0), "exercise": "isometric"}
    r = await live.client.post(f"/patients/{world.p1}/prescriptions", json=body, headers=t1)
    assert r.status_code == 422
    (error,) = r.json()["detail"]
    assert error["loc"] == ["body", "axes", 0, "stiffness"]
    assert error["msg"].startswith("Stiffness K on pitch is not used in “Isometric”")


@pytest.mark.asyncio
async def test_other_forms_and_parameters_speak_sentences_too(live: Live, world: World) -> None:
    t1 = bearer(world.t1)
    r = await live.client.post("/patients", json={"display_name": "  "}, headers=t1)
    assert r.status_code == 422
    assert r.json()["detail"][0]["msg"] == "Display name is required."
    r = await live.client.get("/exercises/limits?side=middle", headers=t1)
    assert r.status_code == 422
    assert r.json()["detail"][0]["msg"] == "Side must be one of left, right or both."


def _near_edges(edges: list[float]) -> list[float]:
    """Stiffnesses just below each edge of the envelope's bands: in float64 only (the device
    receives the edge itself, in float32: 4.9999999 is 5), the float32 just below it, and
    some a sentence would round onto it."""
    out: list[float] = []
    for edge in edges:
        if edge <= 0:
            continue
        below32 = float(np.nextafter(np.float32(edge), np.float32(0)))
        out += [edge * (1 - 2e-8), edge * (1 - 1e-7), below32, edge * (1 - 1e-5), edge - 0.01]
    return out


@pytest.mark.asyncio
async def test_the_envelope_is_checked_as_the_device_receives_k_and_its_sentence_agrees(
    live: Live, world: World
) -> None:
    """K and B are checked in float32, as the device receives and checks them: K =
    4.9999999 reaches it as 5, where the published envelope asks B 0.8, so B 0.8 is taken.
    A refusal says the stiffness so that the published envelope at it asks the damping the
    sentence asks (never "at least 1 at a stiffness of 5", where it publishes 0.8)."""
    t1 = bearer(world.t1)
    limits = (await live.client.get("/exercises/limits", headers=t1)).json()
    for axis in ("roll", "pitch", "yaw"):
        bands = limits["axes"][axis]["envelope"]
        edges = [b["stiffness_from"] for b in bands]

        def published(k: float, bands: list[dict[str, float]] = bands) -> float:
            return [b["damping_min"] for b in bands if k >= b["stiffness_from"]][-1]

        for k in _near_edges(edges):
            k32 = float(np.float32(k))
            least = published(k32)  # what the device asks of this K as it receives it
            body = {**STRENGTH, "axes": [{**STRENGTH["axes"][0], "axis": axis}]}
            body["axes"][0] |= {"stiffness": k, "damping": least}
            r = await live.client.post(f"/patients/{world.p1}/prescriptions", json=body, headers=t1)
            assert r.status_code == 201, (axis, k, r.text)
            lower = float(np.nextafter(np.float32(least), np.float32(0)))
            body["axes"][0]["damping"] = lower
            r = await live.client.post(f"/patients/{world.p1}/prescriptions", json=body, headers=t1)
            assert r.status_code == 422, (axis, k, r.text)
            (error,) = r.json()["detail"]
            said = re.fullmatch(
                rf"Damping B on {axis} must be at least ([\d.]+) N·m·s/rad \([^)]*\): the least "
                r"the platform renders steadily at a stiffness of ([\d.]+) N·m/rad\.",
                error["msg"],
            )
            assert said is not None, error["msg"]
            said_least, said_k = float(said[1]), float(said[2])
            assert said_least == pytest.approx(least, abs=0.05), (axis, k, error["msg"])
            assert published(float(np.float32(said_k))) == least, (axis, k, error["msg"])


CROSS_FIELD = {("amplitude", "max"), ("rom_low", "max"), ("rom_high", "min")}
"""Bounds no prescription reaches for another rule's sake: a sine of 90° leaves every axis's
range, and the lowest angle at the top of the range (the highest at its bottom) leaves none
above (below) it. At these the API refuses with that other rule's sentence; past them, with
the published one."""


def _top_level(name: str, value: float) -> dict[str, Any]:
    """A prescription whose only unusual number is ``name`` = ``value``: one short repetition
    so that no count or time at its bound makes the session too long."""
    body = {**STRENGTH, "sets": 1, "repetitions": 1, "repetition_s": 1.0, "rest_s": 0.0}
    if name == "rest_s":
        body["sets"] = 2
    if name in ("sets", "repetitions", "sessions_per_week"):
        value = int(value)
    return {**body, name: value}


def _on_axis(axis: str, name: str, value: float) -> dict[str, Any]:
    """A prescription on ``axis`` whose only unusual number is ``name`` = ``value``, with the
    waveform that uses it and companions every other rule takes (a damping the envelope asks
    at any stiffness; the isometric exercise, which asks neither, for a damping of 0)."""
    a: dict[str, Any] = {**STRENGTH["axes"][0], "axis": axis, "damping": 50.0}
    exercise = "strength"
    if name == "damping" and value == 0.0:
        exercise, a["stiffness"] = "isometric", 0.0
    elif name in ("amplitude", "frequency"):
        a |= {"waveform": "sine", "amplitude": 1.0, "frequency": 0.5}
        if value == 0.0:  # a sine of no amplitude needs no frequency, one of some does
            a["frequency" if name == "amplitude" else "amplitude"] = 0.0
    elif name in ("ramp_end", "ramp_rate"):
        a |= {"waveform": "ramp", "ramp_end": 10.0, "ramp_rate": 10.0}
        if name == "ramp_rate" and value == 0.0:
            a["ramp_end"] = 0.0
    a[name] = value
    return {**STRENGTH, "exercise": exercise, "axes": [a]}


@pytest.mark.asyncio
async def test_every_published_bound_is_the_one_the_api_enforces(live: Live, world: World) -> None:
    """Each number field's published bounds, against the API: a value at an inclusive bound
    (just above an exclusive least) is taken, or, at a bound another rule keeps out of reach,
    refused by that rule; one just past it is refused at that field with the published
    sentence. The torque and force limits were published as "above 0" while the device
    refused under 2 N·m and 60 N."""
    t1 = bearer(world.t1)
    limits = (await live.client.get("/exercises/limits", headers=t1)).json()
    cases: list[tuple[list[Any], str, dict[str, Any], Any]] = [
        ([name], name, bounds, lambda v, n=name: _top_level(n, v))
        for name, bounds in limits["fields"].items()
    ]
    for axis, published in limits["axes"].items():
        cases += [
            (["axes", 0, name], name, bounds, lambda v, x=axis, n=name: _on_axis(x, n, v))
            for name, bounds in published["fields"].items()
        ]
    assert {"torque_limit", "force_limit", "sets", "rest_s"} <= set(limits["fields"])
    url = f"/patients/{world.p1}/prescriptions"
    checked = 0
    for loc, name, bounds, body in cases:
        for end, sentence, past_by in (("min", "below", -1.0), ("max", "above", 1.0)):
            bound = bounds[end]
            if bound is None:
                continue
            # Past the bound by a step no rounding hides: a count by one, a number by a
            # millionth of a unit (angles are compared with 1e-9° of slack).
            step = 1.0 if name in ("sets", "repetitions", "sessions_per_week") else 1e-6
            past = await live.client.post(url, json=body(bound + past_by * step), headers=t1)
            assert past.status_code == 422, (loc, end, past.text)
            (error,) = past.json()["detail"]
            assert (error["loc"], error["msg"]) == (["body", *loc], bounds[sentence]), (loc, end)
            if end == "min" and bounds["min_exclusive"]:  # refused at it, taken just above
                at = await live.client.post(url, json=body(bound), headers=t1)
                assert at.status_code == 422, (loc, end, at.text)
                assert at.json()["detail"][0]["msg"] == bounds["below"]
                bound += step
            at = await live.client.post(url, json=body(bound), headers=t1)
            if (name, end) in CROSS_FIELD:
                assert at.status_code == 422, (loc, end, at.text)
                assert at.json()["detail"][0]["msg"] != bounds[sentence], (loc, end)
            else:
                assert at.status_code == 201, (loc, end, at.text)
            checked += 1
    assert checked == 2 * len(cases)
