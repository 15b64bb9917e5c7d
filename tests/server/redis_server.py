"""A real Redis for the relay's tests: Debian's ``redis-server`` on a free port, in a temp dir.

Started once per test session; each test that uses it gets an emptied database. A machine
without ``redis-server`` fails these tests with a sentence saying what to install, rather
than skipping them: the relay between processes is part of what is tested.
"""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import redis

from lab import services
from lab.services import free_port as free_port


@contextmanager
def spawned_redis(
    workdir: Path, port: int | None = None
) -> Iterator[tuple[subprocess.Popen[bytes], str]]:
    """A redis-server of its own in ``workdir`` (on ``port``, or a free one), answering: the
    process and its URL."""
    try:
        with services.spawned_redis(workdir, port) as server:
            yield server.proc, server.url
    except services.ServiceError as exc:
        pytest.fail(str(exc))


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
