"""The patient's home station: device on one side, server on the other, the session on disk.

Three things run side by side and none waits for another: the device link (telemetry into
the session file and up to the server, events into the exercise timeline), the server link
(prescriptions and live commands down), and the uploader. A lost server never stops an
exercise: samples go to disk first and the device's own watchdog guards the serial side.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
import re
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from device.client import (
    CommandRefused,
    DeviceClient,
    DeviceError,
    LinkTimeout,
    Stall,
    Subscription,
)
from device.commands import CommandError, check_segment_as_received, published
from device.protocol.messages import Capability, DeviceHello, DeviceMode, Telemetry
from sessions import wire
from sessions.home_progress import HomeProgress
from sessions.prescription import PrescriptionBody
from sessions.recording import (
    SAMPLE_DTYPE,
    End,
    Header,
    RecordingWriter,
    RecordType,
    SessionEvent,
    encode_json,
    encode_samples,
    sample_row,
)
from sessions.translate import device_event, device_info, telemetry_sample
from sessions.wire import PrescriptionItem
from station.config import StationConfig
from station.progress import ProgressWatch
from station.reasons import (
    Reasons,
    ends_at,
    patient_resume_refusal,
    supply_is_low,
    supply_notice,
)
from station.server_link import ServerLink
from station.spool import Spool
from station.timeline import HOMING_TIMEOUT_S, ExerciseRun, SessionClock, segment_for, send_home
from station.uploader import Uploader

log = logging.getLogger("ankle.station")
SOFTWARE = "ankle-station 0.1.0"
FLUSH_S = 0.2
"""Session samples are written this often and then synced to the disk: at most this much
(and the disk's own delay) is lost if the station's power is cut; nothing if it is killed."""
DEVICE_STALE_S = 2.0
"""The device's link is lost once it has sent nothing for this long (s) while the station ran
(:func:`_next_sample`)."""
STALE_STEP_S = 0.25
"""The step :func:`_next_sample` waits in: a station that stood still through one reads what
the device sent meanwhile in the next."""
APPLIES_TEXT: dict[wire.Applies, str] = {
    "now": "acknowledged by the device",
    "on_resume": "accepted by the device; the platform is held, so it applies on Resume",
    "next_repetition": "accepted; it applies from the next repetition",
}
"""The answer to a K/B change, by when the device renders it."""
STOP_WAIT_S = 8.0
"""How long a station asked to stop (SIGTERM) waits for the exercise to end as on STOP."""
NOTHING_HELD = "nothing to resume: no exercise is paused and the platform is not held"
ENDED = (
    "the exercise has ended, so there is nothing to resume: the platform goes home "
    "(start the exercise again to carry on)"
)
SEGMENT_MODES = (DeviceMode.ACTIVE, DeviceMode.HOLD)
"""The device's modes with a segment loaded: one that no exercise runs is sent home
(:meth:`Station._left_watch`)."""
HOLD_CHECK_S = 0.25
"""How often a held exercise is checked against the hold limit (s)."""
HEARD_KEPT = 256
"""Device events remembered as heard (:attr:`Station._heard`): more than the device keeps
for replay (64)."""
REASON_MAX = 240
"""Characters of the server's reason a status gives for each refused session (the whole
reason is in the spool, beside the session)."""
DISK_FULL = "the station's disk is full"
RECORD_ROOM = 1 << 20
"""Bytes kept free in the spool beyond a session's samples (:func:`room_needed`): its
header, events and end take a few kilobytes."""


class Station:
    def __init__(self, config: StationConfig, spool: Spool | None = None) -> None:
        self.config = config
        self.spool = spool if spool is not None else Spool(config.spool)
        self.dev: DeviceClient | None = None
        self.link = ServerLink(
            config.server, config.token, self._hello, self._on_server, config.batch_hz
        )
        self.uploader = Uploader(config.server, config.token, self.spool)
        self.progress_watch = ProgressWatch(self.uploader.client, self.link.connected)
        self.uploader.on_uploaded = self.progress_watch.wake
        self.prescriptions: list[PrescriptionItem] = [
            PrescriptionItem.model_validate(p) for p in self.spool.load_prescriptions()
        ]
        self.run_: ExerciseRun | None = None
        self.writer: SessionWriter | None = None
        self.session_id: str | None = None
        self.clock: SessionClock | None = None
        """The running session's time (its recording's stamps), or None."""
        self.message = ""
        """The last session's notice (why it ended early, why it could not start): kept until
        the next start, across a reconnection to the device."""
        self._link_notice = ""
        """Why the device's link is down, while it is."""
        self.ended_link_lost = False
        """The last exercise ended because the device's link was lost (the patient's page
        says so in its own words)."""
        self._heard: dict[int, float] = {}
        """Device time of each event heard from the device lately, by event id: the device
        replays its newest events to a host that connects, and one heard already on an
        earlier link is not news (its id and time match; a restarted device's do not)."""
        self._impedance = asyncio.Lock()
        """Live K/B changes one at a time: each is merged, sent and, if refused, undone before
        the next is merged, so that its before and after are exact."""
        self.reasons = Reasons()
        self._stall_heard: Stall | None = None
        self._status_dirty = asyncio.Event()
        self._started = False
        self._session_task: asyncio.Task[None] | None = None
        self._repeat_task: asyncio.Task[None] | None = None
        self.starts_again_at: float | None = None
        """When the demo starts its exercise again by itself (wall clock), or None."""
        self._repeating = config.autostart and config.repeat_after_s is not None
        self._last_phase: wire.Phase = "idle"
        self._segment_base = max(1, int(time.time()) & 0xFFFF)
        self._stopping = ""
        """Why the station is stopping (:meth:`wind_down`); nothing starts from then on."""
        self._homing: asyncio.Task[None] | None = None
        """Sending home a segment that no exercise runs (:meth:`_send_home`)."""
        self._left_tried: int | None = None
        """The segment id last sent home that way: the station tries each once by itself (a
        device that refuses to home says why, each time); a Stop tries again."""

    # -- running -------------------------------------------------------------------------
    async def run(self) -> None:
        closed = self.spool.recover_unfinished()
        if closed:
            log.info("closed %d interrupted session(s) from before: %s", len(closed), closed)
        tasks = [
            asyncio.create_task(self.link.run(), name="server-link"),
            asyncio.create_task(self.uploader.run(), name="uploader"),
            asyncio.create_task(self.progress_watch.run(), name="progress"),
            asyncio.create_task(self._device_loop(), name="device"),
            asyncio.create_task(self._status_loop(), name="status"),
            asyncio.create_task(self._hold_watch(), name="hold-watch"),
        ]
        try:
            await asyncio.gather(*tasks)
        finally:
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            await self._shutdown()

    async def wind_down(self, why: str) -> None:
        """Stop as asked by whoever runs the station (SIGTERM, SIGINT), before :meth:`run` is
        cancelled: a running exercise stops as on STOP (the platform holds and goes home) and
        its session ends ``stopped`` with ``why``, on disk. Bounded by STOP_WAIT_S, within
        the time a supervisor gives before it kills (``ankle run``: 10 s); a platform not
        home by then is held, and the session ends all the same (:meth:`_shutdown`)."""
        self._stopping = why
        self._repeats(False)
        run, session = self.run_, self._session_task
        if run is None or session is None:
            return
        log.info("stopping the exercise: %s", why)
        run.stop(why)
        try:
            async with asyncio.timeout(STOP_WAIT_S):
                await asyncio.shield(session)
        except TimeoutError:
            log.warning("the platform was not home within %g s; holding it", STOP_WAIT_S)
            if self.dev is not None:
                with contextlib.suppress(DeviceError):
                    await self.dev.hold()

    async def _shutdown(self) -> None:
        self._repeats(False)
        if self.run_ is not None:
            self.run_.stop()
        if self.dev is not None:
            with contextlib.suppress(DeviceError):
                await self.dev.hold()  # whatever the telemetry says: see ExerciseRun's abort
            await self.dev.close()
        writer, self.writer = self.writer, None
        if writer is not None:
            run = self.run_
            if self._stopping and run is not None:
                # Stopped as asked, but not yet ended (the platform was still going home).
                writer.end(
                    End(
                        ended_at=self._stamp(),
                        reason="stopped",
                        sets_completed=run.sets_done,
                        repetitions_completed=run.reps_done,
                        text=f"{self._stopping}; the platform was held before it was home",
                    )
                )
            writer.close()  # else left open: recovered and closed as interrupted next start
        await self.uploader.aclose()

    async def _device_loop(self) -> None:
        while True:
            try:
                dev = await DeviceClient.connect(self.config.device, self.config.baud)
            except (DeviceError, OSError) as exc:
                notice = unreachable(self.config.device, exc)
                if notice != self._link_notice:
                    log.warning("%s (%s)", notice, exc)  # the link's own words, once
                self._link_notice = notice
                self._status_dirty.set()
                await asyncio.sleep(1.0)
                continue
            self.dev = dev
            self._link_notice = ""
            self.reasons.link_back(time.time())
            assert dev.hello is not None
            log.info(
                "device %s (%s) on %s", dev.hello.firmware, dev.hello.hardware, self.config.device
            )
            if not dev.hello.capabilities & Capability.CALIBRATED:
                # Sessions record it too (DeviceInfo.calibrated): their ranges carry the
                # sensors' zero errors, up to a millimetre of leg on a real build.
                log.warning(
                    "device on %s runs uncalibrated: start it with --calibration "
                    "(made once by `ankle device --identify FILE`, plate empty)",
                    self.config.device,
                )
            self.link.send(self._hello())
            self._status_dirty.set()
            why = ""  # cancelled: the station is stopping, and stops a run as it does
            try:
                why = await self._serve_device(dev)
            finally:
                self.dev = None
                self._link_notice = "lost the platform's link" + (f": {why}" if why else "")
                if why:
                    log.error("%s", self._link_notice)
                    self.reasons.link_lost(why, time.time())
                if self.run_ is not None:
                    if why:
                        self.run_.lost(why)
                    else:
                        self.run_.stop()
                await dev.close()
                self._status_dirty.set()
            await asyncio.sleep(1.0)

    async def _serve_device(self, dev: DeviceClient) -> str:
        """Serve one link to the device until it is lost; how it was lost."""
        telemetry = asyncio.create_task(self._telemetry(dev))
        events = asyncio.create_task(self._events(dev))
        left = asyncio.create_task(self._left_watch(dev))
        try:
            self._autostart()
            done, _ = await asyncio.wait({telemetry, events}, return_when=asyncio.FIRST_COMPLETED)
            for t in done:
                t.result()
            if telemetry in done and telemetry.result():
                return telemetry.result()
            return dev.link_error or "the link closed"
        finally:
            homing = self._homing
            tasks = [telemetry, events, left] + ([homing] if homing is not None else [])
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

    async def _telemetry(self, dev: DeviceClient) -> str:
        """Record and stream the device's telemetry until its link closes (``""``) or goes
        silent (how long, in words)."""
        last_flush = time.monotonic()  # not the wall clock: one set back stopped the flushes
        stream = dev.telemetry()
        while True:
            try:
                t = await _next_sample(stream)
            except StopAsyncIteration:
                return ""  # the link closed: reconnect
            except TimeoutError:
                # Silent while this side ran (a stall of its own is not counted, and the
                # watchdog's heartbeats name it).
                return (
                    f"the platform sent nothing for {DEVICE_STALE_S:g} s (the device stalled, "
                    "or its cable was cut)"
                )
            run = self.run_
            s, r = (run.set, run.rep) if run else (0, 0)
            if self.writer is not None:
                self.writer.add(sample_row(t, self._stamp(), s, r))
                now = time.monotonic()
                if now - last_flush >= FLUSH_S:
                    self.writer.flush_soon()
                    last_flush = now
            self.link.send_sample(
                telemetry_sample(t, s, r), dev.hello.telemetry_hz if dev.hello else 0
            )

    async def _events(self, dev: DeviceClient) -> None:
        async for e in dev.events():
            if self._heard.get(e.event_id) == e.time:
                continue  # heard on an earlier link: replayed to this one, not news
            self._heard[e.event_id] = e.time
            while len(self._heard) > HEARD_KEPT:
                del self._heard[next(iter(self._heard))]
            # When it happened: an event may reach the station late (a replay after a stall
            # or to a station that has just connected).
            latest = dev.latest
            lag = max(0.0, latest.time - e.time) if latest is not None else 0.0
            self.reasons.device_event(e, time.time() - lag)
            run = self.run_
            if run is not None:
                run.device_event(e)
            # One from before this session began (the device's past, replayed to a station
            # that has just connected) is not this session's record; what it says of the
            # device (above) may still change the status.
            if run is None or run.follows(e):
                self._event(device_event(e, self._stamp() - lag))
            self._status_dirty.set()

    async def _left_watch(self, dev: DeviceClient) -> None:
        """Send home a segment that no exercise runs: the device holds (or runs) the segment
        of an exercise that ended while the station could not end it there (its link was
        lost: the device held the platform on its own), or from before the station started.
        Left so, a Resume moved the platform as that exercise, with no session recording
        it and no Stop that would end it."""
        while True:
            await asyncio.sleep(HOLD_CHECK_S)
            latest = dev.latest
            if (
                latest is None
                or self._stopping
                or self.run_ is not None
                or self._sending_home
                or dev.mode not in SEGMENT_MODES
                or latest.segment_id == self._left_tried
            ):
                continue
            self._send_home(dev, "station")

    @property
    def _sending_home(self) -> bool:
        return self._homing is not None and not self._homing.done()

    def _send_home(self, dev: DeviceClient, by: str) -> None:
        """End the segment the device has (no exercise runs) and bring the platform home."""
        if not self._sending_home:
            self._homing = asyncio.create_task(self._home_left(dev, by), name="send-home")

    async def _home_left(self, dev: DeviceClient, by: str) -> None:
        latest = dev.latest
        segment = latest.segment_id if latest is not None else 0
        self._left_tried = segment
        mode = dev.mode.name if dev.mode is not None else "UNKNOWN"
        text = (
            f"the platform was in {mode} on segment {segment}, which no exercise runs now: "
            "sent home"
        )
        log.warning("%s (by %s)", text, by)
        self._event(SessionEvent(wall=self._stamp(), kind="stop", by=by, detail={"text": text}))
        try:
            home, note = await send_home(dev)
        except DeviceError as exc:
            note, home = f"the platform could not be sent home ({exc})", False
        if note:
            log.error("%s", note)
            self.message = "; ".join(m for m in (self.message, note) if m)
        elif home:
            log.info("the platform is home")
        self._status_dirty.set()

    def _event(self, event: SessionEvent) -> None:
        if self.writer is not None:
            self.writer.event(event)
        self.link.send(wire.EventMsg(session_id=self.session_id, event=event))

    def _stamp(self) -> float:
        """Now, as the running session's recording stamps it (:class:`SessionClock`); the
        wall clock when none runs."""
        return self.clock.now() if self.clock is not None else time.time()

    def _write_failed(self, why: str) -> None:
        """The session file could not be written (``why``: the disk, in words): the exercise
        stops as on STOP (the platform holds and goes home), what the file holds is kept,
        and the session ends ``interrupted`` saying so. The station itself carries on."""
        then = (
            "free some space on the station before the next exercise"
            if why == DISK_FULL
            else "have the station's disk checked before the next exercise"
        )
        said = f"{why}: the exercise was stopped, and what was recorded until then is kept; {then}"
        log.error("the session file cannot be written: %s", said)
        self.message = said
        run = self.run_
        if run is not None and not run.ending:
            run.interrupt(said)
        self._status_dirty.set()

    # -- sessions ------------------------------------------------------------------------
    def _autostart(self) -> None:
        if self.config.autostart and not self._started and self.dev and self.prescriptions:
            self._started = True
            self.start(self.prescriptions[0].id)

    def start(self, prescription_id: int) -> str:
        """Start a prescription; a reason it cannot start, or ``""``."""
        if self._stopping:
            return "the station is stopping"
        if self.run_ is not None:
            return "an exercise is already running"
        if self._sending_home:
            return "the platform is going home from an exercise that ended: start once it is home"
        if self.dev is None or self.dev.hello is None:
            return "the platform is not connected"
        item = next((p for p in self.prescriptions if p.id == prescription_id), None)
        if item is None:
            return wire.not_prescribed(prescription_id)
        welcome = self.link.welcome
        hello = self.dev.hello
        self.message = ""  # the last session's notice is history now
        self.ended_link_lost = False
        no_room = self._no_room(item.body, hello)
        if no_room:
            log.error("exercise not started: %s", no_room)
            self.message = no_room
            self._status_dirty.set()
            return no_room
        self.session_id = str(uuid.uuid4())
        self.clock = SessionClock()
        header = Header(
            session_id=self.session_id,
            station_id=welcome.station_id if welcome else 0,
            patient_id=item.patient_id,
            prescription_id=item.id,
            prescription=item.body.model_dump(mode="json"),
            device=device_info(hello),
            software=SOFTWARE,
            started_at=self.clock.started_at,
        )
        path = self.spool.path(self.session_id)
        try:
            self.writer = SessionWriter(path, header, self._write_failed)
        except OSError as exc:
            # Not even the header went to disk: no session, and no empty file left behind.
            path.unlink(missing_ok=True)
            self.session_id = self.clock = None
            why = f"{disk_words(exc)}: the exercise cannot be recorded, so it does not start"
            log.error("exercise not started: %s (%s)", why, exc)
            self.message = why
            self._status_dirty.set()
            return why
        self.uploader.skip(path)
        # Refused here, with the reason the patient can act on, rather than by the device's
        # NACK of the homing a moment later. The status says it while it lasts (not kept as
        # this start's notice, which would outlive the air coming back).
        low = supply_notice(self.dev.latest)
        refused = low or self._refusal(item, hello)
        if refused:
            self._refused_start(refused, keep=not low)
            return refused
        self.run_ = ExerciseRun(
            self.dev,
            item.id,
            item.body,
            self._event,
            self._status_dirty.set,
            first_segment_id=self._segment_base,
            clock=self.clock,
        )
        self._session_task = asyncio.create_task(self._run_session(self.run_), name="exercise")
        self._status_dirty.set()
        return ""

    def _no_room(self, body: PrescriptionBody, hello: DeviceHello) -> str:
        """Why the spool has no room for a session of ``body``, or ``""``."""
        need = room_needed(body, hello.telemetry_hz, self.config.hold_limit_s)
        try:
            free = self.spool.free_bytes()
        except OSError as exc:
            return f"{disk_words(exc)}: the exercise cannot be recorded, so it does not start"
        if free >= need:
            return ""
        return (
            f"the station's disk is too full to record this exercise: {_mb(free)} free where "
            f"sessions are kept, and it needs {_mb(need)}; free some space on the station, "
            "then start again"
        )

    @staticmethod
    def _refusal(item: PrescriptionItem, hello: DeviceHello) -> str:
        """Why the device would refuse this prescription's repetitions, by its own check of
        the values as it receives them against the limits it published; ``""`` if it would
        not. (The server refuses such a prescription; one stored before may still hold one.)"""
        body = item.body
        k: dict[str, float] = {a.axis: a.stiffness for a in body.axes}
        b: dict[str, float] = {a.axis: a.damping for a in body.axes}
        limits, geometry = published(hello)
        try:
            check_segment_as_received(segment_for(hello, 1, body, k, b), limits, geometry)
        except CommandError as exc:
            return f"the platform refuses this exercise ({exc.code.name} [{exc.field}]: {exc})"
        return ""

    def _refused_start(self, why: str, keep: bool = True) -> None:
        """A start the device would refuse: the session is recorded as ended at once, with the
        reason, so that the therapist sees it (an early end) and nothing moves. ``keep``: the
        reason stays the status's notice until the next start."""
        log.error("exercise not started: %s", why)
        self._event(
            SessionEvent(wall=self._stamp(), kind="refused", by="station", detail={"text": why})
        )
        writer, self.writer = self.writer, None
        if writer is not None:
            writer.end(
                End(
                    ended_at=self._stamp(),
                    reason="stopped",
                    sets_completed=0,
                    repetitions_completed=0,
                    text=why,
                )
            )
            writer.close()
        self.session_id = self.clock = None
        self.message = why if keep else ""
        self._last_phase = "stopped"
        self.uploader.skip(None)
        self.uploader.wake()
        self._status_dirty.set()

    async def _run_session(self, run: ExerciseRun) -> None:
        # Every way a run ends returns its end (a lost device link too): a session closed
        # without one is a cut-off recording, which the server refuses.
        end = await run.run()
        if run.link_lost:
            log.error("exercise interrupted: %s", end.text)
        writer, self.writer = self.writer, None
        if writer is not None:
            writer.end(end)
            writer.close()
        if end.text:
            self.message = end.text
        if writer is not None and writer.failed and not writer.ended:
            # Not even the end record went to disk: closed at the next start from what the
            # file holds (and uploaded then), and said so now.
            self.uploader.hold(writer.path)
            self.message = "; ".join(
                m for m in (self.message, "the session's end could not be recorded") if m
            )
        self.ended_link_lost = run.link_lost
        latest = run.dev.latest
        self.reasons.settled(latest.mode if latest is not None else None)
        self._segment_base = max(1, (run.last_segment_id + 1) & 0xFFFF)
        if not run.link_lost:
            # It ended its segment on the device itself (or said why it could not): the
            # device holds it only over a lost link, which _left_watch then sends home.
            self._left_tried = run.last_segment_id
        self.run_ = None
        self.session_id = self.clock = None
        self._last_phase = run.phase  # shown until the next start: done, stopped or fault
        self.uploader.skip(None)
        self.uploader.wake()
        after = self.config.repeat_after_s
        if self._repeating and run.phase == "done" and after is not None:
            # Known before the status that says "done" goes out: the page says both at once.
            self.starts_again_at = time.time() + after
            self._repeat_task = asyncio.create_task(self._repeat(after), name="demo-repeat")
        self._status_dirty.set()

    async def _repeat(self, after_s: float) -> None:
        try:
            await asyncio.sleep(after_s)
        finally:
            self.starts_again_at = None
        self._started = False
        self._autostart()

    def _repeats(self, on: bool) -> None:
        """A start lets the demo repeat again, a stop ends its repeats; either way a repeat
        waiting to start is off: the platform never moves by itself after the patient
        pressed STOP, nor starts a second exercise over one started by hand."""
        self._repeating = on and self.config.autostart and self.config.repeat_after_s is not None
        if self._repeat_task is not None:
            self._repeat_task.cancel()
            self._repeat_task = None
            self.starts_again_at = None
            self._status_dirty.set()

    # -- server messages -----------------------------------------------------------------
    async def _on_server(self, message: Any) -> None:
        if isinstance(message, wire.Prescriptions):
            self.prescriptions = message.items
            self.spool.save_prescriptions([p.model_dump(mode="json") for p in message.items])
            self._status_dirty.set()
            self._autostart()
        elif isinstance(message, wire.Command):
            result = await self.command(message)
            self.link.send(result)

    async def command(self, cmd: wire.Command) -> wire.CommandResult:
        """Carry out a therapist's (or the patient's) command; the device's answer."""
        dev, run = self.dev, self.run_
        t0 = time.perf_counter()

        def result(
            ok: bool,
            code: str = "",
            field: str = "",
            text: str = "",
            change: wire.ImpedanceChange | None = None,
        ) -> wire.CommandResult:
            return wire.CommandResult(
                request_id=cmd.request_id,
                ok=ok,
                code=code,
                field=field,
                text=text,
                rtt_ms=(time.perf_counter() - t0) * 1e3,
                change=change,
            )

        if cmd.action == "start":
            if cmd.prescription_id is None:
                why = wire.START_NEEDS_PRESCRIPTION
            else:
                why = self.start(cmd.prescription_id)
            if not why:
                self._repeats(True)
            return result(not why, "REFUSED" if why else "", "prescription_id", why)
        if cmd.action == "stop":
            self._repeats(False)  # whatever else happens: nothing starts by itself now
        if dev is None:
            return result(False, "OFFLINE", "", "the platform is not connected")
        try:
            if cmd.action == "set_impedance":
                if run is None:
                    return result(False, "REFUSED", "action", "no exercise is running")
                refused = run.impedance_refusal(cmd.stiffness, cmd.damping)
                if refused is not None:
                    return result(False, "REFUSED", *refused)
                async with self._impedance:
                    change = await self._set_impedance(dev, run, cmd)
                    self._event(
                        SessionEvent(
                            wall=self._stamp(),
                            kind="impedance",
                            by=cmd.by or "station",
                            detail=change.model_dump(mode="json"),
                        )
                    )
                code = "" if change.applies == "now" else "DEFERRED"
                return result(True, code, "", APPLIES_TEXT[change.applies], change)
            if cmd.action == "hold":
                if run is not None:
                    run.pause()
                if run is not None or dev.mode == DeviceMode.ACTIVE:
                    self.reasons.asked(cmd.by or "station")  # else it holds nothing
                await dev.hold()
            elif cmd.action == "resume":
                if run is None and (dev.mode in SEGMENT_MODES or self._sending_home):
                    # The device holds the segment of an exercise that has ended: resumed,
                    # it moved as that exercise with no session recording it.
                    return result(False, "REFUSED", "action", ENDED)
                if run is not None and run.ending:
                    return result(False, "REFUSED", "action", "the exercise is ending")
                if dev.mode != DeviceMode.HOLD and (run is None or run.phase != "paused"):
                    # As a Stop with nothing running is refused: an ACK here said a Resume
                    # was carried out when nothing was held.
                    return result(False, "REFUSED", "action", NOTHING_HELD)
                hold = self._hold()
                if cmd.by == "patient" and hold is not None and not hold.patient_may_resume:
                    return result(False, "REFUSED", "action", patient_resume_refusal(hold))
                if dev.mode == DeviceMode.HOLD:
                    await dev.resume()
                self.reasons.resumed()
                if run is not None:
                    run.resume()
            elif cmd.action == "stop":
                if run is None:
                    if self._sending_home:
                        return result(True, text="the platform is going home")
                    if dev.mode not in SEGMENT_MODES:
                        return result(False, "REFUSED", "action", "no exercise is running")
                    # A segment no exercise runs: held at once, then sent home.
                    await dev.hold()
                    self._send_home(dev, cmd.by or "station")
                    return result(True, text="acknowledged by the device; the platform goes home")
                run.stop()
            self._event(SessionEvent(wall=self._stamp(), kind=cmd.action, by=cmd.by or "station"))
            return result(True, text="acknowledged by the device")
        except CommandRefused as exc:
            return result(False, exc.nack.code.name, exc.nack.field, exc.nack.text)
        except DeviceError as exc:
            return result(False, "TIMEOUT", "", str(exc))

    async def _set_impedance(
        self, dev: DeviceClient, run: ExerciseRun, cmd: wire.Command
    ) -> wire.ImpedanceChange:
        """Merge a live K/B change into the run and send it to the device when the device
        renders one; what changed and when it applies. A change the device refuses is taken
        out of the run again (CommandRefused is raised on). Called under ``_impedance``: a
        change merged while this one waits for the device would show in this one's after,
        and its undo would put back this one's before over it."""
        before = (dict(run.stiffness), dict(run.damping))
        k, b = run.apply_impedance(cmd.stiffness, cmd.damping)
        after = (dict(run.stiffness), dict(run.damping))
        if dev.mode not in (DeviceMode.ACTIVE, DeviceMode.HOLD):
            return wire.ImpedanceChange.between(before, after, cmd, "next_repetition")
        try:
            ack = await dev.set_impedance(k, b)
        except CommandRefused:
            undo = wire.ImpedanceChange.between(before, after, cmd, "now").old
            run.apply_impedance(undo.stiffness, undo.damping)
            raise
        # Held, the device keeps rendering what it had and slews to the new K and B from
        # Resume: the mode at its ACK says which.
        held = ack.mode == DeviceMode.HOLD
        return wire.ImpedanceChange.between(before, after, cmd, "on_resume" if held else "now")

    # -- the patient's page ----------------------------------------------------------------
    def note(self, kind: str, detail: dict[str, Any], by: str = "patient") -> bool:
        """Record an event (a game score, a remark) in the running session and send it to the
        server; False, and nothing recorded, when no session runs."""
        if self.writer is None or self.run_ is None:
            return False
        latest = self.dev.latest if self.dev is not None else None
        self._event(
            SessionEvent(
                wall=self._stamp(),
                t=latest.time if latest is not None else None,
                kind=kind,
                by=by,
                detail=detail,
            )
        )
        return True

    def foot(self) -> tuple[float, ...] | None:
        """The platform's newest measured pose (x, y, z in m; roll, pitch, yaw in rad; from
        home), or None without a device or when its telemetry has gone stale."""
        dev = self.dev
        latest = dev.latest if dev is not None else None
        if dev is None or latest is None or time.perf_counter() - dev.latest_at > DEVICE_STALE_S:
            return None
        return tuple(latest.pose)

    def progress(self) -> tuple[int, int]:
        """Sets and repetitions finished in the running exercise; (0, 0) when none runs."""
        run = self.run_
        return (run.sets_done, run.reps_done) if run is not None else (0, 0)

    @property
    def home_progress(self) -> HomeProgress | None:
        """The patient's own progress as the server last told it, or None."""
        return self.progress_watch.latest

    @property
    def online(self) -> bool:
        """Whether the server is reachable now (sessions upload later when it is not)."""
        return self.link.connected.is_set()

    @property
    def supply_low(self) -> bool:
        """Whether the device says its air supply is low now (what the status's message
        tells, from the same telemetry): the patient's page shows it on its platform light."""
        return supply_is_low(self.dev.latest if self.dev is not None else None)

    # -- status --------------------------------------------------------------------------
    def _hello(self) -> wire.StationHello:
        hello = self.dev.hello if self.dev is not None else None
        return wire.StationHello(
            protocol=wire.PROTOCOL,
            software=SOFTWARE,
            device=device_info(hello) if hello else None,
        )

    def _hold(self) -> wire.HoldInfo | None:
        """Why the device or the exercise is held now, and when the exercise ends if it stays
        held; None when nothing holds."""
        dev, run = self.dev, self.run_
        stall = dev.stats.last_stall if dev is not None else None
        if stall is not None and stall != self._stall_heard:  # this computer stood still
            self._stall_heard = stall
            self.reasons.host_stalled(stall.quiet_ms, stall.ended)
        latest = dev.latest if dev is not None else None
        paused = run is not None and run.phase == "paused" and not run.ending
        hold = self.reasons.hold(latest.mode if latest is not None else None, paused)
        if hold is None or run is None or not paused:
            return hold
        return hold.model_copy(
            update={"ends_at": ends_at(hold, run.began, self.config.hold_limit_s)}
        )

    async def _hold_watch(self) -> None:
        """End an exercise held past the limit (the device never resumes by itself, and a
        hold nobody answers would leave the patient's foot in a frozen platform)."""
        seen: tuple[int, float, float] | None = None  # run, hold.since, when it began
        while True:
            await asyncio.sleep(HOLD_CHECK_S)
            run, hold = self.run_, self._hold()
            if run is None or hold is None or hold.ends_at is None:
                seen = None
                continue
            if seen is None or seen[:2] != (id(run), hold.since):
                # How long it has been held: from the wall clock once, as the hold is first
                # seen, then on the monotonic clock. A clock set back an hour mid-hold kept
                # the patient's foot in a held platform an hour past the limit.
                before = max(0.0, time.time() - max(hold.since, run.began))
                seen = (id(run), hold.since, time.monotonic() - before)
            held = time.monotonic() - seen[2]
            if held < self.config.hold_limit_s:
                continue
            why = f"held {held:.0f} s, longer than the {self.config.hold_limit_s:g} s limit: "
            why += hold.text
            log.warning("the exercise ends: %s", why)
            self._event(
                SessionEvent(
                    wall=self._stamp(),
                    kind="interrupted",
                    by="station",
                    detail={"text": why, "hold": hold.code, "held_s": round(held, 1)},
                )
            )
            run.interrupt(why)

    def status(self) -> wire.StatusMsg:
        dev, run = self.dev, self.run_
        latest = dev.latest if dev is not None else None
        body = run.body if run else None
        refused = list(self.uploader.refused.items())
        return wire.StatusMsg(
            sent=time.time(),
            device_link="connected" if dev is not None else "lost",
            device_mode=dev.mode.name if dev is not None and dev.mode is not None else "UNKNOWN",
            trip=int(latest.trip) if latest else 0,
            phase=run.phase if run else self._last_phase,
            session_id=self.session_id,
            prescription_id=run.prescription_id if run else None,
            exercise=body.exercise.value if body else None,
            set=run.set if run else 0,
            rep=run.rep if run else 0,
            sets=body.sets if body else 0,
            repetitions=body.repetitions if body else 0,
            rest_remaining_s=round(run.rest_remaining(), 1) if run else 0.0,
            pending_uploads=self.uploader.pending(),
            refused_uploads=len(refused),
            refused_sessions=[f"{sid}: {_cut(why)}" for sid, why in refused[: wire.REFUSED_NAMED]],
            overruns=latest.overruns if latest else 0,
            frames_lost=dev.stats.frames_lost if dev else 0,
            message=(
                run.message
                if run and run.message
                else supply_notice(latest) or self._link_notice or self.link.notice or self.message
            ),
            hold=self._hold(),
            fault=self.reasons.fault(latest.mode if latest else None, latest.trip if latest else 0),
        )

    async def _status_loop(self) -> None:
        while True:
            self._status_dirty.clear()
            # Status is state, not history: none is queued while the server is away (a
            # station offline for days would pile up one a second and replay them all).
            if self.link.connected.is_set():
                self.link.send(self.status())
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(1.0):  # not wait_for: see _telemetry
                    await self._status_dirty.wait()


