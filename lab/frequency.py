"""The whole frequency response of each axis, past the device's own speed limits (lab only).

The device refuses a sine faster than its axis speed limit (``SafetyLimits.axis_speed_max``)
or above :data:`device.waveforms.SINE_HZ_MAX`, and trips when a leg moves faster than its
leg speed limit (0.4 m/s): :func:`lab.experiments.sweep` therefore stops at about 9 Hz for
pitch at 2 deg, below where the platform's light modes ring. To see those modes this module
drives the simulated rig with :data:`LAB_LIMITS`, which lifts both speed limits, and
commands the sine through the rig's unchecked path (``Rig.apply_track``), so frequencies up
to 40 Hz are accepted. Everything else the device enforces (range of motion, stroke ends,
the supervision) still trips the run, and every frequency's :class:`~lab.experiments.Health`
still says whether it tripped or its valves saturated.

This is a measurement mode of the lab's rig, never of the device: the device service builds
its rig with the device's own limits (``SafetyLimits()``) and nothing in ``device/`` or
``server/`` imports this module.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from device.geometry import AXES
from device.rig import AxisTarget, CommandError
from device.safety import SafetyLimits
from device.tickloop import COL
from device.waveforms import Waveform
from lab import experiments as ex
from lab.metrics import sine_response

LAB_LIMITS = SafetyLimits(
    leg_speed_limit=5.0,
    axis_speed_max=(2.0, 2.0, 2.0, 40.0, 40.0, 40.0),
)
"""LAB ONLY, never used by the device service: the device's limits with the leg speed limit
(0.4 m/s on the device) raised to 5 m/s and the axis speed limits (0.1 m/s, 2 rad/s) to
2 m/s and 40 rad/s, so a small sine can be driven to 40 Hz. The leg speed check still runs
(a runaway leg still trips); the range of motion, stroke ends and supervision are the
device's own."""

RESPONSE_HZ: tuple[float, ...] = (
    0.5, 1.0, 2.0, 3.0, 5.0, 7.0, 10.0, 12.0, 15.0, 18.0, 20.0, 22.0, 25.0, 30.0, 35.0, 40.0,
)  # fmt: skip
"""Frequencies of :func:`response` (Hz): dense from 10 to 25 Hz, where the platform's light
modes (heave and pitch) showed their peaks before the plant had its delays."""

RESPONSE_HZ_MAX = 40.0
"""Highest frequency the lab mode drives (Hz): ten samples a period of the 250 Hz position
loop's output still fit, and 40 Hz is above every mode the plant has shown (25-30 Hz)."""

AMPLITUDE: dict[str, float] = {
    "x": 1.5,
    "y": 1.2,
    "z": 0.3,
    "roll": 0.25,
    "pitch": 0.25,
    "yaw": 0.5,
}
"""Amplitude of each axis' sweep (mm, deg): no valve runs at its largest duty at any
frequency up to 40 Hz on the nominal plant (the response is the loop's, not the valves'
flow limit), and the most-moved leg moves at least :data:`lab.experiments.MIN_SINE_COUNTS`
sensor counts (smallest: x 0.64 mm, y 0.56, z 0.27, roll 0.15 deg, pitch 0.16, yaw 0.32).
Measured on the nominal plant: the next larger amplitudes tried saturated the valves
(x 3 mm at 30-40 Hz, y 2 mm at 35-40, z 0.4 mm at 30, roll 0.35 deg at 30-35, pitch
0.3 deg at 30, yaw 1 deg at 30-40). Since the position loop's rate observer
(``ControllerConfig.rate_observer``) x at 2 mm saturated at 35-40 Hz, so x sweeps 1.5 mm.
The response depends on the amplitude (dead band, friction, flow): these are small-signal
numbers."""


@dataclass(frozen=True)
class Point:
    """One frequency of a sweep."""

    hz: float
    gain_db: float
    phase_deg: float
    health: ex.Health


