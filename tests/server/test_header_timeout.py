"""Connections that never finish a request are closed by the server alone (no proxy in front),
while everyone else is served: a request's headers within ``header_timeout_s`` of their
first byte, however slowly they trickle in, and a new connection that sends nothing within
``keep_alive_s`` (``server.protocols``)."""

from __future__ import annotations

import http.client
import os
import select
import socket
import subprocess
import sys
import time
from pathlib import Path

from server.cli import wait_healthy
from tests.processes import free_port, stop

HEADER_TIMEOUT_S = 3.0
KEEP_ALIVE_S = 2
GIVE_UP_S = 120.0
"""A busy machine closes late, never this late: the bounds are asserted from below only."""


def _closed(sock: socket.socket) -> bool:
    """Whether the server has closed ``sock`` (a read would not block and gives nothing)."""
    if not select.select([sock], [], [], 0)[0]:
        return False
    try:
        return sock.recv(1024) == b""
    except ConnectionError:
        return True


def test_unfinished_requests_are_closed_after_their_bounds_and_others_are_served(
    tmp_path: Path,
) -> None:
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("ANKLE_")}
    env["ANKLE_HEADER_TIMEOUT_S"] = str(HEADER_TIMEOUT_S)
    env["ANKLE_KEEP_ALIVE_S"] = str(KEEP_ALIVE_S)
    proc = subprocess.Popen(
        [sys.executable, "-m", "ankle", "server", "--data-dir", "data", "--port", str(port)],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    stuck: dict[str, tuple[socket.socket, float, float]] = {}  # name: socket, start, bound
    try:
        wait_healthy(f"http://127.0.0.1:{port}", proc, timeout=120)
        for name, first in (
            ("partial", b"GET /api/v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n"),
            ("trickle", b"GET /api/v1/health HTTP/1.1\r\nX-Slow: "),
            ("silent", b""),
        ):
            start = time.monotonic()  # before the connection exists: bounds hold from here
            sock = socket.create_connection(("127.0.0.1", port), timeout=30)
            sock.sendall(first)
            stuck[name] = (sock, start, KEEP_ALIVE_S if not first else HEADER_TIMEOUT_S)

        # Meanwhile a client is served, one sending its headers in two parts among them.
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
        conn.request("GET", "/api/v1/health")
        assert conn.getresponse().status == 200
        conn.close()
        with socket.create_connection(("127.0.0.1", port), timeout=30) as split:
            split.sendall(b"GET /api/v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n")
            time.sleep(0.5)
            split.sendall(b"Connection: close\r\n\r\n")
            answer = split.makefile("rb").read()
        assert answer.startswith(b"HTTP/1.1 200 "), answer[:200]

        closed_after: dict[str, float] = {}
        began = min(start for _, start, _ in stuck.values())
        while len(closed_after) < len(stuck):
            now = time.monotonic()
            for name, (sock, start, _) in stuck.items():
                if name in closed_after:
                    continue
                gone = _closed(sock)
                if not gone and name == "trickle":
                    try:
                        sock.sendall(b"x")  # a byte now and then: the headers never end
                    except ConnectionError:
                        gone = True
                if gone:
                    closed_after[name] = time.monotonic() - start
            open_ = sorted(set(stuck) - set(closed_after))
            assert now - began < GIVE_UP_S, f"still open after {GIVE_UP_S:g} s: {open_}"
            time.sleep(0.2)
        for name, (_, _, bound) in stuck.items():
            assert closed_after[name] >= bound, (name, closed_after[name], bound)
    finally:
        for sock, _, _ in stuck.values():
            sock.close()
        stop(proc)