async def _next_sample(stream: Subscription[Telemetry]) -> Telemetry:
    """The next telemetry sample; TimeoutError once the device has sent nothing for
    DEVICE_STALE_S while this station was running.

    A station that stood still (its process stopped, its loop blocked, no free core) wakes
    with every wait past its end and the device's samples unread in the port: one wait of
    DEVICE_STALE_S timed out before they were read, and an 11 s stall of the station closed
    its session as the device's lost link, the watchdog's hold (waiting with them) never
    recorded. Waited in short steps instead, each counting only as long as it was meant to
    last: the time the station stood still is not the device's silence, and the next step
    reads what waits."""
    loop = asyncio.get_running_loop()
    silent = 0.0
    while True:
        began = loop.time()
        try:
            # Not wait_for: on Python 3.11 it drops a cancellation that arrives together
            # with a sample (at 100 Hz that happens), and the station would never stop.
            async with asyncio.timeout(STALE_STEP_S):
                return await anext(stream)
        except TimeoutError:
            silent += min(loop.time() - began, STALE_STEP_S)
            if silent >= DEVICE_STALE_S:
                raise


def _cut(text: str, most: int = REASON_MAX) -> str:
    return text if len(text) <= most else text[: most - 1] + "…"


_NO_ROWS = np.zeros(0, SAMPLE_DTYPE)


