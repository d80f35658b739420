"""The slow tier (tests/conftest.py)."""
