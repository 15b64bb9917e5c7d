"""Shared test settings, and the store fixtures every directory that serves the API uses
(SQLite by default, PostgreSQL too for tests marked ``both_stores``)."""

from collections.abc import Iterator

import pytest
from hypothesis import settings

from tests.server.live_server import parametrize_stores, seeded_store, seeds, store
from tests.server.postgres import pg_cluster, pg_url

__all__ = ["pg_cluster", "pg_url", "seeded_store", "seeds", "store"]

# Hypothesis keeps no example database in the tree; CI runs are reproducible from seeds.
settings.register_profile("project", database=None, deadline=None)
settings.load_profile("project")


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
