"""Throwaway services for benchmarks and tests: a private ``redis-server`` on a free port.

Debian's ``redis-server`` in a temp dir, no persistence, bound to loopback; gone when the
context ends. The benchmark reads its CPU time from ``/proc`` like the server's.
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import redis

START_S = 20.0
"""Deadline for redis-server to answer PING on a busy machine."""


class ServiceError(RuntimeError):
    """A throwaway service could not be started; the message says what to do."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@dataclass(frozen=True)
class Redis:
    proc: subprocess.Popen[bytes]
    url: str
    """``redis://127.0.0.1:PORT`` (add ``/DB``)."""


@contextmanager
def spawned_redis(workdir: Path, port: int | None = None) -> Iterator[Redis]:
    """A redis-server of its own in ``workdir``, answering PING, until the context ends; on
    ``port`` (one a stopped one used, to start it again) or a free one."""
    binary = shutil.which("redis-server")
    if binary is None:
        raise ServiceError("redis-server is not installed: apt-get install redis-server (Debian)")
    workdir.mkdir(parents=True, exist_ok=True)
    port = free_port() if port is None else port
    args = [binary, "--port", str(port), "--bind", "127.0.0.1", "--dir", str(workdir)]
    args += ["--save", "", "--appendonly", "no"]
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    url = f"redis://127.0.0.1:{port}"
    try:
        with redis.Redis.from_url(url) as client:
            deadline = time.monotonic() + START_S
            while True:
                try:
                    if client.ping():
                        break
                except redis.ConnectionError:
                    pass
                if proc.poll() is not None:
                    raise ServiceError(f"redis-server exited with code {proc.returncode}")
                if time.monotonic() > deadline:
                    raise ServiceError(f"redis-server did not answer within {START_S:g} s")
                time.sleep(0.05)
        yield Redis(proc, url)
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
