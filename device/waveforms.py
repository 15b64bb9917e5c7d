"""Target waveforms of the task-space axes: the vocabulary commands and the controller share.

Plain Python: the protocol, the host's client and the station import it without the
compiled controller. Values are relative to the home pose, in metres or radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum


class Waveform(IntEnum):
    """Target waveform of one task-space axis."""

    HOLD = 0
    """Stay at ``center``."""
    SINE = 1
    """``center + amplitude sin(2 pi f (t - t0))``, its amplitude faded in over the
    controller's ``sine_fade_in``."""
    RAMP = 2
    """From ``center`` toward ``end`` at ``rate`` per second, then stay."""


SINE_HZ_MAX = 20.0
"""Highest sine frequency a command may ask for (Hz): beyond it the legs cannot follow even
a tiny amplitude (the position loop runs at 250 Hz)."""


@dataclass(frozen=True)
class AxisTarget:
    """Target waveform of one task-space axis, relative to the home pose (m or rad)."""

    kind: Waveform = Waveform.HOLD
    center: float = 0.0
    amplitude: float = 0.0
    """Sine amplitude, or ramp rate per second."""
    frequency: float = 0.0
    """Sine frequency (Hz), or the ramp's end value."""

    @staticmethod
    def ramp(start: float, end: float, rate: float) -> AxisTarget:
        return AxisTarget(Waveform.RAMP, start, abs(rate), end)

    def extent(self) -> tuple[float, float]:
        """Lowest and highest value the waveform reaches."""
        if self.kind == Waveform.SINE:
            a = abs(self.amplitude)
            return self.center - a, self.center + a
        if self.kind == Waveform.RAMP:
            return min(self.center, self.frequency), max(self.center, self.frequency)
        return self.center, self.center

    def peak_speed(self) -> float:
        """Fastest the target moves (per second)."""
        if self.kind == Waveform.SINE:
            return 2.0 * math.pi * abs(self.frequency) * abs(self.amplitude)
        if self.kind == Waveform.RAMP:
            return abs(self.amplitude)
        return 0.0
