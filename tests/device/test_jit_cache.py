"""The compile cache of one source does not evict the caches another checkout still uses."""

from __future__ import annotations

import os
import time
from pathlib import Path

from device import _jit


def _cache(root: Path, name: str, age_s: float) -> Path:
    cache = root / name
    cache.mkdir()
    index = cache / "step.nbi"
    index.write_bytes(b"x")
    then = time.time() - age_s
    os.utime(index, (then, then))
    os.utime(cache, (then, then))
    return cache


def test_a_new_source_drops_only_stale_caches(tmp_path: Path) -> None:
    in_use = _cache(tmp_path, "numba-aaaa", age_s=3600.0)  # another checkout, used an hour ago
    stale = _cache(tmp_path, "numba-bbbb", age_s=_jit.STALE_S + 3600.0)
    _jit._prune(str(tmp_path / "numba-cccc"))
    assert in_use.is_dir()
    assert not stale.exists()


def test_an_existing_cache_prunes_nothing(tmp_path: Path) -> None:
    stale = _cache(tmp_path, "numba-bbbb", age_s=_jit.STALE_S + 3600.0)
    current = _cache(tmp_path, "numba-cccc", age_s=0.0)
    _jit._prune(str(current))
    assert stale.is_dir()
