"""The device service as a child process (device.process)."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from device.client import DeviceClient, build_segment
from device.console import DEMO_PITCH
from device.process import ServiceProcess
from device.protocol.messages import DeviceMode

START = """
import sys, time
from device.process import ServiceProcess
service = ServiceProcess("--link", "tcp://127.0.0.1:0")
print(service.pid, flush=True)
time.sleep(600)
"""


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"  # a zombie has stopped


def test_the_service_stops_when_what_started_it_is_killed() -> None:
    """A hung benchmark killed by the test runner (SIGKILL: nothing of it runs on) used to
    leave its service running, at real-time priority and holding its port, for good."""
    with subprocess.Popen(
        [sys.executable, "-c", START], stdout=subprocess.PIPE, text=True, cwd=os.getcwd()
    ) as parent:
        try:
            assert parent.stdout is not None
            pid = int(parent.stdout.readline())
            assert _alive(pid)
            parent.send_signal(signal.SIGKILL)
            parent.wait(10.0)
            deadline = time.monotonic() + 60.0
            while _alive(pid) and time.monotonic() < deadline:
                time.sleep(0.1)
            assert not _alive(pid), "the service outlived the process that started it"
        finally:
            if parent.poll() is None:
                parent.kill()


def test_nothing_compiles_once_the_service_serves(monkeypatch: pytest.MonkeyPatch) -> None:
    """Numba compiles a function at its first call. Called first from the loop (a mode
    change's reset, a trip, the loop itself) that stopped the device for as long as the
    compile took: seconds on a test machine whose parallel workers had just rewritten the
    cache, telemetry and watchdog included. The service loads all of them before it
    announces itself; numba's cache log says when each was loaded or compiled."""
    monkeypatch.setenv("NUMBA_DEBUG_CACHE", "1")

    async def session(link: str) -> None:
        async with await DeviceClient.connect(link) as dev:
            assert dev.hello is not None
            await dev.arm_home()
            await dev.wait_for_mode(DeviceMode.READY, timeout=60.0)
            await dev.start_segment(build_segment(dev.hello, 1, 5.0, {"pitch": DEMO_PITCH}))
            await dev.wait_for_mode(DeviceMode.ACTIVE)
            await dev.set_impedance((0, 0, 0, 0, 40, 0), (0, 0, 0, 0, 1.0, 0))
            await dev.hold()
            await dev.resume()
            await dev.estop()
            await dev.rearm()
            await dev.release()

    with ServiceProcess("--link", "pty", "--patient-torque", "3") as service:
        asyncio.run(session(service.link))
        lines = list(service.output)
    serving = next(i for i, line in enumerate(lines) if "serving on" in line)
    assert any("[cache]" in line for line in lines[:serving])  # the log is on
    late = [line for line in lines[serving:] if "[cache]" in line]
    assert not late, late


BUSY = "import time\nend = time.monotonic() + 120\nwhile time.monotonic() < end:\n    pass\n"
IDLE = "import time\ntime.sleep(120)\n"


def test_a_start_still_busy_is_waited_for_past_its_timeout_an_idle_one_is_not() -> None:
    """A cold cache on a busy machine compiled for longer than ``ankle run``'s 180 s, and the
    whole system stopped with a stack dump of numba's compiler. Past its timeout a child
    that keeps using the CPU (compiling) is waited for, up to the limit; one that uses none
    (hung) is stopped at the timeout, and the error says which."""
    from device.process import ServiceStartError

    t0 = time.monotonic()
    with pytest.raises(ServiceStartError, match="idle; its stack"):
        ServiceProcess(
            start_timeout=1.0, start_limit=60.0, slice_s=0.5, argv=[sys.executable, "-c", IDLE]
        )
    idle_waited = time.monotonic() - t0
    t0 = time.monotonic()
    with pytest.raises(ServiceStartError, match="still busy at the limit"):
        ServiceProcess(
            start_timeout=1.0, start_limit=4.0, slice_s=0.5, argv=[sys.executable, "-c", BUSY]
        )
    busy_waited = time.monotonic() - t0
    assert 1.0 <= idle_waited < 45.0, idle_waited  # stopped at a slice past its timeout
    assert busy_waited >= 4.0, busy_waited  # waited for past its timeout, to the limit
