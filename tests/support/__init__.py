"""The tests' shared helpers and fixtures, imported as ``tests.support.X`` from every tier and
by the benchmarks."""
