"""Why the device holds, as the station learns it: the station's own HOLDs and the device's
events meet in one place, the stronger reason wins, and a hold is timed from its start."""

from __future__ import annotations

from device.protocol.messages import DeviceMode, Event, EventKind
from device.trips import Trip, describe
from sessions.wire import HoldInfo
from station.reasons import Reasons, ends_at, patient_resume_refusal

A, H, R = DeviceMode.ACTIVE, DeviceMode.HOLD, DeviceMode.READY


def event(
    kind: EventKind,
    mode_from: DeviceMode,
    mode_to: DeviceMode,
    code: int = 0,
    value: float = 0.0,
    text: str = "",
) -> Event:
    return Event(
        event_id=1,
        time=10.0,
        kind=kind,
        mode_from=mode_from,
        mode_to=mode_to,
        code=code,
        value=value,
        text=text,
    )


def held(reasons: Reasons) -> tuple[str, str, float, bool]:
    """Who holds, by whom, since when, and whether the patient may continue it."""
    hold = reasons.hold(H, paused=True)
    assert hold is not None
    return hold.code, hold.by, hold.since, hold.patient_may_resume


def test_the_patients_pause_is_theirs_until_the_device_holds_for_its_own_reason() -> None:
    reasons = Reasons()
    reasons.asked("patient", now=100.0)
    # The device's MODE_CHANGE for the HOLD the station sent does not hide who asked.
    reasons.device_event(event(EventKind.MODE_CHANGE, A, H, text="hold"), at=100.1)
    assert held(reasons) == ("pause", "patient", 100.0, True)
    # The therapist's HOLD during the pause takes it from the patient, from the same start.
    reasons.asked("therapist:7", now=130.0)
    assert held(reasons) == ("therapist", "therapist:7", 100.0, False)
    hold = reasons.hold(H, paused=True)
    assert hold is not None and "therapist" in patient_resume_refusal(hold)
    # A later pause by the patient does not weaken it.
    reasons.asked("patient", now=140.0)
    assert reasons.hold(H, paused=True) == hold
    # Resumed: nothing holds.
    reasons.device_event(event(EventKind.MODE_CHANGE, H, A, text="resumed"), at=150.0)
    assert reasons.hold(A, paused=False) is None


def test_the_watchdog_wins_over_a_pause_sent_as_the_link_stalled() -> None:
    reasons = Reasons()
    reasons.asked("patient", now=200.0)
    reasons.device_event(
        event(EventKind.WATCHDOG, A, H, value=412.0, text="no valid frame for 412 ms"),
        at=199.8,
    )
    assert held(reasons) == ("watchdog", "device", 199.8, False)
    hold = reasons.hold(H, paused=True)
    assert hold is not None and "412 ms" in hold.text
    assert "keep you safe" in patient_resume_refusal(hold)


def test_a_supply_hold_carries_the_devices_words_and_a_fault_replaces_any_hold() -> None:
    reasons = Reasons()
    text = "air supply low (4.2 bar): held until it recovers"
    reasons.device_event(event(EventKind.SUPPLY_LOW, A, H, text=text), at=5.0)
    hold = reasons.hold(H, paused=True)
    assert hold is not None and hold.code == "supply_low" and text in hold.text
    assert reasons.fault(H, 0) == ""

    fault = "SUPPLY_LOSS: the air supply was lost while moving"
    reasons.device_event(
        event(EventKind.FAULT, H, DeviceMode.FAULT, code=int(Trip.SUPPLY_LOSS), text=fault), 6.0
    )
    assert reasons.hold(DeviceMode.FAULT, paused=False) is None
    assert reasons.fault(DeviceMode.FAULT, int(Trip.SUPPLY_LOSS)) == fault
    # Re-armed: no fault any more.
    reasons.device_event(event(EventKind.MODE_CHANGE, DeviceMode.FAULT, DeviceMode.IDLE), 7.0)
    assert reasons.fault(DeviceMode.IDLE, 0) == ""


