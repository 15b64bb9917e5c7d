"""``ankle run`` (what ``make run`` starts): the whole system up, and all of it down again
when it is stopped by a signal rather than Ctrl-C."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx

from tests.system.harness import free_port


def listening(port: int) -> bool:
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def test_run_serves_dashboard_and_patient_page_and_stops_all_on_sigterm(tmp_path: Path) -> None:
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

        proc.send_signal(signal.SIGTERM)
        assert proc.wait(30) == 0
        assert "stopped; valves closed" in log.read_text()
        # Its children are gone with it: nothing listens on either port any more.
        assert not listening(port)
        assert not listening(page_port)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
