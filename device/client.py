"""The host's side of the serial link: an asyncio client of the device service.

The home station uses it to drive the device::

    async with await DeviceClient.connect("/dev/pts/5") as dev:
        await dev.arm_home()
        await dev.wait_for_mode(DeviceMode.READY, timeout=15)
        await dev.start_segment(segment)
        async for sample in dev.telemetry():
            ...

``connect`` opens the port (any pyserial name or URL such as ``socket://host:port``),
shakes hands (a device of another protocol version is a :class:`ProtocolVersionError`, not
a timeout) and keeps the device's watchdog fed with heartbeats. Each command waits for its
ACK; a lost frame is sent again with the same sequence number, which the device answers
without running it twice. A NACK raises :class:`CommandRefused` carrying the device's code
and reason. Events lost on the way are asked for again (``ReplayEvents``).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import random
import time
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from types import TracebackType
from typing import Generic, NamedTuple, TypeVar

from device.protocol import messages as msg
from device.protocol.framing import HANDSHAKE_TYPE, PROTOCOL_VERSION, Frame, FrameDecoder
from device.protocol.messages import DeviceMode
from device.segments import AxisPlan as AxisPlan  # re-exported: hosts build with these
from device.segments import build_segment as build_segment
from device.transport import open_stream

HOST_NAME = "ankle-host 0.1.0"
CLOSE_TIMEOUT = 2.0
"""Seconds :meth:`DeviceClient.close` waits for the port to flush before it drops it."""
STALL_S = 0.1
"""A heartbeat's wait (its period's sleep, or its ACK's) this much past its bound is a stall
of this host, or less where the watchdog is short (:attr:`DeviceClient.stall_threshold`):
half the device's default watchdog (``ankle device --watchdog-ms``, 200 ms)."""
STALL_SHARE = 0.5
"""A stall is also anything over this share of the device's watchdog, where that is less.
The device hears nothing for a heartbeat period plus the stall, and holds past the
watchdog: a stall over half of it is counted before it can hold (a 75 ms stall held a
100 ms watchdog, under a fixed 100 ms uncounted)."""
log = logging.getLogger("ankle.host")
T = TypeVar("T")
HEARTBEATS_PER_WATCHDOG = 4
"""Heartbeats sent at least this often within the device's watchdog (the one it publishes in
HELLO, then the one configured): a heartbeat late or unanswered leaves room for the next.
The device's least watchdog (``watchdog_ms_min``) makes this 25 ms at most."""
EARLY_MAX = 1024
"""Events held back past a gap at most (the device keeps its latest 64 for replay)."""


class DeviceError(Exception):
    """Something went wrong talking to the device."""


class LinkTimeout(DeviceError):
    """No answer from the device in time (after the retries)."""


class LinkClosed(DeviceError):
    """The link was closed."""


class ProtocolVersionError(DeviceError):
    """The device speaks another protocol version."""


class CommandRefused(DeviceError):
    """The device answered NACK: nothing was changed."""

    def __init__(self, nack: msg.Nack) -> None:
        where = f" [{nack.field}]" if nack.field else ""
        super().__init__(f"{nack.code.name}{where}: {nack.text}")
        self.nack = nack


GAPS_KEPT = 16
"""The newest writes whose preceding silence is remembered (:meth:`DeviceClient._send`)."""


class Stall(NamedTuple):
    """One time this host stood still (:meth:`DeviceClient._check_stall`)."""

    ended: float
    """Unix time when it ended."""
    ms: float
    """How late the heartbeat's wait ended past its bound."""
    quiet_ms: float
    """How long the device had then heard nothing from this host (since the last frame
    written): the silence this stall made, at least. A hold whose silence is longer is not
    this stall's alone."""


@dataclass
class ClientStats:
    frames: int = 0
    frames_lost: int = 0
    """Gaps in the device's frame sequence numbers."""
    events_lost: int = 0
    """Events the device no longer keeps when this host asked for them again (a host that
    connected after more events than the device keeps, or was away that long)."""
    undecodable: int = 0
    retries: int = 0
    rtt_ms: list[float] = field(default_factory=list)
    """Command to ACK/NACK round trips (the last 10000)."""
    stalls: int = 0
    """Heartbeats that left more than :attr:`DeviceClient.stall_threshold` late: this host
    stood still (its event loop blocked, or the process got no core) and the device heard
    nothing meanwhile."""
    stall_ms_max: float = 0.0
    """The longest such stall (ms)."""
    last_stall: Stall | None = None
    """The newest."""


