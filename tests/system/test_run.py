"""``ankle run`` (what ``make run`` starts): the whole system up, and all of it down again
when it is stopped by a signal rather than Ctrl-C."""

from __future__ import annotations

import itertools
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest

from ankle.system import RestartPolicy, StartError, _Child, _Module, _supervise
from tests.system.harness import free_port


def listening(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def _children(pid: int) -> dict[int, str]:
    """The direct children of ``pid``: their pids and command lines."""
    found = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        for child in (task / "children").read_text().split():
            cmdline = Path(f"/proc/{child}/cmdline").read_bytes().replace(b"\0", b" ")
            found[int(child)] = cmdline.decode()
    return found


def _wait_for(
    what: str, check: Callable[[], bool], log: Path, proc: subprocess.Popen[bytes], s: float
) -> None:
    deadline = time.monotonic() + s
    while not check():
        assert proc.poll() is None, log.read_text()
        assert time.monotonic() < deadline, f"{what} within {s} s\n{log.read_text()}"
        time.sleep(0.3)


def test_run_serves_dashboard_and_patient_page_restarts_a_killed_station_and_stops_all_on_sigterm(
    tmp_path: Path,
) -> None:
    port, page_port = free_port(), free_port()
    log = tmp_path / "run.log"
    with log.open("wb") as out:
        proc = subprocess.Popen(
            [
                *(sys.executable, "-m", "ankle", "run", "--data-dir", str(tmp_path / "data")),
                *("--port", str(port), "--page-port", str(page_port)),
            ],
            stdout=out,
            stderr=subprocess.STDOUT,
            env=os.environ.copy(),
        )
    try:
        deadline = time.monotonic() + 90
        while b"is running" not in log.read_bytes() or not listening(page_port):
            assert proc.poll() is None, log.read_text()
            assert time.monotonic() < deadline, log.read_text()
            time.sleep(0.3)
        banner = log.read_text()
        assert f"http://127.0.0.1:{port}/app/" in banner
        assert f"http://127.0.0.1:{page_port}/" in banner
        login = httpx.get(f"http://127.0.0.1:{port}/app/login")
        assert login.status_code == 200 and "Sign in" in login.text
        page = httpx.get(f"http://127.0.0.1:{page_port}/")
        assert page.status_code == 200 and "STOP" in page.text

        # A station killed outright is started again, and its page comes back.
        def stations() -> list[int]:
            return [pid for pid, cmd in _children(proc.pid).items() if " station " in cmd]

        (killed,) = stations()
        os.kill(killed, signal.SIGKILL)

        def restarted() -> bool:
            said = "station was killed by SIGKILL; restarting it" in log.read_text()
            return said and stations() not in ([], [killed]) and listening(page_port)

        _wait_for("the station restarted", restarted, log, proc, 60)
        assert httpx.get(f"http://127.0.0.1:{page_port}/").status_code == 200
        assert httpx.get(f"http://127.0.0.1:{port}/api/v1/health").status_code == 200  # untouched

        # A killed device is started again, and the station with it, on the new link.
        (device,) = [pid for pid, cmd in _children(proc.pid).items() if " device --sim" in cmd]
        os.kill(device, signal.SIGKILL)

        def device_back() -> bool:
            text = log.read_text()
            return (
                "device was killed by SIGKILL; restarting it" in text
                and "restarting the station on the new device" in text
                and len(stations()) == 1
                and listening(page_port)
            )

        _wait_for("the device and the station restarted", device_back, log, proc, 120)

        # Stopped as `timeout make run` stops it: SIGTERM, and make passes on another; an
        # impatient Ctrl-C after. The first starts the orderly stop, the others cannot cut
        # it short (they did: the server and the station were left running).
        proc.send_signal(signal.SIGTERM)
        time.sleep(0.2)
        proc.send_signal(signal.SIGTERM)
        time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30) == 0
        assert "stopped; valves closed" in log.read_text()
        assert "Traceback" not in log.read_text()
        # Its children are gone with it: nothing listens on either port any more.
        assert not listening(port)
        assert not listening(page_port)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_run_refuses_a_taken_page_port_with_a_clear_message(tmp_path: Path) -> None:
    port = free_port()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        page_port = taken.getsockname()[1]
        done = subprocess.run(
            [
                *(sys.executable, "-m", "ankle", "run", "--data-dir", str(tmp_path / "data")),
                *("--port", str(port), "--page-port", str(page_port)),
            ],
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert done.returncode == 1, done.stdout + done.stderr
    assert f"the patient's page cannot listen on 127.0.0.1:{page_port}" in done.stderr
    assert "--page-port" in done.stderr
    assert not listening(port), "nothing may have started"


def test_a_crash_loop_stops_everything_with_a_message_naming_the_child(tmp_path: Path) -> None:
    """Real processes that exit at once: restarted with growing delays, then given up on."""
    out = tmp_path / "out.txt"
    policy = RestartPolicy(first_delay_s=0.05, max_delay_s=0.4, window_s=60, max_restarts=3)
    starts: list[float] = []

    def start() -> _Module:
        starts.append(time.monotonic())
        return _Module("--no-such-command")  # exits with the usage error, 2

    crashing = _Child("device", start)
    crashing.start()
    try:
        with out.open("w") as fh, pytest.raises(StartError) as raised:
            _supervise([crashing], policy, 60, fh)
    finally:
        crashing.stop()
    text = out.read_text()
    assert "the device exited with code 2; restarting it in 0.05 s (restart 1 of at most 3" in text
    assert "restarting it in 0.2 s (restart 3 of at most 3" in text
    assert "3 restarts in 60 s is a crash loop" in str(raised.value)
    assert len(starts) == 4  # the first start and three restarts
    gaps = [b - a for a, b in itertools.pairwise(starts)]
    assert gaps[2] >= 0.2 and gaps[0] >= 0.05  # the delays grew
