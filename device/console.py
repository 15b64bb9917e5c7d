"""The device service on a pty with a console client showing live telemetry.

What ``make run`` shows until the server and home station exist: the simulated device runs
as its own process on a pseudo-terminal, exactly as it would on the embedded PC, and this
client drives it over the serial protocol like a home station would: it homes the platform,
then runs 30 s segments of slow plantar/dorsiflexion (8 deg at 0.2 Hz) against 30 N m/rad
while the simulated patient pushes back, one status line a second. Ctrl-C holds the
platform, stops the service (which closes the valves) and exits.
"""

from __future__ import annotations

import asyncio
import math
import sys
from typing import TextIO

from device.client import AxisPlan, DeviceClient, DeviceError, build_segment
from device.process import ServiceProcess, ServiceStartError
from device.protocol.messages import DeviceMode, Telemetry
from device.waveforms import Waveform

SEGMENT_S = 30.0
DEMO_PITCH = AxisPlan(
    Waveform.SINE,
    amplitude=math.radians(8.0),
    frequency=0.2,
    stiffness=30.0,
    damping=1.0,
    compliant=True,
)
"""Slow plantar/dorsiflexion, 8 deg at 0.2 Hz, compliant at 30 N m/rad and 1 N m s/rad."""


def _line(t: Telemetry, lost: int) -> str:
    return (
        f"{t.time:7.1f} | {t.mode.name:6s} | {math.degrees(t.pose[4]):6.2f} "
        f"({math.degrees(t.pose_cmd[4]):6.2f}) | {t.wrench[4]:7.2f}         | "
        f"{t.stiffness[4]:5.1f}     | {t.pacing_lag_ms:5.2f}  | {lost}"
    )


async def _drive(link: str, seconds: float | None, out: TextIO) -> None:
    async with await DeviceClient.connect(link) as dev:
        assert dev.hello is not None
        hello = dev.hello
        print(
            f"ankle: connected to {hello.firmware} ({hello.hardware}) on {link}; "
            f"telemetry {hello.telemetry_hz} Hz, watchdog {hello.watchdog_ms} ms",
            file=out,
        )
        await dev.arm_home()
        await dev.wait_for_mode(DeviceMode.READY, timeout=30.0)
        print(
            "time s  | mode   | pitch deg (cmd) | foot torque N m | K N m/rad | lag ms | lost",
            file=out,
        )
        loop = asyncio.get_running_loop()
        start = loop.time()
        segment_id = 0
        next_print = 0.0
        async for t in dev.telemetry():
            if t.mode == DeviceMode.READY:
                segment_id += 1
                await dev.start_segment(
                    build_segment(hello, segment_id, SEGMENT_S, {"pitch": DEMO_PITCH})
                )
            elif t.mode in (DeviceMode.FAULT, DeviceMode.ESTOP, DeviceMode.HOLD):
                print(f"ankle: the device is in {t.mode.name} (trip {t.trip.name})", file=out)
                break
            if t.time >= next_print:
                print(_line(t, dev.stats.frames_lost), file=out, flush=True)
                next_print = t.time + 1.0
            if seconds is not None and loop.time() - start >= seconds:
                break
        await dev.hold()


def run_console(seconds: float | None = None, out: TextIO = sys.stdout) -> int:
    """Start the service, drive it until ``seconds`` pass (forever if None) or Ctrl-C."""
    print("ankle: starting the device service (first start compiles for ~2 min)...", file=out)
    try:
        service = ServiceProcess("--link", "pty", "--patient-torque", "3")
    except ServiceStartError as exc:
        print(f"ankle: {exc}", file=sys.stderr)
        return 1
    code = 0
    try:
        print(f"ankle: device service on {service.link} (pid {service.pid})", file=out)
        asyncio.run(_drive(service.link, seconds, out))
    except KeyboardInterrupt:
        pass
    except DeviceError as exc:
        print(f"ankle: {exc}", file=sys.stderr)
        code = 1
    finally:
        service.stop()
        print("ankle: stopped; valves closed.", file=out)
    return code
