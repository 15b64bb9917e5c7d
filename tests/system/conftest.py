"""Fixtures for the whole-system tests; the helpers live in ``harness``."""

from tests.system.harness import system, therapist

__all__ = ["system", "therapist"]