def room_needed(body: PrescriptionBody, telemetry_hz: float, hold_limit_s: float) -> int:
    """Bytes of spool a session of ``body`` may fill: the device's samples (and each flush's
    record framing) for twice the exercise's time (the moves to and from each repetition,
    pauses), one hold to its limit and a homing, plus :data:`RECORD_ROOM`."""
    per_s = telemetry_hz * SAMPLE_DTYPE.itemsize + len(encode_samples(_NO_ROWS)) / FLUSH_S
    seconds = 2.0 * body.total_s() + hold_limit_s + HOMING_TIMEOUT_S
    return int(per_s * seconds) + RECORD_ROOM


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


def disk_words(exc: OSError) -> str:
    """What a failed write to the station's disk means, for the patient and the therapist."""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return DISK_FULL
    if exc.errno == errno.EROFS:
        return "the station's disk cannot be written to (it is read-only)"
    return f"the station could not write to its disk ({exc.strerror or exc})"


_ERRNO = re.compile(r"\[Errno (\d+)\]")
_UNREACHABLE: dict[int, str] = {
    errno.ECONNREFUSED: "nothing answers at {link}: is the platform switched on and connected?",
    errno.ENOENT: "there is no port {link}: is the platform's cable plugged in?",
    errno.EACCES: "the station may not open {link} (permission denied)",
    errno.EPERM: "the station may not open {link} (permission denied)",
    errno.EBUSY: "{link} is in use by another program",
    errno.EHOSTUNREACH: "{link} cannot be reached over the network",
    errno.ENETUNREACH: "{link} cannot be reached over the network",
    errno.ETIMEDOUT: "{link} did not answer in time: is the platform switched on?",
}
"""Why the platform's link could not be opened, by the innermost error number the link's
error names (the transport nests the system's words in its own)."""


