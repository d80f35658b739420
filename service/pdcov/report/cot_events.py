"""Cursor-on-Target event XML, with no I/O: the event skeleton every pdcov event shares and
the pin's event, for the live feed (ground/cot.py, ``pdcov watch --cot``) and the ATAK data
package (report/atak_package.py) alike.

A pin (a candidate) is an unknown ground object (CANDIDATE_TYPE: nobody has looked at it
yet), uid its pin's ``uid`` (docs/protocol.md "detections": durable across the daemon's
restarts, so a pin keeps its TAK marker), ``ce`` its 90 % circular error, its p_person,
looks and hits, MGRS and UTM references in the remarks (core/geodesy.py
``grid_references``: needs mgrs), linked to its aircraft (``aircraft_uid``).

Heights: CoT's ``hae`` is above the WGS84 ellipsoid and pdcov's are MSL (pdcov has no
geoid model), so every point says its height is unknown (9999999, CoT's own value) and
the MSL altitude is in the remarks.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from typing import Any

from pdcov.core.geodesy import deg_text, grid_references
from pdcov.core.utc_clock import utc_text

__all__ = ["AIRCRAFT_TYPE", "CANDIDATE_TYPE", "CE90_PER_SIGMA", "UNKNOWN", "aircraft_uid",
           "candidate_event", "cot_time", "event_element", "tenths"]

AIRCRAFT_TYPE = "a-f-A-M-F-Q"
"""MIL-STD-2525 friendly air, unmanned aerial vehicle: the UAV symbol TAK clients draw."""
CANDIDATE_TYPE = "a-u-G"
"""Unknown ground object."""
UNKNOWN = "9999999.0"
"""CoT's value for an unknown ce, le or hae."""
CE90_PER_SIGMA = 2.146
"""90 % circular error of a circular normal distribution, in units of its 1-sigma."""


def cot_time(unix_s: float) -> str:
    """A CoT time: UTC, ISO 8601 to the millisecond, 'Z' (core/utc_clock.utc_text)."""
    text = utc_text(unix_s)
    if text is None:
        raise ValueError(f"CoT time {unix_s!r}: expected a finite UTC time (s)")
    return text


def event_element(uid: str, cot_type: str, how: str, lat_deg: float, lon_deg: float,
                  ce: str, now_unix_s: float, stale_s: float, observed_utc: str | None = None
                  ) -> tuple[ET.Element, ET.Element]:
    """An ``<event>`` made at ``now_unix_s``, stale ``stale_s`` later, with its ``<point>``
    (hae and le unknown), and its empty ``<detail>``. ``observed_utc``: when what it
    describes was seen (ISO 8601 UTC, a detection's time_utc), its ``time`` and ``start``;
    None: ``now_unix_s``."""
    now = cot_time(now_unix_s)
    event = ET.Element("event", version="2.0", uid=uid, type=cot_type, how=how,
                       time=observed_utc or now, start=observed_utc or now,
                       stale=cot_time(now_unix_s + stale_s))
    ET.SubElement(event, "point", lat=deg_text(lat_deg), lon=deg_text(lon_deg), hae=UNKNOWN,
                  ce=ce, le=UNKNOWN)
    return event, ET.SubElement(event, "detail")


def tenths(v: float) -> str:
    """A CoT figure to 0.1."""
    return f"{v:.1f}"


def aircraft_uid(vehicle_id: str) -> str:
    return f"pdcov-{vehicle_id}"


def candidate_event(vehicle_id: str, c: dict[str, Any], now_unix_s: float, stale_s: float,
                    *, archive: bool = False) -> bytes:
    """A candidate's event (a detections payload's candidate entry): uid the pin's, how
    "m-f" (computed from the pose and the pixels), ce its 90 % circle (needs mgrs: the
    COT extra), ``time`` and ``start`` its last detection's ``last_time_utc`` when known.
    ``archive``: with TAK's ``<archive/>`` detail, which keeps the marker across the
    client's restarts (a data package's markers)."""
    event, detail = event_element(c["uid"], CANDIDATE_TYPE, "m-f",
                                  float(c["lat_deg"]), float(c["lon_deg"]),
                                  tenths(CE90_PER_SIGMA * float(c["sigma_m"])), now_unix_s,
                                  stale_s, c.get("last_time_utc"))
    ET.SubElement(detail, "contact", callsign=f"{c['class']} {c['p_person']:.2f} {c['uid']}")
    ET.SubElement(detail, "link", uid=aircraft_uid(vehicle_id), type=AIRCRAFT_TYPE,
                  relation="p-p")
    if archive:
        ET.SubElement(detail, "archive")
    alt = c.get("alt_msl_m")
    mgrs, utm = grid_references(float(c["lat_deg"]), float(c["lon_deg"]))
    ET.SubElement(detail, "remarks").text = (
        f"{c['class']} pin {c['uid']}: p_person {c['p_person']:.4f}, detected {c['hits']} "
        f"of {c['looks']} looks; cell P_D {c['pd']:.2f}, P_FA {c['pfa']:.3f}; best "
        f"confidence {c['confidence']:.2f}" + ("" if alt is None else f"; {alt:.1f} m MSL")
        + f"; MGRS {mgrs}" + ("" if utm is None else f"; UTM {utm}"))
    return ET.tostring(event)
