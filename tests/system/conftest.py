"""Fixtures for the whole-system tests; the helpers live in ``harness``.

Every test here that uses the ``system`` fixture runs on both stacks (``harness.STACKS``),
unless it is marked ``sqlite_only``.
"""

import pytest

from tests.server.redis_server import redis_server, relay_url
from tests.system.harness import STACKS, device_args, stack, system, therapist

__all__ = ["device_args", "redis_server", "relay_url", "stack", "system", "therapist"]


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    if "stack" in metafunc.fixturenames and not metafunc.definition.get_closest_marker(
        "sqlite_only"
    ):
        metafunc.parametrize("stack", STACKS, indirect=True, ids=STACKS)
