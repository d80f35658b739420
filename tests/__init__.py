"""pdcov's tests, one folder per tier (CONTRIBUTING.md "Tests")."""
