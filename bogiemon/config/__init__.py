"""Shipped data: the default config, the DBC, vehicle parameter files (no code)."""