def test_what_the_device_finds_after_a_stop_is_told_beside_what_stopped_it() -> None:
    # The patient's e-stop, then a valve that sticks open after it: the therapist reads
    # both, the stop's cause first; a third word replaces the second, never the first.
    reasons = Reasons()
    reasons.device_event(
        event(EventKind.ESTOP, A, DeviceMode.ESTOP, int(Trip.ESTOP), text="emergency stop"), 1.0
    )
    held = "VALVE on chamber 2 (leg 1, rod side): its air reading moved with every valve shut"
    later = event(EventKind.FAULT, DeviceMode.ESTOP, DeviceMode.ESTOP, int(Trip.VALVE), text=held)
    reasons.device_event(later, 2.0)
    assert reasons.fault(DeviceMode.ESTOP, int(Trip.ESTOP)) == f"emergency stop; then {held}"
    other = event(EventKind.FAULT, DeviceMode.ESTOP, DeviceMode.ESTOP, int(Trip.VALVE), text="x")
    reasons.device_event(other, 3.0)
    assert reasons.fault(DeviceMode.ESTOP, int(Trip.ESTOP)) == "emergency stop; then x"
    # Re-armed, then a new stop: only its own words.
    reasons.device_event(event(EventKind.MODE_CHANGE, DeviceMode.ESTOP, DeviceMode.IDLE), 4.0)
    fault = "FOLLOWING on pitch"
    reasons.device_event(
        event(EventKind.FAULT, A, DeviceMode.FAULT, int(Trip.FOLLOWING), text=fault), 5.0
    )
    assert reasons.fault(DeviceMode.FAULT, int(Trip.FOLLOWING)) == fault


def test_a_fault_the_station_never_heard_of_is_told_from_its_trip_code() -> None:
    assert Reasons().fault(DeviceMode.ESTOP, int(Trip.ESTOP)) == describe(Trip.ESTOP)


def test_a_hold_with_no_event_heard_shows_from_when_it_was_first_seen() -> None:
    reasons = Reasons()
    first = reasons.hold(H, paused=False, now=50.0)
    again = reasons.hold(H, paused=False, now=70.0)
    assert first is not None and first.code == "device" and "did not hear why" in first.text
    assert again == first  # the same hold, the same start
    # Its event arrives late: the device's own reason replaces the stand-in.
    reasons.device_event(event(EventKind.WATCHDOG, A, H, value=250.0), at=49.9)
    hold = reasons.hold(H, paused=False)
    assert hold is not None and (hold.code, hold.since) == ("watchdog", 49.9)


def test_a_hold_that_ends_with_the_exercise_is_forgotten_unless_the_device_still_holds() -> None:
    reasons = Reasons()
    reasons.asked("therapist:1", now=1.0)
    reasons.settled(H)
    assert reasons.hold(H, paused=False) is not None
    reasons.settled(R)
    assert reasons.hold(H, paused=False, now=2.0) == HoldInfo(
        code="device",
        text="the device holds the platform; the station did not hear why",
        by="device",
        since=2.0,
        patient_may_resume=False,
    )


def test_the_limit_counts_from_the_hold_but_never_from_before_the_exercise() -> None:
    hold = HoldInfo(code="watchdog", text="", by="device", since=100.0, patient_may_resume=False)
    assert ends_at(hold, began=40.0, limit_s=180.0) == 280.0
    # A hold older than the exercise (the device held before it started) is timed from
    # the exercise's start.
    assert ends_at(hold, began=150.0, limit_s=180.0) == 330.0


UNKNOWN = "the cause is unknown"
NAMED = "the home station's computer stood still and sent nothing for"


def test_a_watchdog_hold_names_the_stations_stall_when_one_explains_it() -> None:
    # The device heard nothing for 501 ms; the station, standing still, had sent it nothing
    # for 530 ms. Whichever the station learns first, the hold ends up naming the stall.
    for stall_first in (False, True):
        reasons = Reasons()
        if stall_first:
            reasons.host_stalled(530.0, at=10.3)
        reasons.device_event(event(EventKind.WATCHDOG, A, H, value=501.0), at=10.2)
        if not stall_first:
            hold = reasons.hold(H, paused=False)
            assert hold is not None and UNKNOWN in hold.text, hold
            reasons.host_stalled(530.0, at=10.3)
        hold = reasons.hold(H, paused=False)
        assert hold is not None and hold.code == "watchdog" and hold.since == 10.2
        assert "no frame from the station for 501 ms" in hold.text
        assert f"{NAMED} 530 ms" in hold.text, hold.text
        # On the therapist's page "this computer" is the therapist's own.
        assert "this computer" not in hold.text, hold.text


