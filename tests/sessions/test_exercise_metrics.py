"""Metrics per exercise against synthetic sessions whose answers are known on paper.

Each session is built repetition by repetition at 100 Hz: a second of READY between
repetitions carries absurd values (40 degrees, 60 N·m) that would show in every number if it
were counted. Angles are written as the device sends them (radians), torques in N·m.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from device.protocol.messages import DeviceMode
from sessions.metrics import HOLD_FRACTION, exercise_metrics
from sessions.prescription import AXIS_INDEX, EXERCISE_LIBRARY, ExerciseKind
from sessions.recording import (
    SAMPLE_DTYPE,
    DeviceInfo,
    End,
    Header,
    Recording,
    RecordingWriter,
    read,
)
from sessions.summary import Summary, summarize

HZ = 100.0
DT = 1.0 / HZ
K = 40.0  # N·m/rad: the patient's torque follows the angle like a spring
Series = Callable[[NDArray[np.float64]], NDArray[Any]]
"""Seconds since the repetition started → degrees (angle) or N·m (torque)."""


def header(kind: ExerciseKind, axes: list[dict[str, Any]] | None = None) -> Header:
    body = EXERCISE_LIBRARY[kind].defaults.model_dump(mode="json")
    if axes is not None:
        body["axes"] = axes
    return Header(
        session_id="5b2c8a1e-0f4d-4a57-8e3b-9c6d1e2f3a4b",
        station_id=1,
        patient_id=1,
        prescription_id=1,
        prescription=body,
        device=DeviceInfo(firmware="sim", hardware="sim", telemetry_hz=100, home_pose=[0.0] * 6),
        software="test",
        started_at=1_700_000_000.0,
    )


def samples(reps: list[dict[str, tuple[Series, Series]]], rep_s: float) -> NDArray[np.void]:
    """READY, then each repetition (ACTIVE, ``rep_s`` long) followed by a second of READY.

    Each repetition maps an axis to (angle in degrees, torque in N·m) as functions of time."""
    n_rep = round(rep_s * HZ) + 1  # both ends of the repetition
    n_ready = round(HZ)
    blocks: list[NDArray[np.void]] = []
    ready = np.zeros(n_ready, SAMPLE_DTYPE)
    ready["mode"] = int(DeviceMode.READY)
    for axis in ("roll", "pitch", "yaw"):
        ready["pose"][:, AXIS_INDEX[axis]] = math.radians(40.0)
        ready["wrench"][:, AXIS_INDEX[axis]] = 60.0
    blocks.append(ready)
    for k, rep in enumerate(reps):
        block = np.zeros(n_rep, SAMPLE_DTYPE)
        block["mode"] = int(DeviceMode.ACTIVE)
        block["set"] = 1
        block["rep"] = k + 1
        block["segment_id"] = k + 1
        t: NDArray[np.float64] = np.arange(n_rep, dtype=np.float64) * DT
        for axis, (angle, torque) in rep.items():
            block["pose"][:, AXIS_INDEX[axis]] = np.radians(angle(t))
            block["pose_cmd"][:, AXIS_INDEX[axis]] = 0.0  # a hold at home: what strength asks
            block["wrench"][:, AXIS_INDEX[axis]] = torque(t)
        blocks.extend([block, ready.copy()])
    s = np.concatenate(blocks)
    s["t"] = 5.0 + np.arange(len(s)) * DT
    s["wall"] = 1_700_000_000.0 + s["t"]
    return s


def recording(tmp_path: Path, head: Header, rows: NDArray[np.void]) -> Recording:
    path = tmp_path / "s.rec"
    with RecordingWriter(path, head) as w:
        for row in rows.tolist():
            w.add(row)
        w.end(
            End(
                ended_at=head.started_at + 60,
                reason="completed",
                sets_completed=1,
                repetitions_completed=1,
            )
        )
    return read(path)


def lopsided(up_deg: float, down_deg: float) -> tuple[Series, Series]:
    """One 2 s cycle: up to ``up_deg`` and back in the first second, down to ``down_deg``
    and back in the next; the patient's torque a spring of K about home."""

    def angle(t: NDArray[np.float64]) -> NDArray[np.float64]:
        s = np.sin(math.pi * t)
        return np.where(s >= 0, up_deg * s, down_deg * s)

    return angle, lambda t: K * np.radians(angle(t))


