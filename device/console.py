"""The simulated device run against the wall clock with a live console summary.

What ``make run`` shows until the device service and the server exist: a relaxed patient
on the simulated platform doing a slow plantar/dorsiflexion exercise against 30 N m/rad,
one status line a second. Simulated time never runs ahead of wall time.
"""

from __future__ import annotations

import math
import sys
import time
from typing import TextIO

import numpy as np

from device.controller import Waveform
from device.hardware import SimulatedHardware
from device.plant.model import SCRIPT_SINE
from device.plant.params import PlantConfig
from device.rig import AxisTarget, Rig

CHUNK_S = 0.02
"""Simulated time advanced per pacing step (s)."""


def run_console(seconds: float | None = None, out: TextIO = sys.stdout) -> int:
    """Run until ``seconds`` of simulated time have passed (forever if None) or Ctrl-C."""
    rig = Rig(SimulatedHardware(PlantConfig(patient="relaxed")))
    print("ankle: starting the simulated device (first start compiles for ~20 s)...", file=out)
    rig.run(1.0 / 7000.0, log_hz=0)
    rig.move_legs(rig.state.leg_x.copy())
    K = np.zeros(6)
    B = np.zeros(6)
    K[4], B[4] = 30.0, 1.0
    rig.set_impedance(K, B, [False, False, False, False, True, False])
    rig.track({"pitch": AxisTarget(Waveform.SINE, 0.0, math.radians(8.0), 0.2)})
    # The patient pushes back a little, then lets go, every 5 s.
    rig.hardware.script_torque(4, SCRIPT_SINE, rig.time, 3.0, 0.1)  # type: ignore[attr-defined]
    print("time s | mode  | pitch deg (cmd) | foot torque N m | K N m/rad | lag ms", file=out)
    start_wall = time.perf_counter()
    start_sim = rig.time
    next_print = start_sim
    lag_ms = 0.0
    try:
        while seconds is None or rig.time - start_sim < seconds:
            rig.run(CHUNK_S, log_hz=0)
            ahead = (rig.time - start_sim) - (time.perf_counter() - start_wall)
            if ahead > 0:
                time.sleep(ahead)
            else:
                lag_ms = -ahead * 1e3
            if rig.time >= next_print:
                s = rig.state
                home = rig.geometry.home_pose[4]
                print(
                    f"{rig.time:6.1f} | {rig.mode.name:5s} | {math.degrees(s.pose[4] - home):6.2f} "
                    f"({math.degrees(s.pose_cmd[4] - home):6.2f}) | "
                    f"{s.wrench[4] - s.tare[4]:7.2f}         | {s.stiffness[4]:5.1f}     | "
                    f"{lag_ms:5.1f}",
                    file=out,
                    flush=True,
                )
                next_print += 1.0
    except KeyboardInterrupt:
        pass
    finally:
        rig.hold()
        print("ankle: stopped; valves closed.", file=out)
    return 0
