"""Cursor-on-Target events for ``pdcov watch --cot URL``, with no I/O: the watcher's state,
``now_s`` (monotonic) and ``now_unix_s`` (for the events' times) in, CoT XML events out
(ground/cot_feed.py sends them with pytak).

Per vehicle (docs/ground-station.md "Cursor-on-Target"):

* the aircraft, uid ``pdcov-<vehicle>``, type AIRCRAFT_TYPE, at its status position, with
  a ``<track>`` detail (``speed`` m/s over the ground and ``course`` degrees true: the
  vehicle's velocity between its last two status positions, ``track_between``; none
  without two such positions) and a ``<sensor>`` detail (the CoT sensor schema ATAK draws
  as a field-of-view wedge: ``azimuth`` degrees true, ``elevation`` degrees (-90 straight
  down), ``fov`` and ``vfov`` horizontal and vertical degrees, ``range`` metres) measured
  on the camera's current ground footprint, so that a gimbal's pointing is shown as it is;
  sent when the position is new, at most every ``aircraft_period_s``, stale after
  ``aircraft_stale_s`` (a silent vehicle fades on the map instead of standing still);
* each candidate (report/cot_events.py ``candidate_event``: the pin's event, shared with
  the ATAK data package) sent when it changed and again every ``candidate_period_s``,
  stale after ``candidate_stale_s``; no ``<track>``: a pin stands still.

Heights: unknown to CoT, MSL in the remarks (report/cot_events.py). At most
``max_events_per_s`` events go out (a token bucket): aircraft first, then changed
candidates, then the repeats.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
import shapely

from pdcov.core.geodesy import Origin, geodetic_to_enu
from pdcov.ground.feed import VehicleFeed
from pdcov.report.cot_events import (
    AIRCRAFT_TYPE,
    UNKNOWN,
    aircraft_uid,
    candidate_event,
    event_element,
    tenths,
)

__all__ = ["CotSchedule", "Sensor", "Track", "aircraft_event", "sensor_from_footprint",
           "track_between"]

NADIR_SHARE = 0.05
"""A footprint centre nearer the point below the aircraft than this share of its height is
taken as straight down: the sensor azimuth is then the vehicle's heading."""
TRACK_MAX_GAP_S = 5.0
"""Two status positions further apart in time (s) give no velocity: a status lost, a
vehicle that stopped talking."""
HOVER_SPEED_MPS = 0.5
"""Below this ground speed (m/s) the course is the vehicle's heading: a hover's drift points
nowhere in particular."""


@dataclass(frozen=True, slots=True)
class Sensor:
    """The CoT ``<sensor>`` detail: degrees and metres (module docstring)."""

    azimuth_deg: float
    elevation_deg: float
    fov_deg: float
    vfov_deg: float
    range_m: float


def sensor_from_footprint(lat_deg: float, lon_deg: float, height_m: float,
                          heading_deg: float | None, ring_lon_lat_deg: Any) -> Sensor | None:
    """The sensor wedge of a camera ``height_m`` above flat ground whose footprint is the
    ring (lon, lat) degrees, as a level pinhole camera looking at the footprint's centroid
    sees it: azimuth, elevation and slant range of that line of sight (azimuth the heading
    when the centroid lies below the aircraft, NADIR_SHARE), and the angles the footprint
    spans across (fov) and along (vfov) it, from the footprint's vertices in that camera's
    image plane (exact for a footprint whose corners are the picture's). None without a
    usable footprint or height."""
    ring = np.asarray(ring_lon_lat_deg, dtype=float).reshape(-1, 2)
    if len(ring) < 3 or not height_m > 0 or not np.isfinite(ring).all():
        return None
    here = Origin(lat_deg, lon_deg, 0.0)
    enu = geodetic_to_enu(ring[:, 1], ring[:, 0], 0.0, here)[:, :2]
    poly = shapely.Polygon(enu)
    if not poly.is_valid or poly.area <= 0:
        return None
    c = np.array(poly.centroid.coords[0])
    d = float(np.hypot(*c))
    az = math.radians(heading_deg or 0.0) if d < NADIR_SHARE * height_m \
        else math.atan2(c[0], c[1])
    los = np.array([c[0], c[1], -height_m])
    b = los / np.linalg.norm(los)  # the line of sight, ENU
    right = np.array([math.cos(az), -math.sin(az), 0.0])  # level, across the azimuth
    up = np.cross(right, b)
    rays = np.c_[enu, np.full(len(enu), -height_m)]
    depth = rays @ b
    x, y = np.arctan((rays @ right) / depth), np.arctan((rays @ up) / depth)
    return Sensor(azimuth_deg=math.degrees(az) % 360.0,
                  elevation_deg=math.degrees(math.asin(float(b[2]))),
                  fov_deg=math.degrees(float(x.max() - x.min())),
                  vfov_deg=math.degrees(float(y.max() - y.min())),
                  range_m=float(np.linalg.norm(los)))


