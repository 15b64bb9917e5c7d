"""``unowned``: the compiled loop's state without reference counting, and nothing lost."""

from __future__ import annotations

import re
import sys
from typing import Any, NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray

from device._jit import unowned


class Inner(NamedTuple):
    x: NDArray[np.float64]
    gain: float


class State(NamedTuple):
    a: NDArray[np.float64]
    grid: NDArray[np.int64]
    inner: Inner
    n: int


@numba.njit(cache=False)
def _bump(grid: NDArray[np.int64]) -> None:
    grid[1, 2] += 1


def _step(s: State, k: int) -> None:
    if s.a[0] > k:
        _bump(s.grid)  # a call that is not inlined, with an array
    else:
        s.inner.x[0] -= s.inner.gain


_step_inline = numba.njit(inline="always")(_step)


def _loop(s: State, reps: int) -> float:
    """Two inlined steps on the state in a row: numba counts the tuple's arrays around each
    (the pattern of the simulated loop's tasks)."""
    total = 0.0
    for i in range(reps):
        _step_inline(s, 2 * i)
        _step_inline(s, 2 * i + 1)
        total += s.a[0] + s.n
    return total


@numba.njit(cache=False)
def _owned(s: State, reps: int) -> float:
    return _loop_inline(s, reps)


@numba.njit(cache=False)
def _unowned(s: State, reps: int) -> float:
    return _loop_inline(unowned(s), reps)


_loop_inline = numba.njit(inline="always")(_loop)


def _state() -> State:
    return State(np.array([2.0, 5.0]), np.zeros((3, 4), np.int64), Inner(np.ones(2), 0.5), 7)


def test_the_views_change_the_callers_arrays_and_read_every_member() -> None:
    s = _state()
    assert _unowned(s, 3) == 3 * (2.0 + 7)
    assert s.grid[1, 2] == 2  # steps 0, 1: through the 2-D array's strides
    assert s.grid.sum() == 2
    assert s.inner.x[0] == 1.0 - 4 * 0.5  # steps 2-5: through the nested tuple
    assert s.inner.x[1] == 1.0


def test_no_reference_is_gained_or_lost_over_calls() -> None:
    s = _state()
    _unowned(s, 1)
    before = [sys.getrefcount(a) for a in (s.a, s.grid, s.inner.x)]
    for _ in range(100):
        _unowned(s, 3)
    assert [sys.getrefcount(a) for a in (s.a, s.grid, s.inner.x)] == before


def _increments(fn: Any) -> int:
    """Reference count increments in ``fn``'s own compiled body (not its Python wrapper)."""
    (llvm,) = fn.inspect_llvm().values()
    for part in re.split(r"\n(?=define )", llvm):
        head = part.split("\n", 1)[0]
        if head.startswith("define") and fn.__name__ in head and "cpython" not in head:
            return part.count("@NRT_incref(")
    raise AssertionError(f"no body of {fn.__name__} in its LLVM IR")


def test_the_loop_over_unowned_views_counts_no_reference() -> None:
    s = _state()
    _owned(s, 1)
    _unowned(s, 1)
    assert _increments(_owned) > 0  # the same loop on the tuple itself does count
    assert _increments(_unowned) == 0