def test_strength_per_direction_and_per_repetition(tmp_path: Path) -> None:
    head = header(ExerciseKind.STRENGTH)  # pitch, a hold at 0 with K = 40
    rec = recording(
        tmp_path, head, samples([{"pitch": lopsided(10, 5)}, {"pitch": lopsided(6, 8)}], 2.0)
    )
    m = exercise_metrics(rec, ["pitch"])

    assert m.kind == "strength"
    assert [(r.set, r.rep) for r in m.repetitions] == [(1, 1), (1, 2)]
    r1, r2 = (r.axes["pitch"] for r in m.repetitions)
    # Furthest angle each way, per repetition and over the session.
    assert (r1.positive.peak_angle_deg, r1.negative.peak_angle_deg) == pytest.approx(
        (10, 5), abs=1e-4
    )
    assert (r2.positive.peak_angle_deg, r2.negative.peak_angle_deg) == pytest.approx(
        (6, 8), abs=1e-4
    )
    whole = m.axes["pitch"]
    assert (whole.positive.peak_angle_deg, whole.negative.peak_angle_deg) == pytest.approx(
        (10, 8), abs=1e-4
    )
    assert whole.range_deg == pytest.approx(18, abs=1e-4)
    # Torque: peak K·A each way; mean |τ| while pushing that way is 2/π of the peak (a sine).
    assert r1.positive.peak_torque_nm == pytest.approx(K * math.radians(10), rel=1e-5)
    assert r1.negative.peak_torque_nm == pytest.approx(K * math.radians(5), rel=1e-5)
    assert r1.positive.mean_torque_nm == pytest.approx(2 / math.pi * K * math.radians(10), rel=1e-2)
    assert r1.negative.mean_torque_nm == pytest.approx(2 / math.pi * K * math.radians(5), rel=1e-2)
    # Work: a spring takes K·A²/2 while |q| grows, once each way per cycle.
    assert r1.positive.work_j == pytest.approx(K * math.radians(10) ** 2 / 2, rel=1e-3)
    assert r1.negative.work_j == pytest.approx(K * math.radians(5) ** 2 / 2, rel=1e-3)
    assert r2.negative.work_j == pytest.approx(K * math.radians(8) ** 2 / 2, rel=1e-3)
    # The two directions add up to the summary's work on the axis.
    s = summarize(rec)
    up, down = whole.positive.work_j, whole.negative.work_j
    assert up is not None and down is not None
    assert s.axes["pitch"].work_j == pytest.approx(up + down)
    assert s.metrics == m


def test_a_strength_hold_has_no_time_in_target(tmp_path: Path) -> None:
    """The target of a strength exercise follows the patient: "on target" would say nothing."""
    rec = recording(
        tmp_path, header(ExerciseKind.STRENGTH), samples([{"pitch": lopsided(6.7, 4.5)}], 2.0)
    )
    s = summarize(rec)
    assert s.axes["pitch"].time_in_target_pct is None
    assert s.axes["pitch"].tracking_error_rms_deg is None
    assert s.metrics is not None and s.metrics.tracking == {}


def test_flexibility_tracks_its_moving_target(tmp_path: Path) -> None:
    head = header(ExerciseKind.FLEXIBILITY)  # pitch sine
    rows = samples([{"pitch": lopsided(12, 9)}], 2.0)
    p = AXIS_INDEX["pitch"]
    active = rows["mode"] == int(DeviceMode.ACTIVE)
    rows["pose_cmd"][active, p] = rows["pose"][active, p] - np.radians(1.0)  # 1 degree behind
    rec = recording(tmp_path, head, rows)
    m = exercise_metrics(rec, ["pitch"])
    assert m.axes["pitch"].positive.peak_angle_deg == pytest.approx(12, abs=1e-4)
    assert m.axes["pitch"].negative.peak_angle_deg == pytest.approx(9, abs=1e-4)
    assert m.tracking["pitch"].error_rms_deg == pytest.approx(1.0, rel=1e-4)
    assert m.tracking["pitch"].time_in_target_pct == pytest.approx(100.0)
    assert summarize(rec).axes["pitch"].time_in_target_pct == pytest.approx(100.0)


