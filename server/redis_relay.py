"""The relay between server processes through Redis (``ANKLE_RELAY_URL=redis://…``).

Pub/sub, not streams: what crosses is live (a viewer wants the newest sample and the events
from now on, not a history). Measured between two processes on a loaded 2-core machine, 100
stations' samples (~650 B) at 50 Hz in one pipeline per tick: pub/sub p50 3.6–5.2 ms, p99
10–17 ms (one run 52 ms); streams (XADD with MAXLEN, one XREAD over the 100) p50 7.6–7.9 ms,
p99 19–22 ms. Keys hold what a newcomer must find: which
process holds each station (``station:<id>``, a lease of ``lease_s`` refreshed every third of
it) and its last status (``status:<id>``); ``alive:<process>`` is written at each heartbeat
of a process holding no station, so that every process finds out when Redis holds writes.

Channels: ``view:<id>`` (events, status, presence, results: ``"<process> <json>"``),
``tele:<id>`` (the newest telemetry, raw), ``proc:<name>`` (to one process) and ``all``.
Telemetry is published only while another process watches the station: a watcher says so
to the holder (``watch``), the holder counts the subscribers when it claims a station, and
stops publishing once a publish reaches nobody.

Redis away, each process goes on with the links it holds. The first failed call makes the
relay unreachable for the hub (its viewers of stations held elsewhere are told that their
presence is not known); the heartbeat, every ``RETRY_S`` meanwhile, makes it reachable
again once the leases are refreshed and the subscription is heard again. Each kind of call
logs once when it starts failing and once when it works again, with how much was lost, not
at every failure (one station's telemetry alone is 25 publishes a second).
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import itertools
import json
import logging
import os
import secrets
import socket
import time
from collections.abc import Sequence
from typing import Any
from urllib.parse import urlsplit

import redis.asyncio as aioredis
from redis.asyncio.client import PubSub
from redis.exceptions import RedisError

from server.relay import RECENT_BATCHES, Listener, Message, Relay, RelayUnreachable

log = logging.getLogger("ankle.server.relay")

PREFIX = "ankle:"
RETRY_S = 0.5
"""Between attempts to hear Redis again after the connection dropped."""
RENEW_GRACE_S = 2 * RETRY_S
"""How long a watched station's lease may be missing before its viewers are told it is
gone. A Redis that hangs (a failover; ``CLIENT PAUSE``) longer than the lease lets every
lease run out though each process is alive and holds its stations; each process renews its
leases within ``RETRY_S`` of Redis taking writes again, and is given twice that."""
_RELEASE = """
if redis.call('get', KEYS[1]) == ARGV[1] then
  return redis.call('del', KEYS[1], KEYS[2])
end
return 0
"""
_REFRESH = """
for i = 1, #KEYS, 2 do
  local holder = redis.call('get', KEYS[i])
  if holder == ARGV[1] or not holder then
    redis.call('set', KEYS[i], ARGV[1], 'PX', ARGV[2])
    redis.call('pexpire', KEYS[i + 1], ARGV[2])
  end
