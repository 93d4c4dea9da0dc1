"""The depth methods."""
