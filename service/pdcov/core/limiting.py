"""What limited a cell's P_D: the best that any frame of a coverage grid did for it."""

from __future__ import annotations

import enum


class LimitingFactor(enum.IntEnum):
    """What limited a cell's P_D: the best that any frame did for it (the largest code over
    its frames, so grids merge by the maximum). A cell in the picture is 'in view'.

    CANOPY and BUILDING are of cells with something standing on them (core/ground_cover.py),
    so they never meet SEEN on one cell: a cell under trees seen at a size the detector
    model covers is CANOPY (the trees cut its P_D), one under a roof in view within range
    BUILDING (never seen). A cell whose every line of sight a building or the terrain
    blocked is HIDDEN."""

    NEVER_IN_VIEW = 0  # no frame had its centre in the picture
    TOO_FAR = 1  # in view only beyond the maximum slant range
    HIDDEN = 2  # in view within range, but terrain or a building hid it (or it faced away)
    TOO_SMALL = 3  # seen, but always smaller than the detector model's smallest size bin
    TOO_LARGE = 4  # seen, but only larger than its largest bin
    SEEN = 5  # seen at a size the detector model covers
    CANOPY = 6  # under tree cover, seen through it at a size the detector model covers
    BUILDING = 7  # under a roof: in view within range, never seen
