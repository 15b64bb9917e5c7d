"""Waits before trying the server again: exponential, jittered and bounded.

After a server restart every station finds its link down in the same second; with fixed
delays they would all come back in the same second too, again and again. Each wait is drawn
from tenacity's ``wait_random_exponential`` ("full jitter"): uniform between 0 and
``first * 2**(n-1)`` for the n-th failure in a row, never above ``cap``.
"""

from __future__ import annotations

from tenacity import RetryCallState, Retrying, wait_random_exponential


class Backoff:
    """The waits of one retry loop: :meth:`next` after each failure, :meth:`reset` after a
    success."""

    def __init__(self, first: float, cap: float) -> None:
        self.first = first
        self.cap = cap
        self._wait = wait_random_exponential(multiplier=first, max=cap)
        self._state = RetryCallState(Retrying(), None, (), {})
        self.failures = 0

    def next(self) -> float:
        """Seconds to wait after one more failure."""
        self.failures += 1
        self._state.attempt_number = self.failures
        return float(self._wait(self._state))

    def reset(self) -> None:
        self.failures = 0
