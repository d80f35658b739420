"""Exports for the tools search teams use, written by ``pdcov evaluate`` (in the run folder)
and ``pdcov watch --record DIR`` (in DIR/exports/), from the same builders
(docs/outputs.md "Exports"):

* ``detections.geojson``: RFC 7946 FeatureCollection, a Point per candidate and per
  detection, every one (WGS84 [lon, lat]; written feature by feature, so that a watcher's
  detections stream from its log on disk);
* ``caltopo.geojson``: the same map for CalTopo / SARTopo's GeoJSON import: P_D outlines and
  gaps as ``Shape`` polygons with stroke and fill, candidates as ``Marker`` points, re-fly
  areas as ``Assignment`` polygons (the properties CalTopo itself writes in its exports);
* ``pdcov.kml`` with ``pd_overlay.png`` and the pins' icon PNGs beside it, and ``pdcov.kmz``
  (the same ``doc.kml`` and PNGs zipped): a P_D ground overlay and the same features, for
  Google Earth and ATAK (report/kml.py; no file refers to the internet);
* ``pdcov_atak.zip``: a TAK data package of the KMZ and a CoT marker per candidate
  (report/atak_package.py);
* ``pdcov.gpx``: GPX 1.1, a track per vehicle (``VehicleTrack``) and a waypoint per
  candidate, for GPS units and mapping apps (report/gpx.py).

Every pin carries its MGRS and UTM references (core/geodesy.grid_references). The builders
are pure: the coverage (``Coverage``), each vehicle's detections (``VehicleDetections``, the
``pdcov.detections`` document as decoded from the bus or read from detections.json) and
flown track in, documents out. ``write_exports`` writes them atomically and says which it
could not write for lack of an extra: the outlines and gaps need ``gis`` (rasterio), as do
the GPX (gpxpy) and the grid references (mgrs, and so the data package's markers), the
overlay, the KMZ and the data package ``plots`` (matplotlib).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pdcov.atomic import atomic_write, write_text_atomic
from pdcov.core.geodesy import (
    Origin,
    deg_rounded,
    enu_to_geodetic,
    geodetic_to_enu,
    grid_references,
)
from pdcov.extras import GIS, GPX, GRID_REFERENCES, PLOTS
from pdcov.report.pin_rank import candidate_ranks
from pdcov.report.search_areas import Coverage, MapLayers, Polygon, map_layers

__all__ = ["Exported", "Pin", "TrackSegment", "VehicleDetections", "VehicleTrack",
           "caltopo_geojson", "every_pin", "pins", "write_detections_geojson",
           "write_exports"]

# One palette for every export (GeoJSON '#rrggbb'; report/kml.py converts it).
OUTLINE_COLORS = ("#f1c40f", "#e67e22", "#27ae60", "#1abc9c", "#2980b9", "#8e44ad")
"""P_D outlines from the lowest threshold to the highest (the target), cycling."""
GAP_COLOR = "#e74c3c"
REFLY_COLOR = "#8e44ad"
PIN_FIGURES = ("rank", "uid", "p_person", "looks", "hits", "mgrs", "utm")
"""What every export says of a pin (docs/protocol.md "detections")."""
CANDIDATE_COLOR = "#ff0000"
DETECTION_COLOR = "#ffa500"


@dataclass(frozen=True, slots=True)
class VehicleDetections:
    """One vehicle's detections and candidates: the ``detections`` and ``candidates``
    entries of a ``pdcov.detections`` document (docs/protocol.md "detections"), whose
    fields the builders read by their JSON names. ``every_detection``: when given, reads
    every detection again (a watcher's log on disk) for detections.geojson, while
    ``detections`` (the latest, in memory) go in the KML; None: ``detections`` are all."""

    vehicle: str
    detections: tuple[Mapping[str, Any], ...] = ()
    candidates: tuple[Mapping[str, Any], ...] = ()
    every_detection: Callable[[], Iterable[Mapping[str, Any]]] | None = None

    def all_detections(self) -> Iterable[Mapping[str, Any]]:
        """Every detection, in the order taken."""
        return self.detections if self.every_detection is None else self.every_detection()

    @classmethod
    def from_doc(cls, doc: Mapping[str, Any]) -> VehicleDetections:
        """From a decoded ``pdcov.detections`` document (bus/detections.py; the same JSON as
        detections.json)."""
        return cls(str(doc["vehicle"]), tuple(doc.get("detections") or ()),
                   tuple(doc.get("candidates") or ()))


@dataclass(frozen=True, slots=True)
class TrackSegment:
    """One flight's positions: ``lat_lon_alt`` (N, 3) WGS84 degrees and m MSL, in time
    order; ``t_unix_s`` (N,) their UTC times (s since 1970; NaN where unknown), None when
    no real time is known (the autopilot's boot clock is none)."""

    lat_lon_alt: np.ndarray
    t_unix_s: np.ndarray | None = None


@dataclass(frozen=True, slots=True)
class VehicleTrack:
    """One vehicle's flown positions: a segment per flight."""

    vehicle: str
    segments: tuple[TrackSegment, ...]

    @classmethod
    def from_enu(cls, vehicle: str, flights_enu: Iterable[np.ndarray | None], origin: Origin,
                 *, heights_msl: bool = True,
                 flights_unix_s: Sequence[np.ndarray | None] = ()) -> VehicleTrack:
        """From each flight's positions (M, 3) ENU m about ``origin`` (None: no position),
        with each flight's UTC times (M,) from ``flights_unix_s`` (s since 1970; none or
        None: no times); ``heights_msl`` False: the origin's ground altitude is unknown (a
        pose CSV's heights above the ground), so the altitudes are too (NaN)."""
        segments = []
        for i, t in enumerate(flights_enu):
            if t is not None and len(t):
                lla = enu_to_geodetic(t, origin)
                if not heights_msl:
                    lla[:, 2] = np.nan
                segments.append(TrackSegment(
                    lla, flights_unix_s[i] if i < len(flights_unix_s) else None))
        return cls(vehicle, tuple(segments))


def tracks_enu(tracks: Sequence[VehicleTrack], origin: Origin) -> np.ndarray | None:
    """Every segment of ``tracks`` (M, 2) in ENU m about ``origin``, one after the other
    with a NaN row between (a line drawn through them breaks there rather than joining two
    vehicles or flights); None without any position."""
    parts = []
    for track in tracks:
        for seg in track.segments:
            lla = np.asarray(seg.lat_lon_alt, dtype=float).reshape(-1, 3)
            alt = np.where(np.isfinite(lla[:, 2]), lla[:, 2], origin.ground_alt_msl_m)
            parts += [geodetic_to_enu(lla[:, 0], lla[:, 1], alt, origin)[:, :2],
                      np.full((1, 2), np.nan)]
    return np.concatenate(parts[:-1]) if parts else None


@dataclass(frozen=True, slots=True)
class Pin:
    """A point to export: a detection or a candidate, at (lon_deg, lat_deg), with its
    properties as detections.geojson carries them."""

    kind: str  # "detection" or "candidate"
    lon_deg: float
    lat_deg: float
    properties: dict[str, Any]

    @property
    def title(self) -> str:
        """A label for a map tool, led by the pin's rank (report/pin_rank.py): 'pin 1:
        person alpha.3fa2c1.3: p_person 0.97, detected 9 of 14 looks'; a detection's 'person
        of pin 1 (alpha.3fa2c1.3) at t 12.5 s'."""
        p = self.properties
        rank = p.get("rank")
        if self.kind == "candidate":
            return (("" if rank is None else f"pin {rank}: ") + f"{p['class']} {p['uid']}: "
                    f"p_person {p['p_person']:.2f}, detected {p['hits']} of {p['looks']} "
                    "looks")
        return (f"{p['class']} of " + ("" if rank is None else f"pin {rank} ")
                + f"({p['uid']}) at t {p['t_boot_s']:.1f} s")

    @property
    def description(self) -> str:
        """The properties as 'name: value' lines."""
        return "\n".join(f"{k}: {_shown(v)}" for k, v in self.properties.items())


def _shown(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return "-" if v is None else str(v)


References = Callable[[float, float], dict[str, str | None]]
"""A pin's ``mgrs`` and ``utm`` properties from its (lat_deg, lon_deg)."""


def _with_references(lat_deg: float, lon_deg: float) -> dict[str, str | None]:
    mgrs, utm = grid_references(lat_deg, lon_deg)
    return {"mgrs": mgrs, "utm": utm}


def _without_references(lat_deg: float, lon_deg: float) -> dict[str, str | None]:
    return {"mgrs": None, "utm": None}


def _pin_references() -> References:
    """The pins' grid references, both None without the mgrs module (looked for once per
    call, not once per pin; ``write_exports`` names the extra)."""
    return _without_references if GRID_REFERENCES.missing() else _with_references


def pins(findings: Sequence[VehicleDetections], coverage: Coverage | None = None
         ) -> list[Pin]:
    """The candidates, then the (in-memory) detections, of every vehicle (in the order
    given). ``pd`` is the P_D of the cell under the point in ``coverage`` when given, else
    the candidate's (the cell's P_D as the daemon sent it); a detection's p_person, looks
    and hits are its candidate's (by uid)."""
    refs, ranks = _pin_references(), candidate_ranks(findings)
    out = [candidate_pin(f.vehicle, c, coverage, refs, ranks) for f in findings
           for c in f.candidates]
    for f in findings:
        by_uid = {c["uid"]: c for c in f.candidates}
        out += (detection_pin(f.vehicle, d, by_uid, coverage, refs, ranks)
                for d in f.detections)
    return out


def candidate_pin(vehicle: str, c: Mapping[str, Any], coverage: Coverage | None,
                  refs: References, ranks: Mapping[tuple[str, str], int]) -> Pin:
    """A candidate entry's pin (``pins``); ``ranks``: report/pin_rank.py's."""
    lat, lon = float(c["lat_deg"]), float(c["lon_deg"])
    return Pin("candidate", lon, lat, {
        "kind": "candidate", "vehicle": vehicle, "uid": c["uid"],
        "rank": ranks.get((vehicle, str(c["uid"]))), "candidate": c["id"],
        "p_person": c["p_person"], "looks": c["looks"], "hits": c["hits"],
        "t_boot_s": c["last_t_boot_s"], "first_t_boot_s": c["first_t_boot_s"],
        "last_t_boot_s": c["last_t_boot_s"], "time_utc": c.get("last_time_utc"),
        "first_time_utc": c.get("first_time_utc"), "last_time_utc": c.get("last_time_utc"),
        "class": c["class"],
        "confidence": c["confidence"], "pd": _cell_pd(coverage, c, c["pd"]), "pfa": c["pfa"],
        "sigma_m": c["sigma_m"], "alt_msl_m": c.get("alt_msl_m"), **refs(lat, lon)})


def detection_pin(vehicle: str, d: Mapping[str, Any], by_uid: Mapping[str, Mapping[str, Any]],
                  coverage: Coverage | None, refs: References,
                  ranks: Mapping[tuple[str, str], int]) -> Pin:
    """A detection entry's pin (``pins``); ``by_uid`` the vehicle's candidates, ``ranks``
    theirs (the detection takes its candidate's)."""
    cand = by_uid.get(d["uid"], {})
    lat, lon = float(d["lat_deg"]), float(d["lon_deg"])
    return Pin("detection", lon, lat, {
        "kind": "detection", "vehicle": vehicle, "uid": d["uid"],
        "rank": ranks.get((vehicle, str(d["uid"]))), "candidate": d["candidate"],
        "p_person": cand.get("p_person"), "looks": cand.get("looks"),
        "hits": cand.get("hits"), "t_boot_s": d["t_boot_s"],
        "time_utc": d.get("time_utc"), "class": d["class"],
        "confidence": d["confidence"], "pd": _cell_pd(coverage, d, cand.get("pd")),
        "sigma_m": d["sigma_m"], "alt_msl_m": d.get("alt_msl_m"), **refs(lat, lon)})


def every_pin(findings: Sequence[VehicleDetections], coverage: Coverage | None = None
              ) -> Iterator[Pin]:
    """As ``pins``, but with every detection (``VehicleDetections.all_detections``), one at
    a time: detections.geojson's."""
    refs, ranks = _pin_references(), candidate_ranks(findings)
    for f in findings:
        for c in f.candidates:
            yield candidate_pin(f.vehicle, c, coverage, refs, ranks)
    for f in findings:
        by_uid = {c["uid"]: c for c in f.candidates}
        for d in f.all_detections():
            yield detection_pin(f.vehicle, d, by_uid, coverage, refs, ranks)


def _cell_pd(coverage: Coverage | None, point: Mapping[str, Any], sent: Any) -> Any:
    if coverage is None:
        return sent
    pd = coverage.pd_at(float(point["x_m"]), float(point["y_m"]))
    return sent if pd is None else round(pd, 6)


def _feature(p: Pin) -> dict[str, Any]:
    return {"type": "Feature", "geometry": _point(p), "properties": p.properties}


def write_detections_geojson(path: Path, all_pins: Iterable[Pin]) -> int:
    """detections.geojson: a Point Feature per pin (RFC 7946: [lon, lat], WGS84; no height,
    as RFC 7946 heights are ellipsoidal and ours MSL: ``alt_msl_m`` is a property), written
    to ``path`` atomically a feature a line as ``all_pins`` yields them (memory: one pin at
    a time); how many features."""
    n = 0
    with atomic_write(path, "wb") as f:
        f.write(b'{"type":"FeatureCollection","features":[\n')
        for p in all_pins:
            f.write((b",\n" if n else b"") + json.dumps(
                _feature(p), allow_nan=False, separators=(",", ":")).encode())
            n += 1
        f.write(b"\n]}\n")
    return n


def _point(p: Pin) -> dict[str, Any]:
    return {"type": "Point", "coordinates": [deg_rounded(p.lon_deg), deg_rounded(p.lat_deg)]}


def caltopo_geojson(layers: MapLayers | None, all_pins: Sequence[Pin], title: str
                    ) -> dict[str, Any]:
    """caltopo.geojson: CalTopo / SARTopo map objects (docs/ground-station.md "CalTopo").

    The properties are those CalTopo writes in its own GeoJSON exports and its API takes:
    ``class`` Shape / Marker / Assignment, ``title``, ``description``; Shapes ``stroke``,
    ``stroke-opacity``, ``stroke-width``, ``fill``, ``fill-opacity`` ('#rrggbb' colours);
    Markers ``marker-color`` (hex without '#', as CalTopo writes it), ``marker-symbol``,
    ``marker-size``, and pdcov's PIN_FIGURES beside them; Assignments ``letter``,
    ``resourceType`` AIR, ``status`` DRAFT. Only
    candidates are exported as markers (detections would bury them: detections.geojson
    has every one)."""
    features: list[dict[str, Any]] = []
    if layers is not None:
        for k, (t, polys) in enumerate(layers.outlines):
            color = OUTLINE_COLORS[k % len(OUTLINE_COLORS)]
            for i, poly in enumerate(polys, start=1):
                features.append(_shape(poly, f"P_D >= {t:g} ({i}/{len(polys)})",
                                       f"free cells whose cumulative P_D is at least {t:g}",
                                       color, 0.1))
        for i, poly in enumerate(layers.gaps, start=1):
            features.append(_shape(poly, f"gap {i} (P_D < {layers.target_pd:g})",
                                   f"free cells below the target P_D {layers.target_pd:g}",
                                   GAP_COLOR, 0.3))
        for i, a in enumerate(layers.refly, start=1):
            features.append({"type": "Feature", "geometry": _polygon(a.polygon),
                             "properties": {
                "class": "Assignment", "letter": f"R{i}", "resourceType": "AIR",
                "status": "DRAFT", "title": f"re-fly R{i}", "area_m2": round(a.area_m2),
                "pod": round(a.pod, 4),
                "description": f"re-fly: {a.gap_cells} cells below P_D "
                               f"{layers.target_pd:g}, {a.area_m2:.0f} m2; POD so far "
                               f"{a.pod:.2f}",
                "stroke": REFLY_COLOR, "stroke-opacity": 1, "stroke-width": 2,
                "fill": REFLY_COLOR, "fill-opacity": 0.1}})
    for p in all_pins:
        if p.kind == "candidate":
            features.append({"type": "Feature", "geometry": _point(p), "properties": {
                "class": "Marker", "title": p.title, "description": p.description,
                "marker-color": CANDIDATE_COLOR.lstrip("#").upper(),
                "marker-symbol": "point", "marker-size": "1",
                **{k: p.properties[k] for k in PIN_FIGURES}}})
    doc: dict[str, Any] = {"type": "FeatureCollection", "features": features,
                           "pdcov": {"title": title}}
    if layers is not None:
        doc["pdcov"].update(target_pd=layers.target_pd, gaps_total=layers.gaps_total,
                            gaps_exported=len(layers.gaps))
    return doc


def _polygon(poly: Polygon) -> dict[str, Any]:
    return {"type": "Polygon", "coordinates": poly}


def _shape(poly: Polygon, title: str, description: str, color: str, fill_opacity: float
           ) -> dict[str, Any]:
    return {"type": "Feature", "geometry": _polygon(poly), "properties": {
        "class": "Shape", "title": title, "description": description, "stroke": color,
        "stroke-opacity": 1, "stroke-width": 2, "fill": color, "fill-opacity": fill_opacity}}


@dataclass(frozen=True, slots=True)
class Exported:
    """What ``write_exports`` wrote (file names) and what not, one line each, and the pins
    it exported (``pins``: the candidates ranked, then the in-memory detections)."""

    files: tuple[str, ...]
    not_written: tuple[str, ...] = field(default=())
    pins: tuple[Pin, ...] = field(default=())


def write_exports(out_dir: str | Path, coverage: Coverage | None,
                  findings: Sequence[VehicleDetections], *, title: str,
                  tracks: Sequence[VehicleTrack] = ()) -> Exported:
    """Write the exports into ``out_dir`` (which must exist), each atomically; without a
    coverage (no grid yet) the files hold the detections only, and ``pdcov.gpx`` the
    ``tracks`` given. Raises OutputError (naming the file) when one cannot be written; the
    files already written stay."""
    from pdcov.report.kml import icon_pngs, kml_document, kmz_bytes, overlay_png

    out = Path(out_dir)
    all_pins = pins(findings, coverage)
    files, not_written = [], []
    refs_missing = GRID_REFERENCES.message()
    if refs_missing is not None and all_pins:
        not_written.append(f"the pins' mgrs and utm properties (null): {refs_missing}")
    write_detections_geojson(out / "detections.geojson", every_pin(findings, coverage))
    layers = None
    if coverage is not None:
        gis_missing = GIS.message("P_D outlines, gaps and re-fly areas need")
        if gis_missing is None:
            layers = map_layers(coverage)
        else:
            not_written.append(f"caltopo.geojson, pdcov.kml without outlines: {gis_missing}")
    _write_json(out / "caltopo.geojson", caltopo_geojson(layers, all_pins, title))
    files += ["detections.geojson", "caltopo.geojson"]
    overlay = None
    if coverage is not None:
        plots_missing = PLOTS.message("the P_D overlay needs")
        if plots_missing is None:
            overlay = overlay_png(coverage)
            with atomic_write(out / "pd_overlay.png", "wb") as f:
                f.write(overlay.png)
            files.append("pd_overlay.png")
        else:
            not_written.append(f"pd_overlay.png, pdcov.kmz, pdcov_atak.zip: {plots_missing}")
    icons = icon_pngs()
    for name, png in icons.items():  # before the KML that refers to them
        with atomic_write(out / name, "wb") as f:
            f.write(png)
        files.append(name)
    doc = kml_document(layers, all_pins, overlay, title)
    with atomic_write(out / "pdcov.kml", "wb") as f:
        f.write(doc)
    files.append("pdcov.kml")
    if overlay is not None:
        kmz = kmz_bytes(doc, overlay, icons)
        with atomic_write(out / "pdcov.kmz", "wb") as f:
            f.write(kmz)
        files.append("pdcov.kmz")
        if refs_missing is None or all(p.kind != "candidate" for p in all_pins):
            from pdcov.report.atak_package import write_atak_package

            files.append(write_atak_package(out, kmz, all_pins, title))
        else:
            not_written.append(f"pdcov_atak.zip (its markers' remarks): {refs_missing}")
    gpx_missing = GPX.message()
    if gpx_missing is None:
        from pdcov.report.gpx import gpx_document

        with atomic_write(out / "pdcov.gpx", "wb") as f:
            f.write(gpx_document(tracks, all_pins, title))
        files.append("pdcov.gpx")
    else:
        not_written.append(f"pdcov.gpx: {gpx_missing}")
    return Exported(tuple(files), tuple(not_written), tuple(all_pins))


def _write_json(path: Path, doc: dict[str, Any]) -> None:
    write_text_atomic(path, json.dumps(doc, allow_nan=False, separators=(",", ":")) + "\n")
