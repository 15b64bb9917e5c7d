"""The clinician's summary against a synthetic session whose answers are known on paper.

The session: 1 s READY, then two cycles of a 10 degree, 0.5 Hz pitch sine while ACTIVE, then
1 s READY, at 100 Hz. The READY samples carry absurd values (30 degrees, 50 N·m, 20 degrees
off target) that would show in every number if they were counted.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray
from pydantic import ValidationError

from device.protocol.messages import DeviceMode
from sessions.metrics import TARGET_TOLERANCE_DEG
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
from sessions.summary import AxisSummary, summarize

HZ = 100.0
DT = 1.0 / HZ
AMPLITUDE_DEG = 10.0
FREQUENCY_HZ = 0.5
CYCLES = 2
K = 40.0  # N·m/rad: the patient's torque follows the angle like a spring
STARTED_AT = 1_700_000_000.0
WALL_OFFSET = 0.25  # station clock minus device clock, s
READY_S = 1.0
N_ACTIVE = round(CYCLES / FREQUENCY_HZ * HZ) + 1  # both ends of the two cycles
N_READY = round(READY_S * HZ)
N_OFF_TARGET = 101  # the first ACTIVE samples are 3 degrees off; the rest 1 degree
PA = 3e5  # chamber pressure, Pa
LEG_M = 0.05


def header(prescription: dict[str, Any] | None = None) -> Header:
    if prescription is None:
        prescription = PrescriptionBody.model_validate(
            {
                "exercise": "flexibility",
                "axes": [
                    {
                        "axis": "pitch",
                        "stiffness": K,
                        "damping": 2.0,
                        "waveform": "sine",
                        "amplitude": AMPLITUDE_DEG,
                        "frequency": FREQUENCY_HZ,
                    }
                ],
                "sets": 2,
                "repetitions": 3,
            }
        ).model_dump(mode="json")
    return Header(
        session_id="0b6c5f0e-3c1a-4f7e-9d1e-5a0f1c2b3d4e",
        station_id=7,
        patient_id=11,
        prescription_id=13,
        prescription=prescription,
        device=DeviceInfo(firmware="sim", hardware="sim", telemetry_hz=100, home_pose=[0.0] * 6),
        software="test",
        started_at=STARTED_AT,
    )


def sine_samples() -> NDArray[np.void]:
    """READY, two ACTIVE sine cycles, READY: 100 Hz rows of SAMPLE_DTYPE."""
    n = N_READY + N_ACTIVE + N_READY
    s = np.zeros(n, SAMPLE_DTYPE)
    t = 10.0 + np.arange(n) * DT
    s["t"] = t
    s["wall"] = STARTED_AT + WALL_OFFSET + t
    s["mode"] = int(DeviceMode.READY)
    s["legs"] = LEG_M
    s["pressures"] = PA
    s["supply"] = 2 * PA
    s["duty"] = np.arange(12, dtype=np.int8) - 6
    p = AXIS_INDEX["pitch"]

    ready = np.r_[0:N_READY, N_READY + N_ACTIVE : n]
    s["pose"][ready, p] = math.radians(30.0)
    s["pose_cmd"][ready, p] = math.radians(10.0)
    s["wrench"][ready, p] = 50.0

    act = np.arange(N_READY, N_READY + N_ACTIVE)
    s["mode"][act] = int(DeviceMode.ACTIVE)
    s["set"][act] = 1
    s["rep"][act] = 1 + np.arange(N_ACTIVE) // 100
    s["segment_id"][act] = 5
    q = math.radians(AMPLITUDE_DEG) * np.sin(2 * math.pi * FREQUENCY_HZ * (act - N_READY) * DT)
    error = np.where(np.arange(N_ACTIVE) < N_OFF_TARGET, 3.0, -1.0)
    s["pose"][act, p] = q
    s["pose_cmd"][act, p] = q - np.radians(error)
    s["wrench"][act, p] = K * q.astype(np.float32)
    return s


EVENTS = [
    *(
        SessionEvent(wall=STARTED_AT + 2.0 + i, t=12.0 + i, kind="rep_done", detail={"rep": i})
        for i in range(5)
    ),
    SessionEvent(wall=STARTED_AT + 3.5, t=13.25, kind="set_done", detail={"set": 1}),
    SessionEvent(
        wall=STARTED_AT + 4.0,
        t=13.75,
        kind="limit",
        by="device",
        detail={"text": "torque limit 40 N·m exceeded", "code": 4},
    ),
    SessionEvent(wall=STARTED_AT + 4.5, kind="fault", by="device", detail={"code": 6}),
    SessionEvent(wall=STARTED_AT + 5.0, kind="note", by="therapist:3", detail={"text": "ok"}),
]
END = End(ended_at=STARTED_AT + 20.0, reason="completed", sets_completed=2, repetitions_completed=6)


def write_recording(
    path: Path,
    samples: NDArray[np.void],
    events: list[SessionEvent],
    end: End | None,
    head: Header | None = None,
) -> Recording:
    """Write a session with the station's writer and read it back, as the server would."""
    with RecordingWriter(path, head or header()) as w:
        rows = samples.tolist()
        half = len(rows) // 2
        for row in rows[:half]:
            w.add(row)
        for e in events:
            w.event(e)
        for row in rows[half:]:
            w.add(row)
        if end is not None:
            w.end(end)
    return read(path)


