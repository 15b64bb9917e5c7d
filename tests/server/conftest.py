"""Fixtures for the server tests; the helpers live in ``live_server`` and ``redis_server``."""

from tests.server.live_server import empty, fresh, live, seeded, world
from tests.server.redis_server import redis_server, relay_url

__all__ = ["empty", "fresh", "live", "redis_server", "relay_url", "seeded", "world"]
