"""Passwords and bearer tokens.

Passwords are hashed with Argon2id (argon2-cffi's defaults: 64 MiB, 3 passes), which takes
about a tenth of a second on purpose: callers in the event loop run these functions in a
thread. Tokens are 256 random bits; the database keeps only their SHA-256, so finding a row
by hash is safe against timing (an attacker learns bits of a hash, never of a token).
"""

from __future__ import annotations

import asyncio
import hashlib
import hmac
import secrets
from collections.abc import Callable
from functools import cache
from typing import TypeVar

from argon2 import PasswordHasher
from argon2.exceptions import InvalidHashError, VerificationError, VerifyMismatchError

T = TypeVar("T")

PASSWORD_MIN_LENGTH = 10
PASSWORD_MAX_LENGTH = 1024
"""Long enough for any passphrase, short enough that hashing one is not a denial of service."""


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


def new_token() -> str:
    """A fresh bearer token: 32 random bytes, URL-safe base64 (43 characters)."""
    return secrets.token_urlsafe(32)


def token_hash(token: str) -> str:
    """SHA-256 of a token, hex: what the database stores and looks tokens up by."""
    return hashlib.sha256(token.encode()).hexdigest()


def same_secret(a: str, b: str) -> bool:
    """Constant-time string comparison for secrets held in memory."""
    return hmac.compare_digest(a.encode(), b.encode())


class HashingSlots:
    """Argon2 work off the event loop, a few at a time.

    Each hash takes a core and 64 MiB for about a tenth of a second: run on the loop it
    would stall every other request, and run all at once (a burst of sign-ins) it would take
    every core and a lot of memory. Callers wait their turn, first come first served.
    """

    def __init__(self, slots: int) -> None:
        self.slots = slots
        self._gate = asyncio.Semaphore(slots)

    async def run(self, fn: Callable[..., T], *args: str) -> T:
        async with self._gate:
            return await asyncio.to_thread(fn, *args)
