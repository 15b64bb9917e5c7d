"""Idle HTTP connections: it is never the server that closes one under a client's request.

A client (httpx, a browser, a proxy's pool) reuses an idle connection for its next request.
If the server gives idle connections up first, a request sent as it closes one is lost:
"server disconnected without sending a response", a 502 behind a proxy. The server's
``keep_alive_s`` must outlast every idle timeout in front of it, and must reach uvicorn."""

from __future__ import annotations

import http.client
import os
import re
import subprocess
import sys
from pathlib import Path

import httpx

from server.cli import wait_healthy
from server.config import Settings
from tests.processes import free_port, stop

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


def _health(conn: http.client.HTTPConnection) -> int:
    """One GET on ``conn``'s connection, read whole so that the connection can be reused."""
    conn.request("GET", "/api/v1/health")
    response = conn.getresponse()
    response.read()
    return response.status


def test_the_server_outlasts_the_clients_and_proxies_idle_connections() -> None:
    keep = Settings().keep_alive_s
    expiry = httpx.Limits().keepalive_expiry
    assert expiry is not None and keep > expiry
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
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
            try:
                assert _health(conn) == 200, keep
                sock = conn.sock
                assert sock is not None
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
                    assert _health(conn) == 200
                    assert conn.sock is sock, "the second request took a new connection"
            finally:
                conn.close()
        finally:
            stop(proc)
