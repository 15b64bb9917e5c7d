"""Typed front for numba's ``njit``.

The 7 kHz controller and the plant step are compiled: under numpy alone one simulated second
costs more than one wall second. ``cache=True`` keeps the machine code beside the sources so
a second process starts in well under a second instead of recompiling.
``NUMBA_DISABLE_JIT=1`` runs everything as plain Python (for debugging and coverage).
"""

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba

F = TypeVar("F", bound=Callable[..., Any])


def njit(fn: F) -> F:
    """Compile ``fn`` in nopython mode, cached on disk, releasing the GIL."""
    return cast(F, numba.njit(cache=True, nogil=True)(fn))
