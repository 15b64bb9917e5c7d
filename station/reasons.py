"""Why the device is held or stopped, as the home station learns it, and how long a hold may last.

Two sources meet here: the device says why it held in its events (its watchdog heard nothing
from the station, its air supply sagged, it latched a fault), and the station knows on whose
behalf it sent a HOLD (the patient's pause, the therapist's HOLD). The station's status
carries the result to the therapist's live view (and, through the server's Welcome, to a view
opened later) and to the patient's page; the station ends an exercise held longer than its
limit (:func:`ends_at`).

Plain logic, no I/O: the station feeds it and reads it.
"""

from __future__ import annotations

import time
from collections import deque

from device.protocol import messages as msg
from device.protocol.messages import DeviceMode, EventKind
from device.trips import describe
from sessions.wire import HoldCode, HoldInfo

HOLD_LIMIT_S = 180.0
"""How long an exercise may stay held before the station ends it (s): long enough for a
pause to drink water or for the therapist to look into a hold, short enough that a patient is
not left with a foot in a frozen platform."""

_RANK: dict[HoldCode, int] = {
    "pause": 0,
    "station": 1,
    "therapist": 2,
    "device": 3,
    "supply_low": 3,
    "watchdog": 3,
}
"""A stronger reason replaces a weaker one while held: the therapist's HOLD during the
patient's pause is no longer the patient's to continue, and the device's own reason is the
one a therapist needs to see."""

_ASKED: dict[HoldCode, str] = {
    "pause": "the patient paused the exercise",
    "therapist": "the therapist pressed HOLD",
    "station": "the station held the platform",
}
_STOPPED = (DeviceMode.FAULT, DeviceMode.ESTOP)
STALL_NEAR_S = 2.0
"""A stall of the station's computer that ended this close to a watchdog hold's start, and
that left the device without a frame at least as long as the silence it measured, explains
the hold. A shorter one does not (a 121 ms stall was named as the cause of a 201 ms silence,
under a 200 ms watchdog): the device heard nothing for longer than the stall can account for."""
STALLS_KEPT = 16
"""The computer's recent stalls remembered, each judged against a hold: a loaded computer
stands still in pieces (995 ms, then 148 and 107 ms), and keeping only the newest let a
short one take back the explanation the long one gave."""
LINK_BEFORE_S = 3.0
"""A watchdog hold that began this long before the station found the device's link lost, or
later, until it had the link back, is the lost link's: the station finds a silent link lost
2 s after the device's last frame (station.app.DEVICE_STALE_S), and a device that hears
nothing from then holds after its watchdog."""
LINK_AFTER_S = 1.0
"""...and this long after it had the link back (the device's clock and the station's, as
the newest telemetry relates them)."""


def asked_code(by: str) -> HoldCode:
    """The hold code for a HOLD the station sends on behalf of ``by``."""
    if by == "patient":
        return "pause"
    if by.startswith("therapist"):
        return "therapist"
    return "station"


def ends_at(hold: HoldInfo, began: float, limit_s: float) -> float:
    """When an exercise that began at ``began`` (Unix s) ends if it stays held: the limit
    counts from the hold's start, never from before the exercise's own start."""
    return max(hold.since, began) + limit_s


def supply_is_low(latest: msg.Telemetry | None) -> bool:
    """Whether the device says its air supply is low (the telemetry's SUPPLY_LOW flag, in any
    mode); False before any telemetry."""
    return latest is not None and bool(latest.flags & msg.TelemetryFlags.SUPPLY_LOW)


def supply_notice(latest: msg.Telemetry | None) -> str:
    """What to tell the patient and the therapist while the device says its air supply is
    low (:func:`supply_is_low`), ``""`` otherwise: nothing can start until then."""
    if latest is None or not supply_is_low(latest):
        return ""
    return (
        f"the platform's air supply is low ({latest.supply / 1e5:.1f} bar): check that the "
        "compressor is on and its hose is connected; exercises can start once it is back"
    )


def patient_resume_refusal(hold: HoldInfo) -> str:
    """Why the patient's page may not continue this hold (only a pause is theirs)."""
    if hold.code == "therapist":
        return "your therapist is holding the exercise and will carry it on"
    return (
        "the platform stopped to keep you safe; your therapist can carry on, "
        "or press STOP to end the exercise"
    )