def test_a_later_short_stall_does_not_take_back_the_one_that_explains_a_hold() -> None:
    # A loaded computer stands still in several pieces: the 995 ms that explains the hold,
    # then 148 and 107 ms. Whichever order the hold and the stalls arrive in, it stays named.
    for hold_first in (False, True):
        reasons = Reasons()
        if hold_first:
            reasons.device_event(event(EventKind.WATCHDOG, A, H, value=501.0), at=10.2)
        reasons.host_stalled(995.0, at=10.4)
        if not hold_first:
            reasons.host_stalled(148.0, at=10.6)
            reasons.device_event(event(EventKind.WATCHDOG, A, H, value=501.0), at=10.2)
        else:
            reasons.host_stalled(148.0, at=10.6)
        reasons.host_stalled(107.0, at=10.8)
        hold = reasons.hold(H, paused=False)
        assert hold is not None and f"{NAMED} 995 ms" in hold.text, hold


def test_a_stall_that_does_not_cover_the_silence_does_not_explain_a_watchdog_hold() -> None:
    """A 121 ms stall was given as the cause of a 201 ms silence (a 200 ms watchdog): the
    device heard nothing for longer than the stall accounts for, and the cause is unknown."""
    for ms, at, silence in ((121.0, 10.3, 201.0), (200.0, 10.3, 201.0), (530.0, 4.0, 501.0)):
        reasons = Reasons()
        reasons.host_stalled(ms, at=at)  # the last one covers it, but 6 s before
        reasons.device_event(event(EventKind.WATCHDOG, A, H, value=silence), at=10.2)
        hold = reasons.hold(H, paused=False)
        assert hold is not None and UNKNOWN in hold.text, hold
        assert "stood still" not in hold.text, hold


def test_a_hold_that_a_lost_link_caused_says_so_not_a_silence_of_0_ms() -> None:
    """A device that holds because a host connected anew says so with a silence of 0 ms: the
    station said "no frame from the station for 0 ms (the station or its cable stalled)",
    after its link to a device that had itself stood still was lost and made again."""
    lost = "the platform sent nothing for 2 s (the device stalled, or its cable was cut)"
    hello = "a new host connection (a new HELLO)"

    def said(reasons: Reasons, value: float, text: str, at: float) -> str:
        reasons.device_event(event(EventKind.WATCHDOG, A, H, value=value, text=text), at=at)
        hold = reasons.hold(H, paused=False)
        assert hold is not None and hold.code == "watchdog" and hold.by == "device"
        assert " 0 ms" not in hold.text and UNKNOWN not in hold.text, hold
        return hold.text

    # The station lost the link at 100 s and had it back at 101 s: the HELLO held.
    reasons = Reasons()
    reasons.link_lost(lost, 100.0)
    reasons.link_back(101.0)
    text = said(reasons, 0.0, hello, 101.0)
    assert text.startswith("the device held the platform when the station connected to it")
    assert lost in text
    # Its watchdog held before the station came back: a silence, with the link's loss.
    reasons = Reasons()
    reasons.link_lost(lost, 100.0)
    reasons.link_back(104.0)
    text = said(reasons, 1200.0, "no valid frame for 1200 ms", 101.5)
    assert "no frame from the station for 1200 ms" in text and lost in text
    # Another host took the link over, no link of this station's lost: the device's words.
    reasons = Reasons()
    text = said(reasons, 0.0, hello, 50.0)
    assert text == f"the device held the platform: {hello}"
    # A watchdog hold long after the link came back is not the old loss's.
    reasons = Reasons()
    reasons.link_lost(lost, 100.0)
    reasons.link_back(101.0)
    reasons.device_event(
        event(EventKind.WATCHDOG, A, H, value=412.0, text="no valid frame for 412 ms"), at=160.0
    )
    hold = reasons.hold(H, paused=False)
    assert hold is not None and lost not in hold.text and UNKNOWN in hold.text, hold
