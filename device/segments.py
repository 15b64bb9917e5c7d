"""Segment messages from per-axis plans: what a host sends to start an exercise segment.

Plain Python: no I/O, no compiled code, so that the server (which checks a prescription's
segment as the device will receive it) builds segments without the serial link the
``DeviceClient`` needs (``device.client`` re-exports both names).
"""

from __future__ import annotations

from dataclasses import dataclass

from device.axes import AXES
from device.limits import SafetyLimits
from device.protocol import messages as msg
from device.waveforms import Waveform


@dataclass(frozen=True)
class AxisPlan:
    """One axis of a segment (relative to home; m or rad), for :func:`build_segment`."""

    waveform: Waveform = Waveform.HOLD
    center: float = 0.0
    amplitude: float = 0.0
    frequency: float = 0.0
    ramp_end: float = 0.0
    ramp_rate: float = 0.0
    stiffness: float = 0.0
    damping: float = 0.0
    compliant: bool = False


def build_segment(
    hello: msg.DeviceHello | SafetyLimits,
    segment_id: int,
    duration: float,
    axes: dict[str, AxisPlan],
    rom_low: tuple[float, ...] | None = None,
    rom_high: tuple[float, ...] | None = None,
    force_limit: float | None = None,
    torque_limit: float | None = None,
) -> msg.StartSegment:
    """A segment message; unnamed axes hold home, unset limits are the device's own (as its
    HELLO publishes them, or as :class:`SafetyLimits` has them)."""
    unknown = set(axes) - set(AXES)
    if unknown:
        raise ValueError(f"unknown axis {sorted(unknown)}; axes are {', '.join(AXES)}")
    plans = [axes.get(a, AxisPlan()) for a in AXES]
    return msg.StartSegment(
        segment_id=segment_id,
        duration=duration,
        waveform=tuple(p.waveform for p in plans),
        center=tuple(p.center for p in plans),
        amplitude=tuple(p.amplitude for p in plans),
        frequency=tuple(p.frequency for p in plans),
        ramp_end=tuple(p.ramp_end for p in plans),
        ramp_rate=tuple(p.ramp_rate for p in plans),
        stiffness=tuple(p.stiffness for p in plans),
        damping=tuple(p.damping for p in plans),
        compliant=tuple(p.compliant for p in plans),
        rom_low=hello.rom_low if rom_low is None else rom_low,
        rom_high=hello.rom_high if rom_high is None else rom_high,
        force_limit=hello.force_limit if force_limit is None else force_limit,
        torque_limit=hello.torque_limit if torque_limit is None else torque_limit,
    )
