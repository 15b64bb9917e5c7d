"""Experiments a researcher runs on the simulated device, all in simulated time.

Each function builds a fresh :class:`~device.rig.Rig` on the plant simulation, runs one
experiment of the paper (Figures 7, 9, 10, 12) and returns its numbers together with the
traces, so the CLI, the benchmark, the plots and the tests share one implementation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from device.controller import ControllerConfig, Waveform
from device.geometry import AXES, AXIS_INDEX
from device.hardware import SimulatedHardware
from device.plant.model import SCRIPT_RAMP
from device.plant.params import PlantConfig
from device.rig import AxisTarget, CommandError, Rig, leg_index
from device.tickloop import COL
from lab.metrics import StepMetrics, sine_response, step_metrics, stiffness_slope

SETTLE_S = 0.5
"""Time the platform is held at home under control before an experiment starts."""


def _rig(
    patient: str = "absent",
    compensate: bool = True,
    seed: int = 1,
    plant: PlantConfig | None = None,
) -> Rig:
    cfg = plant if plant is not None else PlantConfig(patient=patient)
    hw = SimulatedHardware(cfg, seed=seed)
    return Rig(hw, ControllerConfig(deadband_compensation=compensate))


def _settle_at_home(rig: Rig) -> None:
    rig.move_legs(np.full(6, 0.5 * rig.geometry.stroke))
    rig.run(SETTLE_S)
    rig.clear_log()


@dataclass(frozen=True)
class StepResult:
    leg: int
    step_mm: float
    compensate: bool
    metrics: StepMetrics
    t: NDArray[np.float64] = field(repr=False)
    displacement_mm: NDArray[np.float64] = field(repr=False)
    """Displacement of the stepped leg relative to its start (mm)."""
    pressure_bar: NDArray[np.float64] = field(repr=False)
    """(n, 2) gauge pressures of its cap and rod chambers (bar)."""
    duty: NDArray[np.float64] = field(repr=False)
    """(n, 2) signed PWM slots of those chambers, as percent of the period."""


def step(
    leg: int = 1,
    mm: float = 10.0,
    compensate: bool = True,
    duration: float = 1.0,
    patient: str = "absent",
    seed: int = 1,
) -> StepResult:
    """Independent joint position step of one leg (paper, Figure 9)."""
    i = leg_index(leg)
    if not math.isfinite(mm) or not 0.0 < abs(mm) <= 45.0:
        raise CommandError(f"step must be a finite nonzero size up to 45 mm, got {mm}")
    if not math.isfinite(duration) or not 0.1 <= duration <= 60.0:
        raise CommandError("duration must be 0.1..60 s")
    rig = _rig(patient, compensate, seed)
    _settle_at_home(rig)
    target = rig.state.leg_target.copy()
    target[i] += mm * 1e-3
    rig.move_legs(target)
    log = rig.run(duration)
    t = log[:, 0] - log[0, 0]
    y = log[:, COL[f"leg_x{i}"]]
    y_start = float(y[0])
    # Against the commanded target, so a static offset cannot hide in the difference.
    m = step_metrics(t, y, y_start, float(target[i]))
    p = log[:, [COL[f"pressure_g{2 * i}"], COL[f"pressure_g{2 * i + 1}"]]] / 1e5
    d = log[:, [COL[f"slots{2 * i}"], COL[f"slots{2 * i + 1}"]]] * (100.0 / 28.0)
    return StepResult(leg, mm, compensate, m, t, (y - y_start) * 1e3, p, d)


@dataclass(frozen=True)
class StaircaseResult:
    leg: int
    step_mm: float
    errors_mm: tuple[float, ...]
    """Steady error after each step (mm)."""
    t: NDArray[np.float64] = field(repr=False)
    displacement_mm: NDArray[np.float64] = field(repr=False)
    target_mm: NDArray[np.float64] = field(repr=False)

    @property
    def resolution_mm(self) -> float:
        """The largest steady error over the staircase."""
        return max(self.errors_mm)


def staircase(
    leg: int = 1, step_mm: float = 0.3, steps: int = 8, dwell: float = 0.5, seed: int = 1
) -> StaircaseResult:
    """Small steps up then down: how fine can a leg be placed?"""
    i = leg_index(leg)
    rig = _rig("absent", True, seed)
    _settle_at_home(rig)
    target = rig.state.leg_target.copy()
    start = float(rig.state.leg_x[i])
    base = float(target[i])
    errors: list[float] = []
    levels = list(range(1, steps + 1)) + list(range(steps - 1, -1, -1))
    ts, ys, rs = [], [], []
    for n in levels:
        target[i] = base + n * step_mm * 1e-3
        rig.move_legs(target)
        log = rig.run(dwell)
        y = log[:, COL[f"leg_x{i}"]]
        tail = log[:, 0] >= log[-1, 0] - 0.1
        errors.append(abs(float(np.mean(y[tail])) - target[i]) * 1e3)
        ts.append(log[:, 0])
        ys.append((y - start) * 1e3)
        rs.append(np.full(y.shape, (target[i] - start) * 1e3))
    t = np.concatenate(ts)
    return StaircaseResult(
        leg, step_mm, tuple(errors), t - t[0], np.concatenate(ys), np.concatenate(rs)
    )


def _axis(axis: str) -> int:
    if axis not in AXIS_INDEX:
        raise CommandError(f"unknown axis {axis!r}; axes are {', '.join(AXES)}")
    return AXIS_INDEX[axis]


def _angular(k: int) -> bool:
    return k >= 3


@dataclass(frozen=True)
class SineResult:
    axis: str
    amplitude: float
    """In degrees for rotations, mm for translations."""
    frequency: float
    gain_db: float
    phase_deg: float
    t: NDArray[np.float64] = field(repr=False)
    command: NDArray[np.float64] = field(repr=False)
    response: NDArray[np.float64] = field(repr=False)


def sine(
    axis: str = "pitch",
    amplitude: float = 2.0,
    hz: float = 1.0,
    cycles: int = 6,
    patient: str = "relaxed",
    seed: int = 1,
) -> SineResult:
    """Pose tracking of a sine on one axis (paper, Figure 10). Amplitude in deg or mm."""
    k = _axis(axis)
    if not (math.isfinite(amplitude) and amplitude > 0.0):
        raise CommandError("amplitude must be a positive number")
    if not (math.isfinite(hz) and 0.05 <= hz <= 20.0):
        raise CommandError("frequency must be 0.05..20 Hz")
    scale = math.radians(1.0) if _angular(k) else 1e-3
    rig = _rig(patient, True, seed)
    _settle_at_home(rig)
    rig.track({axis: AxisTarget(Waveform.SINE, 0.0, amplitude * scale, hz)})
    lead = max(1.0 / hz, 0.3)  # let the start-up transient die
    rig.run(lead)
    rig.clear_log()
    log = rig.run(cycles / hz)
    home = rig.geometry.home_pose[k]
    command = (log[:, COL[f"pose_cmd_{axis}"]] - home) / scale
    response = (log[:, COL[f"pose_{axis}"]] - home) / scale
    t = log[:, 0]
    reference = amplitude * np.sin(2.0 * math.pi * hz * (t - rig.state.trajectory[k, 4]))
    gain, phase = sine_response(t, reference, response, hz)
    return SineResult(axis, amplitude, hz, gain, phase, t - t[0], command, response)


@dataclass(frozen=True)
class SweepResult:
    axis: str
    amplitude: float
    frequencies: tuple[float, ...]
    gains_db: tuple[float, ...]
    phases_deg: tuple[float, ...]
    bandwidth_hz: float
    """First frequency where the gain falls below -3 dB (interpolated); inf if it never
    does within the sweep (the bandwidth is then above its highest frequency)."""


def sweep(
    axis: str = "pitch",
    amplitude: float = 2.0,
    frequencies: tuple[float, ...] = (
        0.5,
        1.0,
        2.0,
        3.0,
        4.0,
        5.0,
        6.0,
        7.0,
        8.0,
        10.0,
        12.0,
        15.0,
    ),
    seed: int = 1,
) -> SweepResult:
    """Frequency response of one axis and its -3 dB bandwidth."""
    gains, phases = [], []
    for f in frequencies:
        r = sine(axis, amplitude, f, cycles=max(3, min(12, int(2 * f))), seed=seed)
        gains.append(r.gain_db)
        phases.append(r.phase_deg)
    bw = math.inf  # never below -3 dB within the sweep: at least its top frequency
    for n in range(len(frequencies)):
        if gains[n] < -3.0:
            if n == 0:
                bw = frequencies[0]
            else:
                f0, f1, g0, g1 = frequencies[n - 1], frequencies[n], gains[n - 1], gains[n]
                bw = f0 + (f1 - f0) * (-3.0 - g0) / (g1 - g0)
            break
    return SweepResult(axis, amplitude, tuple(frequencies), tuple(gains), tuple(phases), bw)


@dataclass(frozen=True)
class ImpedanceResult:
    axis: str
    stiffness: float
    damping: float
    measured_stiffness: float
    error_pct: float
    t: NDArray[np.float64] = field(repr=False)
    angle: NDArray[np.float64] = field(repr=False)
    """Platform angle (rad) or position (m) from home."""
    torque: NDArray[np.float64] = field(repr=False)
    """Measured foot torque (N m) or force (N) on that axis, tare removed."""


def impedance(
    axis: str = "pitch",
    k: float = 50.0,
    b: float = 1.0,
    torque: float = 10.0,
    ramp_s: float = 4.0,
    seed: int = 1,
) -> ImpedanceResult:
    """The patient pushes with a slow torque ramp against the rendered impedance (Figure 12).

    Returns the stiffness measured as the slope of foot torque against platform angle.
    """
    ax = _axis(axis)
    if not _angular(ax):
        raise CommandError("the patient pushes with a torque: choose roll, pitch or yaw")
    for name, v in (("stiffness", k), ("damping", b), ("torque", torque)):
        if not math.isfinite(v):
            raise CommandError(f"{name} must be a finite number")
    if k <= 0.0:
        raise CommandError("stiffness must be positive to measure it")
    if b < 0.0:
        raise CommandError("damping cannot be negative")
    if torque == 0.0 or abs(torque) > 40.0:
        raise CommandError("torque must be nonzero and at most 40 N m")
    rig = _rig("relaxed", True, seed)
    _settle_at_home(rig)
    K = np.full(6, 0.0)
    B = np.full(6, 0.0)
    K[ax], B[ax] = k, b
    on = [i == ax for i in range(6)]
    rig.set_impedance(K, B, on)
    rig.track({})
    rig.run(0.3)
    t0 = rig.time
    rig.hardware.script_torque(ax, SCRIPT_RAMP, t0, torque / ramp_s, torque)  # type: ignore[attr-defined]
    rig.clear_log()
    log = rig.run(ramp_s + 0.5)
    home = rig.geometry.home_pose[ax]
    angle = log[:, COL[f"pose_meas_{AXES[ax]}"]] - home
    tq = log[:, COL[f"wrench_{AXES[ax]}"]] - rig.state.tare[ax]
    t = log[:, 0] - t0
    window = (t > 0.15 * ramp_s) & (t < ramp_s)
    slope = stiffness_slope(angle[window], tq[window])
    return ImpedanceResult(axis, k, b, slope, abs(slope - k) / k * 100.0, t, angle, tq)
