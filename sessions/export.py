"""Session downloads in open formats: CSV, Parquet, MCAP and JSON.

Every export is bytes plus their SHA-256 (:func:`content_hash`), so a download can be checked
and cited. The same recording always gives the same bytes (for one version of pyarrow and
mcap): nothing in an export depends on when or where it was made.

``csv`` — for clinicians and spreadsheets: one row per telemetry sample, one header row, no
comments; UTF-8, comma-separated, names and text cells in double quotes (RFC 4180). Units
are in the column names and are the clinic's: degrees, millimetres, bar (gauge), newtons,
newton metres. Columns, in order:

    time_s (device clock), wall_unix_s (station clock, Unix), mode (IDLE, HOMING, READY,
    ACTIVE, HOLD, ESTOP, FAULT), trip (NONE or the latched safety trip), segment_id,
    set, rep (1-based; 0 outside a repetition),
    x_mm y_mm z_mm roll_deg pitch_deg yaw_deg (measured pose, relative to home),
    x_cmd_mm … yaw_cmd_deg (commanded pose),
    force_x_n force_y_n force_z_n torque_roll_nm torque_pitch_nm torque_yaw_nm (the
    patient's wrench on the foot plate at the ankle),
    stiffness_x_n_per_m … stiffness_roll_nm_per_rad …, damping_x_ns_per_m …
    damping_roll_nms_per_rad … (impedance in force),
    leg1_mm … leg6_mm (piston displacements), p1_bar … p12_bar (chambers: p(2i-1) cap side
    and p(2i) rod side of leg i), supply_bar, duty1 … duty12 (valve duty in slots of 28;
    positive intake, negative exhaust).

Numbers are rounded for reading (:data:`COLUMNS` gives the decimals: 0.001 degree, 0.001 mm,
0.001 N and N·m, 0.0001 bar, 1 µs). A value the device could not measure (NaN) is an empty
cell.

``parquet`` — for analysis: the same columns and units at full precision (float64 times,
float32 measurements as the device sends them, missing values null), zstd-compressed; mode
and trip are text (dictionary-encoded on disk). The schema metadata holds the session as
JSON: ``ankle.header``, ``ankle.events`` and ``ankle.summary``; each field's metadata holds
its ``unit``.

``mcap`` — for Foxglove and robotics tools: JSON messages on channels with JSON Schema.
``/telemetry`` carries each sample in the device's own SI units (m, rad, N, N·m, Pa, s), as
the serial protocol and the recording do; ``/events`` carries the session events. Log and
publish times are the station's wall clock in Unix nanoseconds; ``timestamp`` in each
message is the same time as ``{sec, nsec}``. Metadata records: ``session`` (the header),
``summary`` and, when the session ended, ``end`` — nested values flattened to dotted keys.

``json`` — the session without its samples: ``{"header", "summary", "events", "end"}``,
indented, without NaN (null instead).
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import IO, Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq
from mcap.writer import Writer
from numpy.typing import NDArray
from pydantic import BaseModel

from device.axes import AXES
from device.protocol.messages import DeviceMode
from device.trips import Trip
from sessions.recording import Recording, SessionEvent
from sessions.summary import summarize

FORMATS = ("csv", "parquet", "mcap", "json")
MEDIA_TYPES: dict[str, str] = {
    "csv": "text/csv; charset=utf-8",
    "parquet": "application/vnd.apache.parquet",
    # MCAP has no registered media type; its own docs serve it as plain bytes
    "mcap": "application/octet-stream",
    "json": "application/json",
}
FILE_SUFFIX: dict[str, str] = {fmt: f".{fmt}" for fmt in FORMATS}

_AXES6 = AXES
_PA_PER_BAR = 1e5


@dataclass(frozen=True)
class Column:
    """One column of the CSV and Parquet exports, from one field (and index) of a sample."""

    name: str
    field: str
    index: int | None
    scale: float
    """Recording unit to column unit."""
    decimals: int | None
    """Rounding in the CSV; None: not a float."""
    unit: str


def _pose_columns(field: str, suffix: str) -> list[Column]:
    return [
        Column(f"{a}{suffix}_mm", field, i, 1000.0, 3, "mm") for i, a in enumerate(_AXES6[:3])
    ] + [
        Column(f"{a}{suffix}_deg", field, i + 3, float(np.degrees(1.0)), 3, "deg")
        for i, a in enumerate(_AXES6[3:])
    ]


def _six(field: str, lin: str, rot: str, lin_unit: str, rot_unit: str, dec: int) -> list[Column]:
    return [
        Column(lin.format(a), field, i, 1.0, dec, lin_unit) for i, a in enumerate(_AXES6[:3])
    ] + [Column(rot.format(a), field, i + 3, 1.0, dec, rot_unit) for i, a in enumerate(_AXES6[3:])]


COLUMNS: tuple[Column, ...] = (
    Column("time_s", "t", None, 1.0, 6, "s"),
    Column("wall_unix_s", "wall", None, 1.0, 6, "s"),
    Column("mode", "mode", None, 1.0, None, ""),
    Column("trip", "trip", None, 1.0, None, ""),
    Column("segment_id", "segment_id", None, 1.0, None, ""),
    Column("set", "set", None, 1.0, None, ""),
    Column("rep", "rep", None, 1.0, None, ""),
    *_pose_columns("pose", ""),
    *_pose_columns("pose_cmd", "_cmd"),
    *_six("wrench", "force_{}_n", "torque_{}_nm", "N", "N·m", 3),
    *_six("stiffness", "stiffness_{}_n_per_m", "stiffness_{}_nm_per_rad", "N/m", "N·m/rad", 2),
    *_six("damping", "damping_{}_ns_per_m", "damping_{}_nms_per_rad", "N·s/m", "N·m·s/rad", 3),
    *(Column(f"leg{i + 1}_mm", "legs", i, 1000.0, 3, "mm") for i in range(6)),
    *(Column(f"p{i + 1}_bar", "pressures", i, 1 / _PA_PER_BAR, 4, "bar") for i in range(12)),
    Column("supply_bar", "supply", None, 1 / _PA_PER_BAR, 4, "bar"),
    *(Column(f"duty{i + 1}", "duty", i, 1.0, None, "slots of 28") for i in range(12)),
)
"""The CSV and Parquet columns, in order."""

_ENUMS: dict[str, type[IntEnum]] = {"mode": DeviceMode, "trip": Trip}


BLOCK_ROWS = 32_768
"""Samples formatted at a time (CSV rows, MCAP messages): an export is written to its file
block by block, so that what is held at once is a block's text (about 30 MB of MCAP
messages), not the whole session's. A 2 h session at 250 Hz made as one piece held 1.8 M
messages and peaked at 5.2 GB."""


def content_hash(data: bytes) -> str:
    """SHA-256 of an export, hex."""
    return hashlib.sha256(data).hexdigest()


def _exporter(fmt: str) -> Callable[[Recording, IO[bytes]], None]:
    try:
        return _EXPORTERS[fmt]
    except KeyError:
        raise ValueError(f"unknown export format {fmt!r}; one of {', '.join(FORMATS)}") from None


def export(rec: Recording, fmt: str) -> bytes:
    """The recording as one of :data:`FORMATS`, in memory (small sessions and tests; the
    server writes files with :func:`write_export`)."""
    make = _exporter(fmt)
    buf = io.BytesIO()
    make(rec, buf)
    return buf.getvalue()


def write_export(rec: Recording, fmt: str, path: Path) -> str:
    """Write an export so that ``path`` is whole or absent, never partial; its SHA-256.

    Written to the file as it is made, then hashed by reading it back a megabyte at a time:
    the whole export is never in memory."""
    make = _exporter(fmt)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w+b") as f:
            make(rec, f)
            f.flush()
            os.fsync(f.fileno())
            f.seek(0)
            digest = hashlib.file_digest(f, "sha256").hexdigest()
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return digest


def _blocks(samples: NDArray[np.void]) -> Iterator[NDArray[np.void]]:
    for start in range(0, len(samples), BLOCK_ROWS):
        yield samples[start : start + BLOCK_ROWS]


# -- CSV and Parquet ------------------------------------------------------------------------


def _enum_names(enum: type[IntEnum], codes: NDArray[np.uint8]) -> pa.Array:
    """Names of u8 codes, looked up all at once; an unknown code keeps its number."""
    known = {int(m): m.name for m in enum}
    table = pa.array([known.get(i, str(i)) for i in range(256)], pa.string())
    return pc.take(table, pa.array(codes.astype(np.int64)))


def _column_values(samples: NDArray[np.void], col: Column) -> NDArray[Any]:
    raw = samples[col.field]
    values = raw if col.index is None else raw[:, col.index]
    if col.decimals is None:
        return np.ascontiguousarray(values)
    # Scale in float64 so that the conversion adds no rounding of its own.
    scaled = values.astype(np.float64) * col.scale
    return scaled if values.dtype == np.float64 else scaled.astype(np.float32)


def _table(samples: NDArray[np.void], *, rounded: bool) -> pa.Table:
    arrays: list[pa.Array] = []
    fields: list[pa.Field] = []
    for col in COLUMNS:
        if col.field in _ENUMS:
            arr = _enum_names(_ENUMS[col.field], samples[col.field])
        else:
            values = _column_values(samples, col)
            if rounded and col.decimals is not None:
                # Round in float64, then store in the column's type: a float32 column then
                # prints as the short decimal, not as the float32 nearest to it in full.
                values = np.round(values.astype(np.float64), col.decimals).astype(values.dtype)
            # from_pandas: NaN becomes null (an empty CSV cell, a Parquet null)
            arr = pa.array(values, from_pandas=True)
        arrays.append(arr)
        fields.append(pa.field(col.name, arr.type, metadata={b"unit": col.unit.encode()}))
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields))


def _csv(rec: Recording, out: IO[bytes]) -> None:
    # Arrow's writer quotes every text cell ("ACTIVE"); that is plain RFC 4180, read the same
    # by pandas and spreadsheets, and it formats 180k rows in C++ instead of Python. Each row
    # is formatted on its own, so block by block gives the same bytes as all at once.
    options = pa_csv.WriteOptions(quoting_style="needed")
    schema = _table(rec.samples[:0], rounded=True).schema
    with pa_csv.CSVWriter(out, schema, write_options=options) as w:
        for block in _blocks(rec.samples):
            w.write_table(_table(block, rounded=True))


def _parquet(rec: Recording, out: IO[bytes]) -> None:
    # One table, not blocks: its row groups (and so its bytes) follow the whole session.
    # What is held is the session's columns, a little more than the recording itself.
    table = _table(rec.samples, rounded=False).replace_schema_metadata(
        {
            b"ankle.header": rec.header.model_dump_json().encode(),
            b"ankle.events": _json_list(rec.events).encode(),
            b"ankle.summary": summarize(rec).model_dump_json().encode(),
        }
    )
    # Dictionaries pay off only for the two text columns; on noisy floats they cost time and
    # bytes. zstd: about 30% smaller than the default snappy, read by every current reader.
    pq.write_table(table, out, use_dictionary=["mode", "trip"], compression="zstd")


def _json_list(events: list[SessionEvent]) -> str:
    # pydantic writes NaN as null; json.dumps would write NaN, which is not JSON
    return "[" + ",".join(e.model_dump_json() for e in events) + "]"


# -- MCAP ------------------------------------------------------------------------------------


def _number_schema(description: str) -> dict[str, Any]:
    return {"type": ["number", "null"], "description": description}


def _axes_schema(description: str, lin_unit: str, rot_unit: str) -> dict[str, Any]:
    return {
        "type": "object",
        "description": description,
        "properties": {
            a: _number_schema(lin_unit if i < 3 else rot_unit) for i, a in enumerate(_AXES6)
        },
        "required": list(_AXES6),
    }


def _array_schema(n: int, description: str) -> dict[str, Any]:
    return {
        "type": "array",
        "description": description,
        "items": {"type": ["number", "null"]},
        "minItems": n,
        "maxItems": n,
    }


_TIME_SCHEMA: dict[str, Any] = {
    "type": "object",
    "description": "Station wall clock, Unix time.",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
    },
    "required": ["sec", "nsec"],
}

_TELEMETRY_PROPERTIES: dict[str, Any] = {
    "timestamp": _TIME_SCHEMA,
    "t": _number_schema("Device time, s."),
    "mode": {"type": "string", "description": ", ".join(m.name for m in DeviceMode)},
    "trip": {"type": "string", "description": "Latched safety trip, NONE if none."},
    "segment_id": {"type": "integer"},
    "set": {"type": "integer", "description": "1-based set; 0 outside a repetition."},
    "rep": {"type": "integer", "description": "1-based repetition; 0 outside one."},
    "pose": _axes_schema("Measured pose relative to home.", "m", "rad"),
    "pose_cmd": _axes_schema("Commanded pose relative to home.", "m", "rad"),
    "wrench": _axes_schema("The patient's wrench on the foot plate.", "N", "N m"),
    "stiffness": _axes_schema("Stiffness in force.", "N/m", "N m/rad"),
    "damping": _axes_schema("Damping in force.", "N s/m", "N m s/rad"),
    "legs": _array_schema(6, "Piston displacements, m."),
    "pressures": _array_schema(
        12, "Chamber gauge pressures, Pa: 2i cap side, 2i+1 rod side of leg i+1."
    ),
    "supply": _number_schema("Supply gauge pressure, Pa."),
    "duty": _array_schema(12, "Valve duty in slots of 28; + intake, - exhaust."),
}

TELEMETRY_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "ankle.Telemetry",
    "description": "One telemetry sample of the ankle platform, SI units.",
    "type": "object",
    "properties": _TELEMETRY_PROPERTIES,
    "required": list(_TELEMETRY_PROPERTIES),
}
"""JSON Schema of a ``/telemetry`` message."""

EVENT_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "ankle.SessionEvent",
    "type": "object",
    "properties": {
        "timestamp": _TIME_SCHEMA,
        "t": _number_schema("Device time, s, when known."),
        "kind": {"type": "string"},
        "by": {"type": "string"},
        "detail": {"type": "object"},
    },
    "required": ["timestamp", "t", "kind", "by", "detail"],
}
"""JSON Schema of an ``/events`` message."""


def _unix_ns(wall: NDArray[np.float64]) -> NDArray[np.int64]:
    # MCAP times are unsigned: a clock that read NaN or before 1970 is logged at 0
    ns = np.round(np.nan_to_num(wall, nan=0.0, posinf=0.0, neginf=0.0) * 1e9)
    return np.clip(ns, 0, 2**63 - 1).astype(np.int64)


def _json_numbers(values: NDArray[Any]) -> pa.Array:
    """Each value as JSON text; NaN and infinities as null."""
    arr = pa.array(np.ascontiguousarray(values))
    text = pc.cast(arr, pa.string())
    if pa.types.is_floating(arr.type):
        # Arrow prints float32 as its shortest decimal, and NaN as "nan", which JSON lacks
        text = pc.if_else(pc.is_finite(arr), text, pa.scalar("null"))
    return text


def _telemetry_messages(s: NDArray[np.void], ns: NDArray[np.int64]) -> list[bytes]:
    """Each sample as one JSON message, formatted column by column in Arrow, not per row."""
    parts: list[Any] = []

    def lit(text: str) -> None:
        parts.append(pa.scalar(text))

    def num(values: NDArray[Any]) -> None:
        parts.append(_json_numbers(values))

    def obj(name: str, field: str) -> None:
        for i, a in enumerate(_AXES6):
            lit(f'"{name}":{{"{a}":' if i == 0 else f',"{a}":')
            num(s[field][:, i])
        lit("},")

    def arr(name: str, field: str, end: str = "],") -> None:
        lit(f'"{name}":[')
        for i in range(s[field].shape[1]):
            if i:
                lit(",")
            num(s[field][:, i])
        lit(end)

    lit('{"timestamp":{"sec":')
    num(ns // 1_000_000_000)
    lit(',"nsec":')
    num(ns % 1_000_000_000)
    lit('},"t":')
    num(s["t"])
    for name in ("mode", "trip"):
        lit(f',"{name}":"')
        parts.append(_enum_names(_ENUMS[name], s[name]))
        lit('"')
    for name in ("segment_id", "set", "rep"):
        lit(f',"{name}":')
        num(s[name])
    lit(",")
    for name in ("pose", "pose_cmd", "wrench", "stiffness", "damping"):
        obj(name, name)
    arr("legs", "legs")
    arr("pressures", "pressures")
    lit('"supply":')
    num(s["supply"])
    lit(",")
    arr("duty", "duty", end="]}")
    joined = pc.binary_join_element_wise(*parts, "")
    out: list[bytes] = pc.cast(joined, pa.binary()).to_pylist()
    return out


def _flatten(value: Any, prefix: str = "") -> dict[str, str]:
    """MCAP metadata is text to text: nested objects become dotted keys, the rest JSON."""
    if isinstance(value, dict) and value:
        out: dict[str, str] = {}
        for k, v in value.items():
            out.update(_flatten(v, f"{prefix}{k}."))
        return out
    key = prefix.removesuffix(".")
    return {key: value if isinstance(value, str) else json.dumps(value, allow_nan=False)}


def _jsonable(model: BaseModel) -> Any:
    # Through pydantic's JSON, which writes NaN as null, so that what follows is plain JSON.
    return json.loads(model.model_dump_json())


def _mcap(rec: Recording, out: IO[bytes]) -> None:
    w = Writer(out)
    w.start(profile="", library="ankle-telerehab")
    telemetry = w.register_channel(
        "/telemetry",
        "json",
        w.register_schema("ankle.Telemetry", "jsonschema", json.dumps(TELEMETRY_SCHEMA).encode()),
    )
    events = w.register_channel(
        "/events",
        "json",
        w.register_schema("ankle.SessionEvent", "jsonschema", json.dumps(EVENT_SCHEMA).encode()),
    )
    seq = 0
    for block in _blocks(rec.samples):
        ns = _unix_ns(block["wall"].astype(np.float64))
        for data, t in zip(_telemetry_messages(block, ns), ns.tolist(), strict=True):
            w.add_message(telemetry, t, data, t, seq)
            seq += 1
    event_ns = _unix_ns(np.array([e.wall for e in rec.events], dtype=np.float64)).tolist()
    for seq, (e, t) in enumerate(zip(rec.events, event_ns, strict=True)):
        body = _jsonable(e)
        message = {
            "timestamp": {"sec": t // 1_000_000_000, "nsec": t % 1_000_000_000},
            "t": body["t"],
            "kind": body["kind"],
            "by": body["by"],
            "detail": body["detail"],
        }
        w.add_message(events, t, json.dumps(message, allow_nan=False).encode(), t, seq)
    w.add_metadata("session", _flatten(_jsonable(rec.header)))
    w.add_metadata("summary", _flatten(_jsonable(summarize(rec))))
    if rec.end is not None:
        w.add_metadata("end", _flatten(_jsonable(rec.end)))
    w.finish()  # type: ignore[no-untyped-call]  # mcap leaves it unannotated


# -- JSON -------------------------------------------------------------------------------------


def _json(rec: Recording, out: IO[bytes]) -> None:
    doc = {
        "header": _jsonable(rec.header),
        "summary": _jsonable(summarize(rec)),
        "events": [_jsonable(e) for e in rec.events],
        "end": _jsonable(rec.end) if rec.end is not None else None,
    }
    out.write((json.dumps(doc, indent=2, ensure_ascii=False, allow_nan=False) + "\n").encode())


_EXPORTERS: dict[str, Callable[[Recording, IO[bytes]], None]] = {
    "csv": _csv,
    "parquet": _parquet,
    "mcap": _mcap,
    "json": _json,
}
