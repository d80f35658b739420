"""The P_D heat map's colours, one rule for every image of it: heatmap.png (report/plots.py),
pd_overlay.png (report/kml.py) and pd_rgba_3857.tif (report/gis.py). Needs the plots extra
(matplotlib's colour maps) where colours are made."""

from __future__ import annotations

import math

import numpy as np

PD_COLORMAP = "viridis"
"""Matplotlib colour map of P_D, 0 to 1."""
OVERLAY_ALPHA = 170
"""Alpha (0..255) of a free cell in the overlay images; 0 elsewhere."""


def pd_rgba(pd: np.ndarray, mask: np.ndarray, max_side: int) -> tuple[np.ndarray, int]:
    """The free cells' P_D (``pd``, ``mask``: rows growing north) as a north-up RGBA image
    (uint8, rows x cols x 4): PD_COLORMAP of P_D clipped to [0, 1], alpha OVERLAY_ALPHA on
    free cells and 0 elsewhere. Over ``max_side`` cells a side, each pixel is a block of
    ``stride`` x ``stride`` cells (returned with the image) drawn by its free cells'
    largest P_D; the last blocks may reach past the grid (transparent there)."""
    import matplotlib

    values = np.where(mask, np.clip(pd, 0.0, 1.0), -1.0)
    n_rows, n_cols = values.shape
    stride = max(1, math.ceil(max(n_rows, n_cols) / max_side))
    h, w = math.ceil(n_rows / stride), math.ceil(n_cols / stride)
    padded = np.full((h * stride, w * stride), -1.0)
    padded[:n_rows, :n_cols] = values
    blocks = np.flipud(padded.reshape(h, stride, w, stride).max(axis=(1, 3)))  # north up
    rgba = matplotlib.colormaps[PD_COLORMAP](np.clip(blocks, 0.0, 1.0), bytes=True)
    rgba[..., 3] = np.where(blocks >= 0, OVERLAY_ALPHA, 0)
    return rgba, stride
