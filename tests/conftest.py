"""Shared test settings, and the store fixtures every directory that serves the API uses
(SQLite by default, PostgreSQL too for tests marked ``both_stores``)."""

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
