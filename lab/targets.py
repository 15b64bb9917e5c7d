"""Benchmark targets and the Markdown table every benchmark prints.

A row whose measurement is invalid (its experiment tripped or saturated) shows
``INVALID (reason)`` instead of a number and never counts as met.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Target:
    key: str
    label: str
    bound: float
    kind: str  # "max", "min" or "eq"

    def met(self, value: float) -> bool:
        if math.isnan(value):
            return False
        if self.kind == "max":
            return value <= self.bound
        if self.kind == "min":
            return value >= self.bound
        return value == self.bound

    def text(self) -> str:
        return {"max": "<= ", "min": ">= ", "eq": "= "}[self.kind] + f"{self.bound:g}"


def table(
    result: dict[str, Any],
    rows: tuple[tuple[str, str], ...],
    targets_met: tuple[Target, ...],
    invalid: dict[str, str] | None = None,
) -> str:
    """A benchmark as a Markdown table (what the README shows).

    ``invalid`` maps a row's key to why its number cannot be trusted; such a row shows
    ``INVALID (reason)`` and its target is not met.
    """
    targets = {t.key: t for t in targets_met}
    bad = invalid or {}
    lines = ["| metric | value | target | met |", "|---|---:|---|---|"]
    for key, label in rows:
        tgt = targets.get(key)
        if key in bad:
            lines.append(
                f"| {label} | INVALID ({bad[key]}) | {tgt.text() if tgt else ''} | "
                f"{'NO' if tgt else ''} |"
            )
            continue
        value = result[key]
        text = f"{value:.3g}" if isinstance(value, float) else str(value)
        if value is None or (isinstance(value, float) and math.isnan(value)):
            # e.g. a step that never settles into its band (NaN, written null in the JSON)
            text = "no number"
            value = math.nan
        if isinstance(value, (int, float)) and not isinstance(value, bool) and abs(value) >= 1000:
            text = f"{value:,.0f}"  # counts and floats alike: 1,248 points, 1,680 s
        if key == "pitch_bandwidth_hz" and result.get("pitch_bandwidth_above_sweep"):
            text = f"> {text} (top of sweep)"
        if key == "pitch_bandwidth_true_hz" and result.get("pitch_bandwidth_true_lower_bound"):
            text = f">= {text} (gain above -3 dB to the top of the sweep)"
        if key == "pitch_bandwidth_true_hz" and result.get("pitch_bandwidth_true_saturated_hz"):
            text += (
                f" (valves saturated from {result['pitch_bandwidth_true_saturated_hz'][0]:g} Hz)"
            )
        lines.append(
            f"| {label} | {text} | {tgt.text() if tgt else ''} | "
            f"{('yes' if tgt.met(float(value)) else 'NO') if tgt else ''} |"
        )
    return "\n".join(lines)
