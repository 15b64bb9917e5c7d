"""What server processes tell each other about live links: one interface, two engines.

The hub (:mod:`server.hub`) keeps the links connected to its own process. Whatever a link on
another process must see goes through a :class:`Relay`:

- presence: which process each station is connected to, as a lease the process refreshes
  (a process that dies lets its stations go offline when their leases run out);
- every telemetry batch of a station, for viewers elsewhere (sent only while some other
  process watches it, gathered into one pipeline every ``1 / view_hz`` s);
- events, status (the last one kept for a viewer's welcome), presence changes and command
  results, for the station's viewers on every process;
- messages addressed to one process (a command for the station it holds, its refusal back,
  word that it ended, or that its asker gave up on it; a prescription push; "your station
  connected elsewhere") or to all of them (re-check every link's credentials);
- what must be found on any process: a 3D view's ticket (``share``, ``look_up``).

:class:`LocalRelay` is the only-one-process engine, the embedded default: every call is a
no-op or an empty answer, so the hub's own direct path is all that runs and nothing is
serialised. ``redis://`` selects :class:`server.redis_relay.RedisRelay`. ``open_relay`` is the
one place an engine is chosen.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from typing import Any, Protocol

Message = dict[str, Any]
RECENT_BATCHES = 8
"""Telemetry batches kept per station (about 0.3 s at 25 a second), on the station's process
and on each process that watches it: a viewer that missed no more than these (two arrived
together, or a send was slow) is sent each one; one that missed more has fallen behind and is
sent the newest."""
"""A message addressed to a process: JSON-able, with a ``type``."""


class Listener(Protocol):
    """What a relay tells its process's hub."""

    def deliver(self, station_id: int, text: str) -> None:
        """An event, status, presence or result another process published for the station's
        viewers."""

    def telemetry_came(self, station_id: int) -> None:
        """A newer batch of a station connected elsewhere is in ``Relay.recent``."""

    def gone(self, station_id: int) -> None:
        """A watched station's process stopped holding its lease without saying goodbye."""

    def back(self, station_id: int) -> None:
        """A watched station is held again by a process, unannounced (its lease came back
        after the relay was away), or the relay is heard again after it was away: its
        viewers are told its presence afresh."""

    def relay_reachable(self, up: bool) -> None:
        """The relay stopped answering (False), or answers again (True): meanwhile what this
        process knows of the others' stations is not known (once it answers, each watched
        station's presence is told by ``back`` or ``gone``)."""

    async def on_message(self, message: Message) -> None:
        """A message sent to this process, or to every process."""


class Relay(abc.ABC):
    """The live links' view of the other server processes."""

    process: str
    """This process's name among the others."""
    reachable: bool = True
    """False from the first call that failed until the relay answers again."""

    @abc.abstractmethod
    async def start(self, listener: Listener) -> None:
        """Begin hearing the others."""

    @abc.abstractmethod
    async def answers(self) -> None:
        """Return once the relay answered a request (``/health``); raise if it cannot."""

    @abc.abstractmethod
    async def close(self) -> None:
        """Stop; the stations claimed here are released."""

    @abc.abstractmethod
    async def claim(self, station_id: int) -> str | None:
        """The station is connected here now; the process it was connected to before, if
        another (it is told to let go of its link)."""

    @abc.abstractmethod
    async def release(self, station_id: int) -> None:
        """The station's link here ended (a claim taken by another process stays)."""

    @abc.abstractmethod
    async def owners(self, station_ids: list[int]) -> dict[int, str]:
        """The process each of these stations is connected to, for those connected to
        another process or this one through the relay."""

    async def owner(self, station_id: int) -> str | None:
        return (await self.owners([station_id])).get(station_id)

    @abc.abstractmethod
    def publish(self, station_id: int, text: str, status: bool = False) -> None:
        """For the station's viewers on the other processes (``status``: also kept as the
        station's last status). Queued, in order."""

    @abc.abstractmethod
    def telemetry(self, station_id: int, raw: str) -> None:
        """The station's newest sample, as it sent it; other processes watching get the
        newest at most ``view_hz`` times a second."""

    @abc.abstractmethod
    def recent(self, station_id: int) -> Sequence[tuple[int, str]]:
        """The newest telemetry batches of a station connected elsewhere (at most
        ``RECENT_BATCHES``, oldest first), each with its number; empty if none came."""

    @abc.abstractmethod
    async def last_status(self, station_id: int) -> str | None:
        """The last status of a station connected elsewhere (its JSON text)."""

    @abc.abstractmethod
    async def watch(self, station_id: int) -> None:
        """This process shows the station (a viewer or a 3D view): hear what it publishes.
        Counted: each ``watch`` wants its ``unwatch``."""

    @abc.abstractmethod
    async def unwatch(self, station_id: int) -> None: ...

    @abc.abstractmethod
    async def share(self, key: str, value: str, ttl_s: float) -> None:
        """Keep ``value`` under ``key`` for every process, for ``ttl_s`` (a 3D view's ticket)."""

    @abc.abstractmethod
    async def look_up(self, key: str, ttl_s: float) -> str | None:
        """What another process shared under ``key``, kept ``ttl_s`` longer; None if none."""

    @abc.abstractmethod
    async def unshare(self, key: str) -> None: ...

    @abc.abstractmethod
    def send(self, process: str, message: Message) -> None:
        """``message`` to one process; queued, in order."""

    @abc.abstractmethod
    def everyone(self, message: Message) -> None:
        """``message`` to every other process; queued, in order."""


class LocalRelay(Relay):
    """One server process: there is nobody to tell, and every station is in the hub."""

    process = "local"

    async def start(self, listener: Listener) -> None:
        return None

    async def close(self) -> None:
        return None

    async def answers(self) -> None:
        return None  # one process: nothing to ask

    async def claim(self, station_id: int) -> str | None:
        return None

    async def release(self, station_id: int) -> None:
        return None

    async def owners(self, station_ids: list[int]) -> dict[int, str]:
        return {}

    def publish(self, station_id: int, text: str, status: bool = False) -> None:
        return None

    def telemetry(self, station_id: int, raw: str) -> None:
        return None

    def recent(self, station_id: int) -> Sequence[tuple[int, str]]:
        return ()

    async def last_status(self, station_id: int) -> str | None:
        return None

    async def watch(self, station_id: int) -> None:
        return None

    async def unwatch(self, station_id: int) -> None:
        return None

    async def share(self, key: str, value: str, ttl_s: float) -> None:
        return None

    async def look_up(self, key: str, ttl_s: float) -> str | None:
        return None

    async def unshare(self, key: str) -> None:
        return None

    def send(self, process: str, message: Message) -> None:
        raise LookupError(f"no server process {process!r}: the relay is in-process")

    def everyone(self, message: Message) -> None:
        return None


class RelayUnreachable(Exception):
    """The relay ``ANKLE_RELAY_URL`` names does not answer: one line saying where and why,
    never the password."""


def open_relay(url: str, lease_s: float, view_hz: float) -> Relay:
    """The engine ``url`` names (``Settings.relay_url``): empty for this process alone,
    ``redis://host:port/db`` (or ``rediss://``) for a Redis shared by every server process."""
    if not url:
        return LocalRelay()
    scheme = url.split(":", 1)[0].lower()
    if scheme in ("redis", "rediss", "unix"):
        from server.redis_relay import RedisRelay  # only a server that relays needs redis

        return RedisRelay(url, lease_s=lease_s, view_hz=view_hz)
    raise ValueError(f"relay_url: {scheme!r} is not a relay; use redis://host:port/db or ''")
