"""Passwords and bearer tokens.

Passwords are hashed with Argon2id (argon2-cffi's defaults: 64 MiB, 3 passes), which takes
about a tenth of a second on purpose: callers in the event loop run these functions in a
thread. Tokens are 256 random bits; the database keeps only their SHA-256, so finding a row
by hash is safe against timing (an attacker learns bits of a hash, never of a token).
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import os
import re
import secrets
import threading
import unicodedata
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from functools import cache
from typing import Any, TypeVar

from argon2 import PasswordHasher
from argon2.exceptions import InvalidHashError, VerificationError, VerifyMismatchError
from zxcvbn import zxcvbn

from sessions.text import has_visible

T = TypeVar("T")

PASSWORD_MIN_LENGTH = 10
PASSWORD_MAX_LENGTH = 1024
"""Long enough for any passphrase, short enough that hashing one is not a denial of service."""
PASSWORD_SCORE_MIN = 3
"""The least zxcvbn score (0 to 4) of a password set here: 3 is "safely unguessable", some
10^10 guesses. Length alone let in twenty spaces, "aaaaaaaaaa", "1234567890" and the
account's own e-mail address."""
SCORED_CHARACTERS = 72
"""A password is scored on its first this many characters (NFKC-normal), zxcvbn's own limit:
its time grows fast with length (1024 "a"s took two minutes), and a password whose start
is strong is no weaker for what follows."""


@cache
def _hasher() -> PasswordHasher:
    return PasswordHasher()


def hash_password(password: str) -> str:
    return _hasher().hash(password)


def verify_password(password_hash: str, password: str) -> bool:
    """Whether ``password`` matches; a malformed stored hash is a mismatch, not an error."""
    try:
        return _hasher().verify(password_hash, password)
    except (VerifyMismatchError, VerificationError, InvalidHashError):
        return False


def needs_rehash(password_hash: str) -> bool:
    """Whether a stored hash was made with weaker parameters than today's."""
    return _hasher().check_needs_rehash(password_hash)


@cache
def _dummy_hash() -> str:
    return hash_password(secrets.token_urlsafe(16))


def burn_verify(password: str) -> None:
    """Spend the time of one verification, so an unknown email answers as slowly as a
    wrong password and response time does not tell which accounts exist."""
    verify_password(_dummy_hash(), password)


def new_password() -> str:
    """A one-time password for a person to type once: 16 URL-safe characters (96 random
    bits), printed or shown once and changed at the next sign-in."""
    return secrets.token_urlsafe(12)


def password_weakness(password: str, user_inputs: Sequence[str] = ()) -> str | None:
    """Why ``password`` may not be set, in a sentence with zxcvbn's own advice; None if it
    may. ``user_inputs``: the account's e-mail address and name, which a password built
    from them is too easy to guess from. About 50 ms: callers in the event loop run it in a
    thread. Only a password being set is judged, never one signing in."""
    text = unicodedata.normalize("NFKC", password)
    if not has_visible(text):
        return "The password has nothing visible in it: not only spaces or invisible characters."
    words = [w for value in user_inputs for w in re.split(r"[\s@.+_-]+", value.lower()) if w]
    result = zxcvbn(text[:SCORED_CHARACTERS], user_inputs=[*user_inputs, *words])
    score = int(result["score"])
    if score >= PASSWORD_SCORE_MIN:
        return None
    feedback = result["feedback"]
    said = [str(feedback["warning"])] if feedback["warning"] else []
    if any(m.get("dictionary_name") == "user_inputs" for m in result["sequence"]):
        said.append("It is made from the account's own e-mail address or name.")
    said += [str(s) for s in feedback["suggestions"]]
    advice = " ".join(said) or "Add another word or two. Uncommon words are better."
    return (
        f"The password is too easy to guess (strength {score} of 4, at least "
        f"{PASSWORD_SCORE_MIN} needed). {advice}"
    )


def new_token() -> str:
    """A fresh bearer token: 32 random bytes, URL-safe base64 (43 characters)."""
    return secrets.token_urlsafe(32)


def token_hash(token: str) -> str:
    """SHA-256 of a token, hex: what the database stores and looks tokens up by."""
    return hashlib.sha256(token.encode()).hexdigest()


def same_secret(a: str, b: str) -> bool:
    """Constant-time string comparison for secrets held in memory."""
    return hmac.compare_digest(a.encode(), b.encode())


HASH_NICE = 10
"""How much lower than the server's own threads the hashing threads run (Linux nice).

Argon2 keeps a core busy for about a tenth of a second per hash; on an equal footing with the
event loop, a burst of sign-ins on a two-core machine delayed every other request (and every
live link) by that much. Lowered, the hashes take what the loop leaves."""


def _lower_priority(nice: int) -> None:
    # On Linux each thread has its own nice value (and the threads it starts inherit it).
    with contextlib.suppress(OSError, AttributeError):
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), nice)


class HashingSlots:
    """Argon2 work off the event loop, a few at a time, at a lower priority.

    Each hash takes a core and 64 MiB for about a tenth of a second: run on the loop it
    would stall every other request, and run all at once (a burst of sign-ins) it would take
    every core and a lot of memory. Callers wait their turn, first come first served, except
    that callers sharing a ``key`` (a client address) hash one at a time: a flood from one
    address holds one slot, and a colleague's sign-in from elsewhere takes another.
    """

    def __init__(self, slots: int, nice: int = HASH_NICE) -> None:
        self.slots = slots
        self._gate = asyncio.Semaphore(slots)
        self._pool = ThreadPoolExecutor(
            slots, thread_name_prefix="argon2", initializer=_lower_priority, initargs=(nice,)
        )
        self._keys: dict[str, tuple[asyncio.Lock, int]] = {}

    async def run(self, fn: Callable[..., T], *args: Any, key: str | None = None) -> T:
        if key is None:
            return await self._hash(fn, *args)
        lock, users = self._keys.get(key, (asyncio.Lock(), 0))
        self._keys[key] = (lock, users + 1)
        try:
            async with lock:
                return await self._hash(fn, *args)
        finally:
            lock, users = self._keys[key]
            if users == 1:
                del self._keys[key]
            else:
                self._keys[key] = (lock, users - 1)

    async def _hash(self, fn: Callable[..., T], *args: Any) -> T:
        async with self._gate:
            return await asyncio.get_running_loop().run_in_executor(self._pool, fn, *args)

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
