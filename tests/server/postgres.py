"""A real PostgreSQL 15 cluster for the tests, from Debian's ``postgresql`` package.

One cluster per test session, in a temporary directory, on a free port with its socket
beside it. PostgreSQL refuses to run as root, so when the tests run as root the cluster
belongs to the ``postgres`` account and its programs run through ``runuser``. Each test gets
its own database, cloned from a template (``CREATE DATABASE ... TEMPLATE``), so tests never
see each other's rows. Missing programs fail the tests that need them: they never skip.
"""

from __future__ import annotations

import contextlib
import os
import pwd
import shutil
import signal
import socket
import subprocess
import tempfile
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

PG_BIN = Path(os.environ.get("ANKLE_TEST_PG_BIN", "/usr/lib/postgresql/15/bin"))
OWNER = "postgres"
"""The account the cluster runs as when the tests run as root."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


class Cluster:
    """A running PostgreSQL server the tests own: databases by name, stop and start."""

    def __init__(self, root: Path) -> None:
        for program in ("initdb", "pg_ctl", "postgres", "psql"):
            if not (PG_BIN / program).is_file():
                raise RuntimeError(
                    f"PostgreSQL's {program} is not in {PG_BIN}: install Debian's postgresql "
                    "package (apt-get install postgresql), or set ANKLE_TEST_PG_BIN"
                )
        self.root = root
        self.data = root / "data"
        self.port = free_port()
        self._as_owner: list[str] = []
        if os.geteuid() == 0:
            pw = pwd.getpwnam(OWNER)
            os.chown(root, pw.pw_uid, pw.pw_gid)
            self._as_owner = ["runuser", "-u", OWNER, "--"]
        self._run(
            PG_BIN / "initdb",
            "-D",
            self.data,
            "-U",
            "postgres",
            "--auth=trust",
            "--encoding=UTF8",
            "--no-sync",
        )
        self.start()

    def _run(self, *argv: object) -> str:
        out = subprocess.run(
            [*self._as_owner, *map(str, argv)], capture_output=True, text=True, check=False
        )
        if out.returncode != 0:
            raise RuntimeError(f"{argv[0]} failed ({out.returncode}): {out.stderr or out.stdout}")
        return out.stdout

    def start(self) -> None:
        options = (
            f"-p {self.port} -k {self.root} -c listen_addresses=127.0.0.1 -c fsync=off "
            "-c full_page_writes=off -c synchronous_commit=off -c max_connections=200"
        )
        self._run(
            PG_BIN / "pg_ctl",
            "-D",
            self.data,
            "-o",
            options,
            "-l",
            self.root / "log",
            "-w",
            "start",
        )

    def stop(self, mode: str = "fast") -> None:
        self._run(PG_BIN / "pg_ctl", "-D", self.data, "-m", mode, "-w", "stop")

    def restart(self) -> None:
        """Stop at once (every connection dropped, as in a crash) and start again."""
        self.stop("immediate")
        self.start()

    @contextlib.contextmanager
    def frozen(self) -> Iterator[None]:
        """The cluster's processes stopped (SIGSTOP) for the block, then resumed: a server
        that accepts connections and answers nothing, as one swapping or stuck on its disk."""
        postmaster = int((self.data / "postmaster.pid").read_text().split()[0])
        children = subprocess.run(
            ["pgrep", "-P", str(postmaster)], capture_output=True, text=True, check=False
        ).stdout.split()
        pids = [postmaster, *map(int, children)]
        for pid in pids:
            os.kill(pid, signal.SIGSTOP)
        try:
            yield
        finally:
            for pid in pids:
                os.kill(pid, signal.SIGCONT)

    def psql(self, sql: str, database: str = "postgres") -> str:
        """Run ``sql`` as the superuser; the rows as psql prints them unaligned."""
        out = subprocess.run(
            [
                str(PG_BIN / "psql"),
                "-h",
                "127.0.0.1",
                "-p",
                str(self.port),
                "-U",
                "postgres",
                "-d",
                database,
                "-v",
                "ON_ERROR_STOP=1",
                "-XAtq",
                "-c",
                sql,
            ],
            capture_output=True,
            text=True,
            check=False,
        )
        if out.returncode != 0:
            raise RuntimeError(out.stderr.strip())
        return out.stdout

    def url(self, database: str) -> str:
        return f"postgresql+asyncpg://postgres@127.0.0.1:{self.port}/{database}"

    def create_database(self, template: str | None = None) -> str:
        """A new empty database (or a copy of ``template``); its name."""
        name = f"t_{uuid.uuid4().hex[:16]}"
        clause = f" TEMPLATE {template}" if template else " TEMPLATE template0"
        self.psql(f"CREATE DATABASE {name}{clause}")
        return name

    def drop_database(self, name: str) -> None:
        self.psql(f"DROP DATABASE IF EXISTS {name} WITH (FORCE)")

    def wait_ready(self, timeout: float = 60.0) -> None:
        deadline = time.monotonic() + timeout
        while True:
            try:
                self.psql("SELECT 1")
                return
            except RuntimeError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.1)


@pytest.fixture(scope="session")
def pg_cluster() -> Iterator[Cluster]:
    """The session's PostgreSQL server; fails (never skips) when PostgreSQL is missing."""
    # A short path: the socket's full name must fit in 107 bytes.
    root = Path(tempfile.mkdtemp(prefix="ankle-pg-"))
    cluster = None
    try:
        cluster = Cluster(root)
        yield cluster
    finally:
        if cluster is not None:
            with contextlib.suppress(RuntimeError):  # a failed test left it stopped
                cluster.stop("immediate")
        shutil.rmtree(root, ignore_errors=True)


@pytest.fixture
def pg_url(pg_cluster: Cluster) -> Iterator[str]:
    """The URL of a new, empty database of its own for one test."""
    name = pg_cluster.create_database()
    yield pg_cluster.url(name)
    pg_cluster.drop_database(name)