class Subscription(Generic[T]):
    """An async iterator over what the device sends from its creation on; it ends when the
    link closes. :meth:`aclose` (or dropping it) stops the delivery."""

    def __init__(
        self,
        subs: list[asyncio.Queue[T | None]],
        maxsize: int,
        ended: bool,
        before: Iterable[T] = (),
    ) -> None:
        self._subs = subs
        self._q: asyncio.Queue[T | None] = asyncio.Queue(maxsize)
        self._done = ended
        if not ended:
            for item in before:
                self._q.put_nowait(item)
            subs.append(self._q)

    def __aiter__(self) -> Subscription[T]:
        return self

    async def __anext__(self) -> T:
        if self._done:
            raise StopAsyncIteration
        item = await self._q.get()
        if item is None:
            self._unsubscribe()
            raise StopAsyncIteration
        return item

    async def aclose(self) -> None:
        self._unsubscribe()

    def _unsubscribe(self) -> None:
        self._done = True
        with contextlib.suppress(ValueError):
            self._subs.remove(self._q)

    def __del__(self) -> None:
        self._unsubscribe()


class DeviceClient:
    """An open, handshaken link to one device."""

    def __init__(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        command_timeout: float = 0.1,
        retries: int = 3,
        heartbeat_period: float = 0.05,
    ) -> None:
        self._reader = reader
        self._writer = writer
        self.command_timeout = command_timeout
        self.retries = retries
        self.heartbeat_period = heartbeat_period
        """The longest wait between heartbeats (:attr:`heartbeat_interval` is the one used)."""
        self.watchdog_ms: int | None = None
        """The device's watchdog as its HELLO said, then as this host configured it."""
        self.heartbeats = True
        """Clear to stop feeding the device's watchdog (to test it)."""
        self.decoder = FrameDecoder()
        self.stats = ClientStats()
        self.hello: msg.DeviceHello | None = None
        self.latest: msg.Telemetry | None = None
        self.latest_at = 0.0
        """Host clock (``time.perf_counter``) when :attr:`latest` arrived."""
        self.last_event: msg.Event | None = None
        """The newest event heard, in order (what a timeout names as the likely cause)."""
        self.mode: DeviceMode | None = None
        """The device's mode as the newest telemetry sample or ACK says. The link keeps
        order, so the last of them heard is the newest state; telemetry alone lags a
        command's ACK by up to a telemetry period (a segment ACKed is ACTIVE at once)."""
        self._seq = itertools.count(random.randrange(0x10000))
        self._pending: dict[int, asyncio.Future[msg.Ack | msg.Nack]] = {}
        self._hello: asyncio.Future[msg.DeviceHello] | None = None
        self._telemetry_subs: list[asyncio.Queue[msg.Telemetry | None]] = []
        self._event_subs: list[asyncio.Queue[msg.Event | None]] = []
        self._unasked: deque[msg.Event] | None = deque(maxlen=EARLY_MAX)
        """Events heard before the first :meth:`events` (None from then): the device sends
        the event of a hold that a new HELLO causes, and its replay, while the handshake is
        under way, before a host can subscribe. The first subscription gets them first."""
        # Subscriptions start when asked for, not at their first read: a hold that came
        # between the two was lost to a caller that asked for events, then stopped the
        # heartbeats and waited.
        self._last_rx_seq: int | None = None
        self._last_event_id = 0
        self._early: dict[int, msg.Event] = {}
        """Events received past a gap, until the gap is filled or known to be for good."""
        self._replay_asked = 0
        self._replay_at = 0.0
        self._replay_seq: int | None = None
        self._replay_lost = 0
        self._sent_at = time.perf_counter()
        """Host clock when the last frame was written to the device."""
        self._gaps: deque[tuple[float, float]] = deque(maxlen=GAPS_KEPT)
        """(host clock of a write, how long the device had heard nothing before it) of the
        newest writes: a stall's silence may have been ended by another task's frame before
        the heartbeat loop, waking too, measured it."""
        self._closed = asyncio.Event()
        self.link_error: str | None = None
        """Why nothing more arrives, once the link has closed or failed."""
        self._tasks: list[asyncio.Task[None]] = [asyncio.create_task(self._read_loop())]

    # -- opening and closing -------------------------------------------------------------
    @classmethod
    async def connect(
        cls,
        url: str,
        baud: int = 921600,
        timeout: float = 2.0,
        heartbeat: bool = True,
        command_timeout: float = 0.1,
        retries: int = 3,
        heartbeat_period: float = 0.05,
    ) -> DeviceClient:
        reader, writer = await open_stream(url, baud)
        client = cls(reader, writer, command_timeout, retries, heartbeat_period)
        try:
            await client.handshake(timeout)
        except BaseException:
            await client.close()
            raise
        if heartbeat:
            client._tasks.append(asyncio.create_task(client._heartbeat_loop()))
        return client

    async def handshake(self, timeout: float = 2.0) -> msg.DeviceHello:
        """Send HELLO until the device answers (a new nonce: old sequence numbers forgotten)."""
        loop = asyncio.get_running_loop()
        hello = msg.Hello(host=HOST_NAME, nonce=random.getrandbits(32))
        deadline = loop.time() + timeout
        while True:
            self._hello = loop.create_future()
            self._write(hello, next(self._seq))
            try:
                remaining = max(0.0, min(0.25, deadline - loop.time()))
                async with asyncio.timeout(remaining):
                    self.hello = await asyncio.shield(self._hello)
                self.watchdog_ms = self.hello.watchdog_ms
                return self.hello
            except TimeoutError:
                if loop.time() >= deadline:
                    raise LinkTimeout(f"no answer to HELLO within {timeout:g} s") from None

    async def close(self) -> None:
        self._closed.set()
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        self._writer.close()
        try:
            # Bounded: a port whose far end stopped reading never flushes what is queued.
            async with asyncio.timeout(CLOSE_TIMEOUT):
                await self._writer.wait_closed()
        except TimeoutError:
            self._writer.transport.abort()
        except Exception:
            pass
        self._end_streams()
        for fut in self._pending.values():
            if not fut.done():
                fut.set_exception(LinkClosed("link closed"))

    async def __aenter__(self) -> DeviceClient:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()

    # -- commands ------------------------------------------------------------------------
    async def command(
        self, message: msg.Message, timeout: float | None = None, retries: int | None = None
    ) -> msg.Ack:
        """Send a command and wait for its ACK; :class:`CommandRefused` on a NACK."""
        if self._closed.is_set():
            raise LinkClosed("link closed")
        timeout = self.command_timeout if timeout is None else timeout
        retries = self.retries if retries is None else retries
        seq = next(self._seq) & 0xFFFF
        loop = asyncio.get_running_loop()
        fut: asyncio.Future[msg.Ack | msg.Nack] = loop.create_future()
        self._pending[seq] = fut
        frame = msg.encode(message, seq)
        start = time.perf_counter()
        try:
            for attempt in range(retries + 1):
                if attempt:
                    self.stats.retries += 1
                self._send(frame)
                try:
                    # Not wait_for: on Python 3.11 it drops a cancellation that arrives as
                    # the ACK does, and a task that sends commands in a loop never stops.
                    async with asyncio.timeout(timeout):
                        reply = await asyncio.shield(fut)
                    break
                except TimeoutError:
                    continue
            else:
                raise LinkTimeout(
                    f"{type(message).__name__}: no answer after {retries + 1} tries of "
                    f"{timeout * 1e3:.0f} ms"
                )
        finally:
            self._pending.pop(seq, None)
        self.stats.rtt_ms.append((time.perf_counter() - start) * 1e3)
        if len(self.stats.rtt_ms) > 10000:
            del self.stats.rtt_ms[:5000]
        if isinstance(reply, msg.Nack):
            raise CommandRefused(reply)
        return reply

    async def configure(self, telemetry_hz: int, watchdog_ms: int) -> msg.Ack:
        ack = await self.command(msg.Configure(telemetry_hz=telemetry_hz, watchdog_ms=watchdog_ms))
        self.watchdog_ms = watchdog_ms  # the heartbeats follow from the next one on
        return ack

    @property
    def heartbeat_interval(self) -> float:
        """Seconds between heartbeats: :attr:`heartbeat_period`, or less, so that
        :data:`HEARTBEATS_PER_WATCHDOG` fit in the device's watchdog."""
        if self.watchdog_ms is None:
            return self.heartbeat_period
        return min(self.heartbeat_period, self.watchdog_ms / 1e3 / HEARTBEATS_PER_WATCHDOG)

    @property
    def stall_threshold(self) -> float:
        """Seconds a heartbeat's wait may end past its bound before it counts as a stall:
        :data:`STALL_S`, or :data:`STALL_SHARE` of the device's watchdog if that is less, so
        that every hold this host's standing still causes shows in :attr:`stats`."""
        if self.watchdog_ms is None:
            return STALL_S
        return min(STALL_S, STALL_SHARE * self.watchdog_ms / 1e3)

    async def arm_home(self) -> msg.Ack:
        return await self.command(msg.ArmHome())

    async def start_segment(self, segment: msg.StartSegment) -> msg.Ack:
        return await self.command(segment)

    async def set_impedance(
        self, stiffness: tuple[float, ...], damping: tuple[float, ...]
    ) -> msg.Ack:
        return await self.command(msg.SetImpedance(stiffness=stiffness, damping=damping))

    async def hold(self) -> msg.Ack:
        return await self.command(msg.HoldCmd())

    async def resume(self) -> msg.Ack:
        return await self.command(msg.Resume())

    async def estop(self) -> msg.Ack:
        return await self.command(msg.EStop())

    async def rearm(self) -> msg.Ack:
        return await self.command(msg.Rearm())

    async def release(self) -> msg.Ack:
        return await self.command(msg.Release())

    @property
    def newest_event_id(self) -> int:
        """The newest event id this host knows the device to have: heard, held back past a
        gap, or named by telemetry. A newer event happened after this moment."""
        named = self.latest.last_event_id if self.latest is not None else 0
        return max(self._last_event_id, named, max(self._early, default=0))

    # -- streams -------------------------------------------------------------------------
    def telemetry(self, maxsize: int = 1024) -> Subscription[msg.Telemetry]:
        """Every telemetry sample from this call on (oldest dropped if the consumer lags)."""
        return Subscription(self._telemetry_subs, maxsize, self._closed.is_set())

    def events(self) -> Subscription[msg.Event]:
        """Every event from this call on, each once, in id order as received; the first call
        also gets those heard before it (since the link opened)."""
        before, self._unasked = self._unasked or (), None
        return Subscription(self._event_subs, 0, self._closed.is_set(), before)

    async def wait_for_mode(self, *modes: DeviceMode, timeout: float = 5.0) -> msg.Telemetry:
        """The first telemetry sample in one of ``modes``; :class:`LinkTimeout` otherwise.
        The newest sample counts only while no ACK since has said another mode."""
        latest = self.latest
        if latest is not None and latest.mode in modes and self.mode == latest.mode:
            return latest
        try:
            async with asyncio.timeout(timeout), contextlib.aclosing(self.telemetry()) as stream:
                async for sample in stream:
                    if sample.mode in modes:
                        return sample
        except TimeoutError:
            pass
        now = self.latest.mode.name if self.latest else "unknown"
        names = " or ".join(m.name for m in modes)
        why = ""
        if (e := self.last_event) is not None:
            why = f"; its last event, #{e.event_id}: {e.kind.name}"
            if e.text:
                why += f", {e.text}"
        raise LinkTimeout(f"device did not reach {names} within {timeout:g} s (it is {now}{why})")

    # -- internals -----------------------------------------------------------------------
    def _end_streams(self) -> None:
        """Let every telemetry and event iterator finish."""
        for q in self._telemetry_subs:
            if q.full():
                q.get_nowait()  # the end must get in: a bounded queue drops its oldest
            q.put_nowait(None)
        for eq in self._event_subs:
            eq.put_nowait(None)

    def _write(self, message: msg.Message, seq: int) -> None:
        self._send(msg.encode(message, seq))

    def _send(self, frame: bytes) -> None:
        self._writer.write(frame)
        now = time.perf_counter()
        self._gaps.append((now, now - self._sent_at))
        self._sent_at = now

    async def _heartbeat_loop(self) -> None:
        # Each wait is bounded (the sleep by its period, the ACK by its timeout): a wait that
        # ends later than that is this host standing still, whichever of the two it hit.
        while not self._closed.is_set():
            period = self.heartbeat_interval  # a configure changes it
            start = time.perf_counter()
            await asyncio.sleep(period)
            self._check_stall(start, period)
            if not self.heartbeats:
                continue
            start = time.perf_counter()
            with contextlib.suppress(DeviceError):
                await self.command(msg.Heartbeat(), timeout=period, retries=0)
            self._check_stall(start, period)

    def _check_stall(self, start: float, period: float) -> None:
        """A heartbeat's wait that began at ``start`` (host clock) was bounded by ``period``
        s: ended later by over :attr:`stall_threshold`, this host stood still; count it and
        say so, so that a hold by the device's watchdog can be told from a broken cable."""
        now = time.perf_counter()
        late = now - start - period
        if late <= self.stall_threshold:
            return
        ms = late * 1e3
        self.stats.stalls += 1
        self.stats.stall_ms_max = max(self.stats.stall_ms_max, ms)
        # The device's silence through the stall: since the last write, or, where a frame
        # of another task that woke first went out before this check, the gap it ended (a
        # station frozen for 1 s was measured as quiet for less than the device's 501 ms
        # of silence, and its hold's cause said "unknown").
        quiet = max([now - self._sent_at] + [gap for at, gap in self._gaps if at >= start])
        quiet_ms = quiet * 1e3
        self.stats.last_stall = Stall(time.time(), ms, quiet_ms)
        log.warning(
            "this computer stood still for %.0f ms and sent the device nothing meanwhile "
            "(the device's watchdog holds the platform after its set silence): the event "
            "loop was blocked, or the computer had no free core",
            ms,
        )

    async def _read_loop(self) -> None:
        try:
            while True:
                data = await self._reader.read(4096)
                if not data:
                    self.link_error = "the device closed the link"
                    return
                for frame in self.decoder.feed(data):
                    self._on_frame(frame)
        except asyncio.CancelledError:
            self.link_error = self.link_error or "closed by this host"
            raise
        except Exception as exc:  # the port failed: every waiter must hear of it
            self.link_error = f"the link failed: {type(exc).__name__}: {exc}"
        finally:
            self._lost()

    def _lost(self) -> None:
        """Nothing more will arrive: end every stream and fail every command waiting."""
        self._closed.set()
        self._end_streams()
        why = self.link_error or "link closed"
        for fut in self._pending.values():
            if not fut.done():
                fut.set_exception(LinkClosed(why))

    def _on_frame(self, frame: Frame) -> None:
        self.stats.frames += 1
        if self._last_rx_seq is not None:
            gap = (frame.seq - self._last_rx_seq - 1) & 0xFFFF
            if gap < 0x8000:
                self.stats.frames_lost += gap
        self._last_rx_seq = frame.seq
        if frame.type == HANDSHAKE_TYPE and frame.version != PROTOCOL_VERSION:
            if self._hello is not None and not self._hello.done():
                self._hello.set_exception(
                    ProtocolVersionError(
                        f"the device speaks protocol version {frame.version}; this host "
                        f"speaks {PROTOCOL_VERSION}: update one of them"
                    )
                )
            return
        try:
            message = msg.decode(frame, "device")
        except msg.MessageError:
            self.stats.undecodable += 1
            return
        if isinstance(message, msg.Telemetry):
            self.latest = message
            self.latest_at = time.perf_counter()
            self.mode = message.mode
            for q in self._telemetry_subs:
                if q.full():
                    q.get_nowait()
                q.put_nowait(message)
            if message.last_event_id > self._last_event_id:
                self._ask_replay(message.last_event_id)
        elif isinstance(message, msg.Ack | msg.Nack):
            if message.ack_seq == self._replay_seq:
                self._replay_answered(isinstance(message, msg.Ack))
                return
            fut = self._pending.get(message.ack_seq)
            if fut is not None and not fut.done():
                if isinstance(message, msg.Ack):
                    self.mode = message.mode
                fut.set_result(message)
        elif isinstance(message, msg.Event):
            if message.event_id <= self._last_event_id or message.event_id in self._early:
                return  # already seen (a replay)
            if message.event_id > self._last_event_id + 1:
                # Held back until the missing ones come, so that the order holds.
                if len(self._early) < EARLY_MAX:
                    self._early[message.event_id] = message
                self._ask_replay(message.event_id)
                return
            self._deliver(message)
        elif isinstance(message, msg.DeviceHello):
            if self._hello is not None and not self._hello.done():
                self._hello.set_result(message)

    def _deliver(self, event: msg.Event) -> None:
        """Hand ``event`` (the next in order) to every subscriber, then those held back
        that now follow in order."""
        while True:
            self._last_event_id = event.event_id
            self.last_event = event
            if self._unasked is not None:
                self._unasked.append(event)
            for eq in self._event_subs:
                eq.put_nowait(event)
            following = self._early.pop(event.event_id + 1, None)
            if following is None:
                return
            event = following

    def _ask_replay(self, newest: int) -> None:
        now = time.perf_counter()
        if self._replay_asked >= newest and now - self._replay_at < 0.2:
            return  # asked already; ask again only if the answer got lost
        self._replay_asked, self._replay_at = newest, now
        self._replay_seq = next(self._seq) & 0xFFFF
        self._replay_lost = self.stats.frames_lost
        self._write(msg.ReplayEvents(after_id=self._last_event_id), self._replay_seq)

    def _replay_answered(self, acked: bool) -> None:
        """The device has sent every event it keeps after the one asked from (they come
        before its ACK, in order). A gap that remains, with no frame lost on the way, is
        for good: the device no longer keeps those events. Count them lost and go on from
        the oldest it sent, rather than ask again for ever and deliver nothing more."""
        self._replay_seq = None
        if not acked or not self._early or self.stats.frames_lost != self._replay_lost:
            return  # asked again at the next telemetry sample that names a newer event
        first = min(self._early)
        self.stats.events_lost += first - self._last_event_id - 1
        self._deliver(self._early.pop(first))
