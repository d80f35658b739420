"""Figures (matplotlib, the ``plots`` extra): the paper's Fig. 5 ray-count map, Fig. 7 heat
map, the threshold curve and Fig. 8's comparison. Axes are ENU metres (east right, north up).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pdcov.atomic import atomic_path
from pdcov.core.domain import Domain, GridGeometry
from pdcov.core.geodesy import Origin, enu_to_geodetic
from pdcov.extras import PLOTS
from pdcov.report.colours import PD_COLORMAP


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend (no display); ExtraMissing without the extra."""
    PLOTS.require()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: Any, path: str | Path) -> None:
    """``fig`` as a PNG at ``path`` (atomically), then closed."""
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=130, bbox_inches="tight")
    pyplot().close(fig)


def draw_domain(ax: Any, domain: Domain) -> None:
    """The domain's boundary and its obstacles, in ENU metres."""
    x, y = domain.boundary.exterior.xy
    ax.plot(x, y, color="black", lw=1.5, label="search domain")
    for i, obstacle in enumerate(domain.obstacles):
        x, y = obstacle.exterior.xy
        ax.fill(x, y, facecolor="0.35", edgecolor="black", lw=1.0,
                label="obstacle" if i == 0 else None)


def nice_step_deg(span_deg: float) -> float:
    """A graticule step giving 3 to 8 lines over ``span_deg``."""
    for step in (1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0):
        if span_deg / step <= 8:
            return step
    return 2.0


def graticule(ax: Any, bounds: tuple[float, float, float, float], origin: Origin) -> None:
    """Lines of constant latitude and longitude (WGS84, exact: curved where the ENU plane
    bends them) over the ENU extent ``bounds`` (x0, x1, y0, y1 m about ``origin``),
    labelled in degrees."""
    x0, x1, y0, y1 = bounds
    xs, ys = np.meshgrid(np.linspace(x0, x1, 80), np.linspace(y0, y1, 80))
    lla = enu_to_geodetic(np.stack([xs, ys, np.zeros_like(xs)], axis=-1), origin)
    for values, hemispheres in ((lla[..., 0], "NS"), (lla[..., 1], "EW")):
        step = nice_step_deg(float(np.ptp(values)))
        levels = np.arange(math.ceil(values.min() / step), math.floor(values.max() / step) + 1
                           ) * step
        if not len(levels):
            continue
        decimals = max(0, -math.floor(math.log10(step)))
        lines = ax.contour(xs, ys, values, levels=levels, colors="0.25", linewidths=0.5,
                           linestyles=":")
        ax.clabel(lines, fontsize=6, fmt=lambda v, d=decimals, h=hemispheres:
                  f"{abs(v):.{d}f}°{h[0] if v >= 0 else h[1]}")


def heatmap_figure(path: str | Path, pd: np.ndarray, mask: np.ndarray,
                   geometry: GridGeometry, domain: Domain, *, title: str,
                   outline_enu: Sequence[Sequence[Sequence[Sequence[float]]]] = (),
                   threshold: float | None = None, track_enu: np.ndarray | None = None,
                   plan_enu: np.ndarray | None = None, terrain_z_m: np.ndarray | None = None,
                   hidden: np.ndarray | None = None, origin: Origin | None = None) -> None:
    """Fig. 7: cumulative P_D per cell with a colour bar, the domain and obstacles, the
    planned path, the flown track (NaN rows break it) and the outline of the cells at or
    above ``threshold``, on axes of ENU metres, with the latitude and longitude lines
    (``graticule``) when the ``origin`` is given. With ``terrain_z_m`` (cell-centre
    heights, m) the P_D is drawn over the terrain's hillshade; ``hidden`` (bool per cell)
    marks the cells terrain hid from every frame."""
    from matplotlib.colors import LightSource, ListedColormap
    from matplotlib.patches import Patch

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 6.5))
    x0, x1, y0, y1 = geometry.extent_enu
    extent = (x0, x1, y0, y1)
    alpha = 1.0
    if terrain_z_m is not None:
        # Light from the north-west, as maps are shaded; rows grow north, the image's down.
        shade = LightSource(azdeg=315, altdeg=45).hillshade(
            np.flipud(terrain_z_m), dx=geometry.cell_size_m, dy=geometry.cell_size_m)
        ax.imshow(np.flipud(shade), origin="lower", extent=extent, cmap="gray", vmin=0,
                  vmax=1, interpolation="bilinear")
        alpha = 0.75
    # float32 with NaN (drawn transparent) costs a fraction of a masked float64 array.
    shown = np.where(mask, pd, np.nan).astype(np.float32)
    im = ax.imshow(shown, origin="lower", extent=extent, cmap=PD_COLORMAP, vmin=0,
                   vmax=1, interpolation="nearest", alpha=alpha)
    fig.colorbar(im, ax=ax, label="cumulative probability of detection $P_D$", shrink=0.85)
    draw_domain(ax, domain)
    legend_extra = []
    if hidden is not None and hidden.any():
        ax.imshow(np.where(hidden & mask, 1.0, np.nan).astype(np.float32), origin="lower",
                  extent=extent, cmap=ListedColormap(["crimson"]), vmin=0, vmax=1,
                  interpolation="nearest", alpha=0.8)
        legend_extra.append(Patch(facecolor="crimson", alpha=0.8, label="hidden by terrain"))
    if plan_enu is not None and len(plan_enu):
        ax.plot(plan_enu[:, 0], plan_enu[:, 1], "--", color="magenta", lw=1.3, label="plan")
    if track_enu is not None and len(track_enu):
        ax.plot(track_enu[:, 0], track_enu[:, 1], color="orangered", lw=1.0,
                label="flown track")
    for k, poly in enumerate(outline_enu):
        for ring in poly:
            r = np.asarray(ring)
            ax.plot(r[:, 0], r[:, 1], color="deepskyblue", lw=1.6,
                    label=f"$P_D \\geq {threshold:g}$" if k == 0 and ring is poly[0] else None)
    pad = 0.05 * max(x1 - x0, y1 - y0)
    bounds = (x0 - pad, x1 + pad, y0 - pad, y1 + pad)
    if origin is not None:
        graticule(ax, bounds, origin)
    ax.set_xlim(*bounds[:2])
    ax.set_ylim(*bounds[2:])
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)" if origin is None else "east of the origin (m)")
    ax.set_ylabel("north (m)" if origin is None else "north of the origin (m)")
    ax.set_title(title)
    ax.legend(handles=ax.get_legend_handles_labels()[0] + legend_extra,
              loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=5, fontsize=8,
              frameon=False)
    save_figure(fig, path)


