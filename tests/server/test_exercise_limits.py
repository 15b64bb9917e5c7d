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
