"""Performance benchmarks of pdcov (issue 7): scenarios S1-S4, the reference implementations
R1 (per-pixel ray casting, the paper's Fig. 5) and R2 (per-cell projection of the whole
domain every frame), the numpy floor, offline evaluation and the planner.

Run ``python -m benchmarks`` (``--smoke`` for the tiny CI size, ``--write-readme`` to
regenerate the README's results table). docs/performance.md explains the figures.
"""
