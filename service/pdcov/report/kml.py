"""KML 2.2 and KMZ of the exports (report/exports.py) for Google Earth and ATAK, written with
xml.etree: a few Styles, a Folder per layer, Placemarks with ExtendedData, and the P_D
ground overlay.

The overlay is the free cells' P_D in the heat map's colours (report/colours.py),
transparent elsewhere, placed by a ``LatLonBox`` (north, south, east, west in WGS84 degrees,
no rotation): the grid's ENU axes point east and north at the origin, and over a search
area of a few km the meridians converge by far less than a cell. The placemarks' icons are
PNGs of their own (ICONS) written beside the KML. A KMZ is a zip holding ``doc.kml`` first
(Google Earth reads the first .kml), then the overlay and icon PNGs it names: every href is
a relative file name, so no reader fetches anything from the internet.
"""

from __future__ import annotations

import io
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from pdcov.core.geodesy import deg_text, enu_to_geodetic
from pdcov.report.colours import pd_rgba
from pdcov.report.exports import (
    CANDIDATE_COLOR,
    DETECTION_COLOR,
    GAP_COLOR,
    OUTLINE_COLORS,
    REFLY_COLOR,
    Pin,
)
from pdcov.report.search_areas import Coverage, MapLayers, Polygon

KML_NS = "http://www.opengis.net/kml/2.2"
OVERLAY_NAME = "pd_overlay.png"
MAX_OVERLAY_SIDE = 4096
"""Overlay pixels a side at most: a larger grid is shown by the maximum of cell blocks."""
ICONS = {"candidate": ("pin_candidate.png", CANDIDATE_COLOR),
         "detection": ("pin_detection.png", DETECTION_COLOR)}
"""The placemarks' icons by pin kind: (file name, '#rrggbb' colour)."""
ICON_PX = 32
"""Icon side, pixels."""


@dataclass(frozen=True, slots=True)
class Overlay:
    """The overlay PNG and where it lies (degrees)."""

    png: bytes
    north_deg: float
    south_deg: float
    east_deg: float
    west_deg: float


def kml_color(rgb: str, alpha: int = 255) -> str:
    """'#rrggbb' and alpha 0..255 as KML's aabbggrr."""
    r, g, b = rgb[1:3], rgb[3:5], rgb[5:7]
    return f"{alpha:02x}{b}{g}{r}".lower()


def overlay_png(coverage: Coverage) -> Overlay:
    """The P_D overlay of ``coverage`` (report/colours.pd_rgba; needs the plots extra:
    matplotlib's colour maps)."""
    from PIL import Image

    rgba, stride = pd_rgba(coverage.pd, coverage.mask, MAX_OVERLAY_SIDE)
    h, w = rgba.shape[:2]
    buf = io.BytesIO()
    Image.fromarray(rgba, "RGBA").save(buf, format="PNG")
    g = coverage.geometry
    x0, y0 = g.x0_m, g.y0_m
    x1, y1 = x0 + w * stride * g.cell_size_m, y0 + h * stride * g.cell_size_m
    corners = enu_to_geodetic(np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]],
                                       dtype=float), coverage.origin)
    return Overlay(buf.getvalue(), float(corners[:, 0].max()), float(corners[:, 0].min()),
                   float(corners[:, 1].max()), float(corners[:, 1].min()))


def icon_pngs() -> dict[str, bytes]:
    """The ICONS as PNG bytes by file name: a disc of the pin's colour with a white rim,
    ICON_PX a side, transparent around it (drawn 4 times larger, then reduced: smooth
    edges)."""
    from PIL import Image, ImageDraw

    out = {}
    big = 4 * ICON_PX
    for name, color in ICONS.values():
        img = Image.new("RGBA", (big, big), (0, 0, 0, 0))
        ImageDraw.Draw(img).ellipse((4, 4, big - 5, big - 5), fill=color, outline="white",
                                    width=12)
        buf = io.BytesIO()
        img.resize((ICON_PX, ICON_PX), Image.Resampling.LANCZOS).save(buf, format="PNG")
        out[name] = buf.getvalue()
    return out


def _sub(parent: ET.Element, tag: str, text: str | None = None) -> ET.Element:
    e = ET.SubElement(parent, tag)
    if text is not None:
        e.text = text
    return e


def _style(doc: ET.Element, sid: str, color: str, *, fill_alpha: int | None = None,
           icon: str | None = None) -> None:
    s = _sub(doc, "Style")
    s.set("id", sid)
    if icon is not None:  # the PNG has the colour: no IconStyle color to tint it
        i = _sub(s, "IconStyle")
        _sub(_sub(i, "Icon"), "href", icon)
        ET.SubElement(i, "hotSpot", x="0.5", y="0.5", xunits="fraction", yunits="fraction")
        return
    line = _sub(s, "LineStyle")
    _sub(line, "color", kml_color(color))
    _sub(line, "width", "2")
    poly = _sub(s, "PolyStyle")
    _sub(poly, "color", kml_color(color, fill_alpha or 0))
    _sub(poly, "fill", "1" if fill_alpha else "0")


