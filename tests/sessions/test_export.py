"""Every download format, read back with the library a user would open it with."""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader
from numpy.typing import NDArray

from device.protocol.messages import DeviceMode
from sessions.export import (
    COLUMNS,
    EVENT_SCHEMA,
    FILE_SUFFIX,
    FORMATS,
    MEDIA_TYPES,
    TELEMETRY_SCHEMA,
    content_hash,
    export,
    write_export,
)
from sessions.prescription import AXIS_INDEX, PrescriptionBody
from sessions.recording import (
    SAMPLE_DTYPE,
    DeviceInfo,
    End,
    Header,
    Recording,
    RecordingWriter,
    SessionEvent,
    read,
)
from sessions.summary import summarize

# The session (tests/sessions/test_summary.py checks the same shape against analytic values):
# 1 s READY at 30 degrees pitch, two cycles of a 10 degree 0.5 Hz pitch sine while ACTIVE
# with the patient's torque K·q, 1 s READY; 100 Hz.
DT = 0.01
AMPLITUDE_DEG = 10.0
K = 40.0
N_READY, N_ACTIVE = 100, 401
STARTED_AT = 1_700_000_000.0
PA = 3e5
LEG_M = 0.05

N = N_READY + N_ACTIVE + N_READY
PITCH = AXIS_INDEX["pitch"]


def header() -> Header:
    body = PrescriptionBody.model_validate(
        {
            "exercise": "flexibility",
            "axes": [
                {
                    "axis": "pitch",
                    "stiffness": K,
                    "damping": 2.0,
                    "waveform": "sine",
                    "amplitude": AMPLITUDE_DEG,
                    "frequency": 0.5,
                }
            ],
            "sets": 2,
            "repetitions": 3,
        }
    )
    return Header(
        session_id="0b6c5f0e-3c1a-4f7e-9d1e-5a0f1c2b3d4e",
        station_id=7,
        patient_id=11,
        prescription_id=13,
        prescription=body.model_dump(mode="json"),
        device=DeviceInfo(firmware="sim", hardware="sim", telemetry_hz=100, home_pose=[0.0] * 6),
        software="test",
        started_at=STARTED_AT,
    )


def sine_samples() -> NDArray[np.void]:
    s = np.zeros(N, SAMPLE_DTYPE)
    s["t"] = 10.0 + np.arange(N) * DT
    s["wall"] = STARTED_AT + 0.25 + s["t"]
    s["mode"] = int(DeviceMode.READY)
    s["legs"] = LEG_M
    s["pressures"] = PA
    s["supply"] = 2 * PA
    s["duty"] = np.arange(12, dtype=np.int8) - 6
    s["pose"][:, PITCH] = math.radians(30.0)
    s["wrench"][:, PITCH] = 50.0
    act = np.arange(N_READY, N_READY + N_ACTIVE)
    q = np.radians(AMPLITUDE_DEG) * np.sin(np.pi * (act - N_READY) * DT)
    s["mode"][act] = int(DeviceMode.ACTIVE)
    s["set"][act] = 1
    s["rep"][act] = 1 + (act - N_READY) // 100
    s["pose"][act, PITCH] = q
    s["pose_cmd"][act, PITCH] = q
    s["wrench"][act, PITCH] = K * q
    return s


EVENTS = [
    *(SessionEvent(wall=STARTED_AT + 2 + i, t=12.0 + i, kind="rep_done") for i in range(5)),
    SessionEvent(wall=STARTED_AT + 3.5, t=13.25, kind="set_done", detail={"set": 1}),
    SessionEvent(wall=STARTED_AT + 4, kind="limit", by="device", detail={"code": 4}),
    SessionEvent(wall=STARTED_AT + 5, kind="note", by="therapist:3", detail={"text": "ok"}),
]
LIMIT_WALL = STARTED_AT + 4
END = End(ended_at=STARTED_AT + 20.0, reason="completed", sets_completed=2, repetitions_completed=6)