@dataclass(frozen=True)
class Response(ex.Checked):
    """The frequency response of one axis at one amplitude, in the lab mode."""

    axis: str
    amplitude: float
    """Sine amplitude, deg for rotations and mm for translations."""
    points: tuple[Point, ...]
    """Every frequency measured: the sweep stops at the first invalid one (included)."""
    health: ex.Health
    """The first invalid frequency's, or a summary of the valid ones' saturations."""
    bandwidth_hz: float
    """First frequency where the gain falls below -3 dB (interpolated); when it never does,
    the last valid frequency (a lower bound, ``bandwidth_kind``)."""
    bandwidth_kind: str
    """``measured``, ``lower_bound`` or ``unknown`` (as lab.experiments.SweepResult)."""
    low_gain_db: float
    """Gain at the lowest frequency measured (0.5 Hz): what the axis follows at rest."""
    peak_db: float
    """Largest gain above ``low_gain_db`` over the valid frequencies (dB); 0 or less means
    no resonance rises above the low-frequency gain."""
    peak_hz: float
    saturated_hz: tuple[float, ...] = field(default=())
    """Frequencies at which a valve ran at its largest duty (the amplitude was too large)."""

    @property
    def valid_points(self) -> tuple[Point, ...]:
        return tuple(p for p in self.points if p.health.valid)

    @property
    def frequencies(self) -> tuple[float, ...]:
        return tuple(p.hz for p in self.points)

    @property
    def gains_db(self) -> tuple[float, ...]:
        return tuple(p.gain_db for p in self.points)

    @property
    def phases_deg(self) -> tuple[float, ...]:
        return tuple(p.phase_deg for p in self.points)


def lab_sine(
    axis: str, amplitude: float, hz: float, seed: int = 1, limits: SafetyLimits = LAB_LIMITS
) -> tuple[float, float, ex.Health, NDArray[np.float64]]:
    """(gain dB, phase deg, health, log) of one sine on the lab rig (see the module)."""
    k = ex._axis(axis)
    scale = ex._unit(k)[0]
    smallest = ex._sine_min_amplitude(k) / scale
    if not (math.isfinite(amplitude) and smallest <= amplitude <= limits.rom_high[k] / scale):
        raise CommandError(f"{axis} amplitude must be at least {smallest:.3g}, got {amplitude:g}")
    if not (math.isfinite(hz) and ex.SINE_HZ_RANGE[0] <= hz <= RESPONSE_HZ_MAX):
        raise CommandError(f"frequency must be {ex.SINE_HZ_RANGE[0]:g}..{RESPONSE_HZ_MAX:g} Hz")
    if 2.0 * math.pi * hz * amplitude * scale > limits.axis_speed_max[k]:
        raise CommandError(f"{axis} {amplitude:g} at {hz:g} Hz is beyond the lab's speed limit")
    rig = ex._rig("relaxed", True, seed, limits=limits)
    ex._settle_at_home(rig)
    six = [AxisTarget() for _ in AXES]
    six[k] = AxisTarget(Waveform.SINE, 0.0, amplitude * scale, hz)
    rig.apply_track(six)  # unchecked: SINE_HZ_MAX is a device command check
    rig.run(max(1.0 / hz, 0.3))  # the fade-in and the start-up transient die
    rig.clear_log()
    cycles = max(3, min(12, int(2 * hz)))
    log = rig.run(cycles / hz)
    health = ex.assess(rig, log, frozenset({"range_of_motion"}))
    if not health.valid:
        return math.nan, math.nan, health, log
    home = rig.geometry.home_pose[k]
    t = log[:, 0]
    response = (log[:, COL[f"pose_{axis}"]] - home) / scale
    reference = amplitude * np.sin(2.0 * math.pi * hz * (t - rig.state.trajectory[k, 4]))
    gain, phase = sine_response(t, reference, response, hz)
    return gain, phase, health, log