class Reasons:
    """The current hold and fault, from the station's commands and the device's events."""

    def __init__(self) -> None:
        self._hold: HoldInfo | None = None
        self._fault = ""
        self._stopped_by = ""
        """The words of the event that stopped the device (an e-stop, a trip)."""
        self._unheard_since: float | None = None
        self._stalls: deque[tuple[float, float]] = deque(maxlen=STALLS_KEPT)
        """The station's computer's recent stalls: when each ended (Unix s), and how long the
        device had then heard nothing from the station (ms)."""
        self._silence_ms = 0.0
        self._watchdog_said = ""
        """The device's words for its newest watchdog hold."""
        self._link: tuple[str, float, float | None] | None = None
        """The device's link as the station last lost it: how, when, and when it had it
        back (None while it is down)."""

    # -- what the station asked --------------------------------------------------------
    def asked(self, by: str, now: float | None = None) -> None:
        """The station is sending a HOLD on behalf of ``by`` (before sending it, so that the
        device's own MODE_CHANGE event finds the reason already there)."""
        code = asked_code(by)
        self._set(code, _ASKED[code], by, time.time() if now is None else now)

    def resumed(self) -> None:
        """The exercise carries on (the device resumed, or a pause between repetitions ended)."""
        self._hold = None

    def settled(self, mode: DeviceMode | None) -> None:
        """An exercise ended: a hold outlives it only if the device still holds."""
        if mode != DeviceMode.HOLD:
            self._hold = None

    def link_lost(self, why: str, at: float) -> None:
        """The station lost the device's link at ``at`` (Unix s); ``why``: how."""
        self._link = (why, at, None)

    def link_back(self, at: float) -> None:
        """The station has the device's link again (a new HELLO: the device holds a motion
        under way, which nobody on the new link commanded)."""
        if self._link is not None and self._link[2] is None:
            self._link = (self._link[0], self._link[1], at)

    # -- what the device said ------------------------------------------------------------
    def device_event(self, event: msg.Event, at: float) -> None:
        """A device event that happened at ``at`` (Unix s)."""
        if event.mode_to in _STOPPED:
            self._hold = None
            words = event.text or describe(event.code)
            if event.mode_from == event.mode_to and self._stopped_by:
                # A later word on a stop already latched (a chamber its own valves now
                # hold): what stopped it stays, beside the newest thing found since.
                self._fault = f"{self._stopped_by}; then {words}"
            else:
                self._fault = self._stopped_by = words
            return
        if event.mode_from in _STOPPED and event.mode_to != event.mode_from:
            self._fault = self._stopped_by = ""
        if event.mode_to == DeviceMode.HOLD and event.mode_from != DeviceMode.HOLD:
            if event.kind == EventKind.WATCHDOG:
                self._silence_ms = event.value
                self._watchdog_said = event.text
                self._set("watchdog", self._watchdog_text(at), "device", at)
            elif event.kind == EventKind.SUPPLY_LOW:
                self._set("supply_low", f"the device held the platform: {event.text}", "device", at)
            elif self._hold is None:
                self._set("device", f"the device held the platform ({event.text})", "device", at)
        elif event.mode_from == DeviceMode.HOLD and event.mode_to != DeviceMode.HOLD:
            self._hold = None

    def host_stalled(self, quiet_ms: float, at: float) -> None:
        """The station's computer stood still until ``at`` (Unix s), and the device had then
        heard nothing from it for ``quiet_ms`` (device.client.Stall). If that covers a
        watchdog hold's silence, the hold says so."""
        self._stalls.append((at, quiet_ms))
        hold = self._hold
        if hold is not None and hold.code == "watchdog":
            self._hold = hold.model_copy(update={"text": self._watchdog_text(hold.since)})

    def _lost_then(self, at: float) -> str:
        """How the station lost the device's link, if a hold at ``at`` came of it; or ""."""
        if self._link is None:
            return ""
        why, lost, back = self._link
        if at < lost - LINK_BEFORE_S or (back is not None and at > back + LINK_AFTER_S):
            return ""
        return why

    def _watchdog_text(self, since: float) -> str:
        lost = self._lost_then(since)
        if self._silence_ms <= 0:
            # No silence: the device holds because a host connected anew (its value is 0),
            # and says which way (a new HELLO, or a connection that took the link over).
            if lost:
                return (
                    "the device held the platform when the station connected to it again "
                    f"after losing its link ({lost}): a motion commanded over a lost link "
                    "does not carry on"
                )
            return f"the device held the platform: {self._watchdog_said}"
        why = "the cause is unknown: the station's program, its computer or its cable"
        if lost:
            why = f"the station had lost the platform's link: {lost}"
        near = [ms for end, ms in self._stalls if abs(end - since) <= STALL_NEAR_S]
        if near and max(near) >= self._silence_ms:
            why = (
                f"the home station's computer stood still and sent nothing for {max(near):.0f} "
                "ms: too busy, or its program blocked"
            )
        return (
            f"the device's watchdog held the platform: no frame from the station for "
            f"{self._silence_ms:.0f} ms ({why})"
        )

    # -- what the status shows -------------------------------------------------------------
    def hold(
        self, mode: DeviceMode | None, paused: bool, now: float | None = None
    ) -> HoldInfo | None:
        """The hold to show: while the device holds, or the exercise is paused between
        repetitions. A device found holding for a reason never heard (its events were lost)
        still shows that it holds, from when the station first saw it."""
        if mode != DeviceMode.HOLD and not paused:
            self._unheard_since = None
            return None
        if self._hold is not None or mode != DeviceMode.HOLD:
            return self._hold
        # Not stored as the hold: the event that says why may still be on its way.
        if self._unheard_since is None:
            self._unheard_since = time.time() if now is None else now
        return HoldInfo(
            code="device",
            text="the device holds the platform; the station did not hear why",
            by="device",
            since=self._unheard_since,
            patient_may_resume=False,
        )

    def fault(self, mode: DeviceMode | None, trip: int) -> str:
        """The device's words for its latched fault or e-stop; "" when there is none."""
        if mode not in _STOPPED:
            return ""
        return self._fault or describe(trip)

    def _set(self, code: HoldCode, text: str, by: str, at: float) -> None:
        old = self._hold
        if old is not None and _RANK[code] <= _RANK[old.code]:
            return
        self._hold = HoldInfo(
            code=code,
            text=text,
            by=by,
            since=at if old is None else min(old.since, at),
            patient_may_resume=code == "pause",
        )