@dataclass(frozen=True, slots=True)
class Track:
    """The CoT ``<track>`` detail: ``speed_mps`` over the ground (horizontal), ``course_deg``
    the direction of motion, degrees clockwise from true north in [0, 360)."""

    speed_mps: float
    course_deg: float


def track_between(before: dict[str, Any], after: dict[str, Any]) -> Track | None:
    """The vehicle's mean velocity between two status poses {lat_deg, lon_deg, t_s (the
    autopilot's clock, s), heading_deg}: the distance over the ground (WGS84, in the plane
    east and north of ``before``) over the time between them. The course is the heading
    of ``after`` below HOVER_SPEED_MPS (the direction of motion when it has none). None
    without both times, or when they are not 0 < dt <= TRACK_MAX_GAP_S apart."""
    t0, t1 = before.get("t_s"), after.get("t_s")
    if t0 is None or t1 is None or not 0.0 < float(t1) - float(t0) <= TRACK_MAX_GAP_S:
        return None
    e, n = geodetic_to_enu(float(after["lat_deg"]), float(after["lon_deg"]), 0.0,
                           Origin(float(before["lat_deg"]), float(before["lon_deg"])))[:2]
    speed = float(math.hypot(e, n)) / (float(t1) - float(t0))
    heading = after.get("heading_deg")
    course = math.degrees(math.atan2(e, n)) if speed >= HOVER_SPEED_MPS or heading is None \
        else float(heading)
    return Track(speed, course % 360.0)


def _bearing(deg: float) -> str:
    """Degrees clockwise from true north, to 0.1 in [0, 360): 359.97 is "0.0"."""
    return tenths(round(deg, 1) % 360.0)


def aircraft_event(vehicle_id: str, pose: dict[str, Any], sensor: Sensor | None,
                   now_unix_s: float, stale_s: float, track: Track | None = None) -> bytes:
    """The aircraft's event from a status ``pose`` {lat_deg, lon_deg, alt_msl_m,
    heading_deg}: its position (how "m-g": GPS), call sign, track (speed and course, both
    or none: TAK's track schema requires both) and the sensor."""
    event, detail = event_element(aircraft_uid(vehicle_id), AIRCRAFT_TYPE, "m-g",
                                  float(pose["lat_deg"]), float(pose["lon_deg"]), UNKNOWN,
                                  now_unix_s, stale_s)
    ET.SubElement(detail, "contact", callsign=f"pdcov {vehicle_id}")
    if track is not None:
        ET.SubElement(detail, "track", course=_bearing(track.course_deg),
                      speed=f"{track.speed_mps:.2f}")
    if sensor is not None:
        ET.SubElement(detail, "sensor", azimuth=_bearing(sensor.azimuth_deg),
                      elevation=tenths(sensor.elevation_deg), fov=tenths(sensor.fov_deg),
                      vfov=tenths(sensor.vfov_deg), range=tenths(sensor.range_m),
                      model="pdcov camera footprint", type="r-e")
    alt = pose.get("alt_msl_m")
    remarks = "pdcov coverage aircraft" + ("" if alt is None else f", {alt:.1f} m MSL")
    ET.SubElement(detail, "remarks").text = remarks
    return ET.tostring(event)


