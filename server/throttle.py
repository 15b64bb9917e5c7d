"""Sign-in throttling: failures are counted per account and per client address.

Each key (an account's email, a client's address) has a limit of failed sign-ins in a
moving window (``login_account_limit``, ``login_address_limit``). The first third of a
limit answers at once, as a person mistyping expects; after that each failure doubles a
delay (from ``DELAY_START_S`` up to ``login_delay_max_s``) spent before the password is
checked; at the limit the answer is 429 with ``Retry-After`` until the oldest failure
leaves the window, and the password is not checked at all. A successful sign-in clears its
account's count (not its address's: one good account must not reset a guesser's address).

Counts live in a ``limits`` storage (``login_throttle_storage``, :func:`open_storage`):
memory for one process, Redis for several. A Redis that does not answer refuses sign-ins
(503) rather than letting them through uncounted. Sign-ins in progress are capped per key
in this process (``login_pending_max``) so that one address sending a hundred at once
queues four for the password hasher, not a hundred, and a colleague's sign-in is not stuck
behind them.

Keys are the SHA-256 of the normalised email (no addresses in a shared store) and the
client address as uvicorn reports it (behind a proxy: the forwarded one it trusts).
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import math
import time
from collections import Counter
from collections.abc import AsyncIterator, Awaitable
from contextlib import asynccontextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar
from urllib.parse import urlsplit

from limits import RateLimitItem, parse
from limits.aio.storage import MovingWindowSupport, Storage
from limits.aio.strategies import MovingWindowRateLimiter
from limits.errors import ConfigurationError, StorageError
from limits.storage import storage_from_string
from starlette.types import ASGIApp, Receive, Scope, Send

from server.guard import answer

if TYPE_CHECKING:
    from server.config import Settings

DELAY_START_S = 0.25
"""The first delay; each further failure doubles it."""
BUSY_RETRY_S = 1
"""Retry-After when too many sign-ins of one key are in progress at once."""
STORAGE_AWAY_RETRY_S = 5
"""Retry-After when the storage of the counts does not answer."""
REDIS_SCHEMES = ("redis", "rediss", "redis+unix", "redis+cluster", "redis+sentinel")
"""Storages that count in Redis, through the ``redis`` package the live relay uses too.
limits' asyncio Redis storage uses ``coredis`` unless told otherwise, which the server does
not install."""
STORAGES_SAID = "memory:// (this process) or redis://host:port/db (shared by server processes)"

T = TypeVar("T")


def open_storage(uri: str) -> Storage:
    """The asyncio ``limits`` storage that ``uri`` (``login_throttle_storage``) names;
    ValueError, in one sentence, for one that cannot count sign-ins here.

    Only storages that work with what the server installs and that keep a moving window:
    memory, and Redis (``REDIS_SCHEMES``, ``async+`` in front or not). limits' memcached
    storage has no moving window; its MongoDB and Valkey storages need packages the server
    does not have. Nothing is connected here: a Redis that is away is found at the first
    sign-in, and answered 503. The URI is never quoted back (it may hold a password)."""
    scheme = urlsplit(uri).scheme.lower().removeprefix("async+")
    if scheme != "memory" and scheme not in REDIS_SCHEMES:
        raise ValueError(
            f"{scheme + '://' if scheme else 'a URI without a scheme'} cannot count failed "
            f"sign-ins: use {STORAGES_SAID}"
        )
    options: dict[str, Any] = {"implementation": "redispy"} if scheme in REDIS_SCHEMES else {}
    plain = f"{scheme}://{uri.strip().split('://', 1)[1]}"  # limits reads the scheme as cased
    try:
        storage = storage_from_string(f"async+{plain}", wrap_exceptions=True, **options)
    except (ConfigurationError, ValueError) as exc:
        said = str(exc).replace(f"async+{plain}", plain).replace(plain, f"{scheme}://...")
        raise ValueError(f"{scheme}:// storage cannot be used: {said}") from None
    assert isinstance(storage, Storage) and isinstance(storage, MovingWindowSupport)
    return storage


class CountsAway(Exception):
    """The storage of the counts did not answer: refuse this sign-in (503), uncounted
    sign-ins would let a guesser past the limits."""

    detail = (
        "sign-in is unavailable for a moment: failed sign-ins cannot be counted (their store "
        f"does not answer); try again in {STORAGE_AWAY_RETRY_S} s"
    )
    retry_after = STORAGE_AWAY_RETRY_S


async def _counted(call: Awaitable[T]) -> T:
    """``call`` to the storage of the counts; CountsAway if it does not answer."""
    try:
        return await call
    except StorageError as exc:
        raise CountsAway(str(exc)) from exc


class Throttled(Exception):
    """Refuse this sign-in: 429 with ``Retry-After: retry_after``."""

    def __init__(self, detail: str, retry_after: int) -> None:
        super().__init__(detail)
        self.detail = detail
        self.retry_after = retry_after


@dataclass(frozen=True)
class _Key:
    what: str  # "account" or "address", for the sentences
    storage_key: str
    limit: RateLimitItem

    @property
    def free(self) -> int:
        """Failures answered without delay."""
        return max(1, self.limit.amount // 3)


class Attempt:
    """One sign-in under way; tell it how it ended."""

    def __init__(self, throttle: LoginThrottle, keys: tuple[_Key, _Key]) -> None:
        self._throttle = throttle
        self._keys = keys

    async def failed(self) -> None:
        for key in self._keys:
            await _counted(self._throttle.limiter.hit(key.limit, key.storage_key))

    async def succeeded(self) -> None:
        account = self._keys[0]
        await _counted(self._throttle.limiter.clear(account.limit, account.storage_key))


class LoginThrottle:
    def __init__(self, settings: Settings) -> None:
        self.storage = open_storage(settings.login_throttle_storage)
        self.limiter = MovingWindowRateLimiter(self.storage)
        self.account_limit = parse(settings.login_account_limit)
        self.address_limit = parse(settings.login_address_limit)
        self.delay_max_s = settings.login_delay_max_s
        self.pending_max = settings.login_pending_max
        self._pending: Counter[str] = Counter()

    async def close(self) -> None:
        """Close the storage's connections (Redis): limits' storages have no close of their
        own, so the clients its Redis bridge holds are closed here."""
        bridge: Any = getattr(self.storage, "bridge", None)
        sentinel = getattr(bridge, "sentinel", None)
        clients = [getattr(bridge, "storage", None), getattr(bridge, "storage_replica", None)]
        clients += list(getattr(sentinel, "sentinels", []))
        for client in clients:
            if client is not None:
                with contextlib.suppress(Exception):
                    await client.aclose()

    def _keys(self, email: str, address: str) -> tuple[_Key, _Key]:
        digest = hashlib.sha256(email.encode("utf-8", "backslashreplace")).hexdigest()[:32]
        return (_Key("account", f"login:account:{digest}", self.account_limit), self._at(address))

    def _at(self, address: str) -> _Key:
        return _Key("address", f"login:address:{address}", self.address_limit)

    def _check_busy(self, key: _Key) -> None:
        """Raise Throttled if ``login_pending_max`` sign-ins of ``key`` are in progress."""
        if self._pending[key.storage_key] >= self.pending_max:
            raise Throttled(
                f"too many sign-ins for this {key.what} at once: try again in {BUSY_RETRY_S} s",
                BUSY_RETRY_S,
            )

    def check_address(self, address: str) -> None:
        """Raise Throttled if this address has too many sign-ins in progress: asked by
        ``LoginGate`` before the request's body is read, and again by ``attempt``."""
        self._check_busy(self._at(address))

    async def _delay(self, keys: tuple[_Key, _Key]) -> float:
        """Raise Throttled at a limit; else the delay this attempt waits, s."""
        over = -1
        for key in keys:
            stats = await _counted(self.limiter.get_window_stats(key.limit, key.storage_key))
            if stats.remaining <= 0:
                wait = max(1, math.ceil(stats.reset_time - time.time()))
                raise Throttled(
                    f"too many failed sign-ins for this {key.what}: try again in {wait} s",
                    wait,
                )
            failures = key.limit.amount - stats.remaining
            over = max(over, failures - key.free)
        return 0.0 if over < 0 else min(self.delay_max_s, DELAY_START_S * 2.0**over)

    @asynccontextmanager
    async def attempt(self, email: str, address: str) -> AsyncIterator[Attempt]:
        """Admit one sign-in (or raise Throttled), wait its delay, and hold its place among
        those in progress until the block ends. CountsAway, here or from the Attempt, when
        the storage of the counts does not answer."""
        keys = self._keys(email, address)
        for key in keys:
            self._check_busy(key)
        for key in keys:  # counted before the first await, or a burst would all pass
            self._pending[key.storage_key] += 1
        try:
            delay = await self._delay(keys)
            if delay:
                await asyncio.sleep(delay)
            yield Attempt(self, keys)
        finally:
            for key in keys:
                self._pending[key.storage_key] -= 1
                if not self._pending[key.storage_key]:
                    del self._pending[key.storage_key]


class LoginGate:
    """Refuses a sign-in from an address that has ``login_pending_max`` in progress, before
    its body is read and before any route, validator or database session is made for it.

    A hundred wrong sign-ins sent at once from one address cost the event loop about a
    millisecond each when each went the whole way to the route's own check; answered here
    they cost a fraction of that, and ``/health`` and the live links wait less behind them.
    The route asks the same question again (``LoginThrottle.attempt``), with the account.
    """

    def __init__(self, app: ASGIApp, path: str) -> None:
        self.app = app
        self.path = path

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["method"] == "POST" and scope["path"] == self.path:
            throttle: LoginThrottle | None = getattr(scope["app"].state, "login_throttle", None)
            client = scope.get("client")
            if throttle is not None:
                try:
                    throttle.check_address(client[0] if client else "unknown")
                except Throttled as exc:
                    retry = [(b"retry-after", str(exc.retry_after).encode())]
                    await answer(send, 429, {"detail": exc.detail}, retry)
                    return
        await self.app(scope, receive, send)
