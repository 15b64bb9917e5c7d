"""Password hashing and tokens."""

from __future__ import annotations

import hashlib

from server.security import (
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