def unreachable(link: str, exc: BaseException) -> str:
    """Why the station cannot reach the platform on ``link``, as a sentence (the patient's
    page shows it; the link's own words, "[Errno 111] …", go to the log)."""
    if isinstance(exc, LinkTimeout):
        why = f"the platform did not answer on {link}: is it switched on?"
    else:
        numbers = _ERRNO.findall(str(exc))
        code = int(numbers[-1]) if numbers else None
        if code in _UNREACHABLE:
            why = _UNREACHABLE[code].format(link=link)
        else:
            why = f"the link to it on {link} could not be opened"
    return f"cannot reach the platform: {why}"


class SessionWriter(RecordingWriter):
    """The session file as the station writes it: rows go to the OS at once, the wait for
    the disk (fsync, up to half a second on a busy disk) runs in a thread. The event loop
    also feeds the device's watchdog: if it stalls for 200 ms the device holds the exercise.

    A write the disk refuses (full, failing) never raises into the station: the file is cut
    back to its last whole record, :attr:`failed` says why, ``on_failure`` is told once,
    and nothing more is written but the end record, which may still fit (a few hundred
    bytes, where the cut-back block was)."""

    def __init__(
        self, path: Path, header: Header, on_failure: Callable[[str], None] = lambda why: None
    ) -> None:
        self.failed = ""
        """Why the file could not be written (the disk, in words), or ``""``."""
        self.ended = False
        """The end record is on disk."""
        self._on_failure = on_failure
        super().__init__(path, header)
        self._sync: asyncio.Future[None] | None = None

    def flush_soon(self) -> None:
        """Write the buffered rows; sync them unless the last sync is still running."""
        self._write_rows()
        if self.failed or self._fd < 0:
            return
        if self._sync is None or self._sync.done():
            self._sync = asyncio.ensure_future(asyncio.to_thread(_fsync_dup, os.dup(self._fd)))
            self._sync.add_done_callback(self._sync_done)

    def event(self, event: SessionEvent) -> None:
        self._write_rows()
        self._append(encode_json(RecordType.EVENT, event))

    def end(self, end: End) -> None:
        self._write_rows()
        if self._append(encode_json(RecordType.END, end), last=True):
            self.ended = True
            self.flush()

    def _write_rows(self) -> None:
        if self._rows and self.failed:
            self._rows.clear()
        if self._rows:
            rows = np.array(self._rows, dtype=SAMPLE_DTYPE)
            self._rows.clear()
            if self._append(encode_samples(rows)):
                self.samples_written += len(rows)

    def flush(self) -> None:
        self._write_rows()
        try:
            os.fsync(self._fd)
        except OSError as exc:
            self._fail(exc)

    def close(self) -> None:
        if self._fd >= 0:
            self.flush()
            os.close(self._fd)
            self._fd = -1

    def _append(self, data: bytes, last: bool = False) -> bool:
        """Append whole records; False, and the file as it was, if the disk would not take
        them. Once a write failed only the end record (``last``) is tried."""
        if self._fd < 0 or (self.failed and not last):
            return False
        size = os.fstat(self._fd).st_size
        view = memoryview(data)
        try:
            while view:
                wrote = os.write(self._fd, view)
                if wrote <= 0:  # no error and no progress: no room
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                view = view[wrote:]
        except OSError as exc:
            # A torn record would end the file for every reader: what follows it is lost.
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, size)
            self._fail(exc)
            return False
        return True

    def _fail(self, exc: OSError) -> None:
        if self.failed:
            return
        self.failed = disk_words(exc)
        log.error("cannot write the session file %s: %s", self.path, exc)
        self._on_failure(self.failed)

    def _sync_done(self, future: asyncio.Future[None]) -> None:
        if future.cancelled() or future.exception() is None:
            return
        exc = future.exception()
        log.error("cannot sync the session file: %s", exc)
        if isinstance(exc, OSError):
            self._fail(exc)


def _fsync_dup(fd: int) -> None:
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