def step(level: float, start: float, end: float, rest: float = 0.0) -> Series:
    return lambda t: np.where((t >= start - 1e-9) & (t < end - 1e-9), level, rest)


def test_isometric_torque_and_time_held(tmp_path: Path) -> None:
    head = header(ExerciseKind.ISOMETRIC)
    still: Series = lambda t: np.zeros_like(t)  # noqa: E731
    reps = [
        # A push up (toes lifted against the plate) of 20 N·m for 3 s, after a 0.5 s build-up
        {"pitch": (still, lambda t: step(-20.0, 1.0, 4.0)(t) + step(-8.0, 0.5, 1.0)(t))},
        # A push down of 15 N·m for 2 s, 0.4 N·m of noise around it
        {"pitch": (still, lambda t: step(15.0, 2.0, 4.0, rest=0.4)(t))},
    ]
    rec = recording(tmp_path, head, samples(reps, 5.0))
    m = exercise_metrics(rec, ["pitch"])
    h1, h2 = (r.holds["pitch"] for r in m.repetitions)
    assert h1.sign == -1
    assert h1.torque_nm == pytest.approx(20)
    assert h1.peak_torque_nm == pytest.approx(20)
    assert h1.held_s == pytest.approx(3.0, abs=DT)  # the 8 N·m build-up is below half the peak
    assert HOLD_FRACTION * 20.0 > 8.0
    assert h2.sign == 1
    assert h2.torque_nm == pytest.approx(15)
    assert h2.held_s == pytest.approx(2.0, abs=DT)


def test_balance_sway(tmp_path: Path) -> None:
    head = header(ExerciseKind.BALANCE)  # roll and pitch
    amp = 2.0
    roll: Series = lambda t: amp * np.sin(2 * math.pi * 0.5 * t)  # noqa: E731
    flat: Series = lambda t: np.zeros_like(t)  # noqa: E731
    rec = recording(tmp_path, head, samples([{"roll": (roll, flat), "pitch": (flat, flat)}], 4.0))
    m = exercise_metrics(rec, ["roll", "pitch"])
    assert m.sway is not None
    assert m.sway.axes["roll"].rms_deg == pytest.approx(amp / math.sqrt(2), rel=1e-2)
    assert m.sway.axes["roll"].range_deg == pytest.approx(2 * amp, abs=1e-4)
    assert m.sway.axes["pitch"].rms_deg == pytest.approx(0.0)
    # Two cycles of a sine travel 4 amplitudes each.
    assert m.sway.path_deg == pytest.approx(8 * amp, rel=1e-4)
    assert m.sway.mean_speed_deg_s == pytest.approx(8 * amp / 4.0, rel=2e-2)
    assert m.tracking == {}


def test_rom_assessment_trials_per_direction(tmp_path: Path) -> None:
    head = header(ExerciseKind.ROM_ASSESSMENT)  # pitch and roll
    trials = [(20.0, 14.0, 8.0, 6.0), (21.0, 13.0, 9.0, 5.0), (19.5, 14.5, 7.0, 6.5)]
    reps = [
        {"pitch": lopsided(p_up, p_down), "roll": lopsided(r_up, r_down)}
        for p_up, p_down, r_up, r_down in trials
    ]
    m = exercise_metrics(recording(tmp_path, head, samples(reps, 2.0)), ["pitch", "roll"])
    got = [
        (
            r.axes["pitch"].positive.peak_angle_deg,
            r.axes["pitch"].negative.peak_angle_deg,
            r.axes["roll"].positive.peak_angle_deg,
            r.axes["roll"].negative.peak_angle_deg,
        )
        for r in m.repetitions
    ]
    assert got == [pytest.approx(t, abs=1e-4) for t in trials]
    assert m.tracking == {}