end
return 0
"""


class _Outage:
    """One kind of call to Redis: logged when it starts failing and when it works again,
    with how many of its messages were lost meanwhile; not at each failure."""

    def __init__(self, what: str, unit: str = "") -> None:
        self.what = what
        self.unit = unit
        self.since: float | None = None
        self.lost = 0

    def failed(self, exc: Exception, lost: int = 0) -> None:
        self.lost += lost
        if self.since is None:
            self.since = time.monotonic()
            log.warning("%s failed: %s (not logged again until it works)", self.what, exc)

    def worked(self) -> None:
        if self.since is None:
            return
        took = time.monotonic() - self.since
        lost = f"; {self.lost} {self.unit} were lost" if self.unit else ""
        log.warning("%s works again after %.1f s%s", self.what, took, lost)
        self.since, self.lost = None, 0


def _name(kind: str, what: object) -> str:
    """A key (``station``, ``status``, ``shared``) or channel (``view``, ``tele``, ``proc``)."""
    return f"{PREFIX}{kind}:{what}"


CHECK_WAIT_S = 5.0
"""How long ``check_reachable`` waits for the relay to connect and answer, seconds."""


def where(url: str) -> str:
    """The Redis a URL names, for a message: host, port and database (no password)."""
    parts = urlsplit(url)
    if parts.scheme == "unix":
        return f"Redis at {parts.path}"
    return f"Redis at {parts.hostname or 'localhost'}:{parts.port or 6379}{parts.path or '/0'}"


async def check_reachable(url: str) -> None:
    """Connect to the relay and PING it; RelayUnreachable, in one line, if it does not
    answer: ``ankle server`` says so before it starts, where a process's start-up failing
    in the hub printed a traceback of 180 lines."""
    client = aioredis.Redis.from_url(
        url, socket_connect_timeout=CHECK_WAIT_S, socket_timeout=CHECK_WAIT_S
    )
    try:
        await client.ping()
    except (RedisError, OSError) as exc:
        said = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise RelayUnreachable(
            f"cannot reach the relay (ANKLE_RELAY_URL: {where(url)}): {said}"
        ) from None
    finally:
        await client.aclose()


class RedisRelay(Relay):
    def __init__(self, url: str, lease_s: float = 10.0, view_hz: float = 50.0) -> None:
        self.redis = aioredis.Redis.from_url(url, decode_responses=True)
        self.process = f"{socket.gethostname()}:{os.getpid()}:{secrets.token_hex(4)}"
        self.lease_s = lease_s
        self.period = 1.0 / view_hz
        self._listener: Listener | None = None
        self._pubsub: PubSub | None = None
        self._mine: set[int] = set()
        """Stations claimed by this process."""
        self._watched: set[int] = set()
        """Stations of this process that another process watches: their telemetry goes out."""
        self._dirty: dict[int, list[str]] = {}
        """Batches of this process's watched stations waiting for the next pipeline, in order."""
        self._watching: collections.Counter[int] = collections.Counter()
        self._unheard: set[int] = set()
        """Stations watched here whose channels could not be subscribed to (Redis was away):
        the heartbeat subscribes once it is back."""
        self._holder: dict[int, str | None] = {}
        """The process each station watched here was last seen on."""
        self._missing: dict[int, float] = {}
        """Watched stations whose lease was first found missing then (``time.monotonic``):
        told gone only once it stays missing ``RENEW_GRACE_S``."""
        self._unsure: set[int] = set()
        """Watched stations whose viewers were told the relay is away: told their presence
        once it is known again."""
        self._recent: dict[int, collections.deque[tuple[int, str]]] = {}
        """The newest batches of each station watched here, numbered per station."""
        self._seq: collections.Counter[int] = collections.Counter()
        self._out: asyncio.Queue[tuple[str, str, str | None]] = asyncio.Queue()
        self._tasks: list[asyncio.Task[None]] = []
        self._handling: set[asyncio.Task[None]] = set()
        self._release = self.redis.register_script(_RELEASE)
        self._refresh = self.redis.register_script(_REFRESH)
        self.reachable = True
        self._listening = _Outage("the relay's subscription")
        self._leases = _Outage("refreshing the relay's leases")
        self._messages = _Outage("publishing live messages", "messages")
        self._batches = _Outage("publishing telemetry", "telemetry batches")

    def _set_reachable(self, up: bool) -> None:
        if up != self.reachable:
            self.reachable = up
            if not up:
                self._unsure = {s for s in self._watching if s not in self._mine}
            if self._listener is not None:
                self._listener.relay_reachable(up)

    # -- life ------------------------------------------------------------------------------
    async def start(self, listener: Listener) -> None:
        self._listener = listener
        self._pubsub = self.redis.pubsub(ignore_subscribe_messages=True)
        await self._pubsub.subscribe(_name("proc", self.process), f"{PREFIX}all")
        self._tasks = [
            asyncio.create_task(self._listen(), name="relay-listen"),
            asyncio.create_task(self._publisher(), name="relay-publish"),
            asyncio.create_task(self._telemetry_out(), name="relay-telemetry"),
            asyncio.create_task(self._heartbeat(), name="relay-heartbeat"),
        ]

    async def answers(self) -> None:
        await self.redis.ping()

    async def close(self) -> None:
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(2.0):
                await self._out.join()
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, *self._handling, return_exceptions=True)
        with contextlib.suppress(Exception):
            for station_id in list(self._mine):
                await self.release(station_id)
        if self._pubsub is not None:
            with contextlib.suppress(Exception):
                # redis-py types aclose() from 8.2 on; the range we accept starts at 5.
                closing: Any = self._pubsub.aclose
                await closing()
        await self.redis.aclose()

    # -- presence --------------------------------------------------------------------------
    async def claim(self, station_id: int) -> str | None:
        self._mine.add(station_id)
        async with self.redis.pipeline(transaction=False) as pipe:
            pipe.set(_name("station", station_id), self.process, px=self._lease_ms(), get=True)
            pipe.pubsub_numsub(_name("tele", station_id))
            before, ((_, listening),) = await pipe.execute()
        if listening:
            self._watched.add(station_id)
        return before if before and before != self.process else None

    async def release(self, station_id: int) -> None:
        self._mine.discard(station_id)
        self._watched.discard(station_id)
        self._dirty.pop(station_id, None)
        keys = [_name("station", station_id), _name("status", station_id)]
        await self._release(keys=keys, args=[self.process])

    async def owners(self, station_ids: list[int]) -> dict[int, str]:
        if not station_ids:
            return {}
        held = await self.redis.mget([_name("station", s) for s in station_ids])
        return {s: str(p) for s, p in zip(station_ids, held, strict=True) if p}

    def _lease_ms(self) -> int:
        return max(1, round(self.lease_s * 1000))

    async def _heartbeat(self) -> None:
        """Refresh this process's leases; notice watched stations whose process vanished or
        came back. While Redis is away, every RETRY_S: the first beat that works makes the
        relay reachable again."""
        while True:
            beat = self.lease_s / 3
            hurry = not self.reachable or self._missing
            await asyncio.sleep(min(beat, RETRY_S) if hurry else beat)
            try:
                # A write at every beat, even with no station here to renew (then a key
                # naming this process, kept for the lease): a Redis that takes reads but
                # holds writes (paused for a failover) is away for this process too, and
                # its expired leases are not read as stations gone.
                keys = [k for s in self._mine for k in (_name("station", s), _name("status", s))]
                if keys:
                    await self._refresh(keys=keys, args=[self.process, self._lease_ms()])
                else:
                    await self.redis.set(_name("alive", self.process), 1, px=self._lease_ms())
                await self._check_watched(hearing=self._listening.since is None)
                for station_id in list(self._unheard):
                    if self._watching[station_id]:
                        await self._hear(station_id)
            except Exception as exc:  # Redis is away: the next beat tries again
                self._leases.failed(exc)
                self._set_reachable(False)
            else:
                self._leases.worked()
                if self._listening.since is None:
                    self._set_reachable(True)

    async def _check_watched(self, hearing: bool = True) -> None:
        """Tell the listener of watched stations that went (their lease missing for
        ``RENEW_GRACE_S``) or came back; and, once the relay is heard again (``hearing``),
        the presence of those whose viewers were told it was away."""
        watched = [s for s in self._watching if s not in self._mine]
        holders = await self.owners(watched)
        now = time.monotonic()
        for station_id in watched:
            holder = holders.get(station_id)
            before = self._holder.get(station_id)
            unsure = hearing and station_id in self._unsure
            if holder is None:
                if before is not None:
                    since = self._missing.setdefault(station_id, now)
                    if now - since < RENEW_GRACE_S:
                        continue  # its process may yet renew it
                self._missing.pop(station_id, None)
                if before is not None:
                    self._recent.pop(station_id, None)
                    if self._listener is not None:
                        self._listener.gone(station_id)
                elif unsure and self._listener is not None:
                    self._listener.back(station_id)  # told as it is: offline
            else:
                self._missing.pop(station_id, None)
                if (before is None or unsure) and self._listener is not None:
                    self._listener.back(station_id)
                self.send(holder, {"type": "watch", "station_id": station_id})
            if hearing:
                self._unsure.discard(station_id)
            self._holder[station_id] = holder

    # -- live data -------------------------------------------------------------------------
    def publish(self, station_id: int, text: str, status: bool = False) -> None:
        status_key = _name("status", station_id) if status else None
        self._out.put_nowait((_name("view", station_id), f"{self.process} {text}", status_key))

    def telemetry(self, station_id: int, raw: str) -> None:
        if station_id in self._watched:
            self._dirty.setdefault(station_id, []).append(raw)

    def recent(self, station_id: int) -> Sequence[tuple[int, str]]:
        return self._recent.get(station_id, ())

    async def last_status(self, station_id: int) -> str | None:
        text = await self.redis.get(_name("status", station_id))
        return None if text is None else str(text)

    async def watch(self, station_id: int) -> None:
        self._watching[station_id] += 1
        if not self.reachable:  # its viewer is told the relay is away
            self._unsure.add(station_id)
        if self._watching[station_id] == 1:
            await self._hear(station_id)

    async def _hear(self, station_id: int) -> None:
        """Subscribe to a station watched here and tell its holder; if Redis is away, the
        heartbeat does so once it is back."""
        assert self._pubsub is not None
        try:
            await self._pubsub.subscribe(_name("view", station_id), _name("tele", station_id))
        except Exception:
            self._unheard.add(station_id)
            raise
        self._unheard.discard(station_id)
        holder = await self.owner(station_id)
        self._holder[station_id] = holder
        if holder is not None and holder != self.process:
            self.send(holder, {"type": "watch", "station_id": station_id})

    async def unwatch(self, station_id: int) -> None:
        self._watching[station_id] -= 1
        if self._watching[station_id] > 0:
            return
        del self._watching[station_id]
        self._unheard.discard(station_id)
        self._unsure.discard(station_id)
        self._missing.pop(station_id, None)
        self._holder.pop(station_id, None)
        self._recent.pop(station_id, None)
        if self._pubsub is not None:
            with contextlib.suppress(Exception):
                await self._pubsub.unsubscribe(_name("view", station_id), _name("tele", station_id))

    async def share(self, key: str, value: str, ttl_s: float) -> None:
        await self.redis.set(_name("shared", key), value, px=max(1, round(ttl_s * 1000)))

    async def look_up(self, key: str, ttl_s: float) -> str | None:
        value = await self.redis.getex(_name("shared", key), px=max(1, round(ttl_s * 1000)))
        return None if value is None else str(value)

    async def unshare(self, key: str) -> None:
        await self.redis.delete(_name("shared", key))

    def send(self, process: str, message: Message) -> None:
        self._out.put_nowait((_name("proc", process), json.dumps(message), None))

    def everyone(self, message: Message) -> None:
        self._out.put_nowait((f"{PREFIX}all", json.dumps(message | {"from": self.process}), None))

    # -- the wire --------------------------------------------------------------------------
    async def _publisher(self) -> None:
        """Everything queued so far in one round trip, in order."""
        while True:
            batch = [await self._out.get()]
            while not self._out.empty():
                batch.append(self._out.get_nowait())
            try:
                async with self.redis.pipeline(transaction=False) as pipe:
                    for channel, payload, status_key in batch:
                        if status_key is not None:
                            pipe.set(status_key, payload.partition(" ")[2], px=self._lease_ms())
                        pipe.publish(channel, payload)
                    await pipe.execute()
            except Exception as exc:
                self._messages.failed(exc, len(batch))
                self._set_reachable(False)
            else:
                self._messages.worked()
            finally:
                for _ in batch:
                    self._out.task_done()

    async def _telemetry_out(self) -> None:
        """The newest sample of each watched station, at most once a period."""
        while True:
            await asyncio.sleep(self.period)
            if not self._dirty:
                continue
            dirty, self._dirty = self._dirty, {}
            try:
                async with self.redis.pipeline(transaction=False) as pipe:
                    for station_id, raws in dirty.items():
                        for raw in raws:  # every batch: a chart on another process loses none
                            pipe.publish(_name("tele", station_id), raw)
                    heard = await pipe.execute()
            except Exception as exc:
                self._batches.failed(exc, sum(len(raws) for raws in dirty.values()))
                self._set_reachable(False)
                continue
            self._batches.worked()
            counts = [heard[i - 1] for i in itertools.accumulate(len(r) for r in dirty.values())]
            for station_id, count in zip(dirty, counts, strict=True):
                if not count:  # nobody listens any more
                    self._watched.discard(station_id)

    async def _listen(self) -> None:
        assert self._pubsub is not None and self._listener is not None
        listener = self._listener
        while True:
            try:
                async for item in self._pubsub.listen():
                    if item.get("type") == "message":
                        self._dispatch(listener, item["channel"], item["data"])
            except asyncio.CancelledError:
                raise
            except Exception as exc:  # the connection dropped
                self._listening.failed(exc)
                self._set_reachable(False)
                await self._listen_again()

    async def _listen_again(self) -> None:
        """Until the subscription's connection is back (redis-py subscribes it again to every
        channel it had when it reconnects)."""
        assert self._pubsub is not None
        while True:
            await asyncio.sleep(RETRY_S)
            try:
                await self._pubsub.ping()
            except Exception as exc:
                self._listening.failed(exc)
            else:
                self._listening.worked()
                return

    def _dispatch(self, listener: Listener, channel: str, data: str) -> None:
        kind, _, name = channel[len(PREFIX) :].partition(":")
        if kind == "tele":
            station_id = int(name)
            if station_id not in self._mine:
                self._seq[station_id] += 1
                recent = self._recent.setdefault(
                    station_id, collections.deque(maxlen=RECENT_BATCHES)
                )
                recent.append((self._seq[station_id], data))
                listener.telemetry_came(station_id)
        elif kind == "view":
            origin, _, text = data.partition(" ")
            if origin != self.process:
                listener.deliver(int(name), text)
        else:
            message: dict[str, Any] = json.loads(data)
            if message.get("from") == self.process:
                return
            if message.get("type") == "watch":
                if message["station_id"] in self._mine:
                    self._watched.add(message["station_id"])
                return
            task = asyncio.create_task(self._handle(listener, message))
            self._handling.add(task)
            task.add_done_callback(self._handling.discard)

    @staticmethod
    async def _handle(listener: Listener, message: Message) -> None:
        try:
            await listener.on_message(message)
        except Exception:
            log.exception("handling relayed %s failed", message.get("type"))
