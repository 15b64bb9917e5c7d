"""A prescription becomes device segments with its own limits, in radians."""

from __future__ import annotations

import math

import pytest

from device.protocol.messages import DeviceHello
from device.safety import SafetyLimits
from sessions.prescription import EXERCISE_LIBRARY, ExerciseKind, PrescriptionBody
from station.timeline import segment_for


def hello() -> DeviceHello:
    lim = SafetyLimits()
    fields = {f: getattr(lim, f) for f in ("rom_low", "rom_high", "force_limit", "torque_limit")}
    return DeviceHello(
        firmware="t",
        hardware="sim",
        capabilities=0,  # type: ignore[arg-type]
        tick_hz=7000,
        pwm_hz=250,
        telemetry_hz=100,
        telemetry_hz_max=250,
        watchdog_ms=200,
        watchdog_ms_min=50,
        watchdog_ms_max=2000,
        stroke=0.1,
        min_length=0.2,
        home_pose=(0.0,) * 6,
        base_joints=(0.0,) * 18,
        platform_joints=(0.0,) * 18,
        stiffness_max=lim.stiffness_max,
        damping_max=lim.damping_max,
        stiffness_slew=lim.stiffness_slew,
        damping_slew=lim.damping_slew,
        axis_speed_max=lim.axis_speed_max,
        leg_speed_limit=lim.leg_speed_limit,
        segment_duration_max=600.0,
        **fields,
    )


def test_a_flexibility_sine_becomes_a_compliant_pitch_segment_in_radians() -> None:
    body = PrescriptionBody.model_validate(
        {
            "exercise": "flexibility",
            "axes": [
                {
                    "axis": "pitch",
                    "stiffness": 60,
                    "damping": 3,
                    "waveform": "sine",
                    "amplitude": 12,
                    "frequency": 0.1,
                    "rom_low": -15,
                    "rom_high": 15,
                }
            ],
            "repetition_s": 10,
            "torque_limit": 25,
        }
    )
    seg = segment_for(hello(), 7, body, {"pitch": 80.0}, {"pitch": 3.0})
    assert seg.segment_id == 7 and seg.duration == 10
    assert seg.amplitude[4] == pytest.approx(math.radians(12))
    assert seg.stiffness[4] == 80.0  # the live value, not the prescribed one
    assert seg.compliant[4] and not seg.compliant[3]
    assert seg.rom_low[4] == pytest.approx(math.radians(-15))
    assert seg.rom_high[4] == pytest.approx(math.radians(15))
    assert seg.rom_high[3] == pytest.approx(SafetyLimits().rom_high[3])  # unprescribed: device's
    assert seg.torque_limit == 25


@pytest.mark.parametrize("kind", list(ExerciseKind))
def test_every_library_default_makes_a_valid_segment(kind: ExerciseKind) -> None:
    body = EXERCISE_LIBRARY[kind].defaults
    k: dict[str, float] = {a.axis: a.stiffness for a in body.axes}
    b: dict[str, float] = {a.axis: a.damping for a in body.axes}
    seg = segment_for(hello(), 1, body, k, b)
    assert all(lo <= hi for lo, hi in zip(seg.rom_low, seg.rom_high, strict=True))
    assert any(seg.compliant) == EXERCISE_LIBRARY[kind].compliant
