"""Fixtures for the server tests; the helpers live in ``live_server``."""

from tests.server.live_server import empty, fresh, live, seeded, world

__all__ = ["empty", "fresh", "live", "seeded", "world"]