def write_recording(
    path: Path, samples: NDArray[np.void], events: list[SessionEvent], end: End | None
) -> Recording:
    """Write with the station's writer and read back, as the server would."""
    with RecordingWriter(path, header()) as w:
        for i, row in enumerate(samples.tolist()):
            if i == len(samples) // 2:
                for e in events:
                    w.event(e)
            w.add(row)
        if not len(samples):
            for e in events:
                w.event(e)
        if end is not None:
            w.end(end)
    return read(path)


def no_nan_json(text: str) -> Any:
    def refuse(name: str) -> None:
        raise AssertionError(f"{name} in JSON")

    return json.loads(text, parse_constant=refuse)


@pytest.fixture
def rec(tmp_path: Path) -> Recording:
    return write_recording(tmp_path / "s.ankl", sine_samples(), EVENTS, END)


@pytest.fixture
def empty(tmp_path: Path) -> Recording:
    return write_recording(tmp_path / "e.ankl", np.zeros(0, SAMPLE_DTYPE), [], None)


def csv_rows(data: bytes) -> tuple[list[str], list[dict[str, str]]]:
    reader = csv.DictReader(io.StringIO(data.decode("utf-8"), newline=""))
    rows = list(reader)
    return list(reader.fieldnames or []), rows


def mcap_messages(data: bytes) -> dict[str, list[tuple[int, int, Any]]]:
    """Topic to (log_time, publish_time, decoded JSON) of every message, in log order."""
    out: dict[str, list[tuple[int, int, Any]]] = {}
    reader = make_reader(io.BytesIO(data))
    for schema, channel, message in reader.iter_messages(log_time_order=True):
        assert schema is not None and schema.encoding == "jsonschema"
        assert channel.message_encoding == "json"
        body = no_nan_json(message.data.decode())
        out.setdefault(channel.topic, []).append((message.log_time, message.publish_time, body))
    return out


def mcap_metadata(data: bytes) -> dict[str, dict[str, str]]:
    return {m.name: dict(m.metadata) for m in make_reader(io.BytesIO(data)).iter_metadata()}


def test_the_format_tables_cover_every_format() -> None:
    assert (
        set(MEDIA_TYPES) == set(FILE_SUFFIX) == set(FORMATS) == {"csv", "parquet", "mcap", "json"}
    )
    assert FILE_SUFFIX["parquet"] == ".parquet"
    assert MEDIA_TYPES["json"] == "application/json"


def test_an_unknown_format_is_refused(rec: Recording) -> None:
    with pytest.raises(ValueError, match="unknown export format 'xlsx'"):
        export(rec, "xlsx")


@pytest.mark.parametrize("fmt", FORMATS)
def test_exports_are_reproducible_and_hashed(rec: Recording, tmp_path: Path, fmt: str) -> None:
    first, second = export(rec, fmt), export(rec, fmt)
    assert first == second
    assert content_hash(first) == hashlib.sha256(first).hexdigest()
    path = tmp_path / f"out{FILE_SUFFIX[fmt]}"
    digest = write_export(rec, fmt, path)
    assert path.read_bytes() == first
    assert digest == hashlib.sha256(path.read_bytes()).hexdigest()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["s.ankl", path.name])


