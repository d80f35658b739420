"""Performance benchmarks of pdcov (issues 7 and 21): scenarios S1-S5, the reference
implementations R1 (per-pixel ray casting, the paper's Fig. 5), R2 (per-cell projection of the
whole domain every frame) and R3 (per-pixel ray casting into a DEM), the numpy floor, offline
evaluation and the planner.

Run ``python -m benchmarks`` (``--smoke`` for the tiny CI size, ``--write-readme`` to
regenerate the README's results table). docs/performance.md explains the figures.
"""
