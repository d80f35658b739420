"""The handover map, ``map.png`` (the ``plots`` extra): the P_D heat map over an offline
basemap when one is given, the domain, the outline at the target P_D, each vehicle's flown
track in its own colour and the candidates numbered by their rank (report/pin_rank.py: 1 is
the highest p_person, as in every export and report.html). Axes are ENU metres about the
mission origin; the latitude and longitude lines drawn over them are computed exactly
(geodesy, every few pixels), not from a scale, so they hold over a whole county.

The basemap: the tiles of a web-Mercator XYZ set (ground/basemap.py reads folders and
MBTiles) at the zoom nearest the map's pixel, sampled at every map pixel's latitude and
longitude; at most MAX_BASEMAP_TILES tiles are read (a coarser zoom otherwise), each
bounded in size and pixels before it is decoded.
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pdcov.core.domain import Domain, GridGeometry
from pdcov.core.geodesy import Origin, enu_to_geodetic, geodetic_to_enu
from pdcov.report.colours import PD_COLORMAP
from pdcov.report.exports import Pin, VehicleTrack
from pdcov.report.plots import draw_domain, graticule, pyplot, save_figure

MAX_BASEMAP_TILES = 64
"""The most tiles a map reads; more at the best zoom: a coarser one."""
MAX_TILE_SIDE_PX = 1024
"""A tile wider or taller is skipped, not decoded."""
MAX_LABELLED_PINS = 40
"""Candidates past this rank are drawn as dots without their number."""
_MAP_PX = 900  # the basemap's pixels across the map's longer side
_TRACK_COLOURS = ("#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#42d4f4",
                  "#f032e6", "#9a6324", "#000075", "#808000")
_EARTH_M_PER_PX_Z0 = 156_543.033_92  # web Mercator metres a pixel at zoom 0 (256 px tiles)


@dataclass(frozen=True, slots=True)
class BasemapTiles:
    """An offline tile set for the map: ``tile(z, x, y)`` the image bytes of a tile (y from
    the north, as XYZ sets number them; None when the set has none), the ``zooms`` held and
    the ``attribution`` to print."""

    tile: Callable[[int, int, int], bytes | None]
    zooms: tuple[int, ...]
    attribution: str = ""


def web_mercator_tile_xy(lat_deg: np.ndarray, lon_deg: np.ndarray, z: int
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Fractional XYZ tile coordinates (x east, y south from the north edge) at zoom ``z``
    of WGS84 points (the spherical web Mercator of OpenStreetMap's tiles)."""
    n = 2.0 ** z
    lat = np.radians(np.clip(lat_deg, -85.05112878, 85.05112878))
    x = (np.asarray(lon_deg) + 180.0) / 360.0 * n
    return x, (1.0 - np.arcsinh(np.tan(lat)) / math.pi) / 2.0 * n


def _zoom(tiles: BasemapTiles, lat_deg: np.ndarray, lon_deg: np.ndarray, lat0_deg: float,
          pixel_m: float) -> int:
    """The held zoom nearest the map's pixel that needs at most MAX_BASEMAP_TILES tiles."""
    wanted = math.log2(_EARTH_M_PER_PX_Z0 * math.cos(math.radians(lat0_deg)) / pixel_m)
    for z in sorted(tiles.zooms, key=lambda z: (z > round(wanted), abs(z - wanted))):
        tx, ty = web_mercator_tile_xy(lat_deg, lon_deg, z)
        span = (np.ptp(np.floor(tx)) + 1) * (np.ptp(np.floor(ty)) + 1)
        if span <= MAX_BASEMAP_TILES:
            return z
    return min(tiles.zooms)


def _decoded(data: bytes | None) -> np.ndarray | None:
    """An RGB tile (S, S, 3) uint8, None for no tile, an undecodable one or an oversized
    one (its size read from the header before decoding)."""
    if data is None:
        return None
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(data)) as img:
            if max(img.size) > MAX_TILE_SIDE_PX:
                return None
            return np.asarray(img.convert("RGB"))
    except (UnidentifiedImageError, OSError, ValueError):
        return None


def basemap_rgb(tiles: BasemapTiles, lat_deg: np.ndarray, lon_deg: np.ndarray,
                pixel_m: float) -> tuple[np.ndarray | None, int]:
    """The basemap (H, W, 3) uint8 at the points (H, W) of ``lat_deg``, ``lon_deg``
    (pixels of ``pixel_m`` on the ground), white where the set has no tile, and the zoom
    read; None when it has no tile there."""
    z = _zoom(tiles, lat_deg, lon_deg, float(np.mean(lat_deg)), pixel_m)
    tx, ty = web_mercator_tile_xy(lat_deg, lon_deg, z)
    ix, iy = np.floor(tx).astype(np.int64), np.floor(ty).astype(np.int64)
    out = np.full((*lat_deg.shape, 3), 255, np.uint8)
    found = False
    for x, y in sorted(set(zip(ix.ravel().tolist(), iy.ravel().tolist(), strict=True))):
        img = _decoded(tiles.tile(z, x, y)) if 0 <= x < 2 ** z and 0 <= y < 2 ** z else None
        if img is None:
            continue
        found = True
        sel = (ix == x) & (iy == y)
        h, w = img.shape[:2]
        px = np.clip(((tx[sel] - x) * w).astype(np.int64), 0, w - 1)
        py = np.clip(((ty[sel] - y) * h).astype(np.int64), 0, h - 1)
        out[sel] = img[py, px]
    return (out if found else None), z


