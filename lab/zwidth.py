"""Z-width: the stiffness and damping the device renders stably, per rotational axis.

Haptic devices are characterised by the region of the K-B plane they render stably (Colgate
and Brown 1994). Each point of a grid is rendered on one rotational axis with the device's
virtual inertia, pushed (2 N m for 0.1 s) and classified as ``lab.envelope`` classifies its
maps (no trip, at most 0.2 deg of oscillation left, no chattering command, no walk away):
stable only if stable with a relaxed foot, a resisting one and an empty plate. The rig's
published envelope (the least B per K band the device accepts) is replaced for each point
by a floor at that point's own B: points below the envelope are measured too (the device
itself never renders them), and the admittance law renders the point's B itself above its
lag corner, none of the loop's lag taken out there, which is the damping the envelope's
floor is about (docs/envelope.md, section 6; below the corner the law takes the lag out as
the device does). Without that floor the law took K times the lag out of B,
and a point read the stability of about none.

``ankle bench zwidth`` runs the grid (a few minutes) and prints, per axis, the least stable
B at each K; ``--plots DIR`` draws the figure.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from device.limits import SafetyLimits
from lab import envelope

K_GRID: tuple[float, ...] = (0.0, 5.0, 20.0, 50.0, 100.0, 200.0, 350.0, 500.0)
"""N m/rad, up to the device's stiffness limit."""
B_GRID: tuple[float, ...] = (0.0, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)
"""N m s/rad; the limit is 50, but every K was stable well below 5 in the envelope's maps."""
AXES = envelope.ROT_AXES
PATIENTS = envelope.PATIENTS


def point(axis: str, k: float, b: float) -> dict[str, Any]:
    """One grid point over every patient: stable only if stable for each. The loop alone:
    the device's ring guard (device.ring), which raises the damping of an axis that rings,
    is off, so the map shows what the law renders at the point's own B."""
    runs = [
        envelope.run_point(axis, p, k, b, limits=envelope.floor_at(b), ring_guard=False)
        for p in PATIENTS
    ]
    worst = max(runs, key=lambda r: r["pp_det_deg"] if math.isfinite(r["pp_det_deg"]) else 1e9)
    return {
        "axis": axis,
        "k": k,
        "b": b,
        "stable": not any(r["marginal"] for r in runs),
        "unstable_with": [p for p, r in zip(PATIENTS, runs, strict=True) if r["marginal"]],
        "trips": sorted({r["trip"] for r in runs if r["trip"] != "NONE"}),
        "pp_det_deg_max": worst["pp_det_deg"],
    }


def _point(args: tuple[str, float, float]) -> dict[str, Any]:
    return point(*args)


def run(
    axes: tuple[str, ...] = AXES,
    ks: tuple[float, ...] = K_GRID,
    bs: tuple[float, ...] = B_GRID,
    progress: Callable[[str], None] | None = None,
    workers: int | None = None,
) -> dict[str, Any]:
    """Every grid point on every axis; with the published envelope beside it."""
    # K = B = 0 is no impedance: the device refuses it as a compliant axis.
    jobs = [(a, k, b) for a in axes for k in ks for b in bs if k > 0.0 or b > 0.0]
    n = workers if workers is not None else min(2, os.cpu_count() or 1)
    points: list[dict[str, Any]] = []
    if n > 1:
        with ProcessPoolExecutor(n) as pool:
            for r in pool.map(_point, jobs):
                points.append(r)
                if progress:
                    progress(f"zwidth: {len(points)}/{len(jobs)} points")
    else:
        for job in jobs:
            points.append(_point(job))
            if progress:
                progress(f"zwidth: {len(points)}/{len(jobs)} points")
    published = SafetyLimits()
    below_edge = [
        p
        for p in points
        if not p["stable"] and p["b"] >= published.damping_min_at(3 + AXES.index(p["axis"]), p["k"])
    ]
    return {"points": points, "unstable_inside_envelope": below_edge}


def least_b(result: dict[str, Any], axis: str, k: float) -> float | None:
    """The least grid B stable at ``k`` with every larger grid B stable too (None: none)."""
    row = sorted((p for p in result["points"] if p["axis"] == axis and p["k"] == k),
                 key=lambda p: p["b"])  # fmt: skip
    best = None
    for p in reversed(row):
        if not p["stable"]:
            break
        best = p["b"]
    return best


def table(result: dict[str, Any]) -> str:
    """Per axis and K: the least stable B measured and the one the device publishes."""
    published = SafetyLimits()
    ks = sorted({p["k"] for p in result["points"]})
    axes = [a for a in AXES if any(p["axis"] == a for p in result["points"])]
    lines = [
        "| K (N m/rad) | " + " | ".join(f"{a}: least stable B / published" for a in axes) + " |",
        "|---:|" + "---|" * len(axes),
    ]
    for k in ks:
        cells = []
        for a in axes:
            b = least_b(result, a, k)
            pub = published.damping_min_at(3 + AXES.index(a), k)
            cells.append(f"{'none' if b is None else f'{b:g}'} / {pub:g}")
        lines.append(f"| {k:g} | " + " | ".join(cells) + " |")
    bad = result["unstable_inside_envelope"]
    lines.append("")
    lines.append(
        f"Unstable points at or above the published envelope: {len(bad)}"
        + "".join(
            f"\n- {p['axis']} K = {p['k']:g}, B = {p['b']:g}: {', '.join(p['unstable_with'])}"
            f" ({p['pp_det_deg_max']:.2f} deg)"
            for p in bad
        )
    )
    return "\n".join(lines)


def figure(result: dict[str, Any], path: Path) -> Path:
    """One panel per axis: stable and unstable points, the published edge, the box."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    published = SafetyLimits()
    fig, axs = plt.subplots(1, len(AXES), figsize=(13, 4.2), sharey=True)
    for ax, name in zip(axs, AXES, strict=True):
        pts = [p for p in result["points"] if p["axis"] == name]
        for stable, marker, colour, label in (
            (True, "o", "tab:green", "stable (every patient)"),
            (False, "x", "tab:red", "unstable or marginal"),
        ):
            sel = [p for p in pts if p["stable"] == stable]
            ax.scatter([p["k"] for p in sel], [p["b"] for p in sel], marker=marker,
                       color=colour, label=label, zorder=3)  # fmt: skip
        ks = [0.0, 1.0, *[k for k in K_GRID if k > 0]]
        edge = [published.damping_min_at(3 + AXES.index(name), k) for k in ks]
        ax.step(ks, edge, where="post", color="black", lw=1.2, label="published least B")
        kmax = published.stiffness_max[3 + AXES.index(name)]
        ax.axvline(kmax, color="grey", ls="--", lw=0.8, label=f"K limit {kmax:g}")
        ax.set_xscale("symlog", linthresh=5.0)
        ax.set_yscale("symlog", linthresh=0.05)
        ax.set_xlim(-0.5, 650.0)
        ax.set_ylim(-0.003, 8.0)
        ax.set_title(name)
        ax.set_xlabel("stiffness K (N m/rad)")
        ax.grid(True, which="both", alpha=0.3)
    axs[0].set_ylabel("damping B (N m s/rad)")
    axs[0].legend(fontsize=7, loc="upper left")
    fig.suptitle("Z-width: impedances rendered stably with a relaxed, a resisting and no foot "
                 "(nominal plant, virtual inertia on, ring guard off)")  # fmt: skip
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