def response(
    axis: str = "pitch",
    amplitude: float | None = None,
    frequencies: tuple[float, ...] = RESPONSE_HZ,
    seed: int = 1,
) -> Response:
    """Gain and phase of ``axis`` from ``frequencies[0]`` to 40 Hz on the lab rig, its -3 dB
    point and its largest resonance peak above the low-frequency gain.

    Stops at the first frequency that tripped (a trip is not roll-off). Valve saturation is
    reported per frequency (``saturated_hz``): the amplitude should be chosen so that there
    is none.
    """
    amp = AMPLITUDE[axis] if amplitude is None else amplitude
    points: list[Point] = []
    stopped: ex.Health | None = None
    for f in frequencies:
        gain, phase, health, _ = lab_sine(axis, amp, f, seed)
        points.append(Point(f, gain, phase, health))
        if not health.valid:
            stopped = health
            break
    valid = [p for p in points if p.health.valid]
    bw, kind = math.nan, "unknown"
    for n, p in enumerate(valid):
        if p.gain_db < -3.0:
            if n == 0:
                bw = p.hz
            else:
                q = valid[n - 1]
                bw = q.hz + (p.hz - q.hz) * (-3.0 - q.gain_db) / (p.gain_db - q.gain_db)
            kind = "measured"
            break
    else:
        if valid:
            bw, kind = valid[-1].hz, "lower_bound"
    low_db, peak_db, peak_hz = math.nan, math.nan, math.nan
    if valid:
        low_db = valid[0].gain_db
        best = max(valid, key=lambda p: p.gain_db)
        peak_db, peak_hz = best.gain_db - low_db, best.hz
    saturated_hz = tuple(p.hz for p in points if "valve_duty" in p.health.saturated)
    if stopped is not None:
        health = stopped
    else:
        sat = tuple(sorted({s for p in points for s in p.health.saturated}))
        warned = next((p.health.warning for p in points if p.health.warning), None)
        health = ex.with_warning(ex.Health(False, None, None, sat, True, None), warned)
    return Response(
        axis, amp, tuple(points), health, bw, kind, low_db, peak_db, peak_hz, saturated_hz
    )


def all_axes(seed: int = 1) -> dict[str, Response]:
    """:func:`response` of every axis at its :data:`AMPLITUDE`."""
    return {axis: response(axis, seed=seed) for axis in AXES}


def largest_peak(responses: dict[str, Response]) -> tuple[str, float, float]:
    """(axis, peak dB, Hz) of the largest resonance peak over ``responses``."""

    def peak(a: str) -> float:
        v = responses[a].peak_db
        return v if math.isfinite(v) else -math.inf

    axis = max(responses, key=peak)
    return axis, responses[axis].peak_db, responses[axis].peak_hz


def table(responses: dict[str, Response]) -> str:
    """Per axis: amplitude, gain at 0.5 Hz, -3 dB point, largest peak, saturations."""
    lines = [
        "| axis | amplitude | gain at 0.5 Hz (dB) | -3 dB point (Hz) | largest peak (dB) | at (Hz) "
        "| valves saturated at (Hz) |",
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    for name, r in responses.items():
        unit = "deg" if AXES.index(name) >= 3 else "mm"
        bw = f"{r.bandwidth_hz:.1f}" + (" (lower bound)" if r.bandwidth_kind != "measured" else "")
        sat = ", ".join(f"{f:g}" for f in r.saturated_hz) or "none"
        if not r.valid:
            sat += f"; INVALID: {r.health.reason}"
        lines.append(
            f"| {name} | {r.amplitude:g} {unit} | {r.low_gain_db:+.1f} | {bw} | "
            f"{r.peak_db:+.1f} | {r.peak_hz:g} | {sat} |"
        )
    return "\n".join(lines)


def main() -> None:
    """``python -m lab.frequency [figure.png]``: every axis on the nominal plant."""
    import sys
    from pathlib import Path

    responses = all_axes()
    print(table(responses))
    for name, r in responses.items():
        print(name, " ".join(f"{p.hz:g}:{p.gain_db:+.1f}/{p.phase_deg:.0f}" for p in r.points))
    if len(sys.argv) > 1:
        from lab import plots

        print(plots.frequency_figure(responses, Path(sys.argv[1])))


if __name__ == "__main__":
    main()
