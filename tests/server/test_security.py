"""Password hashing and tokens."""

from __future__ import annotations

import asyncio
import hashlib
import os
import threading
import time

import pytest

from server.security import (
    HASH_NICE,
    HashingSlots,
    hash_password,
    needs_rehash,
    new_token,
    same_secret,
    token_hash,
    verify_password,
)


def test_argon2id_round_trip() -> None:
    stored = hash_password("correct horse battery")
    assert stored.startswith("$argon2id$")
    assert verify_password(stored, "correct horse battery")
    assert not verify_password(stored, "correct horse batterY")
    assert not verify_password("not a hash", "correct horse battery")
    assert not needs_rehash(stored)
    weak = "$argon2id$v=19$m=8,t=1,p=1$c29tZXNhbHQ$hnPsQtGmgAL5MKNDlIodDvJfEC7tuiHIbm8b3lO7mZk"
    assert needs_rehash(weak)


def test_tokens_are_random_and_stored_as_sha256() -> None:
    a, b = new_token(), new_token()
    assert a != b and len(a) == 43
    assert token_hash(a) == hashlib.sha256(a.encode()).hexdigest()
    assert same_secret(token_hash(a), token_hash(a))
    assert not same_secret(token_hash(a), token_hash(b))


# -- hashing off the loop ---------------------------------------------------------------------
def _held(gate: threading.Event, started: list[str], name: str) -> int:
    started.append(name)
    assert gate.wait(10)
    return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())


@pytest.mark.asyncio
async def test_one_address_holds_one_hashing_slot_so_another_gets_the_other() -> None:
    slots = HashingSlots(2)
    gate = threading.Event()
    started: list[str] = []
    try:
        flood = [
            asyncio.create_task(slots.run(_held, gate, started, f"a{i}", key="attacker"))
            for i in range(3)
        ]
        colleague = asyncio.create_task(slots.run(_held, gate, started, "b", key="colleague"))
        deadline = time.monotonic() + 10
        while len(started) < 2:
            assert time.monotonic() < deadline, started
            await asyncio.sleep(0.01)
        await asyncio.sleep(0.1)  # a third would have started by now if it could
        assert sorted(started) == ["a0", "b"], started
        gate.set()
        nice = await asyncio.gather(*flood, colleague)
        assert len(started) == 4
        # The hashing threads run below the loop's priority (or at the floor, 19).
        own = os.getpriority(os.PRIO_PROCESS, 0)
        assert all(n >= min(19, own + HASH_NICE) for n in nice), (own, nice)
    finally:
        gate.set()
        slots.close()
