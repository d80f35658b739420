"""The browsers tier (tests/conftest.py)."""
