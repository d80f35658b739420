"""pdcov: cumulative probability-of-detection coverage for search-and-rescue UAVs.

The core (camera, rotations, pose, footprint, detector, domain, grid) is pure: numpy,
OpenCV and shapely in, values out. The edges (config, logs, CLI, plots) adapt the world
to it. See DESIGN.md in the project for the method and the frames.
"""

__version__ = "0.1.0"
