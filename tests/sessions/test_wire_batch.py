"""Telemetry batches on the wire: several samples per message as columns, validated strictly."""

from __future__ import annotations

import json
from typing import Any

import pytest
from pydantic import ValidationError

from sessions import wire
from tests.server.ws_client import sample


def rows(n: int) -> list[dict[str, Any]]:
    """``n`` distinct samples, 10 ms apart, each value telling which sample it is."""
    out = []
    for i in range(n):
        six = [i + k / 10 for k in range(6)]
        out.append(
            sample(
                t=12.0 + i * 0.01,
                mode="ACTIVE" if i % 2 else "HOLD",
                trip=0,
                segment_id=7,
                set=1,
                rep=i,
                pose=six,
                pose_cmd=[-x for x in six],
                legs=[x / 100 for x in six],
                pressures=[1e5 * (i + 1) + k for k in range(12)],
                wrench=[x * 3 for x in six],
                stiffness=[20000.0, 20000.0, 20000.0, 30.0 + i, 30.0, 10.0],
                damping=[200.0, 200.0, 200.0, 1.0, 1.0 + i, 0.5],
                lag_ms=0.1 * i,
                overruns=i,
                frames_dropped=2 * i,
            )
        )
    return out


def batch_json(n: int = 4, **change: Any) -> dict[str, Any]:
    body: dict[str, Any] = json.loads(
        wire.TelemetryBatch.of(rows(n), sent=1700000000.5).model_dump_json()
    )
    return body | change


def refusal(body: dict[str, Any]) -> str:
    """Why a station's message is refused, as the close reason says it."""
    with pytest.raises(ValidationError) as exc:
        wire.STATION_UP.validate_json(json.dumps(body))
    return wire.error_text(exc.value)


def test_a_batch_round_trips_every_sample_in_order() -> None:
    sent = rows(4)
    raw = wire.TelemetryBatch.of(sent, sent=1700000000.5).model_dump_json()
    for adapter in (wire.STATION_UP, wire.VIEWER_DOWN):
        got = adapter.validate_json(raw)
        assert isinstance(got, wire.TelemetryBatch)
        assert len(got) == 4
        samples = got.samples()
        assert [s.model_dump(exclude={"type", "sent"}) for s in samples] == sent
        assert {s.sent for s in samples} == {1700000000.5}
        assert got.newest() == samples[-1]
        assert got.newest().t == pytest.approx(12.03) and got.newest().rep == 3
        assert got.sample(0).mode == "HOLD" and got.sample(1).mode == "ACTIVE"


def test_a_batch_is_smaller_than_its_samples_one_message_each() -> None:
    batch = wire.TelemetryBatch.of(rows(4), sent=1700000000.5).model_dump_json()
    singles = [
        wire.TelemetryMsg.model_validate(r | {"sent": 1700000000.5}).model_dump_json()
        for r in rows(4)
    ]
    assert len(batch) < 0.8 * sum(len(s) for s in singles), (len(batch), len(singles[0]))


def test_the_columns_are_the_fields_of_a_sample() -> None:
    assert set(wire.SAMPLE_COLUMNS) == set(wire.TelemetryMsg.model_fields) - {"type", "sent"}
    assert set(wire.TelemetryBatch.model_fields) == {"type", "sent", *wire.SAMPLE_COLUMNS}
    schema = wire.json_schemas()["station_to_server"]["$defs"]["TelemetryBatch"]
    assert schema["properties"]["pose"]["items"]["minItems"] == 6
    assert schema["properties"]["t"]["maxItems"] == wire.BATCH_MAX
    assert schema["additionalProperties"] is False


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"mode": ["ACTIVE"] * 3}, "mode has 3 samples, t has 4"),
        ({"t": [1.0, 2.0, float("nan"), 3.0]}, "telemetry.t.2"),
        ({"t": []}, "telemetry.t"),
        ({"pressures": [[0.0] * 12] * 3 + [[0.0] * 11]}, "telemetry.pressures.3"),
        ({"trip": [0, 0, 0, 1.5]}, "telemetry.trip.3"),
        ({"pose": [[0.0] * 6] * 5}, "pose has 5 samples, t has 4"),
        ({"extra": [1, 2, 3, 4]}, "telemetry.extra"),
        ({"sent": "soon"}, "telemetry.sent"),
    ],
)
def test_a_malformed_batch_is_refused_naming_the_field(change: dict[str, Any], named: str) -> None:
    assert named in refusal(batch_json() | change)


def test_a_column_left_out_is_refused_by_name() -> None:
    body = batch_json()
    del body["damping"]
    assert refusal(body).startswith("telemetry.damping")


def test_a_batch_holds_at_most_batch_max_samples() -> None:
    wire.TelemetryBatch.of(rows(wire.BATCH_MAX), sent=0.0)
    assert len(wire.TelemetryBatch.of(rows(wire.BATCH_MAX), sent=0.0).model_dump_json()) < (
        wire.MAX_MESSAGE_BYTES
    )
    with pytest.raises(ValidationError, match="at most 50"):
        wire.TelemetryBatch.of(rows(wire.BATCH_MAX + 1), sent=0.0)


def test_a_single_sample_message_of_protocol_1_is_refused() -> None:
    old = rows(1)[0] | {"type": "telemetry", "sent": 1.0}
    assert "telemetry.t" in refusal(old)
    assert wire.PROTOCOL >= 2  # batches came with protocol 2
