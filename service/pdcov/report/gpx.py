"""GPX 1.1 of the exports (report/exports.py) for GPS units and mapping apps, written with
gpxpy: a track (``trk``) per vehicle, named by it, with a segment (``trkseg``) per flight,
and a waypoint (``wpt``) per candidate, named by its pin's uid.

Latitudes and longitudes are WGS84 to DEG_DECIMALS places; elevations are metres above
mean sea level (as GPS units show them), to the centimetre: a track point's the vehicle's
(or, from a pose CSV, the camera's), a waypoint's the ground point's where known (none
otherwise). A track point has a ``time`` (UTC, ISO 8601) only where a real time is known
(the autopilot's real-time clock, core/utc_clock.py; its boot clock is none), a waypoint
its candidate's last detection's (``time_utc``) when known. A track of more than
MAX_TRACK_POINTS positions keeps every n-th (and each flight's last), so that a handheld
unit takes it whole and the watcher's rewrites stay cheap.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import datetime, timezone

import numpy as np

from pdcov.core.geodesy import deg_rounded
from pdcov.report.exports import Pin, TrackSegment, VehicleTrack

MAX_TRACK_POINTS = 10_000
"""Track points a vehicle's track keeps at most (give or take a flight's last)."""
CREATOR = "pdcov"


def thinned(segments: Sequence[TrackSegment], max_points: int = MAX_TRACK_POINTS
            ) -> list[TrackSegment]:
    """``segments`` without their non-finite positions, every n-th point kept (n the
    smallest that keeps at most ``max_points`` of them all) and each segment's last; empty
    segments dropped."""
    finite = []
    for s in segments:
        a = np.asarray(s.lat_lon_alt, dtype=float).reshape(-1, 3)
        ok = np.isfinite(a[:, :2]).all(axis=1)
        if ok.any():
            finite.append(TrackSegment(a[ok], None if s.t_unix_s is None
                                       else np.asarray(s.t_unix_s, dtype=float)[ok]))
    step = max(1, math.ceil(sum(len(s.lat_lon_alt) for s in finite) / max_points))
    out = []
    for s in finite:
        n = len(s.lat_lon_alt)
        keep = np.unique(np.r_[np.arange(0, n, step), n - 1])
        out.append(TrackSegment(s.lat_lon_alt[keep],
                                None if s.t_unix_s is None else s.t_unix_s[keep]))
    return out


def _time(t_unix_s: float | None) -> datetime | None:
    if t_unix_s is None or not math.isfinite(t_unix_s):
        return None
    return datetime.fromtimestamp(round(t_unix_s, 3), tz=timezone.utc)


def _utc_time(text: str | None) -> datetime | None:
    return None if text is None else datetime.fromisoformat(text)


def _elevation(alt_msl_m: float | None) -> float | None:
    if alt_msl_m is None or not math.isfinite(alt_msl_m):
        return None
    return round(float(alt_msl_m), 2)


def waypoint_description(p: Pin) -> str:
    """A candidate waypoint's description: its title ('pin 1: person uav1.3fa2c1.3:
    p_person 0.97, detected 9 of 14 looks'), its 1-sigma horizontal uncertainty and MGRS."""
    mgrs = p.properties.get("mgrs")
    return (f"{p.title}; sigma {p.properties['sigma_m']:.1f} m"
            + ("" if mgrs is None else f"; MGRS {mgrs}"))


def gpx_document(tracks: Sequence[VehicleTrack], all_pins: Sequence[Pin], title: str
                 ) -> bytes:
    """pdcov.gpx (UTF-8 bytes): a ``trk`` per vehicle of ``tracks`` that has a position,
    then a ``wpt`` per candidate of ``all_pins`` (detections are not waypoints: they would
    bury the pins)."""
    import gpxpy.gpx

    doc = gpxpy.gpx.GPX()
    doc.creator = CREATOR
    doc.name = title
    for track in tracks:
        segments = thinned(track.segments)
        if not segments:
            continue
        trk = gpxpy.gpx.GPXTrack(name=track.vehicle)
        for s in segments:
            seg = gpxpy.gpx.GPXTrackSegment()
            times: list[float | None] = ([None] * len(s.lat_lon_alt) if s.t_unix_s is None
                                         else s.t_unix_s.tolist())
            seg.points = [gpxpy.gpx.GPXTrackPoint(
                latitude=deg_rounded(lat), longitude=deg_rounded(lon),
                elevation=_elevation(alt), time=_time(t))
                for (lat, lon, alt), t in zip(s.lat_lon_alt.tolist(), times, strict=True)]
            trk.segments.append(seg)
        doc.tracks.append(trk)
    for p in all_pins:
        if p.kind == "candidate":
            doc.waypoints.append(gpxpy.gpx.GPXWaypoint(
                latitude=deg_rounded(p.lat_deg), longitude=deg_rounded(p.lon_deg),
                elevation=_elevation(p.properties.get("alt_msl_m")),
                name=str(p.properties["uid"]), description=waypoint_description(p),
                type=str(p.properties["class"]), time=_utc_time(p.properties.get("time_utc"))))
    return doc.to_xml(version="1.1").encode("utf-8")


def route_document(name: str, description: str, lat_lon_alt: np.ndarray) -> bytes:
    """A planned mission as a GPX route (UTF-8 bytes): one ``rte`` named ``name`` with a
    ``rtept`` per waypoint ('WP 1', ...) of ``lat_lon_alt`` (N, 3: degrees, m MSL; NaN
    altitudes left out)."""
    import gpxpy.gpx

    doc = gpxpy.gpx.GPX()
    doc.creator = CREATOR
    doc.name = name
    rte = gpxpy.gpx.GPXRoute(name=name, description=description)
    rte.points = [gpxpy.gpx.GPXRoutePoint(latitude=deg_rounded(lat), longitude=deg_rounded(lon),
                                          elevation=_elevation(alt), name=f"WP {k}")
                  for k, (lat, lon, alt) in enumerate(lat_lon_alt.tolist(), 1)]
    doc.routes.append(rte)
    return doc.to_xml(version="1.1").encode("utf-8")
