"""Figures to hold next to the paper's Figures 7, 9, 10 and 12 (matplotlib, PNG)."""

from __future__ import annotations

import contextlib
import math
import textwrap
from collections.abc import Iterator
from pathlib import Path

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.figure import Figure

from lab.experiments import (
    ImpedanceResult,
    SineResult,
    StaircaseResult,
    StepResult,
    SweepResult,
)
from lab.frequency import Response

_INVALID: list[str] = []


@contextlib.contextmanager
def invalid(note: str | None) -> Iterator[None]:
    """Figures saved inside say ``note`` across their top in red: the trace of a run that
    tripped or saturated is drawn (it is the one wanted), and must not read as a valid
    response (a step cut short by a trip looked like a poor step)."""
    _INVALID.append(note or "")
    try:
        yield
    finally:
        _INVALID.pop()


def _save(fig: Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    if _INVALID and _INVALID[-1]:
        note = textwrap.fill(_INVALID[-1], 90)
        fig.text(0.5, 0.995, note, color="crimson", ha="center", va="top", fontsize=9)
        fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.025 * (note.count("\n") + 2)))
    else:
        fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def step_figure(results: list[StepResult], path: Path) -> Path:
    """Figure 7/9 analogue: displacement, chamber pressures and duty of a leg step."""
    fig, ax = plt.subplots(3, 1, figsize=(7, 8), sharex=True)
    for r in results:
        label = "dead-band compensated" if r.compensate else "uncompensated"
        t = r.t * 1e3
        ax[0].plot(t, r.displacement_mm, label=label)
        ax[1].plot(t, r.pressure_bar[:, 0], label=f"lower, {label}")
        ax[1].plot(t, r.pressure_bar[:, 1], "--", label=f"upper, {label}")
        ax[2].step(t, r.duty[:, 0], where="post", label=f"lower, {label}")
    r0 = results[0]
    ax[0].axhline(r0.step_mm, color="k", lw=0.6, ls=":")
    ax[0].set_ylabel("displacement (mm)")
    ax[0].set_title(f"Leg {r0.leg}: {r0.step_mm:g} mm step (cf. paper Fig. 7 and 9)")
    ax[1].set_ylabel("pressure (bar gauge)")
    ax[2].set_ylabel("duty (%, + intake, - exhaust)")
    ax[2].set_xlabel("time (ms)")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
    return _save(fig, path)


def staircase_figure(r: StaircaseResult, path: Path) -> Path:
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.plot(r.t, r.displacement_mm, label="leg displacement")
    ax.step(r.t, r.target_mm, where="post", color="k", lw=0.8, label="target")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("mm")
    ax.set_title(f"{r.step_mm:g} mm staircase: largest steady error {r.resolution_mm:.3f} mm")
    ax.grid(alpha=0.3)
    ax.legend()
    return _save(fig, path)


def bandwidth_figure(trace: SineResult, sweep: SweepResult, path: Path) -> Path:
    """Figure 10 analogue: pitch following a sine, and the frequency response."""
    fig, ax = plt.subplots(2, 1, figsize=(7, 6))
    ax[0].plot(trace.t * 1e3, trace.command, "k--", lw=0.8, label="command")
    ax[0].plot(trace.t * 1e3, trace.response, label="platform")
    ax[0].set_xlabel("time (ms)")
    ax[0].set_ylabel(f"{trace.axis} (deg)")
    ax[0].set_title(
        f"{trace.axis} at {trace.frequency:g} Hz, {trace.amplitude:g} deg "
        f"(gain {trace.gain_db:+.1f} dB, phase {trace.phase_deg:.0f} deg)"
    )
    ax[0].legend()
    ax[0].grid(alpha=0.3)
    ax[1].semilogx(sweep.frequencies, sweep.gains_db, "o-")
    ax[1].axhline(-3.0, color="r", lw=0.8, ls=":")
    if sweep.bandwidth_kind == "measured":
        ax[1].axvline(sweep.bandwidth_hz, color="r", lw=0.8)
    ax[1].set_xlabel("frequency (Hz)")
    ax[1].set_ylabel("gain (dB)")
    stop = f"; {sweep.health.words()} at {sweep.stopped_hz:g} Hz" if sweep.stopped_hz else ""
    if sweep.bandwidth_kind == "lower_bound":
        title = f"gain stays above -3 dB up to {sweep.bandwidth_hz:g} Hz{stop}"
    elif sweep.bandwidth_kind == "unknown":
        title = "single frequency" if len(sweep.frequencies) == 1 and not stop else f"{stop[2:]}"
    else:
        title = f"-3 dB bandwidth {sweep.bandwidth_hz:.1f} Hz{stop}"
    ax[1].set_title(title)
    ax[1].grid(alpha=0.3, which="both")
    return _save(fig, path)


def impedance_figure(r: ImpedanceResult, path: Path) -> Path:
    """Figure 12 analogue: foot angle and torque under position-based impedance control."""
    fig, ax = plt.subplots(3, 1, figsize=(7, 8))
    ax[0].plot(r.t, [math.degrees(a) for a in r.angle])
    ax[0].set_ylabel(f"X_foot {r.axis} (deg)")
    ax[1].plot(r.t, r.torque)
    ax[1].set_ylabel(f"F {r.axis} (N m)")
    ax[1].set_xlabel("time (s)")
    ax[2].plot(r.angle, r.torque, ".", ms=1.5, label="measured")
    lo, hi = float(min(r.angle)), float(max(r.angle))
    ax[2].plot(
        [lo, hi],
        [r.stiffness * lo, r.stiffness * hi],
        "k--",
        lw=0.8,
        label=f"K = {r.stiffness:g} N m/rad",
    )
    ax[2].set_xlabel(f"{r.axis} (rad)")
    ax[2].set_ylabel("torque (N m)")
    ax[2].set_title(f"measured {r.measured_stiffness:.1f} N m/rad ({r.error_pct:.1f} % off)")
    ax[2].legend()
    ax[0].set_title(f"Patient pushes against K = {r.stiffness:g} N m/rad (cf. paper Fig. 12)")
    for a in ax:
        a.grid(alpha=0.3)
    return _save(fig, path)


