"""The simulators tier (tests/conftest.py)."""
