"""Running one prescription on the device: sets of repetitions with rest between sets.

Each repetition is one device segment (the device moves gently to the waveform's start,
runs it for ``repetition_s`` with the prescription's own limits loaded, returns home and
reports SEGMENT_DONE). The station only sequences; every limit is enforced by the device.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Mapping
from typing import Literal

from device.client import CommandRefused, DeviceClient, DeviceError, LinkTimeout
from device.protocol import messages as msg
from device.protocol.messages import DeviceMode, EventKind
from sessions.prescription import Axis, PrescriptionBody, device_segment
from sessions.recording import End, EndReason, SessionEvent

HOMING_TIMEOUT_S = 40.0
SEGMENT_MARGIN_S = 30.0
"""Beyond ``repetition_s``: the approach and return moves and any pause are added to it."""
STOPPED_MODES = (DeviceMode.FAULT, DeviceMode.ESTOP)

Phase = Literal["homing", "running", "rest", "paused", "done", "stopped", "fault", "interrupted"]


class SessionClock:
    """A session's time, as its recording stamps it: the wall clock read once, at the start,
    plus the monotonic clock's count since. A wall clock set back while a session ran made
    it end before it started, a session the server refuses for good; set forward by hours,
    it made a short session hours long. Neither changes this count."""

    def __init__(self) -> None:
        self.started_at = time.time()
        self._began = time.monotonic()

    def now(self) -> float:
        """Unix s, as the session counts it: ``started_at`` plus the time elapsed since."""
        return self.started_at + (time.monotonic() - self._began)


def segment_for(
    hello: msg.DeviceHello,
    segment_id: int,
    body: PrescriptionBody,
    stiffness: dict[str, float],
    damping: dict[str, float],
) -> msg.StartSegment:
    """The device segment of one repetition (the prescription with the live K and B)."""
    return device_segment(hello, segment_id, body, stiffness, damping)


async def send_home(dev: DeviceClient) -> tuple[bool, str]:
    """End the device's segment as STOP does: hold where it is, then home slowly to READY.
    Whether the platform is home, and why not when it could have been (``""`` for a device
    stopped by a fault or an e-stop, which stays where it is until re-armed).

    A device that refuses to home (its air supply is low) keeps holding where it is, valves
    closed; the caller ends what it ends all the same, and says so."""
    latest = dev.latest
    if latest is None or latest.mode in STOPPED_MODES:
        return False, ""
    # Held whatever the newest telemetry says: a segment the device ACKed a moment ago
    # may not show as ACTIVE in it yet (and homing is refused while ACTIVE, so the
    # platform would run the repetition out after STOP). HOLD changes nothing in READY;
    # its ACK says the mode the device is in now.
    if (await dev.hold()).mode in STOPPED_MODES:
        return False, ""
    try:
        await dev.arm_home()
    except CommandRefused as exc:
        return False, f"the platform could not go home ({exc.nack.text}) and holds where it is"
    try:
        sample = await dev.wait_for_mode(DeviceMode.READY, *STOPPED_MODES, timeout=HOMING_TIMEOUT_S)
    except LinkTimeout:
        if dev.link_error is not None:
            raise  # the link closed meanwhile: the caller's link is lost
        return False, f"the platform was not home within {HOMING_TIMEOUT_S:g} s"
    return sample.mode == DeviceMode.READY, ""


class ExerciseRun:
    """One run of a prescription; :meth:`run` returns how it ended."""

    def __init__(
        self,
        dev: DeviceClient,
        prescription_id: int,
        body: PrescriptionBody,
        on_event: Callable[[SessionEvent], None],
        on_change: Callable[[], None],
        first_segment_id: int = 1,
        clock: SessionClock | None = None,
    ) -> None:
        assert dev.hello is not None
        self.clock = clock if clock is not None else SessionClock()
        """The session's time (its events and its end are stamped with it)."""
        self.dev = dev
        self.hello = dev.hello
        self.prescription_id = prescription_id
        self.body = body
        self._on_event = on_event
        self._on_change = on_change
        self.stiffness: dict[str, float] = {a.axis: a.stiffness for a in body.axes}
        self.damping: dict[str, float] = {a.axis: a.damping for a in body.axes}
        self.set = 0
        self.rep = 0
        self.reps_done = 0
        self.sets_done = 0
        self.phase: Phase = "homing"
        self.rest_until = 0.0
        self.message = ""
        self.began = time.time()
        """Unix s: a hold is timed from here at the earliest (see station.reasons.ends_at)."""
        self._interrupted = False
        self._lost = ""
        """Why the station lost the device's link during this run (:meth:`lost`), or ""."""
        self._refused = False
        """The device refused a repetition's segment: the run ended without it."""
        self._homing_note = ""
        self._stop_why = ""
        self._segment_id = first_segment_id
        self._after_event: int | None = None
        """The device's newest event id when this run first heard from it: events up to it
        (a replay of the device's past to a station that has just connected) are history."""
        self._segment_done = asyncio.Event()
        self._stop = asyncio.Event()
        self._resumed = asyncio.Event()
        self._resumed.set()
        self._paused = asyncio.Event()

    # -- from the station --------------------------------------------------------------
    def follows(self, event: msg.Event) -> bool:
        """``event`` happened while this run had the device (not before it began)."""
        return self._after_event is not None and event.event_id > self._after_event

    def device_event(self, event: msg.Event) -> None:
        if not self.follows(event):
            return  # an old e-stop or end replayed must not stop this run
        if event.kind == EventKind.SEGMENT_DONE:
            self._segment_done.set()
        elif event.mode_to in STOPPED_MODES:
            self.message = event.text
            self._stop.set()
        elif event.mode_to == DeviceMode.HOLD and self.phase == "running":
            self._pause()

    def pause(self) -> None:
        self._pause()

    def resume(self) -> None:
        if self.phase == "paused":
            self.phase = "running" if self.rest_until == 0.0 else "rest"
            self._paused.clear()
            self._resumed.set()
            self._on_change()

    def stop(self, why: str = "") -> None:
        """End the run as STOP does; ``why``: said in its end record (the station stopping),
        when it ends before it is complete."""
        if why and not self._stop_why:
            self._stop_why = why
        self._stop.set()
        self._resumed.set()  # wakes a paused timeline, which then sees the stop

    def interrupt(self, why: str) -> None:
        """End the run because it was held too long: the segment is abandoned, the platform
        sent home, and the session ends ``interrupted`` with ``why``."""
        self._interrupted = True
        self.message = why
        self.phase = "interrupted"  # over for the patient now; the platform goes home
        self.stop()
        self._on_change()

    def lost(self, why: str) -> None:
        """End the run because the device's link is gone (``why``: how it went). Nothing more
        can be asked of the device, and the session still ends, ``interrupted``, saying so:
        left without an end record it was a cut-off recording the server refuses."""
        if self._lost:
            return
        self._lost = why
        self._interrupted = True
        self.message = f"the platform's link was lost: {why}"
        self._event("interrupted", text=self.message)
        self.phase = "interrupted"
        self.stop()
        self._on_change()

    @property
    def link_lost(self) -> bool:
        """The run ended (or is ending) because the device's link was lost."""
        return bool(self._lost)

    @property
    def ending(self) -> bool:
        """Stopped or interrupted, and winding down: nothing may resume it."""
        return self._stop.is_set()

    @property
    def last_segment_id(self) -> int:
        return self._segment_id

    def rest_remaining(self) -> float:
        return max(0.0, self.rest_until - time.monotonic()) if self.rest_until else 0.0

    def _pause(self) -> None:
        if self.phase in ("running", "rest"):
            self.phase = "paused"
            self._resumed.clear()
            self._paused.set()
            self._on_change()

    def _event(self, kind: str, **detail: object) -> None:
        self._on_event(SessionEvent(wall=self.clock.now(), kind=kind, by="station", detail=detail))

    # -- the timeline ------------------------------------------------------------------
    async def run(self) -> End:
        reason: EndReason = "completed"
        try:
            await self._timeline()
        except CommandRefused as exc:
            # Refused outside a repetition (homing with the air supply low): nothing moved.
            self.message = f"the platform refused the exercise ({exc})"
            self._refused = True
            self._stop.set()
        except DeviceError as exc:
            # The link failed under a command or a wait (no answer, or closed): the device
            # can be asked nothing more, and the session ends with what it has.
            self.lost(self.dev.link_error or f"no answer from the device ({exc})")
        finally:
            latest = self.dev.latest
            if latest is not None and latest.mode in STOPPED_MODES:
                reason = "fault"
            elif self._interrupted:
                reason = "interrupted"
            elif self._stop.is_set() and self.sets_done < self.body.sets:
                reason = "stopped"
            self.phase = "done" if reason == "completed" else reason
            self.set = self.rep = 0
            self._on_change()
        said = self.message if reason in ("fault", "interrupted") or self._refused else ""
        why = self._stop_why if reason != "completed" else ""
        return End(
            ended_at=self.clock.now(),
            reason=reason,
            sets_completed=self.sets_done,
            repetitions_completed=self.reps_done,
            text="; ".join(t for t in (said, why, self._homing_note) if t),
        )

    async def _timeline(self) -> None:
        await self._home()
        for s in range(1, self.body.sets + 1):
            for r in range(1, self.body.repetitions + 1):
                self.set, self.rep = s, r
                # A pause that came as the last repetition ended holds this one back.
                self.phase = "running" if self._resumed.is_set() else "paused"
                self._on_change()
                if not await self._repetition():
                    break
                self.reps_done += 1
                self._event("rep_done", set=s, rep=r)
            if self._stop.is_set():
                break
            self.sets_done += 1
            self._event("set_done", set=s)
            if s < self.body.sets and self.body.rest_s > 0:
                await self._rest(self.body.rest_s)
            if self._stop.is_set():
                break

    async def _home(self) -> None:
        latest = await self.dev.wait_for_mode(*DeviceMode, timeout=5.0)
        self._after_event = self.dev.newest_event_id
        mode = latest.mode if self.dev.mode is None else self.dev.mode  # an ACK is newer
        if mode in STOPPED_MODES:
            self.message = f"the device is in {mode.name}; it must be re-armed"
            self._stop.set()
            return
        if mode == DeviceMode.READY:
            return
        if mode == DeviceMode.ACTIVE:
            await self.dev.hold()
        if mode != DeviceMode.HOMING:
            await self.dev.arm_home()
        self.phase = "homing"
        self._on_change()
        await self._until_mode(DeviceMode.READY, HOMING_TIMEOUT_S)

    async def _until_mode(self, mode: DeviceMode, timeout: float) -> None:
        stop = asyncio.create_task(self._stop.wait())
        ready = asyncio.create_task(self.dev.wait_for_mode(mode, *STOPPED_MODES, timeout=timeout))
        try:
            await asyncio.wait({stop, ready}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            stop.cancel()
            ready.cancel()
        if ready.done() and not ready.cancelled() and ready.exception() is None:
            if ready.result().mode in STOPPED_MODES:
                self._stop.set()
        elif ready.done() and not ready.cancelled():
            self.message = str(ready.exception())
            self._stop.set()

    async def _repetition(self) -> bool:
        """Run one segment to its end; False if the run was stopped."""
        await self._resumed.wait()
        if self._stop.is_set():
            return False
        self._segment_id += 1
        self._segment_done.clear()
        try:
            await self.dev.start_segment(
                segment_for(self.hello, self._segment_id, self.body, self.stiffness, self.damping)
            )
        except CommandRefused as exc:
            # Nothing moves: the run ends here, recorded, with the device's own words.
            nack = exc.nack
            self.message = (
                f"the platform refused the repetition ({nack.code.name} [{nack.field}]: "
                f"{nack.text})"
            )
            self._refused = True
            self._event("refused", text=self.message)
            self._stop.set()
            return False
        done = asyncio.create_task(self._segment_done.wait())
        stop = asyncio.create_task(self._stop.wait())
        try:
            await asyncio.wait({done, stop}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            done.cancel()
            stop.cancel()
        if self._stop.is_set() and not self._segment_done.is_set():
            if not self._lost:  # else there is no link to hold it over (see lost)
                await self._abort_segment()
            return False
        return True

    async def _abort_segment(self) -> None:
        """Stop a running segment (:func:`send_home`)."""
        home, note = await send_home(self.dev)
        if note:
            self._homing_note = note
        elif home and self._interrupted:
            self._homing_note = "the platform went home"

    async def _rest(self, seconds: float) -> None:
        self.phase = "rest"
        remaining = seconds
        while remaining > 0 and not self._stop.is_set():
            await self._resumed.wait()
            if self._stop.is_set():
                break
            self.rest_until = time.monotonic() + remaining
            self._on_change()
            self._event("rest", seconds=round(remaining, 1))
            paused = asyncio.create_task(self._paused.wait())
            stop = asyncio.create_task(self._stop.wait())
            try:
                await asyncio.wait({paused, stop}, timeout=remaining)
            finally:
                paused.cancel()
                stop.cancel()
            remaining = self.rest_until - time.monotonic()
        self.rest_until = 0.0

    # -- live changes -------------------------------------------------------------------
    def impedance_refusal(
        self, stiffness: Mapping[Axis, float] | None, damping: Mapping[Axis, float] | None
    ) -> tuple[str, str] | None:
        """Why a live K/B change cannot be made, as (field, sentence): it names an axis this
        exercise does not use (the platform holds it; nothing would change), or none at all.
        None when it can be made."""
        for field, asked in (("stiffness", stiffness), ("damping", damping)):
            for name in asked or {}:
                if name not in self.stiffness:
                    return field, f"{name} is not part of this exercise: it is held"
        if not stiffness and not damping:
            return "stiffness", "nothing to change: give K or B on an axis of this exercise"
        return None

    def apply_impedance(
        self, stiffness: Mapping[Axis, float] | None, damping: Mapping[Axis, float] | None
    ) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Merge a live change into this run; the 6-axis K and B to send to the device."""
        for name, value in (stiffness or {}).items():
            if name in self.stiffness:
                self.stiffness[name] = value
        for name, value in (damping or {}).items():
            if name in self.damping:
                self.damping[name] = value
        seg = segment_for(self.hello, 1, self.body, self.stiffness, self.damping)
        return seg.stiffness, seg.damping