def test_csv_reads_back_in_clinic_units(rec: Recording) -> None:
    data = export(rec, "csv")
    assert not data.startswith(b"#")
    names, rows = csv_rows(data)
    assert names == [c.name for c in COLUMNS]
    assert len(names) == len(set(names))
    assert len(rows) == N
    for name in ("time_s", "mode", "pitch_deg", "torque_pitch_nm", "p12_bar", "duty12"):
        assert name in names

    active = [r for r in rows if r["mode"] == "ACTIVE"]
    assert len(active) == N_ACTIVE
    assert {r["mode"] for r in rows} == {"READY", "ACTIVE"}
    pitch = [float(r["pitch_deg"]) for r in active]
    assert max(pitch) == pytest.approx(AMPLITUDE_DEG, abs=1e-3)
    assert min(pitch) == pytest.approx(-AMPLITUDE_DEG, abs=1e-3)
    assert max(float(r["torque_pitch_nm"]) for r in active) == pytest.approx(
        K * math.radians(AMPLITUDE_DEG), abs=1e-3
    )
    assert float(rows[0]["pitch_deg"]) == pytest.approx(30.0, abs=1e-3)  # READY, from radians
    assert float(rows[0]["p1_bar"]) == pytest.approx(PA / 1e5)
    assert float(rows[0]["supply_bar"]) == pytest.approx(2 * PA / 1e5)
    assert float(rows[0]["leg6_mm"]) == pytest.approx(LEG_M * 1000, abs=1e-3)
    assert [int(rows[0][f"duty{i + 1}"]) for i in range(12)] == list(range(-6, 6))
    assert float(rows[1]["time_s"]) - float(rows[0]["time_s"]) == pytest.approx(0.01, abs=1e-6)
    assert float(rows[0]["wall_unix_s"]) == pytest.approx(rec.samples["wall"][0], abs=1e-6)
    assert rows[N_READY]["trip"] == "NONE"
    # Rounded for reading: no float32 noise like 9.999999776482582
    assert all(len(r["pitch_deg"].partition(".")[2]) <= 3 for r in rows)


def test_parquet_reads_back_with_its_metadata(rec: Recording) -> None:
    table = pq.read_table(io.BytesIO(export(rec, "parquet")))
    assert table.num_rows == N
    assert table.column_names == [c.name for c in COLUMNS]
    assert table.schema.field("time_s").type == pa.float64()
    assert table.schema.field("pitch_deg").type == pa.float32()
    assert table.schema.field("duty1").type == pa.int8()
    assert table.schema.field("torque_pitch_nm").metadata == {b"unit": "N·m".encode()}
    pitch = np.asarray(table.column("pitch_deg"))
    mode = table.column("mode").to_pylist()
    assert max(p for p, m in zip(pitch, mode, strict=True) if m == "ACTIVE") == pytest.approx(
        AMPLITUDE_DEG, abs=1e-4
    )

    meta = table.schema.metadata
    header = json.loads(meta[b"ankle.header"])
    assert header["session_id"] == rec.header.session_id
    events = json.loads(meta[b"ankle.events"])
    assert [e["kind"] for e in events] == [e.kind for e in rec.events]
    summary = json.loads(meta[b"ankle.summary"])
    assert summary == summarize(rec).model_dump(mode="json")
    assert summary["axes"]["pitch"]["rom_deg"] == pytest.approx(2 * AMPLITUDE_DEG, abs=1e-3)