def read_envelope_map(path: Path) -> dict[tuple[str, float, float], bool]:
    """A K-B map written by ``python -m lab.envelope`` (one line per axis, patient, K, B):
    (axis, K, B) -> stable for every patient in it."""
    stable: dict[tuple[str, float, float], bool] = {}
    for line in path.read_text().splitlines():
        parts = line.split()
        if len(parts) < 6 or not parts[2].startswith("K="):
            continue
        axis = parts[0]
        rest = " ".join(parts[2:])
        k = float(rest.split("K=")[1].split()[0])
        b = float(rest.split("B=")[1].split()[0])
        ok = rest.split("B=")[1].split()[1] == "ok"
        key = (axis, k, b)
        stable[key] = stable.get(key, True) and ok
    return stable


def envelope_figure(
    with_inertia: dict[tuple[str, float, float], bool],
    without: dict[tuple[str, float, float], bool],
    path: Path,
) -> Path:
    """Per rotational axis: the measured K-B map (stable for a relaxed, a resisting and no
    foot, or not) with and without the virtual inertia, and the published envelope."""
    from device.axes import AXIS_INDEX
    from device.limits import SafetyLimits

    lim = SafetyLimits().published()
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.2), sharey=True)
    for ax, name in zip(axes, ("roll", "pitch", "yaw"), strict=True):
        for data, dx, label in ((without, 0.88, "without"), (with_inertia, 1.12, "with")):
            pts = [(k, b, ok) for (a, k, b), ok in data.items() if a == name]
            for ok in (True, False):
                ks = [max(k, 0.5) * dx for k, b, s in pts if s == ok]
                bs = [max(b, 0.02) for k, b, s in pts if s == ok]
                ax.scatter(
                    ks,
                    bs,
                    marker=("o" if ok else "x"),
                    s=14,
                    color=("tab:green" if ok else "tab:red"),
                    alpha=(1.0 if label == "with" else 0.35),
                    label=f"{'stable' if ok else 'oscillates or trips'} ({label} virtual inertia)",
                )
        edges = [max(e, 0.5) for e in lim.envelope_stiffness]
        values = [lim.damping_min_at(AXIS_INDEX[name], e) for e in lim.envelope_stiffness]
        ax.step(
            [*edges, 600.0],
            [*values, values[-1]],
            where="post",
            color="black",
            lw=2,
            label="published envelope: least B",
        )
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(name)
        ax.set_xlabel("stiffness K (N m/rad; 0 drawn at 0.5)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("damping B (N m s/rad; 0 drawn at 0.02)")
    fig.suptitle(
        "Rendered K and B after a 2 N m push: stable for a relaxed, a resisting and no foot, "
        "or not (docs/envelope.md)"
    )
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles[:5], labels[:5], loc="lower center", ncol=3, fontsize=8)
    fig.subplots_adjust(bottom=0.3, top=0.85, wspace=0.08)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def frequency_figure(
    responses: dict[str, Response],
    path: Path,
    after: dict[str, Response] | None = None,
    labels: tuple[str, str] = ("before", "after"),
) -> Path:
    """Gain and phase against frequency of every axis (lab.frequency, to 40 Hz with the
    device's speed limits lifted); with ``after``, the same axes after a change beside."""
    from device.geometry import AXES

    fig, axes = plt.subplots(4, 3, figsize=(13, 10), sharex=True)
    runs = [(responses, labels[0] if after else "")] + ([(after, labels[1])] if after else [])
    for k, name in enumerate(AXES):
        row, col = (0 if k < 3 else 2), k % 3
        g, ph = axes[row, col], axes[row + 1, col]
        for data, label in runs:
            r = data[name]
            pts = r.valid_points
            hz = [p.hz for p in pts]
            tag = f"{label}: " if label else ""
            g.semilogx(
                hz,
                [p.gain_db for p in pts],
                "o-",
                ms=3,
                label=f"{tag}peak {r.peak_db:+.1f} dB at {r.peak_hz:g} Hz",
            )
            unwrapped = np.degrees(np.unwrap(np.radians([p.phase_deg for p in pts])))
            ph.semilogx(hz, unwrapped, "o-", ms=3, label=label or None)
            sat = [p for p in pts if "valve_duty" in p.health.saturated]
            if sat:
                g.plot([p.hz for p in sat], [p.gain_db for p in sat], "rx", ms=7)
        unit = "deg" if k >= 3 else "mm"
        g.set_title(f"{name}, {responses[name].amplitude:g} {unit}")
        g.axhline(-3.0, color="r", lw=0.7, ls=":")
        g.axhline(3.0, color="k", lw=0.7, ls=":")
        g.set_ylabel("gain (dB)")
        ph.set_ylabel("phase (deg)")
        g.legend(fontsize=7)
        for a in (g, ph):
            a.grid(alpha=0.3, which="both")
    for a in axes[3]:
        a.set_xlabel("frequency (Hz)")
    fig.suptitle(
        "Frequency response per axis, lab mode (speed limits lifted), nominal plant, "
        "relaxed foot; dotted: +3 and -3 dB"
    )
    return _save(fig, path)