@pytest.fixture
def rec(tmp_path: Path) -> Recording:
    return write_recording(tmp_path / "s.ankl", sine_samples(), EVENTS, END)


def no_nan_json(text: str) -> Any:
    def refuse(name: str) -> None:
        raise AssertionError(f"{name} in JSON")

    return json.loads(text, parse_constant=refuse)


def test_sine_session_gives_the_analytic_numbers(rec: Recording) -> None:
    s = summarize(rec)
    amp = math.radians(AMPLITUDE_DEG)

    assert s.samples == N_READY + N_ACTIVE + N_READY
    assert s.duration_s == pytest.approx(N_ACTIVE * DT, rel=1e-9)
    assert s.elapsed_s == pytest.approx((len(rec.samples) - 1) * DT, rel=1e-6)
    assert list(s.axes) == ["pitch"]
    a = s.axes["pitch"]
    assert a.rom_min_deg == pytest.approx(-AMPLITUDE_DEG, abs=1e-4)
    assert a.rom_max_deg == pytest.approx(AMPLITUDE_DEG, abs=1e-4)
    assert a.rom_deg == pytest.approx(2 * AMPLITUDE_DEG, abs=2e-4)
    assert a.peak_torque_nm == pytest.approx(K * amp, rel=1e-5)
    assert a.mean_torque_nm == pytest.approx(2 / math.pi * K * amp, rel=5e-3)
    # A spring: the patient puts K·A²/2 in on each of the 2 quarters per cycle where |q| grows.
    assert a.work_j == pytest.approx(CYCLES * K * amp**2, rel=1e-4)
    off = N_OFF_TARGET / N_ACTIVE
    assert a.tracking_error_rms_deg == pytest.approx(math.sqrt(off * 9 + (1 - off)), rel=1e-5)
    assert 1.0 < TARGET_TOLERANCE_DEG < 3.0  # the two error levels sit either side of it
    assert a.time_in_target_pct == pytest.approx(100 * (1 - off), rel=1e-9)


def test_counts_come_from_the_end_record_and_the_prescription(rec: Recording) -> None:
    s = summarize(rec)
    assert (s.sets_completed, s.repetitions_completed) == (2, 6)
    assert s.repetitions_prescribed == 6
    assert s.end_reason == "completed"
    assert s.events == {"fault": 1, "limit": 1, "note": 1, "rep_done": 5, "set_done": 1}
    assert [(f.kind, f.by) for f in s.faults] == [("limit", "device"), ("fault", "device")]
    assert s.faults[0].at_s == pytest.approx(4.0)
    assert s.faults[0].text == "torque limit 40 N·m exceeded"
    assert s.faults[1].text == '{"code":6}'


def test_without_an_end_record_the_events_are_counted(tmp_path: Path) -> None:
    rec = write_recording(tmp_path / "s.ankl", sine_samples(), EVENTS, None)
    s = summarize(rec)
    assert rec.end is None
    assert (s.sets_completed, s.repetitions_completed) == (1, 5)
    assert s.end_reason is None
    assert s.axes["pitch"].rom_deg == pytest.approx(2 * AMPLITUDE_DEG, abs=2e-4)


def test_an_empty_recording_is_zero_and_null_never_nan(tmp_path: Path) -> None:
    rec = write_recording(tmp_path / "s.ankl", np.zeros(0, SAMPLE_DTYPE), [], None)
    s = summarize(rec)
    assert (s.samples, s.duration_s, s.elapsed_s) == (0, 0.0, 0.0)
    assert (s.sets_completed, s.repetitions_completed, s.end_reason) == (0, 0, None)
    assert s.events == {} and s.faults == []
    assert set(s.axes["pitch"].model_dump().values()) == {None}
    assert no_nan_json(s.model_dump_json())["axes"]["pitch"]["work_j"] is None


def test_no_active_samples_means_no_exercise(rec: Recording) -> None:
    samples = rec.samples.copy()
    samples["mode"] = int(DeviceMode.HOLD)
    s = summarize(replace(rec, samples=samples))
    assert s.duration_s == 0.0
    assert s.samples == len(samples)
    assert s.axes["pitch"].rom_deg is None and s.axes["pitch"].work_j is None


def test_nan_readings_are_left_out_not_propagated(rec: Recording) -> None:
    samples = rec.samples.copy()
    p = AXIS_INDEX["pitch"]
    bad = np.flatnonzero(samples["mode"] == int(DeviceMode.ACTIVE))[::7]
    samples["pose"][bad, p] = np.nan
    samples["wrench"][bad, p] = np.inf
    samples["wrench"][0, p] = -np.inf  # READY and not moving: inf times a zero step
    s = summarize(replace(rec, samples=samples))
    a = s.axes["pitch"]
    assert a.rom_max_deg == pytest.approx(AMPLITUDE_DEG, abs=0.05)
    assert a.peak_torque_nm == pytest.approx(K * math.radians(AMPLITUDE_DEG), rel=1e-3)
    assert a.work_j is not None and 0 < a.work_j < CYCLES * K * math.radians(AMPLITUDE_DEG) ** 2
    assert a.tracking_error_rms_deg is not None and math.isfinite(a.tracking_error_rms_deg)
    no_nan_json(s.model_dump_json())


