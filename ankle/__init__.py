"""ankle package."""
