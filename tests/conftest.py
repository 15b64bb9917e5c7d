"""Shared test settings, and the store fixtures every directory that serves the API uses
(SQLite by default, PostgreSQL too for tests marked ``both_stores``)."""

import os
import subprocess
import sys
from collections.abc import Iterator

import pytest
from hypothesis import settings

from tests.server.live_server import parametrize_stores, seeded_store, seeds, store
from tests.server.postgres import pg_cluster, pg_url

__all__ = ["pg_cluster", "pg_url", "seeded_store", "seeds", "store"]

# Hundreds of apps start in this one process: none freezes the collector (server/app.py).
# The servers the system tests start as processes freeze it, as deployed (tests/system).
os.environ.setdefault("ANKLE_GC_FREEZE", "false")

# Hypothesis keeps no example database in the tree; CI runs are reproducible from seeds.
settings.register_profile("project", database=None, deadline=None)
settings.load_profile("project")


WARM_TIMEOUT_S = 1800.0
"""A cold compile takes ~40 s on an idle core; a slow, shared CI machine several times that."""


def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile the device's loops once, before any worker starts (runs ahead of xdist's own
    hook, which starts the workers). Cold, every worker and every device service a test
    starts would compile the same code at the same time: on two busy cores that took one
    service past its start deadline. Warm, each loads the cache in about a second."""
    if hasattr(session.config, "workerinput"):  # a worker: the controller has warmed it
        return
    argv = [sys.executable, "-m", "device", "device", "--sim", "--link", "tcp://127.0.0.1:0"]
    done = subprocess.run(
        [*argv, "--seconds", "0"], capture_output=True, text=True, timeout=WARM_TIMEOUT_S
    )
    if done.returncode != 0:
        raise pytest.UsageError(
            f"the device service does not start (exit {done.returncode}):\n"
            + done.stdout[-4000:]
            + done.stderr[-4000:]
        )


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    parametrize_stores(metafunc)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    """A failed test that ran the whole system shows the tail of every process's log (the
    servers', the station's): a test that failed on a loaded machine is then diagnosable
    from its report, after pytest has removed its temporary folder."""
    outcome = yield
    report = outcome.get_result()  # type: ignore[attr-defined]
    system = getattr(item, "funcargs", {}).get("system")
    if report.failed and system is not None and hasattr(system, "log_tail"):
        report.sections.append(("system logs", system.log_tail()))