def test_no_exercise_gives_nulls_never_nan(tmp_path: Path) -> None:
    rows = samples([], 1.0)
    m = exercise_metrics(recording(tmp_path, header(ExerciseKind.STRENGTH), rows), ["pitch"])
    assert m.repetitions == []
    assert m.axes["pitch"].positive.peak_angle_deg is None
    assert m.axes["pitch"].positive.work_j is None
    json.loads(m.model_dump_json(), parse_constant=lambda c: pytest.fail(f"{c} in JSON"))


def test_a_summary_stored_before_metrics_still_reads(tmp_path: Path) -> None:
    rec = recording(
        tmp_path, header(ExerciseKind.STRENGTH), samples([{"pitch": lopsided(5, 5)}], 2.0)
    )
    old = summarize(rec).model_dump(mode="json")
    del old["metrics"]
    assert Summary.model_validate(old).metrics is None


@pytest.mark.parametrize("kind", [ExerciseKind.STRENGTH, ExerciseKind.ISOMETRIC])
def test_each_repetition_is_its_samples_wherever_they_lie(
    tmp_path: Path, kind: ExerciseKind
) -> None:
    """A repetition's figures come from its own samples (sorted once), value for value what
    a mask of the whole recording gives, even where the station's tags do not come in runs:
    a (set, rep) that comes back later, two interleaved, a gap in the telemetry inside one,
    unmeasured angles and torques."""
    from sessions.metrics import _axis_metrics, _Columns, _hold

    rng = np.random.default_rng(3)
    n = 6000
    rows = np.zeros(n, SAMPLE_DTYPE)
    dt = np.full(n, DT)
    dt[rng.random(n) < 0.003] = 0.5  # gaps
    rows["t"] = 5.0 + np.cumsum(dt)
    rows["wall"] = 1_700_000_000.0 + rows["t"]
    rows["mode"] = np.where(rng.random(n) < 0.9, int(DeviceMode.ACTIVE), int(DeviceMode.HOLD))
    segment = np.arange(n) // 150
    rows["set"] = segment % 2 + 1  # the sets interleave: (1, r) and (2, r) alternate
    rows["rep"] = np.where(rng.random(n) < 0.05, 0, (segment // 2) % 5 + 1)  # and come back
    for name, scale in (("pose", 0.3), ("wrench", 20.0)):
        x = scale * np.sin(np.arange(n)[:, None] / 37.0 + np.arange(6)) + rng.normal(
            0, 0.01 * scale, (n, 6)
        )
        x[rng.random((n, 6)) < 0.01] = np.nan
        rows[name] = x
    rec = recording(tmp_path, header(kind, [{"axis": "pitch"}, {"axis": "roll"}]), rows)
    axes = ["pitch", "roll"]

    m = exercise_metrics(rec, axes)

    c = _Columns(rec)
    in_rep = c.active & (c.rep > 0)
    pairs = sorted(set(zip(c.set[in_rep].tolist(), c.rep[in_rep].tolist(), strict=True)))
    assert [(r.set, r.rep) for r in m.repetitions] == pairs
    assert len(pairs) == 10
    for r in m.repetitions:
        mask = in_rep & (c.set == r.set) & (c.rep == r.rep)
        # Each comes back at least once, after other repetitions' samples.
        assert np.count_nonzero(np.diff(mask.astype(np.int8)) == 1) >= 2
        assert r.duration_s == float(c.weights[mask].sum())
        for axis in axes:
            assert r.axes[axis] == _axis_metrics(c, axis, mask)
            if kind == ExerciseKind.ISOMETRIC:
                assert r.holds.get(axis) == _hold(c, axis, mask)
    if kind == ExerciseKind.ISOMETRIC:
        assert any(r.holds for r in m.repetitions)