def _coords(ring: list[list[float]]) -> str:
    return " ".join(f"{deg_text(lon)},{deg_text(lat)}" for lon, lat in ring)


def _polygon_placemark(folder: ET.Element, name: str, style: str, poly: Polygon,
                       description: str) -> None:
    pm = _sub(folder, "Placemark")
    _sub(pm, "name", name)
    _sub(pm, "description", description)
    _sub(pm, "styleUrl", f"#{style}")
    p = _sub(pm, "Polygon")
    _sub(p, "tessellate", "1")
    for k, ring in enumerate(poly):
        b = _sub(p, "outerBoundaryIs" if k == 0 else "innerBoundaryIs")
        _sub(_sub(b, "LinearRing"), "coordinates", _coords(ring))


def kml_document(layers: MapLayers | None, all_pins: Sequence[Pin], overlay: Overlay | None,
                 title: str) -> bytes:
    """doc.kml (UTF-8 bytes): the overlay (named OVERLAY_NAME, when given), the outlines,
    gaps and re-fly areas (when ``layers``), candidates and detections as Placemarks."""
    kml = ET.Element("kml", xmlns=KML_NS)
    doc = _sub(kml, "Document")
    _sub(doc, "name", title)
    for k in range(len(layers.outlines) if layers is not None else 0):
        _style(doc, f"outline-{k}", OUTLINE_COLORS[k % len(OUTLINE_COLORS)], fill_alpha=0)
    _style(doc, "gap", GAP_COLOR, fill_alpha=80)
    _style(doc, "refly", REFLY_COLOR, fill_alpha=40)
    for kind, (icon, color) in ICONS.items():
        _style(doc, kind, color, icon=icon)
    if overlay is not None:
        folder = _sub(doc, "Folder")
        _sub(folder, "name", "P_D overlay")
        go = _sub(folder, "GroundOverlay")
        _sub(go, "name", "cumulative P_D")
        _sub(_sub(go, "Icon"), "href", OVERLAY_NAME)
        box = _sub(go, "LatLonBox")
        for tag in ("north", "south", "east", "west"):
            _sub(box, tag, deg_text(getattr(overlay, f"{tag}_deg")))
        _sub(box, "rotation", "0")
    if layers is not None:
        for k, (t, polys) in enumerate(layers.outlines):
            folder = _sub(doc, "Folder")
            _sub(folder, "name", f"P_D >= {t:g}")
            for i, poly in enumerate(polys, start=1):
                _polygon_placemark(folder, f"P_D >= {t:g} ({i})", f"outline-{k}", poly,
                                   f"free cells whose cumulative P_D is at least {t:g}")
        folder = _sub(doc, "Folder")
        _sub(folder, "name", f"gaps (P_D < {layers.target_pd:g})")
        for i, poly in enumerate(layers.gaps, start=1):
            _polygon_placemark(folder, f"gap {i}", "gap", poly,
                               f"free cells below the target P_D {layers.target_pd:g}")
        folder = _sub(doc, "Folder")
        _sub(folder, "name", "re-fly areas")
        for i, a in enumerate(layers.refly, start=1):
            _polygon_placemark(folder, f"re-fly R{i}", "refly", a.polygon,
                               f"{a.gap_cells} cells below P_D {layers.target_pd:g}, "
                               f"{a.area_m2:.0f} m2; POD so far {a.pod:.2f}")
    for kind in ("candidate", "detection"):
        folder = _sub(doc, "Folder")
        _sub(folder, "name", f"{kind}s")
        if kind == "detection":  # every box of every pin: listed, drawn when asked for
            _sub(folder, "visibility", "0")
        for p in all_pins:
            if p.kind != kind:
                continue
            pm = _sub(folder, "Placemark")
            _sub(pm, "name", p.title)
            _sub(pm, "description", p.description)
            _sub(pm, "styleUrl", f"#{kind}")
            data = _sub(pm, "ExtendedData")
            for name, value in p.properties.items():
                d = _sub(data, "Data")
                d.set("name", name)
                _sub(d, "value", "" if value is None else str(value))
            _sub(_sub(pm, "Point"), "coordinates",
                 f"{deg_text(p.lon_deg)},{deg_text(p.lat_deg)}")
    return ET.tostring(kml, encoding="utf-8", xml_declaration=True)


def kmz_bytes(doc_kml: bytes, overlay: Overlay, icons: Mapping[str, bytes]) -> bytes:
    """The KMZ: ``doc.kml`` first, then the overlay and the icon PNGs (``icon_pngs``) it
    refers to."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("doc.kml", doc_kml)
        z.writestr(OVERLAY_NAME, overlay.png)
        for name, png in icons.items():
            z.writestr(name, png)
    return buf.getvalue()
