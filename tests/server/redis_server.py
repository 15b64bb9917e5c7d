"""A real Redis for the relay's tests: Debian's ``redis-server`` on a free port, in a temp dir.

Started once per test session; each test that uses it gets an emptied database. A machine
without ``redis-server`` fails these tests with a sentence saying what to install, rather
than skipping them: the relay between processes is part of what is tested.
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import redis

START_S = 20.0
"""Deadline for redis-server to answer PING on a busy machine."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@contextmanager
def spawned_redis(workdir: Path) -> Iterator[tuple[subprocess.Popen[bytes], str]]:
    """A redis-server of its own in ``workdir``, answering: the process and its URL."""
    binary = shutil.which("redis-server")
    if binary is None:
        pytest.fail("redis-server is not installed: apt-get install redis-server (Debian)")
    port = free_port()
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
                    pytest.fail(f"redis-server exited with code {proc.returncode}")
                if time.monotonic() > deadline:
                    pytest.fail(f"redis-server did not answer within {START_S:g} s")
                time.sleep(0.05)
        yield proc, url
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


@pytest.fixture(scope="session")
def redis_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The base URL of a private redis-server (``redis://127.0.0.1:PORT``) for the session."""
    with spawned_redis(tmp_path_factory.mktemp("redis")) as (_, url):
        yield url


@pytest.fixture
def relay_url(redis_server: str) -> str:
    """The relay URL of an emptied Redis database, for one test."""
    url = f"{redis_server}/0"
    with redis.Redis.from_url(url) as client:
        client.flushdb()
    return url
