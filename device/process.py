"""The device service as a child process: what ``ankle run``, the link benchmark and the
end-to-end tests start, so the service has its own interpreter and its own core as it
would on the embedded PC.
"""

from __future__ import annotations

import collections
import contextlib
import ctypes
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from types import TracebackType

SERVING = re.compile(r"serving on (\S+)")
OUTPUT_LINES = 1000
"""The service's last lines of output kept (for a crash report)."""


PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:
    """In the child, before exec: SIGTERM it (it closes its valves and link) when the
    process that started it dies, however that died. A test runner that SIGKILLs a hung
    benchmark left its service running at real-time priority, a pty held, for good. Linux
    only; elsewhere, and where it fails, the child runs on as before."""
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


class ServiceStartError(RuntimeError):
    """The device service did not come up."""


START_BUSY_SHARE = 0.05
"""Past its start timeout a service still not serving is waited for while, over each slice
of the wait, it used at least this share of a core: it is compiling (numba, a cold cache: on
an idle machine 133-161 s, more on a busy one), not hung."""
START_SLICE_S = 10.0
"""...judged over slices this long (s)."""


class ServiceProcess:
    """``python -m device device --sim ...`` started and waited for until it serves: for
    ``start_timeout`` seconds, and past it for as long as it is busy (``START_BUSY_SHARE``),
    up to ``start_limit`` in all. ``argv`` replaces the command (a test's stand-in child)."""

    def __init__(
        self,
        *args: str,
        start_timeout: float = 180.0,
        start_limit: float = 900.0,
        slice_s: float = START_SLICE_S,
        argv: list[str] | None = None,
    ) -> None:
        self.argv = argv or [sys.executable, "-m", "device", "device", "--sim", *args]
        # The signal is tied to the thread that forks: only from the main thread, whose
        # end is the process's.
        main = threading.current_thread() is threading.main_thread()
        self.proc = subprocess.Popen(
            self.argv,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            bufsize=1,
            preexec_fn=_die_with_parent if main and sys.platform == "linux" else None,
        )
        self.output: collections.deque[str] = collections.deque(maxlen=OUTPUT_LINES)
        # One thread reads every line for as long as the service lives (a pipe nobody reads
        # fills up, 64 KiB, and the service would block on its next log line, control loop
        # and all) and hands over the link it serves on. Waiting on the pipe with select()
        # and then reading lines does not work: the reader buffers what came in one chunk,
        # and a "serving on" line that arrived with the one before it sat in that buffer,
        # unseen, until the start deadline (600 s in the system tests).
        self._serving: queue.Queue[str | None] = queue.Queue()
        self._reader: threading.Thread | None = threading.Thread(
            target=self._read_on, name="device-output", daemon=True
        )
        self._reader.start()
        self.link = self._wait_for_link(start_timeout, max(start_limit, start_timeout), slice_s)

    def _read_on(self) -> None:
        assert self.proc.stdout is not None
        served = False
        for line in self.proc.stdout:
            self.output.append(line.rstrip("\n"))
            found = None if served else SERVING.search(line)
            if found:
                served = True
                self._serving.put(found.group(1))
        self._serving.put(None)  # its output closed: it has exited

    def _wait_for_link(self, timeout: float, limit: float, slice_s: float) -> str:
        start = time.monotonic()
        cpu = self._cpu_or_zero()
        idle = False
        while True:
            now = time.monotonic()
            left = (start + timeout if now < start + timeout else start + limit) - now
            try:
                link = self._serving.get(timeout=max(0.0, min(slice_s, left)))
            except queue.Empty:  # still running, not serving
                was, cpu = cpu, self._cpu_or_zero()
                elapsed = time.monotonic() - start
                idle = cpu - was < START_BUSY_SHARE * slice_s
                if elapsed < timeout or (elapsed < limit and not idle):
                    continue
                break
            else:
                if link is not None:
                    return link
                with contextlib.suppress(subprocess.TimeoutExpired):
                    self.proc.wait(5.0)  # its output has closed: it is exiting
                break
        waited = time.monotonic() - start
        if self.proc.poll() is None:
            # Hung: its faulthandler prints every thread's stack on SIGABRT.
            why = "idle" if idle else "still busy at the limit"
            how = f"still not serving after {waited:.0f} s, {why}; its stack when stopped:"
            self.proc.send_signal(signal.SIGABRT)
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.proc.wait(10.0)
            if self._reader is not None:
                self._reader.join(10.0)  # the stack, to the end of its output
        elif self.proc.returncode < 0:
            name = signal.Signals(-self.proc.returncode).name
            oom = " (out of memory?)" if name == "SIGKILL" else ""
            how = f"killed by {name}{oom} after {waited:.0f} s:"
        else:
            how = f"exited with code {self.proc.returncode} after {waited:.0f} s:"
        self.stop()
        raise ServiceStartError(
            f"the device service did not start ({how})\n" + "\n".join(list(self.output)[-60:])
        )

    @property
    def pid(self) -> int:
        return self.proc.pid

    def _cpu_or_zero(self) -> float:
        try:
            return self.cpu_seconds()
        except (OSError, IndexError, ValueError):  # gone, or not Linux
            return 0.0

    def cpu_seconds(self) -> float:
        """User + system CPU time the service has used (Linux ``/proc``)."""
        with open(f"/proc/{self.pid}/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        ticks = os.sysconf("SC_CLK_TCK")
        return (int(fields[11]) + int(fields[12])) / ticks

    def stop(self, timeout: float = 10.0) -> int:
        """SIGTERM (the service closes its valves and link), then SIGKILL if it hangs."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self._reader is not None:
            self._reader.join(timeout)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        return self.proc.returncode

    def __enter__(self) -> ServiceProcess:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()