@dataclass(slots=True)
class CotSchedule:
    """Which events to send now (module docstring): call ``due`` every tick."""

    aircraft_period_s: float = 1.0
    aircraft_stale_s: float = 10.0
    candidate_period_s: float = 15.0
    candidate_stale_s: float = 300.0
    max_events_per_s: float = 20.0
    sent: int = 0
    _tokens: float = 0.0
    _last_s: float | None = None
    _sent_at: dict[tuple[str, ...], tuple[float, Any]] = field(default_factory=dict)
    """(kind, vehicle[, candidate uid]) -> (when sent, what it said)."""
    _tracks: dict[str, tuple[dict[str, Any], Track | None]] = field(default_factory=dict)
    """vehicle -> (the last status pose seen, the track from the one before to it)."""

    def due(self, feeds: Iterable[VehicleFeed], now_s: float, now_unix_s: float
            ) -> list[bytes]:
        """The events to send at ``now_s`` (monotonic s; ``now_unix_s`` stamps them), at
        most what the rate allows; the rest wait for the next call."""
        refill = self.max_events_per_s if self._last_s is None \
            else (now_s - self._last_s) * self.max_events_per_s
        self._tokens = min(self.max_events_per_s, self._tokens + max(0.0, refill))
        self._last_s = now_s
        ranked: list[tuple[int, tuple[str, ...], Any, Callable[[], bytes]]] = []
        for feed in feeds:
            vid = feed.vehicle_id
            pose = (feed.status or {}).get("pose")
            if isinstance(pose, dict):
                at = (pose.get("t_s"), pose.get("lat_deg"), pose.get("lon_deg"))
                track = self._track(vid, pose)
                last = self._sent_at.get(("a", vid))
                if last is None or (last[1] != at
                                    and now_s - last[0] >= self.aircraft_period_s):
                    ranked.append((0, ("a", vid), at, partial(
                        aircraft_event, vid, pose, _sensor(feed, pose), now_unix_s,
                        self.aircraft_stale_s, track)))
            for uid, c in feed.candidates.items():
                said = (c["hits"], c["looks"], c["p_person"], c["lat_deg"], c["lon_deg"],
                        c["sigma_m"])
                last = self._sent_at.get(("c", vid, uid))
                changed = last is None or last[1] != said
                if changed or (last is not None and now_s - last[0] >= self.candidate_period_s):
                    ranked.append((1 if changed else 2, ("c", vid, uid), said, partial(
                        candidate_event, vid, c, now_unix_s, self.candidate_stale_s)))
        ranked.sort(key=lambda r: r[0])
        out = []
        for _, key, said, build in ranked:
            if self._tokens < 1.0:
                break
            self._tokens -= 1.0
            self._sent_at[key] = (now_s, said)
            out.append(build())
        self.sent += len(out)
        return out

    def _track(self, vehicle_id: str, pose: dict[str, Any]) -> Track | None:
        """The vehicle's track at ``pose``: from the pose seen before it (every status pose
        is seen: statuses come once a second, ``due`` runs more often)."""
        seen = self._tracks.get(vehicle_id)
        at = (pose.get("t_s"), pose.get("lat_deg"), pose.get("lon_deg"))
        if seen is not None and (seen[0].get("t_s"), seen[0].get("lat_deg"),
                                 seen[0].get("lon_deg")) == at:
            return seen[1]
        track = None if seen is None else track_between(seen[0], pose)
        self._tracks[vehicle_id] = (dict(pose), track)
        return track


def _sensor(feed: VehicleFeed, pose: dict[str, Any]) -> Sensor | None:
    """The sensor wedge from the vehicle's footprint and its height over the origin's
    ground (the grid's flat ground)."""
    geom = (feed.footprint or {}).get("geometry")
    origin = ((feed.status or {}).get("grid") or {}).get("origin") or {}
    ground, alt = origin.get("ground_alt_msl_m"), pose.get("alt_msl_m")
    if not isinstance(geom, dict) or ground is None or alt is None:
        return None
    return sensor_from_footprint(float(pose["lat_deg"]), float(pose["lon_deg"]),
                                 float(alt) - float(ground), pose.get("heading_deg"),
                                 geom["coordinates"][0])
