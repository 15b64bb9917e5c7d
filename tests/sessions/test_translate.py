"""The device's messages in a session's words: one sample, one event, the device's identity."""

from __future__ import annotations

from dataclasses import replace

from device.protocol import messages as m
from sessions import wire
from sessions.translate import device_event, device_info, telemetry_sample


def test_a_sample_makes_a_valid_telemetry_batch() -> None:
    t = m.Telemetry(
        time=12.5, mode=m.DeviceMode.ACTIVE, segment_id=7, pose=(0.0, 0.0, 0.0, 0.1, 0.2, 0.0)
    )
    row = telemetry_sample(t, 2, 3)
    batch = wire.TelemetryBatch.of([row, {**row, "t": 12.51}], sent=100.0)
    newest = batch.newest()
    assert (newest.t, newest.mode, newest.segment_id) == (12.51, "ACTIVE", 7)
    assert (newest.set, newest.rep) == (2, 3)
    assert newest.pose[4] == 0.2


def test_events_are_named_as_sessions_name_them() -> None:
    e = m.Event(
        event_id=1,
        time=3.0,
        kind=m.EventKind.MODE_CHANGE,
        mode_from=m.DeviceMode.IDLE,
        mode_to=m.DeviceMode.HOMING,
        text="homing",
    )
    event = device_event(e, wall=1000.0)
    assert (event.kind, event.by, event.t, event.wall) == ("mode", "device", 3.0, 1000.0)
    assert event.detail["from"] == "IDLE" and event.detail["to"] == "HOMING"
    # A kind without a session name of its own keeps the device's, in lower case.
    low = device_event(replace(e, kind=m.EventKind.SUPPLY_LOW), 0.0)
    assert low.kind == "supply_low"


def test_the_device_a_session_ran_on() -> None:
    hello = m.DeviceHello(firmware="fw 1", hardware="sim", telemetry_hz=100)
    info = device_info(hello)
    assert (info.firmware, info.hardware, info.telemetry_hz) == ("fw 1", "sim", 100)
    assert len(info.home_pose) == 6
    assert not info.calibrated
    calibrated = replace(hello, capabilities=m.Capability.SIMULATED | m.Capability.CALIBRATED)
    assert device_info(calibrated).calibrated