def test_work_counts_only_what_the_patient_puts_in(rec: Recording) -> None:
    """A damper-like torque along the motion is all positive work; against it, none."""
    samples = rec.samples.copy()
    p = AXIS_INDEX["pitch"]
    act = samples["mode"] == int(DeviceMode.ACTIVE)
    omega = 2 * math.pi * FREQUENCY_HZ
    amp = math.radians(AMPLITUDE_DEG)
    B = 3.0
    phase = omega * np.arange(N_ACTIVE) * DT
    samples["wrench"][act, p] = B * amp * omega * np.cos(phase)
    pushing = summarize(replace(rec, samples=samples)).axes["pitch"].work_j
    # B ∫ q̇² dt over whole cycles: B A² ω² T / 2
    assert pushing == pytest.approx(B * amp**2 * omega**2 * (CYCLES / FREQUENCY_HZ) / 2, rel=1e-3)

    samples["wrench"][act, p] *= -1
    assert summarize(replace(rec, samples=samples)).axes["pitch"].work_j == pytest.approx(
        0.0, abs=1e-9
    )


def test_a_gap_in_the_telemetry_is_not_exercise_time(rec: Recording) -> None:
    lost = np.r_[N_READY + 100 : N_READY + 200]  # one second of ACTIVE telemetry never arrived
    samples = np.delete(rec.samples, lost)
    s = summarize(replace(rec, samples=samples))
    # The sample before the gap counts one ordinary interval, not the whole second.
    assert s.duration_s == pytest.approx((N_ACTIVE - len(lost)) * DT, rel=1e-9)


def test_a_prescription_without_axes_summarizes_all_three(tmp_path: Path) -> None:
    rec = write_recording(tmp_path / "s.ankl", sine_samples(), [], None, header({}))
    s = summarize(rec)
    assert list(s.axes) == ["roll", "pitch", "yaw"]
    assert s.repetitions_prescribed is None
    assert s.axes["roll"].rom_deg == 0.0
    assert s.axes["pitch"].rom_deg == pytest.approx(2 * AMPLITUDE_DEG, abs=2e-4)


def test_the_models_refuse_nan() -> None:
    with pytest.raises(ValidationError):
        AxisSummary(
            rom_min_deg=math.nan,
            rom_max_deg=None,
            rom_deg=None,
            peak_torque_nm=None,
            mean_torque_nm=None,
            work_j=None,
            tracking_error_rms_deg=None,
            time_in_target_pct=None,
        )


def test_summarizing_180k_rows_is_vectorised(rec: Recording) -> None:
    """30 min at 100 Hz: a per-sample Python loop would take seconds, numpy milliseconds."""
    samples = np.resize(rec.samples, 180_000)
    samples["t"] = np.arange(len(samples)) * DT
    start = time.perf_counter()
    s = summarize(replace(rec, samples=samples))
    assert time.perf_counter() - start < 2.0  # about 0.05 s; a Python loop would be ~100x
    assert s.samples == 180_000
    assert s.axes["pitch"].rom_max_deg == pytest.approx(AMPLITUDE_DEG, abs=1e-4)


def game_event(
    wall: float, game: object, score: object, gates: object, missed: object
) -> SessionEvent:
    return SessionEvent(
        wall=STARTED_AT + wall,
        kind="game_score",
        by="patient",
        detail={"game": game, "score": score, "gates": gates, "missed": missed},
    )


def test_the_game_is_the_last_score_of_each_game_added_up(tmp_path: Path) -> None:
    """One event per gate with running totals; a page reloaded mid-session starts game 2."""
    games = [
        game_event(2.0, 11, 1, 1, 0),
        game_event(4.5, 11, 1, 2, 1),
        game_event(7.0, 11, 2, 3, 1),
        game_event(9.5, 23, 0, 1, 1),
        game_event(12.0, 23, 1, 2, 1),
        # Not results: a count that is not a whole number, a missing one, a negative one.
        game_event(13.0, 23, 5.5, 9, 0),
        game_event(13.5, 31, True, 1, 0),
        SessionEvent(wall=STARTED_AT + 14.0, kind="game_score", detail={"score": 4}),
        game_event(14.5, 37, -1, 0, 1),
    ]
    rec = write_recording(tmp_path / "s.ankl", sine_samples(), [*EVENTS, *games], END)
    s = summarize(rec)
    assert s.game is not None
    assert s.game.model_dump() == {"games": 2, "score": 3, "gates": 5, "missed": 2}
    assert s.events["game_score"] == len(games)
    assert no_nan_json(s.model_dump_json())["game"]["score"] == 3


def test_no_game_played_is_null(rec: Recording) -> None:
    s = summarize(rec)
    assert s.game is None
    assert no_nan_json(s.model_dump_json())["game"] is None