def proportion_curve(pd: np.ndarray, mask: np.ndarray, n: int = 201
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Thresholds 0..1 and the proportion of free cells with P_D at or above each."""
    t = np.linspace(0.0, 1.0, n)
    values = np.sort(pd[mask])
    if len(values) == 0:
        return t, np.zeros_like(t)
    return t, 1.0 - np.searchsorted(values, t, side="left") / len(values)


def proportions_at_or_above(pd: np.ndarray, mask: np.ndarray,
                            thresholds: Sequence[float]) -> list[float]:
    """Proportion of free cells with P_D at or above each threshold (0 without free cells)."""
    values = pd[mask]
    return [float((values >= t).mean()) if len(values) else 0.0 for t in thresholds]


def thresholds_figure(path: str | Path, curve: tuple[np.ndarray, np.ndarray],
                      shares: dict[float, float], *, title: str) -> None:
    """Proportion of free cells at or above each P_D threshold: ``curve`` (thresholds
    0..1 and the proportions, report/output_extent.py) and the configured thresholds'
    shares marked (``Metrics.proportion_at_or_above``), their values in a legend (one
    line each: labels beside close markers of similar shares would overlap)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    t, p = curve
    ax.plot(t, p, color="navy", lw=2)
    markers = "osD^vP*Xph"
    for k, (th, share) in enumerate(sorted(shares.items())):
        ax.plot([th], [share], markers[k % len(markers)], color="crimson", ls="none",
                label=f"{share:.3f} at $P_D \\geq {th:g}$")
    if shares:
        ax.legend(loc="lower left", fontsize=9, title="share of free cells",
                  title_fontsize=9)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("$P_D$ threshold")
    ax.set_ylabel("proportion of free cells at or above")
    ax.grid(alpha=0.3)
    ax.set_title(title)
    save_figure(fig, path)


def compare_figure(path: str | Path, runs: Sequence[tuple[str, np.ndarray, np.ndarray]],
                   thresholds: Sequence[float]) -> None:
    """Fig. 8: per run (name, pd, mask) the proportion at each threshold as grouped bars,
    beside the full proportion curves."""
    plt = pyplot()
    fig, (ax_bar, ax_curve) = plt.subplots(1, 2, figsize=(12, 4.6))
    width = 0.8 / max(len(runs), 1)
    x = np.arange(len(thresholds))
    for i, (name, pd, mask) in enumerate(runs):
        shares = proportions_at_or_above(pd, mask, thresholds)
        bars = ax_bar.bar(x + (i - (len(runs) - 1) / 2) * width, shares, width, label=name)
        ax_bar.bar_label(bars, fmt="%.3f", fontsize=7, rotation=90, padding=2)
        t, p = proportion_curve(pd, mask)
        ax_curve.plot(t, p, lw=1.8, label=name)
    ax_bar.set_xticks(x, [f"$P_D \\geq {t:g}$" for t in thresholds])
    ax_bar.set_ylim(0, 1.15)
    ax_bar.set_ylabel("proportion of free cells")
    ax_bar.set_title("cells reaching each threshold")
    ax_bar.legend(fontsize=8)
    ax_curve.set_xlim(0, 1)
    ax_curve.set_ylim(0, 1.02)
    ax_curve.set_xlabel("$P_D$ threshold")
    ax_curve.set_ylabel("proportion at or above")
    ax_curve.grid(alpha=0.3)
    ax_curve.set_title("proportion over thresholds")
    save_figure(fig, path)


def ray_count_figure(path: str | Path, counts: np.ndarray, geometry: GridGeometry,
                     footprint_xy: np.ndarray | None, camera_xy: Sequence[float] | np.ndarray, *,
                     title: str) -> None:
    """Fig. 5: rays from the camera's pixels meeting the ground, counted per cell."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 6))
    x0, x1, y0, y1 = geometry.extent_enu
    shown = np.ma.masked_where(counts == 0, counts)
    im = ax.imshow(shown, origin="lower", extent=(x0, x1, y0, y1), cmap="magma",
                   interpolation="nearest")
    fig.colorbar(im, ax=ax, label="pixel rays per cell", shrink=0.85)
    if footprint_xy is not None and len(footprint_xy):
        ax.plot(footprint_xy[:, 0], footprint_xy[:, 1], color="deepskyblue", lw=1.2,
                label="footprint")
    ax.plot([camera_xy[0]], [camera_xy[1]], "w+", ms=12, mew=2, label="camera (nadir point)")
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_title(title)
    ax.legend(loc="upper right", fontsize=8)
    save_figure(fig, path)
