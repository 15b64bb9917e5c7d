"""Shared test settings."""

from hypothesis import settings

# Hypothesis keeps no example database in the tree; CI runs are reproducible from seeds.
settings.register_profile("project", database=None, deadline=None)
settings.load_profile("project")
