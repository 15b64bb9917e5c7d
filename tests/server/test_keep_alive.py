"""Idle HTTP connections: it is never the server that closes one under a client's request.

A client (httpx, a browser, a proxy's pool) reuses an idle connection for its next request.
If the server gives idle connections up first, a request sent as it closes one is lost:
"server disconnected without sending a response", a 502 behind a proxy. The server's
``keep_alive_s`` must outlast every idle timeout in front of it, and must reach uvicorn."""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
from pathlib import Path

import httpx

from server.cli import wait_healthy
from server.config import Settings
from tests.processes import free_port, stop

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"

REQUEST = b"GET /api/v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: keep-alive\r\n\r\n"


def _answer(sock: socket.socket) -> bytes:
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(4096)
        if not chunk:
            return data
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    length = int(re.search(rb"content-length: (\d+)", head, re.IGNORECASE).group(1))  # type: ignore[union-attr]
    while len(body) < length:
        body += sock.recv(4096)
    return head


def test_the_server_outlasts_the_clients_and_proxies_idle_connections() -> None:
    keep = Settings().keep_alive_s
    assert keep > httpx.Limits().keepalive_expiry  # type: ignore[operator]
    nginx = (DEPLOY / "nginx" / "ankle.conf").read_text()
    (upstream,) = re.findall(r"^\s*keepalive_timeout (\d+)s;", nginx, re.MULTILINE)
    caddy = (DEPLOY / "caddy" / "Caddyfile").read_text()
    (pool,) = re.findall(r"^\s*keepalive (\d+)s$", caddy, re.MULTILINE)
    assert int(upstream) < keep and int(pool) < keep, (upstream, pool, keep)


def test_the_keep_alive_setting_reaches_the_real_server(tmp_path: Path) -> None:
    """With ANKLE_KEEP_ALIVE_S=1 a real ``ankle server`` closes an idle connection by
    itself (the read below ends with nothing); with the default it answers a second request
    on a connection left idle longer than uvicorn's own default (5 s)."""
    for keep, idle in ((1, None), (None, 6.0)):
        port = free_port()
        env = {k: v for k, v in os.environ.items() if not k.startswith("ANKLE_")}
        if keep is not None:
            env["ANKLE_KEEP_ALIVE_S"] = str(keep)
        proc = subprocess.Popen(
            [sys.executable, "-m", "ankle", "server", "--data-dir", "data", "--port", str(port)],
            cwd=tmp_path,
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            wait_healthy(f"http://127.0.0.1:{port}", proc, timeout=120)
            with socket.create_connection(("127.0.0.1", port), timeout=30) as sock:
                sock.sendall(REQUEST)
                assert _answer(sock).startswith(b"HTTP/1.1 200"), keep
                if idle is None:
                    assert sock.recv(1) == b"", "the server should have closed the idle link"
                else:
                    sock.settimeout(idle)
                    try:
                        closed = sock.recv(1) == b""
                    except TimeoutError:
                        closed = False
                    assert not closed, f"closed within {idle} s with the default keep-alive"
                    sock.settimeout(30)
                    sock.sendall(REQUEST)
                    assert _answer(sock).startswith(b"HTTP/1.1 200")
        finally:
            stop(proc)