def test_mcap_reads_back_with_json_schemas(rec: Recording) -> None:
    data = export(rec, "mcap")
    messages = mcap_messages(data)
    assert set(messages) == {"/telemetry", "/events"}

    telemetry = messages["/telemetry"]
    assert len(telemetry) == N
    required = set(TELEMETRY_SCHEMA["required"])
    for log_time, publish_time, body in telemetry[:: N // 20]:
        assert set(body) == required
        assert log_time == publish_time
        assert body["timestamp"]["sec"] * 10**9 + body["timestamp"]["nsec"] == log_time
        assert len(body["legs"]) == 6 and len(body["pressures"]) == 12 and len(body["duty"]) == 12
    first = telemetry[0]
    assert first[0] == round(rec.samples["wall"][0] * 1e9)
    assert first[2]["t"] == pytest.approx(rec.samples["t"][0])
    assert first[2]["pressures"][0] == pytest.approx(PA)
    assert first[2]["duty"] == list(range(-6, 6))
    active = [b for _, _, b in telemetry if b["mode"] == "ACTIVE"]
    assert len(active) == N_ACTIVE
    # SI, as the device sends it: radians
    assert max(b["pose"]["pitch"] for b in active) == pytest.approx(
        math.radians(AMPLITUDE_DEG), rel=1e-6
    )
    assert [log for log, _, _ in telemetry] == sorted(log for log, _, _ in telemetry)

    events = messages["/events"]
    assert set(EVENT_SCHEMA["required"]) == set(events[0][2])
    assert sorted(b["kind"] for _, _, b in events) == sorted(e.kind for e in rec.events)
    limit = next(b for _, _, b in events if b["kind"] == "limit")
    assert limit["detail"]["code"] == 4
    assert next(log for log, _, b in events if b["kind"] == "limit") == round(LIMIT_WALL * 1e9)

    meta = mcap_metadata(data)
    assert set(meta) == {"session", "summary", "end"}
    assert meta["session"]["session_id"] == rec.header.session_id
    assert meta["session"]["device.telemetry_hz"] == "100"
    assert float(meta["summary"]["axes.pitch.rom_deg"]) == pytest.approx(
        2 * AMPLITUDE_DEG, abs=1e-3
    )
    assert meta["end"]["reason"] == "completed"


def test_json_is_the_session_without_samples(rec: Recording) -> None:
    data = export(rec, "json")
    doc = no_nan_json(data.decode())
    assert list(doc) == ["header", "summary", "events", "end"]
    assert b'\n  "header": {' in data  # indented for reading
    assert doc["header"]["patient_id"] == rec.header.patient_id
    assert doc["summary"]["repetitions_completed"] == END.repetitions_completed
    assert doc["summary"]["axes"]["pitch"]["work_j"] == pytest.approx(
        summarize(rec).axes["pitch"].work_j
    )
    assert len(doc["events"]) == len(EVENTS)
    assert doc["end"]["reason"] == "completed"
    assert len(data) < 20_000  # no samples


def test_a_recording_without_end(tmp_path: Path) -> None:
    rec = write_recording(tmp_path / "s.ankl", sine_samples(), EVENTS, None)
    assert no_nan_json(export(rec, "json").decode())["end"] is None
    assert "end" not in mcap_metadata(export(rec, "mcap"))
    meta = pq.read_table(io.BytesIO(export(rec, "parquet"))).schema.metadata
    assert json.loads(meta[b"ankle.summary"])["end_reason"] is None
    assert len(csv_rows(export(rec, "csv"))[1]) == N


def test_an_empty_recording_exports_everywhere(empty: Recording) -> None:
    names, rows = csv_rows(export(empty, "csv"))
    assert names == [c.name for c in COLUMNS] and rows == []
    table = pq.read_table(io.BytesIO(export(empty, "parquet")))
    assert table.num_rows == 0 and table.column_names == names
    assert table.schema.field("pitch_deg").type == pa.float32()
    data = export(empty, "mcap")
    assert mcap_messages(data) == {}
    assert set(mcap_metadata(data)) == {"session", "summary"}
    doc = no_nan_json(export(empty, "json").decode())
    assert doc["summary"]["samples"] == 0 and doc["events"] == [] and doc["end"] is None


def test_unmeasured_values_are_empty_or_null_never_nan(rec: Recording) -> None:
    samples = rec.samples.copy()
    samples["pose"][3, PITCH] = np.nan
    samples["wrench"][4, PITCH] = np.inf
    bad = replace(rec, samples=samples)

    _, rows = csv_rows(export(bad, "csv"))
    assert rows[3]["pitch_deg"] == ""
    assert rows[2]["pitch_deg"] != ""
    assert b"nan" not in export(bad, "csv").lower()

    table = pq.read_table(io.BytesIO(export(bad, "parquet")))
    assert table.column("pitch_deg").null_count == 1
    assert table.column("pitch_deg")[3].as_py() is None

    telemetry = mcap_messages(export(bad, "mcap"))["/telemetry"]
    assert telemetry[3][2]["pose"]["pitch"] is None
    assert telemetry[4][2]["wrench"]["pitch"] is None
    assert telemetry[5][2]["wrench"]["pitch"] == pytest.approx(50.0)

    no_nan_json(export(bad, "json").decode())


def test_an_unknown_mode_code_keeps_its_number(rec: Recording) -> None:
    samples = rec.samples.copy()
    samples["mode"][0] = 77
    _, rows = csv_rows(export(replace(rec, samples=samples), "csv"))
    assert rows[0]["mode"] == "77"
    assert rows[1]["mode"] == DeviceMode.READY.name