def _pin_label(p: Pin) -> str:
    rank = p.properties.get("rank")
    return str(rank) if isinstance(rank, int) else "?"


def map_figure(path: str | Path, pd: np.ndarray, mask: np.ndarray, geometry: GridGeometry,
               domain: Domain, origin: Origin, *, title: str,
               outline_enu: Sequence[Sequence[Sequence[Sequence[float]]]] = (),
               threshold: float | None = None, tracks: Sequence[VehicleTrack] = (),
               pins: Sequence[Pin] = (), basemap: BasemapTiles | None = None) -> bool:
    """Write map.png (``pd``, ``mask`` and ``outline_enu`` as heatmap_figure's; ``pins``
    the exported ones, of which the candidates are drawn); False when ``basemap`` has no
    tile over the map (drawn without it), else True."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8.0, 7.2))
    x0, x1, y0, y1 = geometry.extent_enu
    pad = 0.05 * max(x1 - x0, y1 - y0)
    bounds = (x0 - pad, x1 + pad, y0 - pad, y1 + pad)
    alpha, basemap_drawn = 1.0, basemap is None
    if basemap is not None:
        pixel_m = max(bounds[1] - bounds[0], bounds[3] - bounds[2]) / _MAP_PX
        xs = np.arange(bounds[0] + pixel_m / 2, bounds[1], pixel_m)
        ys = np.arange(bounds[2] + pixel_m / 2, bounds[3], pixel_m)
        ex, ny = np.meshgrid(xs, ys)
        lla = enu_to_geodetic(np.stack([ex, ny, np.zeros_like(ex)], axis=-1), origin)
        rgb, _ = basemap_rgb(basemap, lla[..., 0], lla[..., 1], pixel_m)
        if rgb is not None:
            ax.imshow(rgb, origin="lower", extent=(xs[0] - pixel_m / 2, xs[-1] + pixel_m / 2,
                                                   ys[0] - pixel_m / 2, ys[-1] + pixel_m / 2),
                      interpolation="bilinear")
            alpha, basemap_drawn = 0.6, True
            if basemap.attribution:
                ax.text(0.99, 0.01, basemap.attribution, transform=ax.transAxes, fontsize=6,
                        ha="right", va="bottom", backgroundcolor=(1, 1, 1, 0.7))
    shown = np.where(mask, pd, np.nan).astype(np.float32)
    im = ax.imshow(shown, origin="lower", extent=(x0, x1, y0, y1), cmap=PD_COLORMAP, vmin=0,
                   vmax=1, interpolation="nearest", alpha=alpha)
    fig.colorbar(im, ax=ax, label="cumulative probability of detection $P_D$", shrink=0.8)
    draw_domain(ax, domain)
    for k, poly in enumerate(outline_enu):
        for ring in poly:
            r = np.asarray(ring)
            ax.plot(r[:, 0], r[:, 1], color="deepskyblue", lw=1.4,
                    label=f"$P_D \\geq {threshold:g}$" if k == 0 and ring is poly[0] else None)
    for i, track in enumerate(tracks):
        colour = _TRACK_COLOURS[i % len(_TRACK_COLOURS)]
        for j, seg in enumerate(track.segments):
            lla = seg.lat_lon_alt
            enu = geodetic_to_enu(lla[:, 0], lla[:, 1], origin.ground_alt_msl_m, origin)
            ax.plot(enu[:, 0], enu[:, 1], color=colour, lw=1.0,
                    label=f"{track.vehicle} track" if j == 0 else None)
    ranked = sorted((p for p in pins if p.kind == "candidate"),
                    key=lambda p: p.properties.get("rank") or math.inf)
    if ranked:
        enu = geodetic_to_enu(np.array([p.lat_deg for p in ranked]),
                              np.array([p.lon_deg for p in ranked]),
                              origin.ground_alt_msl_m, origin)
        ax.scatter(enu[:, 0], enu[:, 1], s=22, c="white", edgecolors="black", zorder=5,
                   label="candidates (number: rank by p_person)")
        for p, (x, y, _) in zip(ranked[:MAX_LABELLED_PINS], enu, strict=False):
            ax.annotate(_pin_label(p), (x, y), textcoords="offset points", xytext=(4, 4),
                        fontsize=7, fontweight="bold", zorder=6,
                        bbox={"boxstyle": "round,pad=0.15", "fc": "white", "alpha": 0.8})
    graticule(ax, bounds, origin)
    ax.set_xlim(bounds[0], bounds[1])
    ax.set_ylim(bounds[2], bounds[3])
    ax.set_aspect("equal")
    ax.set_xlabel("east of the origin (m)")
    ax.set_ylabel("north of the origin (m)")
    ax.set_title(title)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.09), ncol=3, fontsize=8,
              frameon=False)
    save_figure(fig, path)
    return basemap_drawn
