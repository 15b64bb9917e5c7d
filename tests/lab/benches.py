"""Run an ``ankle bench`` command as a real process, for the lab tests."""

from __future__ import annotations

import subprocess
import sys


def ankle_bench(name: str, *args: str) -> subprocess.CompletedProcess[str]:
    """``ankle bench NAME ARGS`` as a real command, its output captured."""
    return subprocess.run(
        [sys.executable, "-m", "ankle", "bench", name, *args],
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )
