"""``ankle bench link``: the serial link as the home station sees it.

The device service runs as its own process on a pty with the simulated plant (a relaxed
patient pushing 3 N m in pitch), a :class:`~device.client.DeviceClient` homes it and runs a
compliant pitch exercise with telemetry at 250 Hz, then for the window:

- changes K every 50 ms and times each command to its ACK (``cmd_ack_rtt_ms_*``);
- counts telemetry received against the configured rate and gaps in the device's frame
  numbers (``frames_lost``), and the longest wait between two samples received
  (``telemetry_gap_ms_max``: a host that stalled shows there, whatever the device did);
- reads the device's own pacing lag from every telemetry sample and its overrun counter;
- reads the service's CPU time from ``/proc``.

Then it pulls the link ``watchdog_runs`` times (stops every frame, heartbeats included) and
times from the last frame it sent to the WATCHDOG event it receives: an upper bound of the
device's time to HOLD (the device also reports its own measure in the event).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from typing import Any

import numpy as np

from device.client import CommandRefused, DeviceClient, DeviceError, build_segment
from device.commands import SEGMENT_DURATION_MAX
from device.console import DEMO_PITCH
from device.process import ServiceProcess
from device.protocol import messages as msg
from device.protocol.messages import DeviceMode, EventKind
from lab.targets import Target
from lab.targets import table as bench_table

TELEMETRY_HZ = 250
WATCHDOG_MS = 200
"""The device's default watchdog, which the benchmark sets unless told another
(``--watchdog-ms``: a longer one keeps a host that stalls on a shared machine from holding
the exercise under way, which ends the benchmark without a measurement)."""


def targets(watchdog_ms: int = WATCHDOG_MS) -> tuple[Target, ...]:
    """The targets, the hold's against the watchdog set: held within one PWM period of it."""
    return (
        Target("cmd_ack_rtt_ms_p99", "command to ACK round trip p99 (ms)", 5.0, "max"),
        Target("frames_lost", "telemetry frames lost", 0, "eq"),
        Target("telemetry_hz_received", "telemetry received (Hz)", 0.99 * TELEMETRY_HZ, "min"),
        Target("pacing_lag_ms_p99", "pacing lag p99 (ms)", 2.0, "max"),
        Target("watchdog_hold_ms_max", "last frame to HOLD, worst (ms)", watchdog_ms + 4.0, "max"),
        Target("service_cpu_pct", "device service CPU (% of one core)", 60.0, "max"),
    )


TARGETS = targets()

ROWS: tuple[tuple[str, str], ...] = (
    ("seconds", "telemetry window (s)"),
    ("cmd_ack_rtt_ms_p50", "command to ACK round trip p50 (ms)"),
    ("cmd_ack_rtt_ms_p99", "command to ACK round trip p99 (ms)"),
    ("commands", "commands timed"),
    ("telemetry_hz_configured", "telemetry configured (Hz)"),
    ("telemetry_hz_received", "telemetry received (Hz)"),
    ("frames_lost", "telemetry frames lost"),
    ("telemetry_gap_ms_max", "longest wait between samples (ms)"),
    ("pacing_lag_ms_p50", "pacing lag p50 (ms)"),
    ("pacing_lag_ms_p99", "pacing lag p99 (ms)"),
    ("pacing_lag_ms_max", "pacing lag max (ms)"),
    ("overruns_per_min", "overruns per minute"),
    ("service_cpu_pct", "device service CPU (% of one core)"),
    ("watchdog_ms", "device watchdog set (ms)"),
    ("watchdog_runs", "watchdog runs"),
    ("watchdog_hold_ms_max", "last frame to HOLD, worst (ms)"),
    ("watchdog_hold_ms_p50", "last frame to HOLD, median (ms)"),
    ("watchdog_device_ms_max", "device's own measure, worst (ms)"),
)


SILENCE_S = 10.0
"""Longest wait (s) for a telemetry sample before the benchmark gives up, naming what it saw
(the device sends 250 a second): once, in a test run on a busy machine, the benchmark waited
on the stream until its 300 s timeout killed it, with nothing to say why."""


HOLD_WAIT_S = 5.0
"""Longest wait (s) for the device's watchdog hold once the host has gone silent (it holds
after 200 ms)."""


def _last_mode(dev: DeviceClient) -> str:
    return dev.latest.mode.name if dev.latest is not None else "unknown"


def _no_hold(dev: DeviceClient, run: int) -> str:
    """One line on a watchdog run that saw no hold: what the device last said."""
    mode = _last_mode(dev)
    last = dev.last_event
    event = f"#{last.event_id} {last.kind.name} ({last.text})" if last is not None else "none"
    return (
        f"watchdog run {run}: no WATCHDOG event within {HOLD_WAIT_S:g} s of the host's last "
        f"frame (the device's last sample said {mode}; its last event {event}; "
        f"{dev.stats.frames_lost} frames lost, {dev.stats.stalls} host stalls)"
    )


def _pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else math.nan


async def _measure(
    service: ServiceProcess, seconds: float, watchdog_runs: int, watchdog_ms: int
) -> dict[str, Any]:
    async with await DeviceClient.connect(service.link) as dev:
        hello = dev.hello
        assert hello is not None
        await dev.configure(TELEMETRY_HZ, watchdog_ms)
        await dev.arm_home()
        await dev.wait_for_mode(DeviceMode.READY, timeout=30.0)
        # As long as the device allows: the benchmark holds it when done, and a host that
        # stalls must show as lost frames and a long gap, not as an exercise that ended.
        await dev.start_segment(
            build_segment(hello, 1, SEGMENT_DURATION_MAX, {"pitch": DEMO_PITCH})
        )
        await dev.wait_for_mode(DeviceMode.ACTIVE, timeout=5.0)
        await asyncio.sleep(0.5)

        # -- telemetry window with live K changes --------------------------------------
        rtts: list[float] = []
        refused: list[str] = []

        changing = True  # a stop the task reads itself, as well as the cancel that wakes it

        async def change_k() -> None:
            k = 30.0
            while changing:
                await asyncio.sleep(0.05)
                k = 40.0 if k == 30.0 else 30.0
                start = time.perf_counter()
                try:
                    await dev.set_impedance((0, 0, 0, 0, k, 0), (0, 0, 0, 0, 1.0, 0))
                except CommandRefused as e:
                    refused.append(str(e))
                    return
                rtts.append((time.perf_counter() - start) * 1e3)

        lost0 = dev.stats.frames_lost
        lags: list[float] = []
        gap_ms = 0.0
        overruns0: int | None = None
        last: msg.Telemetry | None = None
        count = 0
        changer = asyncio.create_task(change_k())
        cpu0, t0 = service.cpu_seconds(), time.perf_counter()
        received = 0.0
        stream = dev.telemetry(maxsize=100000)
        while True:
            try:
                async with asyncio.timeout(SILENCE_S):
                    sample = await anext(stream)
            except (StopAsyncIteration, TimeoutError) as exc:
                changing = False
                changer.cancel()
                with contextlib.suppress(asyncio.CancelledError, DeviceError):
                    await changer
                if isinstance(exc, StopAsyncIteration):
                    why = dev.link_error
                    raise RuntimeError(f"the link closed during the benchmark ({why})") from None
                raise RuntimeError(
                    f"no telemetry from the device for {SILENCE_S:g} s (its last sample said "
                    f"{_last_mode(dev)}); the link is still open"
                ) from None
            now = time.perf_counter()
            if overruns0 is None:
                overruns0 = sample.overruns
                t0 = received = now
                cpu0 = service.cpu_seconds()
                continue
            gap_ms = max(gap_ms, (now - received) * 1e3)
            received = now
            count += 1
            lags.append(sample.pacing_lag_ms)
            last = sample
            if time.perf_counter() - t0 >= seconds:
                break
        wall = time.perf_counter() - t0
        cpu = service.cpu_seconds() - cpu0
        changing = False
        changer.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await changer
        lost = dev.stats.frames_lost - lost0
        assert last is not None and overruns0 is not None
        if last.mode != DeviceMode.ACTIVE or refused:
            why = f"; K change refused: {refused[0]}" if refused else ""
            event = dev.last_event
            if event is not None and event.kind == EventKind.WATCHDOG:
                why += (
                    f"; its watchdog held it ({event.text}), and this host stood still "
                    f"{dev.stats.stalls} times, up to {dev.stats.stall_ms_max:.0f} ms: on a "
                    "shared machine, a longer --watchdog-ms"
                )
            raise RuntimeError(
                f"the exercise stopped during the benchmark (device {last.mode.name}{why}; "
                f"window {wall:.1f} s, longest wait between samples {gap_ms:.0f} ms)"
            )

        # -- watchdog: pull the link ------------------------------------------------------
        holds: list[float] = []
        device_ms: list[float] = []
        events = dev.events()
        for _ in range(watchdog_runs):
            dev.heartbeats = False
            await asyncio.sleep(dev.heartbeat_period * 2)  # let a heartbeat in flight land
            sent = time.perf_counter()
            await dev.command(msg.Heartbeat())  # the last valid frame
            try:
                async with asyncio.timeout(HOLD_WAIT_S):  # for the hold, whatever else comes
                    while (event := await anext(events)).kind != EventKind.WATCHDOG:
                        pass
            except (TimeoutError, StopAsyncIteration):
                raise RuntimeError(_no_hold(dev, len(holds) + 1)) from None
            holds.append((time.perf_counter() - sent) * 1e3)
            device_ms.append(event.value)
            dev.heartbeats = True
            await dev.resume()
            await asyncio.sleep(0.3)
        await events.aclose()
        await dev.hold()

    return {
        "seconds": wall,
        "cmd_ack_rtt_ms_p50": _pct(rtts, 50),
        "cmd_ack_rtt_ms_p99": _pct(rtts, 99),
        "commands": len(rtts),
        "telemetry_hz_configured": TELEMETRY_HZ,
        "telemetry_hz_received": count / wall,
        "frames_lost": lost,
        "telemetry_gap_ms_max": gap_ms,
        "pacing_lag_ms_p50": _pct(lags, 50),
        "pacing_lag_ms_p99": _pct(lags, 99),
        "pacing_lag_ms_max": max(lags),
        "overruns_per_min": (last.overruns - overruns0) / (wall / 60.0),
        "service_cpu_pct": 100.0 * cpu / wall,
        "watchdog_ms": watchdog_ms,
        "watchdog_runs": len(holds),
        "watchdog_hold_ms_max": max(holds),
        "watchdog_hold_ms_p50": _pct(holds, 50),
        "watchdog_device_ms_max": max(device_ms),
    }


def run(
    seconds: float = 60.0, watchdog_runs: int = 20, watchdog_ms: int = WATCHDOG_MS
) -> dict[str, Any]:
    with ServiceProcess("--link", "pty", "--patient-torque", "3") as service:
        return asyncio.run(_measure(service, seconds, watchdog_runs, watchdog_ms))


def table(result: dict[str, Any]) -> str:
    return bench_table(result, ROWS, targets(int(result["watchdog_ms"])))
