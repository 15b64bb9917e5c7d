"""Numba inlines without its two needless deep copies (device._jit._inline_without_copies),
and what it inlines still computes what it did."""

from __future__ import annotations

import copy
import re
from pathlib import Path
from typing import Any

import numba
import numpy as np
import pytest
from numba.core import inline_closurecall
from numba.extending import overload

from device import _jit

LOCK = Path(__file__).resolve().parents[2] / "requirements" / "dev.txt"


def test_the_locked_numba_inlines_without_the_copies() -> None:
    """Against the numba the project locks, the change is made; a new numba whose inlining
    code differs gets no change (and compiles slowly) until someone reads it again."""
    locked = re.search(r"^numba==(\S+)$", LOCK.read_text(encoding="utf-8"), re.M)
    assert locked is not None
    if numba.__version__ != locked.group(1):
        pytest.skip(f"numba {numba.__version__} is not the locked {locked.group(1)}")
    assert _jit.INLINE_WITHOUT_COPIES


@numba.njit(inline="always")
def _scaled(x: float, k: float) -> float:
    y = x * k
    if y > 10.0:
        y = 10.0
    return y


@numba.njit(inline="always")
def _twice(x: float) -> float:
    return _scaled(x, 2.0) + _scaled(x + 1.0, 3.0)  # nested, two call sites of one callee


def _py_scaled(x: float, k: float) -> float:
    return min(x * k, 10.0)


def _clipped_sum(a: float) -> float:
    raise NotImplementedError  # compiled only, through the overload below


@overload(_clipped_sum, inline="always")
def _clipped_sum_impl(a: float):  # type: ignore[no-untyped-def]
    """Inlined by numba's typed pass, from an IR it keeps and reuses at every call site:
    that path must still copy it. (Its body assigns each name once: numba 0.68 warns of a
    variable not in scope in such an inlined body otherwise, with or without the change.)"""

    def impl(a: float) -> float:
        return min(a, 10.0) + 1.0

    return impl


@numba.njit
def _caller(values: np.ndarray) -> np.ndarray:
    out = np.empty(values.size * 3)
    for i in range(values.size):
        out[3 * i] = _twice(values[i])
        out[3 * i + 1] = _twice(-values[i])  # the same inlined code at another site
        out[3 * i + 2] = _clipped_sum(values[i]) + _clipped_sum(values[i] * 4.0)
    return out


def test_inlined_calls_at_many_sites_compute_what_python_does() -> None:
    values = np.array([-3.0, 0.0, 0.5, 1.0, 2.5, 7.0])
    got = _caller(values)
    for i, v in enumerate(values):
        twice = _py_scaled(v, 2.0) + _py_scaled(v + 1.0, 3.0)
        assert got[3 * i] == twice
        assert got[3 * i + 1] == _py_scaled(-v, 2.0) + _py_scaled(-v + 1.0, 3.0)
        assert got[3 * i + 2] == _py_scaled(v, 1.0) + _py_scaled(v * 4.0, 1.0) + 2.0
    inlining: Any = inline_closurecall  # untyped: its ``copy`` is not exported
    assert inlining.copy is copy  # put back once compiled
